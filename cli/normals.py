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
    help="Neighbours for the PCA estimate [normals.k].",
)
@click.option(
    "--radius",
    type=click.FloatRange(0, min_open=True),
    default=None,
    help="PCA neighbourhood radius in input units [normals.radius].",
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
    from recon.kernels.options import thread_count
    from recon.normals import compute_normals

    cfg = build_config(config_path, preset, overrides)
    cfg = with_values(
        cfg,
        normals={
            "k": k,
            "radius": radius,
            "orient_k": orient_k,
            "viewpoint": viewpoint,
            "orientation": orientation,
            "mode": mode,
        },
        io={"ascii": True if ascii_ else None},
    )
    if threads is not None:
        cfg = apply_overrides(cfg, {"threads": threads})
    if not output_path.is_dir():  # (a folder: check_output_path says so)
        check_points_output(output_path)  # before --mkdir makes a folder for a refused name
    output_path = check_output_path(output_path, inputs=[input_path], mkdir=mkdir)
    keep_freed_memory()  # one command in this process: reuse freed memory (recon/heap.py)
    cloud = read_points(
        input_path, max_points=cfg.io.max_points, merge_duplicates=cfg.io.merge_duplicates
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
                f"estimated (k={info['k']}), oriented {info['orientation']}: "
                f"{info['n_components']} component(s), {info['n_guessed']} guessed"
            )
        click.echo(f"{output_path}: {len(cloud):,} points, {how}, {info['time_s']:.2f}s", err=True)
