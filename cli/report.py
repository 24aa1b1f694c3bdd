"""``oprecon report``: topology, triangle quality and fidelity of any mesh (+ a PNG)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import click

from recon.errors import InputError
from recon.serialize import dumps

from .common import catch_errors, note_first_compile

# --------------------------------------------------------------------------------------------
# helpers shared with ``oprecon compare``


def fmt(value: Any, digits: int = 4) -> str:
    """A number for a table: ints with separators, floats in 4 significant digits."""
    if value is None:
        return "-"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, int):
        return f"{value:,}"
    if isinstance(value, float):
        return f"{value:.{digits}g}"
    return str(value)


def table(rows: list[tuple[str, ...]], indent: int = 2) -> str:
    """Left-aligned columns."""
    widths = [max(len(r[i]) for r in rows if i < len(r)) for i in range(max(map(len, rows)))]
    lines = []
    for r in rows:
        cells = [c.ljust(widths[i]) for i, c in enumerate(r)]
        lines.append(" " * indent + "  ".join(cells).rstrip())
    return "\n".join(lines)


#: (label, key) of the topology rows, in display order.
TOPOLOGY_ROWS = (
    ("vertices", "n_vertices"),
    ("faces", "n_faces"),
    ("components", "components"),
    ("boundary edges", "boundary_edges"),
    ("boundary loops", "boundary_loops"),
    ("non-manifold edges", "non_manifold_edges"),
    ("non-manifold vertices", "non_manifold_vertices"),
    ("watertight", "watertight"),
    ("consistently oriented", "consistently_oriented"),
    ("orientable", "orientable"),
    ("Euler characteristic", "euler_characteristic"),
    ("genus", "genus"),
    ("degenerate faces", "degenerate_faces"),
    ("duplicate faces", "duplicate_faces"),
    ("unreferenced vertices", "unreferenced_vertices"),
    ("largest hole perimeter", "largest_hole_perimeter"),
)


#: The numba kernels every report calls (``module.function`` under :mod:`recon.kernels`):
#: topology (half-edge order, fans, components) and the self-intersection search (the
#: triangle tests of :mod:`recon.kernels.tri_intersect` are compiled into ``sphere_pairs``).
#: Compiling them takes about 30 s on a machine without their cache.
REPORT_KERNELS: tuple[str, ...] = (
    "mesh_tables.half_edge_order",
    "mesh_tables.fan_labels",
    "mesh_tables.vertex_component_labels",
    "mesh_tables.bounding_spheres",
    "grid_query.coordinate_extent",
    "sphere_pairs.sphere_pairs",
)
#: Those the picture (``--png``) adds.
PNG_KERNELS: tuple[str, ...] = ("mesh_tables.area_vectors", "mesh_tables.edge_table")


def read_mesh_checked(path: Path, role: str = "MESH") -> tuple[Any, Any]:
    """``recon.io.read_mesh`` that refuses files without faces and non-finite coordinates in
    any vertex, used or not (names the file)."""
    from recon.io import read_mesh

    vertices, faces = read_mesh(path, all_finite=True)
    if len(faces) == 0:
        raise InputError(f"{path}: has no faces (a point cloud?); {role} must be a triangle mesh")
    return vertices, faces


def load_fit_history(mesh_path: Path) -> tuple[Path | None, dict[str, Any] | None]:
    """The fit report beside a mesh and its ``history``; unreadable ones are skipped (warned)."""
    from recon.fitting import report_path_for

    path = report_path_for(mesh_path)
    if not path.is_file():
        return None, None
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        click.echo(f"oprecon: warning: ignoring {path}: {exc}", err=True)
        return None, None
    history = data.get("history") if isinstance(data, dict) else None
    if not isinstance(history, dict):
        return path, None
    return path, history


#: (label, key) of the rows of ``report``'s closed-component check (not in ``compare``).
ORIENTATION_ROWS = (
    ("closed components", "closed_components"),
    ("  facing inward", "closed_components_inward"),
)


def no_proper_face(topology: dict[str, Any]) -> str:
    """The line that says a mesh has faces but no non-degenerate one."""
    n = topology["n_faces"]
    return (
        f"no non-degenerate face: {'the' if n == 1 else 'all'} {n:,} "
        f"{'face is' if n == 1 else 'faces are'} degenerate (a repeated vertex index or zero area)"
    )


#: What ``oprecon report`` suggests about crossings (the mesh may come from any tool).
REPORT_CROSSING_HINT = (
    "repair the mesh before such use (an oprecon mesh: refit with a larger --spacing, or remove "
    "outliers from the input)"
)


def crossing_warning_of(report: dict[str, Any]) -> str | None:
    """The warning about the crossing face pairs a ``quality_report`` counted (None: none)."""
    from recon.fitting.mesh_warnings import crossing_warning

    return crossing_warning(report.get("self_intersections") or 0, hint=REPORT_CROSSING_HINT)


def format_quality(report: dict[str, Any], mesh_name: str, input_name: str | None) -> str:
    """The human table of a ``quality_report`` dict."""
    topo = report["topology"]
    tq = report["triangle_quality"]
    out = [
        f"{mesh_name}: {topo['n_vertices']:,} vertices, {topo['n_faces']:,} faces, "
        f"bounding-box diagonal {fmt(report['mesh_bbox_diag'])}",
        "topology",
        table(
            [(label, fmt(topo[key])) for label, key in TOPOLOGY_ROWS[2:]]
            + [(label, fmt(topo[key])) for label, key in ORIENTATION_ROWS if key in topo]
            + [("self-intersections", fmt(report.get("self_intersections")))]
        ),
        *([f"  warning: {w}"] if (w := crossing_warning_of(report)) else []),
        f"triangles ({tq['n_measured']:,} non-degenerate)",
    ]
    if not tq["n_measured"] and topo["n_faces"]:
        out.append(f"  {no_proper_face(topo)}")
    if tq["n_measured"]:
        out.append(
            table(
                [
                    ("", "mean", "p5 / p95", "extreme"),
                    (
                        "min angle [deg]",
                        fmt(tq["min_angle_mean_deg"], 3),
                        fmt(tq["min_angle_p5_deg"], 3),
                        fmt(tq["min_angle_min_deg"], 3),
                    ),
                    ("max angle [deg]", "", "", fmt(tq["max_angle_max_deg"], 4)),
                    (
                        "aspect ratio R/2r",
                        fmt(tq["aspect_ratio_mean"], 3),
                        fmt(tq["aspect_ratio_p95"], 3),
                        fmt(tq["aspect_ratio_max"], 3),
                    ),
                    (
                        "edge length",
                        fmt(tq["edge_length_mean"]),
                        f"cv {fmt(tq['edge_length_cv'], 3)}",
                        "",
                    ),
                ]
            )
        )
    fid = report.get("fidelity")
    if fid:
        out.append(
            f"fidelity: {input_name} ({fid['n']:,} points) to the mesh, "
            f"relative to the input diagonal {fmt(fid['diag'])}"
        )
        out.append(
            table(
                [
                    ("", "mean", "rms", "p95", "max"),
                    ("absolute", *(fmt(fid[k]) for k in ("mean", "rms", "p95", "max"))),
                    (
                        "÷ diagonal",
                        *(fmt(fid[f"{k}_relative"], 3) for k in ("mean", "rms", "p95", "max")),
                    ),
                ]
            )
        )
    return "\n".join(out)


# --------------------------------------------------------------------------------------------
# the command


@click.command("report")
@click.argument("mesh_path", metavar="MESH", type=click.Path(path_type=Path))
@click.option(
    "--input",
    "input_path",
    metavar="POINTS",
    type=click.Path(path_type=Path),
    help="Point cloud the mesh should represent: adds input-to-mesh distances (absolute and "
    "divided by the input's bounding-box diagonal).",
)
@click.option("--json", "as_json", is_flag=True, help="Print a JSON object instead of tables.")
@click.option(
    "--png",
    "png_path",
    metavar="OUT.png",
    type=click.Path(path_type=Path),
    help="Also draw the mesh from three sides (boundary edges red, non-manifold magenta), "
    "plus the convergence plot when the <name>.report.json of `oprecon fit` is beside MESH; "
    "a PNG image, so the name must end in .png.",
)
@catch_errors
def command(mesh_path: Path, input_path: Path | None, as_json: bool, png_path: Path | None) -> None:
    """Check any triangle mesh (ours or another tool's): topology, triangle quality, fidelity.

    Reads PLY or OBJ. Reports components, boundary edges and loops, non-manifold edges and
    vertices, orientation, Euler characteristic and genus, degenerate faces; the minimum-angle
    and aspect-ratio statistics of the triangles; and, with --input, how far the input points
    lie from the surface. Closed components (every edge in two faces, wound consistently)
    whose signed volume is negative are counted as facing inward (inside out).

    \b
    Examples:
      oprecon report mesh.ply
      oprecon report mesh.ply --input scan.ply             + distances of the scan to the mesh
      oprecon report poisson.obj --input scan.ply --json   machine-readable
      oprecon report mesh.ply --png mesh.png               picture (+ convergence if fitted)

    Exit codes: 0 success, 2 bad input or usage, 130 interrupted.
    """
    from recon.io import check_output_path, check_png_output, read_points
    from recon.metrics import quality_report

    if png_path is not None:
        check_output_path(
            png_path, [p for p in (mesh_path, input_path) if p is not None], mkdir_option=None
        )
        check_png_output(png_path, "the picture")
    kernels = REPORT_KERNELS + (PNG_KERNELS if png_path is not None else ())
    note_first_compile(False, kernels, how_long="about a minute of CPU")
    vertices, faces = read_mesh_checked(mesh_path)
    points = None
    if input_path is not None:
        points = read_points(input_path).absolute_points()
    report = quality_report(points, vertices, faces, intersections=True, orientation=True)
    fit_path, history = load_fit_history(mesh_path)
    if not report["triangle_quality"]["n_measured"] and as_json:
        click.echo(f"oprecon: warning: {mesh_path}: {no_proper_face(report['topology'])}", err=True)
    if as_json and (crossings := crossing_warning_of(report)):
        click.echo(f"oprecon: warning: {mesh_path}: {crossings}", err=True)

    if png_path is not None:
        from recon.render import check_history, render_mesh_png

        if history is not None:
            try:  # only a bad history falls back to the mesh alone
                check_history(history)
            except InputError as exc:
                click.echo(f"oprecon: warning: {fit_path}: history not drawn: {exc}", err=True)
                history = None
        render_mesh_png(png_path, vertices, faces, history=history, title=mesh_path.name)

    if as_json:
        payload = {
            "mesh": str(mesh_path),
            "input": None if input_path is None else str(input_path),
            "fit_report": None if fit_path is None else str(fit_path),
            "png": None if png_path is None else str(png_path),
            **report,
        }
        click.echo(dumps(payload, strict=True))
    else:
        click.echo(format_quality(report, str(mesh_path), str(input_path)))
        if fit_path is not None:
            click.echo(f"fit report: {fit_path}")
        if png_path is not None:
            click.echo(f"wrote {png_path}")
