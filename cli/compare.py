"""``oprecon compare``: distances, F-score and topology of a mesh against a reference."""

from __future__ import annotations

import sys
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import click
from click.core import ParameterSource

from recon.config import load_yaml_file
from recon.errors import ConfigError, InputError
from recon.schema import Schema, from_dict, option, to_dict
from recon.serialize import dumps

from .common import EXIT_CHECK_FAILED, catch_errors
from .report import TOPOLOGY_ROWS, fmt, read_mesh_checked, table


@dataclass(frozen=True)
class CompareTolerances(Schema):
    """The keys of a ``--tolerances`` file (the option names with '_' for '-').

    Validated by the same machinery as the pipeline configuration (:mod:`recon.schema`), with
    the same bounds as the command-line options. ``None`` means "not given": the option's value
    (or default) applies.
    """

    max_chamfer: float | None = option(None, "Chamfer-L1 / reference diagonal limit.", 0.0)
    max_chamfer_abs: float | None = option(None, "Chamfer-L1 limit in input units.", 0.0)
    min_fscore: float | None = option(None, "Lowest F-score at tau.", 0.0, 1.0)
    max_hausdorff95: float | None = option(None, "95% Hausdorff / diagonal limit.", 0.0)
    same_topology: bool | None = option(None, "Require the reference's topology.")
    tau: float | None = option(None, "F-score threshold [input units].", 0.0, lo_open=True)
    tau_relative: float | None = option(
        None, "F-score threshold / reference diagonal.", 0.0, lo_open=True
    )
    samples: int | None = option(None, "Points sampled on each surface.", 1)
    seed: int | None = option(None, "Sampling seed.", 0)


#: Keys of a --tolerances file.
TOLERANCE_KEYS: tuple[str, ...] = tuple(f.name for f in fields(CompareTolerances))

#: Check metric -> option that sets its limit (for the failure table).
OPTION_OF = {
    "chamfer_l1_relative": "--max-chamfer",
    "chamfer_l1": "--max-chamfer-abs",
    "fscore": "--min-fscore",
    "hausdorff95_relative": "--max-hausdorff95",
}


def load_tolerances(path: Path) -> dict[str, Any]:
    """Read a YAML tolerance file (:class:`CompareTolerances`); return the keys it sets.

    Raises
    ------
    InputError
        Missing or unreadable file.
    ConfigError
        Not YAML, not a mapping, an unknown key (named, with the closest valid key), or a value
        of the wrong type or out of range; the message starts with the file name.
    """
    if not path.is_file():
        raise InputError(f"{path}: no such file" if not path.exists() else f"{path}: not a file")
    data = load_yaml_file(path)  # safe loader; syntax errors give the line and column
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a mapping of tolerances, got {type(data).__name__}")
    try:
        tolerances = from_dict(
            CompareTolerances, {str(k).replace("-", "_"): v for k, v in data.items()}
        )
    except ConfigError as exc:
        raise ConfigError(f"{path}: {exc}") from None
    return {k: v for k, v in to_dict(tolerances).items() if v is not None}


def read_reference(path: Path, as_points: bool) -> Any:
    """A (vertices, faces) mesh, or a ``PointCloud`` when the file has no faces."""
    from recon.io import read_mesh, read_points

    if not as_points and path.suffix.lower() in (".ply", ".obj"):
        vertices, faces = read_mesh(path, all_finite=True)  # every vertex is measured
        if len(faces):
            return vertices, faces
    return read_points(path, merge_duplicates=False)


def _excess_text(check: dict[str, Any]) -> str:
    if check["passed"] or check["excess"] is None:
        return ""
    limit = check["limit"]
    sign = "+" if check["op"] == "<=" else "-"
    text = f"{sign}{fmt(check['excess'], 3)}"
    if not limit:  # no share of a zero limit
        return text
    side = "over" if check["op"] == "<=" else "under"
    return f"{text} ({100 * check['excess'] / abs(limit):.0f}% {side})"


def format_comparison(
    result: dict[str, Any], checks: list[dict[str, Any]], mesh: Path, reference: Path
) -> str:
    """Human tables: distances, F-score, normals, topology side by side, then the checks."""
    r = result
    n = r["n_samples"]
    kind = r["reference_kind"]
    out = [
        f"{mesh} vs {reference} (reference: {'mesh' if kind == 'mesh' else 'point cloud'})",
        f"  {n['mesh']:,} samples on the mesh, {n['reference']:,} on the reference, seed "
        f"{r['seed']}; reference diagonal {fmt(r['diag'])}; tau {fmt(r['tau'])} "
        f"({fmt(100 * r['tau_relative'], 3)}% of the diagonal)",
    ]
    out += [f"  note: {note}" for note in r["notes"]]
    m2r, r2m = r["mesh_to_reference"], r["reference_to_mesh"]
    rows = [
        ("distance", "absolute", "÷ diagonal"),
        ("Chamfer-L1", fmt(r["chamfer_l1"]), fmt(r["chamfer_l1_relative"], 3)),
        ("Chamfer-L2", fmt(r["chamfer_l2"]), fmt(r["chamfer_l2_relative"], 3) + " (÷ diag²)"),
        ("Hausdorff", fmt(r["hausdorff"]), fmt(r["hausdorff_relative"], 3)),
        ("Hausdorff 95%", fmt(r["hausdorff95"]), fmt(r["hausdorff95_relative"], 3)),
        ("mesh -> ref mean", fmt(m2r["mean"]), fmt(m2r["mean_relative"], 3)),
        ("mesh -> ref p95", fmt(m2r["p95"]), fmt(m2r["p95_relative"], 3)),
        ("ref -> mesh mean", fmt(r2m["mean"]), fmt(r2m["mean_relative"], 3)),
        ("ref -> mesh p95", fmt(r2m["p95"]), fmt(r2m["p95_relative"], 3)),
    ]
    out += ["", table(rows)]
    nc = r["normal_consistency"]
    out += [
        "",
        table(
            [
                ("F-score @ tau", fmt(r["fscore"])),
                ("precision / recall", f"{fmt(r['precision'])} / {fmt(r['recall'])}"),
                (
                    "normal consistency",
                    "not measured"
                    if nc is None
                    else f"{fmt(nc)} (signed {fmt(r['normal_consistency_signed'])})",
                ),
            ]
        ),
    ]
    topo_m, topo_r = r["topology"]["mesh"], r["topology"]["reference"]
    rows = [("topology", "mesh", "reference")]
    for label, key in TOPOLOGY_ROWS:
        rows.append((label, fmt(topo_m[key]), "-" if topo_r is None else fmt(topo_r[key])))
    out += ["", table(rows)]
    if checks:
        rows = [("check", "value", "limit", "result", "by")]
        for c in checks:
            name = c["metric"] + (
                f" ({OPTION_OF[c['metric']]})" if c["metric"] in OPTION_OF else ""
            )
            rows.append(
                (
                    name,
                    fmt(c["value"]),
                    f"{c['op']} {fmt(c['limit'])}",
                    "ok" if c["passed"] else "FAIL",
                    _excess_text(c),
                )
            )
        n_failed = sum(not c["passed"] for c in checks)
        verdict = (
            "result: PASS (all checks within tolerance)"
            if n_failed == 0
            else f"result: FAIL ({n_failed} of {len(checks)} checks outside tolerance)"
        )
        out += ["", table(rows), verdict]
    return "\n".join(out)


@click.command("compare")
@click.argument("mesh_path", metavar="MESH", type=click.Path(path_type=Path))
@click.argument("reference_path", metavar="REFERENCE", type=click.Path(path_type=Path))
@click.option(
    "--samples",
    type=click.IntRange(min=1),
    default=100_000,
    show_default=True,
    help="Points sampled on each surface (a point-cloud reference uses at most this many).",
)
@click.option(
    "--seed", type=click.IntRange(min=0), default=0, show_default=True, help="Sampling seed."
)
@click.option(
    "--tau",
    type=click.FloatRange(min=0, min_open=True),
    help="F-score distance threshold in input units (instead of --tau-relative).",
)
@click.option(
    "--tau-relative",
    type=click.FloatRange(min=0, min_open=True),
    default=0.01,
    show_default=True,
    help="F-score threshold as a fraction of the reference's bounding-box diagonal.",
)
@click.option(
    "--max-chamfer",
    type=click.FloatRange(min=0),
    help="Fail if Chamfer-L1 divided by the reference's bounding-box diagonal exceeds this "
    "(e.g. 2e-3).",
)
@click.option(
    "--max-chamfer-abs",
    type=click.FloatRange(min=0),
    help="Fail if Chamfer-L1 in input units exceeds this.",
)
@click.option(
    "--min-fscore", type=click.FloatRange(0, 1), help="Fail if the F-score at tau is below this."
)
@click.option(
    "--max-hausdorff95",
    type=click.FloatRange(min=0),
    help="Fail if the 95% Hausdorff distance divided by the reference diagonal exceeds this.",
)
@click.option(
    "--same-topology",
    is_flag=True,
    help="Fail unless components, boundary loops, genus and watertightness match.",
)
@click.option(
    "--tolerances",
    "tolerances_path",
    metavar="FILE.yaml",
    type=click.Path(path_type=Path),
    help="YAML file with any of: max_chamfer, max_chamfer_abs, min_fscore, max_hausdorff95, "
    "same_topology, tau, tau_relative, samples, seed. Command-line options win.",
)
@click.option(
    "--reference-points",
    is_flag=True,
    help="Treat REFERENCE as a point cloud (its vertices) even if it has faces.",
)
@click.option("--json", "as_json", is_flag=True, help="Print a JSON object instead of tables.")
@catch_errors
def command(
    mesh_path: Path,
    reference_path: Path,
    samples: int,
    seed: int,
    tau: float | None,
    tau_relative: float,
    max_chamfer: float | None,
    max_chamfer_abs: float | None,
    min_fscore: float | None,
    max_hausdorff95: float | None,
    same_topology: bool,
    tolerances_path: Path | None,
    reference_points: bool,
    as_json: bool,
) -> None:
    """Compare the triangle mesh MESH with REFERENCE (a mesh, or a point cloud).

    Samples points on each surface and measures their exact distance to the other surface:
    Chamfer-L1/L2, Hausdorff and its 95th percentile, precision/recall/F-score at tau, normal
    consistency, all absolute and divided by the reference's bounding-box diagonal; and the
    topology of both. A REFERENCE without faces is a point cloud: only point-based metrics
    apply, and the output says so.

    \b
    Examples:
      oprecon compare mesh.ply gt.ply
      oprecon compare mesh.ply gt.ply --max-chamfer 2e-3 --min-fscore 0.95
      oprecon compare mesh.ply gt.ply --same-topology --json
      oprecon compare mesh.ply gt.ply --tolerances golden.yaml
      oprecon compare mesh.ply scan.ply          (point-cloud reference)

    \b
    A tolerance file, e.g.:
      max_chamfer: 0.002
      min_fscore: 0.95
      same_topology: true

    Exit codes: 0 within tolerance (or no tolerance given), 1 a check failed (the table says
    which, its value, the limit and by how much), 2 bad input or usage, 130 interrupted.
    """
    from recon.metrics import SurfaceError, check_comparison, compare_meshes

    ctx = click.get_current_context()
    file_values = load_tolerances(tolerances_path) if tolerances_path is not None else {}
    given = {
        name for name in ctx.params if ctx.get_parameter_source(name) is ParameterSource.COMMANDLINE
    }

    def pick(name: str, value: Any) -> Any:
        return value if name in given or name not in file_values else file_values[name]

    if "tau" in given and "tau_relative" in given:
        raise click.UsageError("--tau and --tau-relative are exclusive; give one")
    if "tau" in given:
        tau_abs, tau_rel = tau, tau_relative
    elif "tau_relative" in given:
        tau_abs, tau_rel = None, tau_relative
    elif "tau" in file_values and "tau_relative" in file_values:
        raise ConfigError(f"{tolerances_path}: tau and tau_relative are exclusive; give one")
    else:
        tau_abs, tau_rel = file_values.get("tau"), file_values.get("tau_relative", tau_relative)

    limits = {
        "max_chamfer": pick("max_chamfer", max_chamfer),
        "max_chamfer_abs": pick("max_chamfer_abs", max_chamfer_abs),
        "min_fscore": pick("min_fscore", min_fscore),
        "max_hausdorff95": pick("max_hausdorff95", max_hausdorff95),
        "same_topology": bool(pick("same_topology", same_topology)),
    }

    mesh = read_mesh_checked(mesh_path, "MESH")
    reference = read_reference(reference_path, reference_points)
    if limits["same_topology"] and not isinstance(reference, tuple):
        raise InputError(
            f"{reference_path}: is a point cloud; --same-topology needs a reference mesh"
        )
    try:
        result = compare_meshes(
            mesh,
            reference,
            n_samples=pick("samples", samples),
            tau=tau_abs,
            tau_relative=tau_rel,
            seed=pick("seed", seed),
        )
    except SurfaceError as exc:  # about one of the two: name that file first
        path = mesh_path if exc.side == "mesh" else reference_path
        raise InputError(
            f"{path}: {exc} (comparing {mesh_path} against {reference_path})"
        ) from None
    except InputError as exc:  # name the files (the library's messages do not know them)
        raise InputError(f"{mesh_path} against {reference_path}: {exc}") from None
    checks = check_comparison(result, **limits)
    passed = all(c["passed"] for c in checks)

    if as_json:
        payload = {
            "mesh": str(mesh_path),
            "reference": str(reference_path),
            **result,
            "limits": limits,
            "checks": checks,
            "passed": passed,
        }
        click.echo(dumps(payload, strict=True))
    else:
        click.echo(format_comparison(result, checks, mesh_path, reference_path))
    if not passed:
        sys.exit(EXIT_CHECK_FAILED)
