"""Refresh (or check) the reference meshes of the regression tests, printing what changed.

``sample_data/references/manifest.json`` lists the references. For each entry the script fits
the entry's input with the entry's fit options (in-process, ``recon.fitting.fit_file``, so
the file is what ``oprecon fit`` writes), then prints, against the OLD reference and against
the ground truth (when the development data set is beside the checkout), a table of
Chamfer-L1, F-score at 1 %, Hausdorff-95, faces, boundary loops and watertightness, and the
``oprecon compare NEW OLD`` checks with the manifest's tolerances (``check_comparison``).

Without ``--check`` it then re-measures the float-noise level of every fit, derives new
tolerances from it, and writes the new meshes and the manifest; every file goes to a
temporary file first and all are renamed into place only after all were written, so a failed
or interrupted run changes nothing.

Usage (from the repository root)::

    make refresh-references                          # refit all, print changes, write
    .venv/bin/python scripts/refresh_references.py   # the same
    .venv/bin/python scripts/refresh_references.py --check          # print only; exit 1 if
                                                                    # outside tolerance
    .venv/bin/python scripts/refresh_references.py bunny-sparse     # some entries only
    .venv/bin/python scripts/refresh_references.py --make-inputs    # rebuild the inputs

Exit codes: 0 done (or ``--check`` within tolerance), 1 ``--check`` found a reference outside
tolerance or missing, 2 bad input (a fit failed, an unknown entry, a broken manifest).

Manifest
--------
Hand-edited fields (the script keeps them): top-level ``compare`` (samples, seed, tau_relative
of the comparisons) and ``tolerance_policy``; per entry ``name``, ``description``, ``input``
(path relative to the repository root), ``source`` (the development case it comes from, and
``subsample``/``subsample_seed`` when it was thinned), ``fit`` (``seed``, ``preset`` and
``set``: dotted config overrides as given to ``--set``) and optional ``tolerance_overrides``.
Written by the script: ``reference``, ``sha256``, ``bytes``, ``mesh`` (counts and topology),
``noise``, ``tolerances``, ``vs_ground_truth`` (or ``vs_ground_truth_note``) and
``made_with`` (version, git revision, date, the full resolved fit config).

Tolerances
----------
The fit is deterministic on one machine, but other platforms and library versions round
differently, and the reconstruction amplifies tiny differences at its discrete decisions
(accepting a particle, pivoting a ball). The noise level is measured by refitting the input
with every coordinate moved by up to one float32 ulp (``noise_runs`` fits with fixed seeds;
differences at the 1e-10 level change nothing measurable) and comparing with the new mesh.
Then ``max_chamfer = max(factor x worst Chamfer, min_chamfer)``, the same for Hausdorff-95,
``min_fscore = 1 - max(factor x (1 - worst F), min_fscore_margin)``, and ``same_topology`` only
when every noise fit kept the topology. To add a reference: add an entry with ``name``,
``description``, ``input``, ``source`` and ``fit``, then run this script.
"""

from __future__ import annotations

import argparse
import datetime
import hashlib
import json
import math
import subprocess
import sys
import tempfile
import time
from contextlib import ExitStack
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from recon import __version__  # noqa: E402
from recon.config import ReconConfig, config_to_dict, load_config  # noqa: E402
from recon.dynamics import warmup  # noqa: E402
from recon.errors import OpreconError  # noqa: E402
from recon.fitting import fit_file, reconstruct  # noqa: E402
from recon.io import atomic_output, cloud_from_arrays, read_mesh, read_points  # noqa: E402
from recon.metrics import check_comparison, compare_meshes, mesh_topology  # noqa: E402

MANIFEST = ROOT / "sample_data" / "references" / "manifest.json"
DEFAULT_DATA = ROOT.parent / "shared" / "data"
#: Bundled files above this size [bytes] get a warning (sample_data/ is kept small).
MAX_FILE_BYTES = 100_000
#: Samples of the comparisons against the ground truth (higher than the test's: once per run).
GT_SAMPLES = 100_000
TOPOLOGY_KEYS = ("components", "boundary_loops", "genus", "watertight")


# --------------------------------------------------------------------------------------------
# manifest and configuration


def load_manifest(path: Path = MANIFEST) -> dict[str, Any]:
    try:
        manifest = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise SystemExit(f"refresh_references: {path}: cannot read the manifest: {exc}") from None
    names = [e.get("name") for e in manifest.get("references", [])]
    if not names or len(set(names)) != len(names) or None in names:
        raise SystemExit(f"refresh_references: {path}: entries need unique names, got {names}")
    return manifest


def config_for(entry: dict[str, Any]) -> ReconConfig:
    """Defaults < ``fit.preset`` (configs/<preset>.yaml) < ``fit.set`` < ``fit.seed``."""
    fit = entry.get("fit", {})
    preset = fit.get("preset")
    path = ROOT / "configs" / f"{preset}.yaml" if preset else None
    return load_config(path, {**fit.get("set", {}), "seed": int(fit.get("seed", 0))})


def flat_config(cfg: ReconConfig) -> dict[str, Any]:
    """``{"section.key": value}`` of a resolved config (one line per key in the manifest)."""
    out: dict[str, Any] = {}

    def walk(node: Any, prefix: str) -> None:
        for key, value in node.items():
            if isinstance(value, dict):
                walk(value, f"{prefix}{key}.")
            else:
                out[f"{prefix}{key}"] = value

    walk(config_to_dict(cfg), "")
    return out


def git_revision() -> str:
    try:
        out = subprocess.run(
            ["git", "describe", "--always", "--dirty"],
            cwd=ROOT,
            capture_output=True,
            text=True,
            timeout=10,
            check=True,
        )
        return out.stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


# --------------------------------------------------------------------------------------------
# measuring


def topology_summary(vertices: np.ndarray, faces: np.ndarray) -> dict[str, Any]:
    t = mesh_topology(vertices, faces)
    keys = ("n_vertices", "n_faces", *TOPOLOGY_KEYS, "non_manifold_edges", "non_manifold_vertices")
    return {k: t[k] for k in keys}


def compare(mesh: tuple, reference: tuple, opts: dict[str, Any]) -> dict[str, Any]:
    return compare_meshes(
        mesh,
        reference,
        n_samples=int(opts.get("samples", 20_000)),
        seed=int(opts.get("seed", 0)),
        tau_relative=float(opts.get("tau_relative", 0.01)),
    )


def vs_ground_truth(mesh: tuple, gt: tuple, gt_name: str) -> dict[str, Any]:
    r = compare_meshes(mesh, gt, n_samples=GT_SAMPLES, seed=0, tau_relative=0.01)
    return {
        "gt": gt_name,
        "samples": GT_SAMPLES,
        "chamfer_l1_relative": r["chamfer_l1_relative"],
        "fscore": r["fscore"],
        "precision": r["precision"],
        "recall": r["recall"],
        "hausdorff95_relative": r["hausdorff95_relative"],
        "normal_consistency": r["normal_consistency"],
        "gt_topology": {k: r["topology"]["reference"][k] for k in TOPOLOGY_KEYS},
    }


def jitter_noise(
    entry: dict[str, Any], cfg: ReconConfig, new_mesh: tuple, opts: dict[str, Any], runs: int
) -> dict[str, Any]:
    """Worst difference between the new mesh and fits of ulp-perturbed copies of the input."""
    cloud = read_points(
        ROOT / entry["input"],
        max_points=cfg.io.max_points,
        merge_duplicates=cfg.io.merge_duplicates,
    )
    points = cloud.absolute_points()
    ulp = np.spacing(np.abs(points).astype(np.float32)).astype(np.float64)
    ref_topo = mesh_topology(*new_mesh)
    worst = {"chamfer_l1_relative": 0.0, "hausdorff95_relative": 0.0, "fscore": 1.0}
    changed: list[str] = []
    for k in range(runs):
        rng = np.random.default_rng(1000 + k)
        moved = points + rng.uniform(-1.0, 1.0, size=points.shape) * ulp
        res = reconstruct(cloud_from_arrays(moved, cloud.normals), cfg)
        r = compare((res.mesh.vertices, res.mesh.faces), new_mesh, opts)
        worst["chamfer_l1_relative"] = max(worst["chamfer_l1_relative"], r["chamfer_l1_relative"])
        worst["hausdorff95_relative"] = max(
            worst["hausdorff95_relative"], r["hausdorff95_relative"]
        )
        worst["fscore"] = min(worst["fscore"], r["fscore"])
        topo = r["topology"]["mesh"]
        changed += [
            f"run {k}: {key} {ref_topo[key]} -> {topo[key]}"
            for key in TOPOLOGY_KEYS
            if topo[key] != ref_topo[key]
        ]
    return {
        "runs": runs,
        "perturbation": "each input coordinate moved by uniform(-1, 1) float32 ulp",
        **worst,
        "topology_stable": not changed,
        "topology_changes": changed,
    }


def _round_up(x: float, digits: int = 2) -> float:
    if x <= 0:
        return 0.0
    scale = 10.0 ** (math.floor(math.log10(x)) - digits + 1)
    return float(f"{math.ceil(x / scale - 1e-9) * scale:.{digits}g}")


def tolerances_from(noise: dict[str, Any], policy: dict[str, Any], overrides: dict) -> dict:
    factor = float(policy["factor"])
    margin = max(factor * (1.0 - noise["fscore"]), float(policy["min_fscore_margin"]))
    tol = {
        "max_chamfer": _round_up(
            max(factor * noise["chamfer_l1_relative"], float(policy["min_chamfer"]))
        ),
        "min_fscore": math.floor(round((1.0 - margin) * 1e4, 6)) / 1e4,
        "max_hausdorff95": _round_up(
            max(factor * noise["hausdorff95_relative"], float(policy["min_hausdorff95"]))
        ),
        "same_topology": bool(noise["topology_stable"]),
    }
    tol.update(overrides or {})
    return tol


# --------------------------------------------------------------------------------------------
# printing


def _num(x: Any, kind: str) -> str:
    if x is None:
        return "-"
    if kind == "sci":
        return f"{x:.3e}"
    if kind == "f":
        return f"{x:.4f}"
    if kind == "bool":
        return "yes" if x else "no"
    return f"{x:,}" if isinstance(x, int) else str(x)


def _change(old: Any, new: Any, kind: str) -> str:
    if old is None or new is None:
        return ""
    if kind == "bool":
        return "same" if old == new else "CHANGED"
    if kind == "int":
        return "same" if old == new else f"{new - old:+,}"
    if kind == "f":
        return f"{new - old:+.4f}"
    return f"{100 * (new - old) / old:+.1f}%" if old else ""


def print_entry(
    entry: dict[str, Any],
    elapsed: float,
    old: dict[str, Any] | None,
    new: dict[str, Any],
    checks: list[dict[str, Any]] | None,
    gt_note: str | None,
) -> None:
    fit = entry.get("fit", {})
    sets = " ".join(f"{k}={v}" for k, v in fit.get("set", {}).items()) or "-"
    print(f"\n== {entry['name']}: {entry['input']} ({entry.get('description', '')})")
    preset = f"; preset {fit['preset']}" if fit.get("preset") else ""
    print(f"   fit {elapsed:.1f} s; seed {fit.get('seed', 0)}{preset}; set {sets}")
    rows = [
        ("chamfer-L1 vs GT", "gt", "chamfer_l1_relative", "sci"),
        ("F@1% vs GT", "gt", "fscore", "f"),
        ("hausdorff95 vs GT", "gt", "hausdorff95_relative", "sci"),
        ("faces", "mesh", "n_faces", "int"),
        ("boundary loops", "mesh", "boundary_loops", "int"),
        ("watertight", "mesh", "watertight", "bool"),
    ]
    print(f"   {'':<20}{'old ref':>12}{'new mesh':>12}  change")
    for label, part, key, kind in rows:
        a = ((old or {}).get(part) or {}).get(key)
        b = (new.get(part) or {}).get(key)
        print(f"   {label:<20}{_num(a, kind):>12}{_num(b, kind):>12}  {_change(a, b, kind)}")
    if gt_note:
        print(f"   (vs GT: {gt_note})")
    if checks is None:
        print("   new vs old reference: no old reference")
        return
    parts = []
    for c in checks:
        if c["metric"].startswith("topology."):
            continue
        v = _num(c["value"], "f" if c["metric"] == "fscore" else "sci")
        lim = _num(c["limit"], "f" if c["metric"] == "fscore" else "sci")
        parts.append(f"{c['metric']} {v} {c['op']} {lim} {'ok' if c['passed'] else 'FAIL'}")
    topo = [c for c in checks if c["metric"].startswith("topology.")]
    if topo:
        bad = [f"{c['metric'][9:]} {c['limit']}->{c['value']}" for c in topo if not c["passed"]]
        parts.append("topology " + ("same ok" if not bad else "FAIL (" + ", ".join(bad) + ")"))
    verdict = "within tolerance" if all(c["passed"] for c in checks) else "OUTSIDE TOLERANCE"
    print("   new vs old reference: " + "; ".join(parts) + f"  => {verdict}")


# --------------------------------------------------------------------------------------------
# inputs


def make_input(entry: dict[str, Any], data: Path) -> bool:
    """Rebuild ``entry['input']`` from the development case named in ``entry['source']``."""
    import plyfile

    source = entry.get("source") or {}
    if "case" not in source:
        print(f"{entry['name']}: no source case; input left as is")
        return False
    src = data / "cases" / source["case"] / "input.ply"
    dest = ROOT / entry["input"]
    if source.get("subsample"):
        ply = plyfile.PlyData.read(str(src))
        rows = ply["vertex"].data
        keep = np.sort(
            np.random.default_rng(int(source.get("subsample_seed", 0))).choice(
                len(rows), int(source["subsample"]), replace=False
            )
        )
        element = plyfile.PlyElement.describe(rows[keep], "vertex")
        with tempfile.TemporaryDirectory() as tmp:
            out = Path(tmp) / "input.ply"
            plyfile.PlyData([element], byte_order="<").write(str(out))
            content = out.read_bytes()
    else:
        content = src.read_bytes()
    if dest.is_file() and dest.read_bytes() == content:
        print(f"{entry['name']}: {entry['input']} is up to date")
        return False
    with atomic_output(dest) as tmp:
        tmp.write_bytes(content)
    print(f"{entry['name']}: wrote {entry['input']} ({len(content):,} bytes) from {src}")
    return True


# --------------------------------------------------------------------------------------------
# main


def refresh(args: argparse.Namespace) -> int:
    manifest = load_manifest()
    entries = manifest["references"]
    known = [e["name"] for e in entries]
    unknown = [n for n in args.names if n not in known]
    if unknown:
        print(f"refresh_references: unknown entries {unknown}; known: {known}", file=sys.stderr)
        return 2
    selected = [e for e in entries if not args.names or e["name"] in args.names]
    data = args.data
    if args.make_inputs:
        if not (data / "cases").is_dir():
            print(f"refresh_references: no development data at {data}", file=sys.stderr)
            return 2
        for entry in selected:
            make_input(entry, data)
        return 0
    has_data = (data / "cases").is_dir()
    opts = manifest["compare"]
    policy = manifest["tolerance_policy"]
    ref_dir = MANIFEST.parent
    mode = "check" if args.check else "refresh"
    print(
        f"{mode}: {len(selected)} reference(s) in {MANIFEST.relative_to(ROOT).as_posix()}; "
        f"ground truth {'from ' + str(data) if has_data else 'not found at ' + str(data)}"
    )

    t0 = time.perf_counter()
    warmup()
    print(f"kernels compiled or loaded in {time.perf_counter() - t0:.1f} s")

    staged: list[tuple[Path, Path]] = []  # (new file in tmp, destination)
    results: list[tuple[str, bool | None]] = []
    revision = git_revision()
    date = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")
    with tempfile.TemporaryDirectory(prefix="oprecon-refs-") as tmpdir:
        for entry in selected:
            cfg = config_for(entry)
            out = Path(tmpdir) / f"{entry['name']}.ply"
            t0 = time.perf_counter()
            try:
                fit_file(ROOT / entry["input"], out, cfg, write_report=False)
            except OpreconError as exc:
                print(
                    f"refresh_references: {entry['name']}: the fit failed: {exc}", file=sys.stderr
                )
                return 2
            elapsed = time.perf_counter() - t0
            new_mesh = read_mesh(out)
            ref_path = ref_dir / f"{entry['name']}.ply"
            old_mesh = read_mesh(ref_path) if ref_path.is_file() else None

            gt_mesh, gt_note, gt_name = None, None, None
            source = entry.get("source") or {}
            if has_data and "case" in source:
                meta = json.loads((data / "cases" / source["case"] / "meta.json").read_text())
                gt_name = meta["gt"]
                gt_mesh = read_mesh(data / gt_name)
            elif not has_data:
                gt_note = f"not measured, no development data at {data}"
            else:
                gt_note = "not measured, the entry names no source case"

            new = {"mesh": topology_summary(*new_mesh)}
            old: dict[str, Any] | None = None
            if gt_mesh is not None:
                new["gt"] = vs_ground_truth(new_mesh, gt_mesh, gt_name)
            if old_mesh is not None:
                old = {"mesh": topology_summary(*old_mesh)}
                if gt_mesh is not None:
                    old["gt"] = vs_ground_truth(old_mesh, gt_mesh, gt_name)
                else:
                    old["gt"] = entry.get("vs_ground_truth")
            checks = None
            if old_mesh is not None and entry.get("tolerances"):
                result = compare(new_mesh, old_mesh, opts)
                checks = check_comparison(result, **entry["tolerances"])
            print_entry(entry, elapsed, old, new, checks, gt_note)
            passed = None if checks is None else all(c["passed"] for c in checks)
            results.append((entry["name"], passed))
            if args.check:
                continue

            noise = jitter_noise(entry, cfg, new_mesh, opts, int(policy["noise_runs"]))
            tol = tolerances_from(noise, policy, entry.get("tolerance_overrides", {}))
            print(
                f"   float noise ({noise['runs']} ulp-perturbed fits): chamfer <= "
                f"{noise['chamfer_l1_relative']:.2e}, H95 <= {noise['hausdorff95_relative']:.2e}"
                f", F >= {noise['fscore']:.4f}, topology "
                f"{'stable' if noise['topology_stable'] else 'UNSTABLE'}"
            )
            print("   new tolerances: " + ", ".join(f"{k} {v}" for k, v in tol.items()))
            size = out.stat().st_size
            if size > MAX_FILE_BYTES:
                print(
                    f"   warning: the reference is {size:,} bytes (> {MAX_FILE_BYTES:,}); "
                    "coarsen the fit options to keep sample_data small"
                )
            entry["reference"] = ref_path.relative_to(ROOT).as_posix()
            entry["sha256"] = sha256(out)
            entry["bytes"] = size
            entry["mesh"] = new["mesh"]
            entry["noise"] = noise
            entry["tolerances"] = tol
            entry.pop("vs_ground_truth_note", None)
            if "gt" in new:
                entry["vs_ground_truth"] = new["gt"]
            else:
                entry["vs_ground_truth"] = None
                entry["vs_ground_truth_note"] = gt_note
            entry["made_with"] = {
                "oprecon_version": __version__,
                "git": revision,
                "date": date,
                "fit_seconds": round(elapsed, 2),
                "config": flat_config(cfg),
            }
            staged.append((out, ref_path))

        print("\nsummary (new mesh vs old reference, with the old tolerances):")
        for name, passed in results:
            state = {None: "no old reference", True: "within tolerance", False: "OUTSIDE"}
            print(f"   {name:<24}{state[passed]}")
        if args.check:
            return 0 if all(p for _, p in results) else 1

        with ExitStack() as stack:
            # entered first, so renamed into place last (ExitStack unwinds in reverse)
            tmp_manifest = stack.enter_context(atomic_output(MANIFEST))
            tmp_manifest.write_text(json.dumps(manifest, indent=1) + "\n")
            for src, dest in staged:
                stack.enter_context(atomic_output(dest)).write_bytes(src.read_bytes())
    print(f"\nwrote {len(staged)} reference mesh(es) and {MANIFEST.relative_to(ROOT).as_posix()}")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__.splitlines()[0],
        epilog="See the module docstring for the manifest format and the tolerance policy.",
    )
    parser.add_argument("names", nargs="*", help="entries to refresh (default: all)")
    parser.add_argument(
        "--check",
        action="store_true",
        help="print the changes only, write nothing; exit 1 if outside tolerance",
    )
    parser.add_argument(
        "--data",
        type=Path,
        default=DEFAULT_DATA,
        help="development data set with the ground-truth meshes (default: ../shared/data "
        "beside the checkout; skipped when missing)",
    )
    parser.add_argument(
        "--make-inputs",
        action="store_true",
        help="rebuild the entries' input files from their development cases, then stop",
    )
    args = parser.parse_args(argv)
    return refresh(args)


if __name__ == "__main__":
    sys.exit(main())
