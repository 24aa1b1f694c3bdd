"""``oprecon normals``: write a consistently oriented point cloud."""

from __future__ import annotations

from pathlib import Path

import click

from recon.config import NormalsConfig

from .common import (
    build_config,
    catch_errors,
    common_run_options,
    config_options,
    parse_viewpoint,
    threads_option,
)

#: The orientation rules, from the config (importing recon.normals here would load scipy at
#: startup, slowing every command and widening the window where Ctrl-C hits an import).
ORIENTATIONS = NormalsConfig.__dataclass_fields__["orientation"].metadata["choices"]


@click.command("normals")
@click.argument("input_path", metavar="IN", type=click.Path(path_type=Path))
@click.option(
    "-o",
    "--output",
    "output_path",
    required=True,
    type=click.Path(path_type=Path),
    help="Output PLY point cloud with nx, ny, nz.",
)
@click.option(
    "--k",
    type=click.IntRange(3, 500),
    default=None,
    help="Neighbours for the PCA estimate, used as given: an explicit --k turns off "
    "normals.auto_scale, which raises a configured k on noisy data (up to 4x, at most 500). "
    "normals.per_point_scale may still take a point's 2k or 4k nearest where its k are not "
    "thin [normals.k].",
)
@click.option(
    "--radius",
    type=click.FloatRange(0, min_open=True),
    default=None,
    help="Of each point's k nearest, only those within this distance (input units, the "
    "point itself included) go into its PCA; a point with fewer than 3 within it takes its "
    "k nearest. Refused when more than half the points would (the message gives a radius "
    "that works); the summary counts the points it trimmed and those that fell back. Turns "
    "off normals.per_point_scale [normals.radius].",
)
@click.option(
    "--orient-k",
    type=click.IntRange(3, 100),
    default=None,
    help="Neighbours in the orientation graph [normals.orient_k].",
)
@click.option(
    "--viewpoint",
    callback=parse_viewpoint,
    metavar="X,Y,Z",
    help="Scanner position (file coordinates); normals face it [normals.viewpoint].",
)
@click.option(
    "--orientation",
    type=click.Choice(ORIENTATIONS),
    default=None,
    help="Global sign rule [normals.orientation].",
)
@click.option(
    "--normals",
    "mode",
    type=click.Choice(("auto", "estimate", "input")),
    default=None,
    help="auto: keep the file's normals if present; estimate: always estimate; input: "
    "require them [normals.mode].",
)
@click.option(
    "--remove-outliers",
    is_flag=True,
    default=None,
    help="Remove stray points before the normals, as oprecon fit --remove-outliers does: "
    "those whose mean distance to their io.outlier_k nearest exceeds the median of that "
    "distance by io.outlier_std_ratio robust standard deviations and is over twice the "
    "median; the output keeps the rest "
    "(a cleaned cloud for a tiled fit) [io.outliers: statistical].",
)
@click.option("--ascii", "ascii_", is_flag=True, default=None, help="ASCII PLY [io.ascii].")
@click.option("--mkdir", is_flag=True, help="Create the output folder if missing.")
@config_options
@threads_option
@common_run_options
@catch_errors
def command(
    input_path: Path,
    output_path: Path,
    k: int | None,
    radius: float | None,
    orient_k: int | None,
    viewpoint: list[float] | None,
    orientation: str | None,
    mode: str | None,
    remove_outliers: bool | None,
    ascii_: bool | None,
    mkdir: bool,
    config_path: Path | None,
    preset: str | None,
    overrides: tuple[str, ...],
    threads: int | None,
    quiet: bool,
) -> None:
    """Estimate (or check) normals of IN, orient them consistently, write an oriented PLY.

    Normals come from PCA over the k nearest neighbours and are oriented with a minimum
    spanning tree over the k-NN graph (Hoppe et al. 1992), then per connected component
    outward (closed shapes), toward --viewpoint (range scans), or to the +z side of the
    best-fit plane (open surfaces). Output coordinates are the input's (absolute).
    Options override --config/--preset/--set.

    \b
    Examples:
      oprecon normals bunny.ply -o bunny-oriented.ply
      oprecon normals scan.xyz -o out/scan.ply --mkdir --viewpoint 0,0,1000
      oprecon normals noisy.ply -o n.ply --k 60 --orientation outward
      oprecon normals scan.ply -o n.ply --preset open_scan --set normals.orient_k=15
    """
    from recon.config import apply_overrides, with_values
    from recon.heap import keep_freed_memory
    from recon.io import check_output_path, check_points_output, read_points, write_points
    from recon.io.outliers import outlier_removal
    from recon.kernels.options import thread_count
    from recon.normals import compute_normals

    cfg = build_config(config_path, preset, overrides)
    cfg = with_values(
        cfg,
        normals={
            "k": k,
            "auto_scale": False if k is not None else None,  # an explicit k is used as given
            "radius": radius,
            "orient_k": orient_k,
            "viewpoint": viewpoint,
            "orientation": orientation,
            "mode": mode,
        },
        io={
            "ascii": True if ascii_ else None,
            "outliers": "statistical" if remove_outliers else None,
        },
    )
    if threads is not None:
        cfg = apply_overrides(cfg, {"threads": threads})
    if not output_path.is_dir():  # (a folder: check_output_path says so)
        check_points_output(output_path)  # before --mkdir makes a folder for a refused name
    output_path = check_output_path(output_path, inputs=[input_path], mkdir=mkdir)
    keep_freed_memory()  # one command in this process: reuse freed memory (recon/heap.py)
    cloud = read_points(
        input_path,
        max_points=cfg.io.max_points,
        merge_duplicates=cfg.io.merge_duplicates,
        all_properties=True,  # a PLY's every per-point scalar goes along (intensity as float)
        outliers=outlier_removal(cfg.io),
    )
    with thread_count(cfg.threads):
        normals, info = compute_normals(cloud, cfg.normals)
    import numpy as np

    # the file's colours and per-point scalars go along: normals, then fit, keeps the colours
    rgb = None if cloud.colors is None else np.round(255.0 * cloud.colors).astype(np.uint8)
    write_points(
        output_path,
        cloud.points,
        normals,
        origin=cloud.origin,
        ascii=cfg.io.ascii,
        colors=rgb,
        vertex_properties=dict(cloud.attributes) or None,
    )
    if not quiet:
        if info["source"] == "input":
            how = "kept the file's normals"
            if info.get("n_filled"):
                how += f" ({info['n_filled']} invalid re-estimated)"
            if "orientation" in info:
                how += f", oriented {info['orientation']}"
        else:
            how = (
                f"{_estimated(info)}, oriented {info['orientation']}: "
                f"{info['n_components']} component(s), {info['n_guessed']} guessed"
            )
        removed = cloud.info.get("n_outliers_removed", 0)
        kept = f"{len(cloud):,} points" + (
            f" ({removed:,} statistical outliers removed)" if removed else ""
        )
        click.echo(f"{output_path}: {kept}, {how}, {info['time_s']:.2f}s", err=True)


def _estimated(info: dict) -> str:
    """``estimated (k=20)`` and what changed k or the neighbourhoods: the noise rule
    (``normals.auto_scale``), a radius (points trimmed, points that fell back)."""
    k = info["k"]
    radius = info.get("radius")
    if radius is None:
        text = f"estimated (k={k})"
    elif info["n_radius_trimmed"] == 0 and info["n_radius_fallback"] == 0:
        text = (
            f"estimated (k={k}; radius {radius:g} holds every point's {k} nearest: it trims none)"
        )
    else:
        text = (
            f"estimated (k={k} within radius {radius:g}: {info['n_radius_trimmed']:,} points "
            f"took fewer of their {k} nearest, {info['n_radius_fallback']:,} had fewer than 3 "
            f"within it and took all {k})"
        )
    if "k_configured" in info:
        text += (
            f", k raised from normals.k={info['k_configured']} on noisy data (normals.auto_scale)"
        )
    return text
