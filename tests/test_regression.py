"""Regression tests: fit each bundled sample and ``oprecon compare`` it with its reference mesh.

The inputs, fit options, reference meshes and tolerances are listed in
``sample_data/references/manifest.json``; ``scripts/refresh_references.py`` makes them. The
tolerances sit a few times above the float noise measured when the references were made, so
a failure means the fit changed. When the change is intended, run ``make refresh-references``,
read the metric changes it prints (against the old reference and the ground truth) and commit
the new references with the change.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from click.testing import CliRunner
from recon.cli.compare import TOLERANCE_KEYS
from recon.cli.main import app

from recon.config import ReconConfig, apply_overrides, config_to_dict, load_config
from recon.fitting import fit_file
from recon.io import read_mesh, write_mesh

ROOT = Path(__file__).resolve().parent.parent
REF_DIR = ROOT / "sample_data" / "references"
MANIFEST = json.loads((REF_DIR / "manifest.json").read_text())
ENTRIES = {e["name"]: e for e in MANIFEST["references"]}
REFRESH = "make refresh-references (or scripts/refresh_references.py --check to only look)"

#: Without the JIT a fit takes minutes; the kernels themselves are tested without it.
needs_jit = pytest.mark.skipif(
    os.environ.get("NUMBA_DISABLE_JIT", "0") not in ("", "0"),
    reason="end-to-end fits are too slow with NUMBA_DISABLE_JIT",
)


def config_for(entry: dict[str, Any]) -> ReconConfig:
    """The entry's fit config, built as ``scripts/refresh_references.py`` builds it."""
    fit = entry.get("fit", {})
    preset = fit.get("preset")
    path = ROOT / "configs" / f"{preset}.yaml" if preset else None
    return load_config(path, {**fit.get("set", {}), "seed": int(fit.get("seed", 0))})


def config_drift(entry: dict[str, Any]) -> list[str]:
    """Config keys whose resolved value differs from the one the reference was made with."""
    recorded = entry.get("made_with", {}).get("config", {})
    now: dict[str, Any] = {}

    def walk(node: dict[str, Any], prefix: str) -> None:
        for key, value in node.items():
            if isinstance(value, dict):
                walk(value, f"{prefix}{key}.")
            else:
                now[f"{prefix}{key}"] = value

    walk(config_to_dict(config_for(entry)), "")
    return [
        f"{k}: {recorded.get(k)!r} -> {now.get(k)!r}"
        for k in sorted(set(recorded) | set(now))
        if recorded.get(k) != now.get(k)
    ]


def compare(mesh: Path, reference: Path, entry: dict[str, Any]) -> Any:
    """``oprecon compare MESH REFERENCE --json`` with the entry's tolerances."""
    tol, opts = entry["tolerances"], MANIFEST["compare"]
    options = {
        "--samples": opts["samples"],
        "--seed": opts["seed"],
        "--tau-relative": opts["tau_relative"],
        "--max-chamfer": tol["max_chamfer"],
        "--min-fscore": tol["min_fscore"],
        "--max-hausdorff95": tol["max_hausdorff95"],
    }
    args = ["compare", mesh, reference, "--json"]
    for flag, value in options.items():
        args += [flag, value]
    if tol["same_topology"]:
        args.append("--same-topology")
    return CliRunner().invoke(app, [str(a) for a in args])


def failed_checks(result: Any) -> list[str]:
    payload = json.loads(result.stdout)
    return [c["metric"] for c in payload["checks"] if not c["passed"]]


def fit(entry: dict[str, Any], out: Path, **overrides: Any) -> Path:
    cfg = config_for(entry)
    if overrides:
        cfg = apply_overrides(cfg, overrides)
    fit_file(ROOT / entry["input"], out, cfg, write_report=False)
    return out


def perturbed(entry: dict[str, Any], out: Path, *, scale: float = 1.0, drop: float = 0.0) -> Path:
    """The entry's reference scaled about its bounding-box centre, or with a patch removed
    (the ``drop`` fraction of faces nearest to one vertex)."""
    vertices, faces = read_mesh(ROOT / entry["reference"])
    centre = 0.5 * (vertices.min(axis=0) + vertices.max(axis=0))
    vertices = centre + scale * (vertices - centre)
    if drop:
        centroids = vertices[faces].mean(axis=1)
        dist = np.linalg.norm(centroids - vertices[faces[len(faces) // 2, 0]], axis=1)
        faces = faces[np.argsort(dist)[int(drop * len(faces)) :]]
    write_mesh(out, vertices, faces)
    return out


# ------------------------------------------------------------------------------------------


@needs_jit
@pytest.mark.parametrize("name", list(ENTRIES))
def test_fit_matches_reference(name, tmp_path):
    entry = ENTRIES[name]
    mesh = fit(entry, tmp_path / f"{name}.ply")
    result = compare(mesh, ROOT / entry["reference"], entry)
    if result.exit_code != 0:
        drift = config_drift(entry)
        why = (
            "the fit config differs from the one the reference was made with:\n  "
            + "\n  ".join(drift)
            if drift
            else "same fit config as the reference: the code changed the result"
        )
        table = CliRunner().invoke(
            app, ["compare", str(mesh), str(ROOT / entry["reference"]), "--samples", "20000"]
        )
        pytest.fail(
            f"{name}: the fit moved outside the reference's tolerances "
            f"({', '.join(failed_checks(result)) or result.stderr.strip()}).\n{why}\n"
            f"If the change is intended: {REFRESH}.\n{table.stdout}"
        )


@needs_jit
def test_same_seed_same_bytes(tmp_path):
    # bunny-sparse is the most chaotic entry (see its noise in the manifest); vertex normals on
    entry = ENTRIES["bunny-sparse"]
    first = fit(entry, tmp_path / "first.ply", **{"output.vertex_normals": True})
    second = fit(entry, tmp_path / "second.ply", **{"output.vertex_normals": True})
    assert first.read_bytes() == second.read_bytes()


def test_gate_fails_on_scaled_reference(tmp_path):
    entry = ENTRIES["sphere-sparse"]
    scaled = perturbed(entry, tmp_path / "scaled.ply", scale=1.02)
    result = compare(ROOT / entry["reference"], scaled, entry)
    assert result.exit_code == 1, result.output
    assert "chamfer_l1_relative" in failed_checks(result)


@pytest.mark.parametrize("name", list(ENTRIES))
def test_gate_fails_on_reference_with_a_hole(name, tmp_path):
    entry = ENTRIES[name]
    holed = perturbed(entry, tmp_path / "holed.ply", drop=0.15)
    result = compare(ROOT / entry["reference"], holed, entry)
    assert result.exit_code == 1, result.output
    assert "fscore" in failed_checks(result)


def test_gate_passes_on_the_reference_itself():
    for entry in ENTRIES.values():
        ref = ROOT / entry["reference"]
        result = compare(ref, ref, entry)
        assert result.exit_code == 0, result.output


def test_manifest_matches_the_files():
    import hashlib

    for name, entry in ENTRIES.items():
        assert (ROOT / entry["input"]).is_file(), entry["input"]
        ref = ROOT / entry["reference"]
        assert ref.is_file(), f"{name}: {ref.name} is missing; run {REFRESH}"
        digest = hashlib.sha256(ref.read_bytes()).hexdigest()
        assert digest == entry["sha256"], f"{name}: {ref.name} differs from the manifest"
        assert set(entry["tolerances"]) <= set(TOLERANCE_KEYS), entry["tolerances"]
