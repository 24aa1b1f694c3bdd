"""``oprecon fit``: the main job."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

import click

from recon.config import apply_overrides, with_values
from recon.errors import OpreconError

from .common import (
    COMPILE_TIMES_NOTE,
    build_config,
    catch_errors,
    common_run_options,
    config_options,
    format_rows,
    mesh_output_option,
    note_first_compile,
    parse_viewpoint,
    threads_option,
)

if TYPE_CHECKING:
    from recon.fitting import FitReport


class Progress:
    """Progress on stderr: a bar over the step budget on a terminal, nothing otherwise."""

    def __init__(self, enabled: bool) -> None:
        self.enabled = enabled and sys.stderr.isatty()
        self.bar: Any = None
        self.last = 0

    def __call__(self, phase: str, info: dict[str, Any]) -> None:
        if not self.enabled:
            return
        if self.bar is None:
            self.bar = click.progressbar(
                length=int(info["max_steps"]),
                label="dynamics",
                file=sys.stderr,
                show_pos=True,
                width=30,
            )
            self.bar.__enter__()
        step = int(info["step"])
        self.bar.label = (
            f"{phase:<7} {info['particles']:>8,} particles  coverage {100 * info['coverage']:5.1f}%"
        )
        self.bar.update(max(0, step - self.last))
        self.last = step

    def close(self) -> None:
        if self.bar is not None:
            self.bar.__exit__(None, None, None)
            self.bar = None


def parse_classes(ctx: click.Context, param: click.Parameter, text: str | None) -> list[int] | None:
    """Click callback: ``"2,6"`` -> [2, 6] (LAS classes 0-255)."""
    if text is None:
        return None
    try:
        values = [int(v) for v in text.replace(" ", "").split(",") if v]
    except ValueError:
        raise click.BadParameter(f"expected class numbers such as 2,6, got {text!r}") from None
    if not values or any(not 0 <= v <= 255 for v in values):
        raise click.BadParameter(f"expected class numbers 0-255 such as 2,6, got {text!r}")
    return values


def _parse_transfer(
    ctx: click.Context, param: click.Parameter, text: str | None
) -> list[str] | None:
    """Click callback: ``"intensity,classification"`` -> a list of attribute names."""
    if text is None:
        return None
    from recon.attributes import TRANSFERABLE

    names = [v for v in text.replace(" ", "").split(",") if v]
    bad = [n for n in names if n not in TRANSFERABLE]
    if bad or not names:
        raise click.BadParameter(
            f"expected a comma-separated list of {', '.join(TRANSFERABLE)}, got {text!r}"
        )
    return names


def _crease_use(report: FitReport) -> str:
    """What the fit did with the sharp features it found (it said "mesh unchanged" always,
    though with ``creases.fit``, the default, the mesh keeps them sharp)."""
    cr = report.creases
    if cr is None or not (cr.crease_points or cr.corner_points):
        return "none found"
    if not report.config.get("creases", {}).get("fit", True):
        return "detected only: creases.fit is off, the mesh rounds them"
    return "kept sharp in the mesh"


def _input_points(report: FitReport) -> str:
    """The summary's input line: the points fitted, and the outliers removed before."""
    text = f"{report.input.points:,}"
    removed = report.input.normals.get("outliers", {}).get("removed", 0)
    if removed:
        text += f" ({removed:,} statistical outliers removed: io.outliers)"
    return text


def format_summary(report: FitReport) -> str:
    """A short human summary of a fit report (stderr)."""
    fid, m2i, topo, qual = (
        report.fidelity,
        report.mesh_to_input,
        report.topology,
        report.triangle_quality,
    )
    times = report.timings
    rows = [
        ("input points", _input_points(report)),
        ("spacing r0", f"{report.spacing:.6g}"),
        ("seeds / particles", f"{report.seeds:,} / {report.particles:,}"),
        ("steps grow / release", f"{report.steps.grow} / {report.steps.release}"),
        (
            "time",
            "  ".join(f"{k} {v:.2f}s" for k, v in times.phases().items())
            + f"  (total {times.total:.2f}s)",
        ),
        ("coverage", f"{100 * (report.coverage or 0):.1f}% of the data near a particle"),
        (
            "fidelity (input->mesh)",
            f"mean {fid.mean:.4g}  p95 {fid.p95:.4g}  max {fid.max:.4g}  "
            f"(mean {fid.mean_relative:.2e} of bbox diagonal)",
        ),
        (
            "mesh on the data",
            f"{100 * m2i.within_reach:.1f}% of the surface within {m2i.reach:.4g} of an input "
            f"point (max of r0 and 2.1x the point spacing; p95 {m2i.p95:.4g})",
        ),
        (
            "mesh",
            f"{topo.n_vertices:,} vertices, {topo.n_faces:,} faces, {topo.components} component(s)",
        ),
        (
            "topology",
            f"boundary loops {topo.boundary_loops}, non-manifold edges "
            f"{topo.non_manifold_edges}, vertices {topo.non_manifold_vertices},"
            f" watertight {'yes' if topo.watertight else 'no'}, genus {topo.genus}",
        ),
        (
            "largest hole",
            "none (closed)"
            if topo.boundary_loops == 0
            else f"{topo.largest_hole_r0:.1f} r0 across (perimeter / pi, "
            f"perimeter {topo.largest_hole_perimeter:.4g})",
        ),
        (
            "self-intersections",
            f"{report.triangulation.self_intersections_left} crossing face pairs"
            f" ({report.triangulation.self_intersections_found} before untangling)",
        ),
        (
            "min angle",
            f"mean {qual.min_angle_mean_deg:.1f} deg, 5th pct {qual.min_angle_p5_deg:.1f} deg",
        ),
    ]
    mem = report.input.memory_estimate
    if mem:
        from recon.fitting.memory import format_bytes

        rows.insert(
            3,
            (
                "memory (estimate)",
                f"{format_bytes(mem['peak_bytes'])} peak for ~{mem['particles']:,} particles",
            ),
        )
    if report.creases is not None:
        cr = report.creases
        rows.append(
            (
                "sharp features",
                f"creases {cr.length:.4g} long ({cr.length_relative:.3g} x bbox diagonal), "
                f"{cr.corners} corner(s) at {cr.angle_deg:g} deg ({_crease_use(report)})",
            )
        )
    split = report.output.crease_vertices_split if report.output is not None else None
    if split:
        rows.append(
            (
                "crease split (PLY)",
                f"{split:,} vertices duplicated for their sides' normals (creases.split_ply): "
                "the file's topology opens along the creases; the topology above is the "
                "welded surface's",
            )
        )
    if report.stop_reason:
        rows.append(("growth stopped", report.stop_reason))
    lines = format_rows(rows)
    lines += [f"  warning: {w}" for w in report.warnings]
    return "\n".join(lines)


@click.command("fit")
@click.argument("input_path", metavar="INPUT", type=click.Path(path_type=Path))
@mesh_output_option
@click.option(
    "--particles",
    "particles_path",
    type=click.Path(path_type=Path),
    help="Also write the final oriented particles as a PLY point cloud.",
)
@click.option(
    "--preview",
    "preview_path",
    type=click.Path(path_type=Path),
    help="Also render a PNG (the name must end in .png): the mesh from three sides and the "
    "convergence plot.",
)
@click.option(
    "--spacing",
    type=float,
    help="Rest spacing r0 in input units (default: seeds.spacing_factor x median point spacing).",
)
@click.option(
    "--spacing-relative",
    type=float,
    help="Rest spacing r0 as a fraction of the bounding-box diagonal.",
)
@click.option(
    "--max-gap", type=float, help="Holes wider than this many r0 stay open (growth.max_gap)."
)
@click.option(
    "--fidelity", type=float, help="Pull toward the data, 0 = pure smoothing (dynamics.fidelity)."
)
@click.option(
    "--normals",
    "normals_mode",
    type=click.Choice(["auto", "estimate", "input"]),
    help="Use the file's normals (input), estimate them, or auto.",
)
@click.option(
    "--viewpoint",
    callback=parse_viewpoint,
    help="Scanner position x,y,z: orient normals toward it (range scans).",
)
@click.option(
    "--classes",
    callback=parse_classes,
    help="LAS/LAZ input: keep only these classes, e.g. 2,6 (ground, buildings) (io.classes).",
)
@click.option(
    "--max-memory",
    help="Refuse (exit 2) when the estimated peak memory exceeds this, e.g. 8G or 512M "
    "(io.max_memory); the message gives a --spacing that fits.",
)
@click.option(
    "--transfer",
    callback=_parse_transfer,
    help="Add input attributes as PLY vertex properties: intensity (weighted mean of the "
    "nearest points), classification (their majority) (output.transfer).",
)
@click.option(
    "--quality",
    is_flag=True,
    default=None,
    help="Add a PLY vertex property 'quality': distance to the nearest input point in r0.",
)
@click.option(
    "--obj-colors",
    is_flag=True,
    default=None,
    help="Write the input's colours into an OBJ mesh too, as 'v x y z r g b' (floats 0-1).",
)
@click.option(
    "--no-colors",
    is_flag=True,
    default=None,
    help="Do not carry the input's colours onto the mesh (output.colors: false).",
)
@click.option(
    "--crease-angle",
    type=float,
    help="Keep sharp creases and corners turning by more than this angle between the two face "
    "normals [deg] (creases.angle_deg, default 50; 90 = box edge): they are detected, "
    "reported, and kept sharp in the mesh (on by default; --set creases.fit=false: report "
    "only).",
)
@click.option(
    "--no-creases",
    is_flag=True,
    default=None,
    help="Skip crease detection (on by default: creases.enabled); smooth fits round every edge.",
)
@click.option(
    "--remove-outliers",
    is_flag=True,
    default=None,
    help="Remove stray points before the fit (io.outliers: statistical): those whose mean "
    "distance to their io.outlier_k (20) nearest exceeds the median of that distance by "
    "io.outlier_std_ratio (3) robust standard deviations and is over twice the median, as "
    "Open3D's remove_statistical_outlier with median and MAD for mean and std. The summary's "
    "input line counts them. Sparse parts of a nonuniformly sampled scan can go too (a "
    "terrestrial scan's far range); not with tiled fits (clean first: oprecon normals "
    "--remove-outliers).",
)
@click.option(
    "--tile-size",
    type=click.FloatRange(min=0, min_open=True),
    metavar="LENGTH",
    help="Fit in cubic tiles of this side (input units), each on a worker, and stitch one "
    "seamless mesh: for scans too large for one fit (tiling.size).",
)
@click.option(
    "--tiles",
    type=click.Choice(["auto"]),
    help="auto: tile only when one fit would exceed --max-memory (else tiling.memory, 2G), "
    "with the largest tile size that fits (tiling.auto).",
)
@click.option(
    "-j",
    "--jobs",
    type=click.IntRange(min=1),
    help="Tiled fits: tiles at a time (local), or LocalCluster workers (dask without "
    "--scheduler). Default: the number of cores; each tile gets cores / jobs threads.",
)
@click.option(
    "--executor",
    type=click.Choice(["local", "dask"]),
    default="local",
    show_default=True,
    help="Tiled fits: local worker processes, or tasks on a Dask cluster "
    '(pip install "oprecon[distributed]"); the input and output folder must then be on '
    "storage every worker sees.",
)
@click.option(
    "--scheduler",
    metavar="ADDRESS",
    help="Tiled fits: the Dask scheduler, e.g. tcp://10.0.0.5:8786 (with --executor dask); "
    "without it a LocalCluster is started.",
)
@click.option("--seed", type=int, help="Random seed (same seed, same mesh).")
@click.option("--max-particles", type=int, help="Cap on particles (dynamics.max_particles).")
@click.option("--max-steps", type=int, help="Cap on dynamics steps (dynamics.max_steps).")
@click.option("--time-limit", type=float, help="Stop with an error after this many seconds.")
@click.option("--ascii", "ascii_", is_flag=True, default=None, help="Write ASCII PLY.")
@click.option("--no-report", is_flag=True, help="Do not write <mesh>.report.json.")
@click.option("--mkdir", is_flag=True, help="Create the output folder if it is missing.")
@click.option("--json", "as_json", is_flag=True, help="Print the report as JSON on stdout.")
@config_options
@threads_option
@common_run_options
@catch_errors
def command(
    input_path: Path,
    output_path: Path,
    particles_path: Path | None,
    preview_path: Path | None,
    spacing: float | None,
    spacing_relative: float | None,
    max_gap: float | None,
    fidelity: float | None,
    normals_mode: str | None,
    viewpoint: list[float] | None,
    classes: list[int] | None,
    max_memory: str | None,
    transfer: list[str] | None,
    quality: bool | None,
    obj_colors: bool | None,
    no_colors: bool | None,
    crease_angle: float | None,
    no_creases: bool | None,
    remove_outliers: bool | None,
    tile_size: float | None,
    tiles: str | None,
    jobs: int | None,
    executor: str,
    scheduler: str | None,
    seed: int | None,
    max_particles: int | None,
    max_steps: int | None,
    time_limit: float | None,
    ascii_: bool | None,
    no_report: bool,
    mkdir: bool,
    as_json: bool,
    config_path: Path | None,
    preset: str | None,
    overrides: tuple[str, ...],
    threads: int | None,
    quiet: bool,
) -> None:
    """Reconstruct a triangle mesh from the point cloud INPUT.

    Reads PLY, XYZ/XYZN/PTS/TXT, PCD, OBJ, LAS/LAZ or E57 points; estimates and orients
    normals (or uses the file's), grows an oriented-particle sheet over the data, releases and
    smooths it, and triangulates it. Prints a quality summary on stderr and writes
    OUTPUT.report.json.

    When the input has colours, every mesh vertex gets the distance-weighted mean colour of
    its nearest input points (PLY red/green/blue; OBJ with --obj-colors). Before fitting, the
    peak memory is estimated from the point count and r0 (--max-memory refuses past a limit).
    An untiled fit keeps the memory it frees for reuse (4M points: 440 -> 365 s, peak +4 %);
    OPRECON_MALLOC=system keeps glibc's own policy instead.

    \b
    Examples:
      oprecon fit scan.ply -o mesh.ply
      oprecon fit scan.ply -o mesh.obj --preset open_scan --viewpoint 0,0,1000
      oprecon fit sparse.xyz -o mesh.ply --max-gap 6 --preview mesh.png
      oprecon fit scan.ply -o mesh.ply --set dynamics.release_steps=200 --seed 3
      oprecon fit city.laz -o roofs.ply --classes 2,6 --transfer classification --quality
      oprecon fit site.e57 -o site.obj --obj-colors --max-memory 8G
      oprecon fit big.laz -o mesh.ply --tile-size 50 --jobs 4
      oprecon fit big.laz -o mesh.ply --tiles auto --max-memory 4G --executor dask

    Tiled fits (--tile-size, --tiles auto) cut space into tiles with a halo of a few r0, fit
    them on worker processes or a Dask cluster with one r0 and configuration for the whole
    scan, and stitch one seamless mesh (faces on a seam are decided with both sides'
    particles). A failed tile is retried once. The report gets a "tiles" section.

    Exit codes: 0 success, 1 tiles failed twice (not an input problem), 2 bad input or usage,
    130 interrupted.
    """
    from recon.fitting import fit_file, report_path_for
    from recon.serialize import dumps

    cfg = build_config(config_path, preset, overrides)
    if (spacing is None) != (spacing_relative is None):
        # one form of r0 on the command line replaces either form from a file or --set
        cfg = apply_overrides(cfg, {"seeds.spacing": None, "seeds.spacing_relative": None})
    cfg = with_values(
        cfg,
        seeds={"spacing": spacing, "spacing_relative": spacing_relative},
        growth={"max_gap": max_gap},
        dynamics={
            "fidelity": fidelity,
            "max_particles": max_particles,
            "max_steps": max_steps,
            "time_limit": time_limit,
        },
        normals={"mode": normals_mode, "viewpoint": viewpoint},
        io={
            "ascii": ascii_,
            "classes": classes,
            "max_memory": max_memory,
            "outliers": "statistical" if remove_outliers else None,
        },
        output={
            "transfer": transfer,
            "quality": quality,
            "obj_colors": obj_colors,
            "colors": False if no_colors else None,
        },
        creases={
            "angle_deg": crease_angle,
            "enabled": False if no_creases else (True if crease_angle is not None else None),
        },
    )
    if tile_size is not None and tiles is not None:
        raise click.UsageError("--tile-size and --tiles auto are exclusive; give one")
    if scheduler and executor != "dask":
        raise click.UsageError("--scheduler needs --executor dask")
    if tile_size is not None:
        cfg = apply_overrides(cfg, {"tiling.size": tile_size, "tiling.auto": False})
    elif tiles == "auto":
        cfg = apply_overrides(cfg, {"tiling.size": None, "tiling.auto": True})
    if seed is not None:
        cfg = apply_overrides(cfg, {"seed": seed})
    if threads is not None:
        cfg = apply_overrides(cfg, {"threads": threads})
    progress = Progress(enabled=not quiet)
    # with a remote scheduler the fit compiles on the workers, whose caches are their own
    compiles = note_first_compile(quiet or scheduler is not None)
    named = [
        str(p)
        for p in (
            input_path,
            output_path,
            # (no report name for a path without a file name: the fit refuses that path)
            report_path_for(output_path) if Path(output_path).name else None,
            particles_path,
            preview_path,
        )
        if p
    ]
    if particles_path is not None:  # refused before the fit, not after it
        from recon.io import check_points_output

        check_points_output(particles_path)
    if preview_path is not None:
        from recon.io import check_png_output

        check_png_output(preview_path, "the preview")
    if cfg.tiling.size is not None or cfg.tiling.auto:
        if _fit_tiles(
            input_path,
            output_path,
            cfg,
            particles_path=particles_path,
            preview_path=preview_path,
            no_report=no_report,
            mkdir=mkdir,
            jobs=jobs,
            executor=executor,
            scheduler=scheduler,
            quiet=quiet,
            as_json=as_json,
            compiles=compiles,
        ):
            return
    from recon.heap import keep_freed_memory

    keep_freed_memory()  # one fit in this process: reuse freed memory (recon/heap.py)
    try:
        result = fit_file(
            input_path,
            output_path,
            cfg,
            particles_path=particles_path,
            preview_path=preview_path,
            write_report=False if no_report else None,
            mkdir=mkdir,
            on_progress=progress,
        )
    except OpreconError as exc:
        # say which file a failed run was about (limits, divergence, too sparse data ...)
        if any(str(exc).startswith(n) for n in named):
            raise
        raise type(exc)(f"{input_path}: {exc}") from exc
    finally:
        progress.close()
    if not quiet:
        click.echo(f"oprecon: wrote {output_path}", err=True)
        click.echo(format_summary(result.report), err=True)
        if compiles:
            click.echo(COMPILE_TIMES_NOTE, err=True)
    if as_json:
        click.echo(dumps(result.report.to_dict()))


class TileProgress:
    """Tiles done and in flight on stderr: one updating line on a terminal, one line per
    finished tile otherwise; retries are always reported."""

    def __init__(self, enabled: bool) -> None:
        self.enabled = enabled
        self.tty = sys.stderr.isatty()
        self.last = ""

    def __call__(self, event: Any) -> None:
        if event.message:
            self._end_line()
            click.echo(f"oprecon: {event.message}", err=True)
        if not self.enabled:
            return
        text = (
            f"{event.phase:<7} tiles {event.done}/{event.total} done, {event.in_flight} in flight"
        )
        if self.tty:
            click.echo("\r" + text.ljust(len(self.last)), err=True, nl=False)
            self.last = text
        elif event.done and text != self.last:
            click.echo(text, err=True)
            self.last = text

    def _end_line(self) -> None:
        if self.tty and self.last:
            click.echo("", err=True)
            self.last = ""

    def close(self) -> None:
        self._end_line()


def format_tiled_summary(report: dict[str, Any]) -> str:
    """A short human summary of a tiled fit's report (stderr)."""
    topo, tiles = report["topology"], report["tiles"]
    seams = tiles["seams"]
    times = report["timings"]
    rows = [
        ("input points", f"{report['input']['points']:,}"),
        ("spacing r0", f"{report['spacing']:.6g}"),
        (
            "tiles",
            f"{tiles['count']} ({' x '.join(map(str, tiles['grid']))} grid, side "
            f"{tiles['size']:.4g}, halo {tiles['halo']:.4g}), {tiles['time_per_tile']['mean']:.1f}"
            f" s per tile (max {tiles['time_per_tile']['max']:.1f} s)",
        ),
        ("particles", f"{report['particles']:,}"),
        (
            "time",
            "  ".join(f"{k} {v:.1f}s" for k, v in times.items() if k != "total")
            + f"  (total {times['total']:.1f}s)",
        ),
        (
            "mesh",
            f"{topo['n_vertices']:,} vertices, {topo['n_faces']:,} faces, "
            f"{topo['components']} component(s)",
        ),
        (
            "topology",
            f"boundary loops {topo['boundary_loops']}, non-manifold edges "
            f"{topo['non_manifold_edges']}, vertices {topo['non_manifold_vertices']}",
        ),
        (
            "seams",
            f"{seams['seam_edges']:,} edges across tiles, {seams['seam_boundary_edges']} of them "
            f"on a boundary; {tiles['repair']['faces_dropped']} overlapping faces dropped, "
            f"{tiles['repair']['seam_loops_zipped']} cracks zipped",
        ),
    ]
    if report.get("creases") is not None:
        rows.append(("sharp features", _tiled_crease_use(report)))
    lines = format_rows(rows)
    lines += [f"  warning: {w}" for w in report["warnings"]]
    return "\n".join(lines)


def _tiled_crease_use(report: dict[str, Any]) -> str:
    """The summary's crease line of a tiled fit: its tiles fit the creases they detect, but the
    scan's crease length and corners are not measured (null in the report)."""
    cr = report["creases"]
    unmeasured = "length and corners not measured in tiled fits"
    if not report["config"].get("creases", {}).get("fit", True):
        return (
            f"at {cr['angle_deg']:g} deg: creases.fit is off, the mesh rounds them ({unmeasured})"
        )
    if not cr["crease_particles"]:
        return f"none fitted at {cr['angle_deg']:g} deg ({unmeasured})"
    return (
        f"{cr['crease_particles']:,} crease particles at {cr['angle_deg']:g} deg: the creases "
        f"the tiles detected are kept sharp in the mesh ({unmeasured})"
    )


def _fit_tiles(
    input_path: Path,
    output_path: Path,
    cfg: Any,
    *,
    particles_path: Path | None,
    preview_path: Path | None,
    no_report: bool,
    mkdir: bool,
    jobs: int | None,
    executor: str,
    scheduler: str | None,
    quiet: bool,
    as_json: bool,
    compiles: bool = False,
) -> bool:
    """The tiled fit; False when --tiles auto found that one fit will do. ``compiles``: the
    run said it compiles the kernels first (its summary then says the times include it)."""
    from recon.serialize import dumps
    from recon.tiling import TileError, fit_tiled

    from .common import fail

    progress = TileProgress(enabled=not quiet)
    try:
        result = fit_tiled(
            input_path,
            output_path,
            cfg,
            jobs=jobs,
            executor=executor,
            scheduler=scheduler,
            particles_path_out=particles_path,
            preview_path=preview_path,
            write_report=False if no_report else None,
            mkdir=mkdir,
            on_event=progress,
        )
    except TileError as exc:
        progress.close()
        fail(f"{input_path}: {exc}", exc.exit_code)
        return True
    except OpreconError as exc:
        if str(exc).startswith(str(input_path)):
            raise
        raise type(exc)(f"{input_path}: {exc}") from exc
    finally:
        progress.close()
    if result is None:
        if not quiet:
            click.echo("oprecon: the scan fits in one fit's memory budget: not tiling", err=True)
        return False
    if not quiet:
        click.echo(f"oprecon: wrote {output_path}", err=True)
        click.echo(format_tiled_summary(result.report), err=True)
        if compiles:
            click.echo(COMPILE_TIMES_NOTE, err=True)
    if as_json:
        click.echo(dumps(result.report))
    return True
