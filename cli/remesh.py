"""``oprecon remesh``: a clean, near-equilateral mesh of an existing mesh."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import click

from .common import (
    COMPILE_TIMES_NOTE,
    EXIT_CHECK_FAILED,
    catch_errors,
    common_run_options,
    format_rows,
    mesh_output_option,
    note_first_compile,
    threads_option,
)


def format_summary(report: dict[str, Any]) -> str:
    """A short human summary of a remesh report (stderr)."""
    inp, out = report["input"], report["output"]
    qi, qo = inp["triangle_quality"], out["triangle_quality"]
    ti, to = inp["topology"], out["topology"]
    dist, feat, times = report["distance"], report["features"], report["timings"]

    def quality(q: dict[str, Any]) -> str:
        if not q.get("n_measured"):
            return "no measurable triangles"
        return (
            f"min angle mean {q['min_angle_mean_deg']:.1f}, p5 {q['min_angle_p5_deg']:.1f}, "
            f"worst {q['min_angle_min_deg']:.2f} deg; aspect ratio mean "
            f"{q['aspect_ratio_mean']:.3f}, max {q['aspect_ratio_max']:.3g}"
        )

    def topo(t: dict[str, Any]) -> str:
        return (
            f"{t['n_vertices']:,} vertices, {t['n_faces']:,} faces, {t['components']} "
            f"component(s), {t['boundary_loops']} boundary loop(s), genus {t['genus']}"
        )

    rows = [
        ("spacing", f"{report['spacing']:.6g}"),
        ("input", topo(ti)),
        ("output", topo(to)),
        ("topology", "preserved" if report["topology_preserved"] else "CHANGED"),
        ("input triangles", quality(qi)),
        ("output triangles", quality(qo)),
        (
            "distance to input",
            f"Hausdorff {dist['hausdorff_relative']:.2e}, Hausdorff-95 "
            f"{dist['hausdorff95_relative']:.2e}, mean {dist['mean_to_input_relative']:.2e} "
            "(x bbox diagonal)",
        ),
        (
            "feature lines",
            f"{feat['boundary_edges']:,} boundary + {feat['crease_edges']:,} crease edges, "
            f"{feat['corners']} corner(s); largest deviation {feat['deviation_max_relative']:.2e}"
            " x diagonal",
        ),
        (
            "time",
            "  ".join(f"{k} {v:.2f}s" for k, v in times.items() if k != "total")
            + f"  (total {times['total']:.2f}s)",
        ),
    ]
    if report.get("spacing_range"):
        lo, hi = report["spacing_range"]
        rows.insert(1, ("adaptive spacing", f"{lo:.4g} to {hi:.4g}"))
    lines = format_rows(rows)
    lines += [f"  repaired: {r}" for r in report["input"]["repairs"]]
    lines += [f"  warning: {w}" for w in report["warnings"]]
    return "\n".join(lines)


@click.command("remesh")
@click.argument("input_path", metavar="INPUT", type=click.Path(path_type=Path))
@mesh_output_option
@click.option(
    "--spacing",
    type=click.FloatRange(min=0, min_open=True),
    help="Target edge length in input units (default: the input's mean edge length, at most "
    "a tenth of its bounding-box diagonal, so a coarse CAD mesh is not meshed by a handful of "
    "particles).",
)
@click.option(
    "--spacing-relative",
    type=click.FloatRange(min=0, min_open=True),
    help="Target edge length as a fraction of the bounding-box diagonal.",
)
@click.option(
    "--faces",
    "n_faces",
    type=click.IntRange(min=4),
    help="Target face count (the spacing follows from the surface area; within ~5%).",
)
@click.option(
    "--adaptive",
    is_flag=True,
    help="Spacing from curvature and local thickness: the given spacing where the curvature "
    "is at its 75th percentile, coarser on flat parts, finer on curved and thin ones.",
)
@click.option(
    "--min-spacing",
    type=click.FloatRange(min=0, min_open=True),
    help="With --adaptive: smallest edge length (default 0.5 x spacing).",
)
@click.option(
    "--max-spacing",
    type=click.FloatRange(min=0, min_open=True),
    help="With --adaptive: largest edge length (default 3 x spacing).",
)
@click.option(
    "--crease-angle",
    type=click.FloatRange(min=0, max=180, min_open=True, max_open=True),
    help="Keep input edges whose two face normals differ by more than this [deg] as creases "
    "(90 = box edge); particles slide along them, their corners stay fixed. Boundaries are "
    "always kept.",
)
@click.option(
    "--steps",
    type=click.IntRange(min=0),
    help="Relaxation steps of the particles (default 40).",
)
@click.option(
    "--no-intersection-check",
    is_flag=True,
    help="Skip the self-intersection test of the input.",
)
@click.option("--seed", type=int, default=0, show_default=True, help="Random seed.")
@click.option("--ascii", "ascii_", is_flag=True, help="Write ASCII PLY.")
@click.option("--no-report", is_flag=True, help="Do not write <mesh>.report.json.")
@click.option("--mkdir", is_flag=True, help="Create the output folder if it is missing.")
@click.option("--json", "as_json", is_flag=True, help="Print the report as JSON on stdout.")
@threads_option
@common_run_options
@catch_errors
def command(
    input_path: Path,
    output_path: Path,
    spacing: float | None,
    spacing_relative: float | None,
    n_faces: int | None,
    adaptive: bool,
    min_spacing: float | None,
    max_spacing: float | None,
    crease_angle: float | None,
    steps: int | None,
    no_intersection_check: bool,
    seed: int,
    ascii_: bool,
    no_report: bool,
    mkdir: bool,
    as_json: bool,
    threads: int | None,
    quiet: bool,
) -> None:
    """Remesh the triangle mesh INPUT into near-equilateral triangles (S&T92 §9).

    Particles are spread over the input surface by area, relaxed with the oriented-particle
    engine while held on the surface (closest point on its triangles), triangulated like
    `fit` does, and polished with edge flips and tangential smoothing. Boundary loops are kept
    (their particles slide along them), and with --crease-angle so are sharp edges. The
    genus, boundary loops and components of the input are kept; the summary says so.

    Reads PLY or OBJ meshes. Duplicate vertices, degenerate or duplicate faces, bow-tie
    vertices and inconsistent winding are repaired (and listed); non-manifold edges, a
    non-orientable or self-intersecting surface, and files without faces are refused.

    \b
    Examples:
      oprecon remesh scan_mc.ply -o clean.ply
      oprecon remesh part.obj -o part.ply --crease-angle 40
      oprecon remesh bunny.ply -o bunny20k.ply --faces 20000
      oprecon remesh bunny.ply -o coarse.ply --adaptive --spacing-relative 0.005

    Exit codes: 0 success, 1 written but the topology changed, 2 bad input or usage,
    130 interrupted.
    """
    given = [
        name
        for name, v in (
            ("--spacing", spacing),
            ("--spacing-relative", spacing_relative),
            ("--faces", n_faces),
        )
        if v is not None
    ]
    if len(given) > 1:
        raise click.UsageError(f"{' and '.join(given)} are exclusive; give one")
    if (min_spacing is not None or max_spacing is not None) and not adaptive:
        raise click.UsageError("--min-spacing and --max-spacing need --adaptive")
    from recon.errors import OpreconError
    from recon.heap import keep_freed_memory
    from recon.remesh import RemeshOptions, remesh_file
    from recon.remesh.pipeline import RELAX_STEPS
    from recon.serialize import dumps

    options = RemeshOptions(
        spacing=spacing,
        spacing_relative=spacing_relative,
        faces=n_faces,
        adaptive=adaptive,
        min_spacing=min_spacing,
        max_spacing=max_spacing,
        crease_angle=crease_angle,
        seed=seed,
        steps=RELAX_STEPS if steps is None else steps,
        check_intersections=not no_intersection_check,
        threads=threads,
    )
    compiles = note_first_compile(quiet, ("pair_loop.step_particles",))  # the relaxation
    keep_freed_memory()
    try:
        result = remesh_file(
            input_path,
            output_path,
            options,
            write_report=not no_report,
            mkdir=mkdir,
            ascii=ascii_,
        )
    except OpreconError as exc:
        if str(exc).startswith(str(input_path)) or str(exc).startswith(str(output_path)):
            raise
        raise type(exc)(f"{input_path}: {exc}") from exc
    report = result.report
    if not quiet:
        click.echo(f"oprecon: wrote {output_path}", err=True)
        click.echo(format_summary(report), err=True)
        if compiles:
            click.echo(COMPILE_TIMES_NOTE, err=True)
    if as_json:
        click.echo(dumps(report))
    if not report["topology_preserved"]:
        click.echo(
            "oprecon: the topology of the output differs from the input's (see the warning)",
            err=True,
        )
        sys.exit(EXIT_CHECK_FAILED)
