"""The benchmarks' options that change what they measure."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _bench_quality():
    spec = importlib.util.spec_from_file_location(
        "bench_quality", ROOT / "benchmarks" / "bench_quality.py"
    )
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize(
    ("env", "expected"),
    [(None, "default"), ("passive", "PASSIVE"), ("ACTIVE", "ACTIVE"), ("", "default")],
)
def test_wait_policy_default_is_never_an_invalid_openmp_value(monkeypatch, env, expected):
    """Unset, the default must not become OMP_WAIT_POLICY=DEFAULT (libgomp rejects it)."""
    if env is None:
        monkeypatch.delenv("OMP_WAIT_POLICY", raising=False)
    else:
        monkeypatch.setenv("OMP_WAIT_POLICY", env)
    assert _bench_quality()._wait_policy_default() == expected


def test_bench_phases_accounts_every_phase(capsys):
    """bench_phases prints wall and CPU seconds for every phase of the fit, and the mesh hash;
    the CPU time of a phase is at least a part of the fit (not zero everywhere)."""
    spec = importlib.util.spec_from_file_location(
        "bench_phases", ROOT / "benchmarks" / "bench_phases.py"
    )
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    sample = ROOT / "sample_data" / "bunny-sparse.ply"
    assert module.main([str(sample), "--runs", "1"]) == 0
    out = capsys.readouterr().out
    rows = {line.split()[0]: line.split()[1:] for line in out.splitlines() if line.strip()}
    for phase in ("normals", "setup", "grow", "release", "triangulate", "report", "total"):
        wall, cpu = map(float, rows[phase])
        assert wall >= 0.0 and cpu >= 0.0
    assert float(rows["total"][1]) > 0.0
    assert "mesh sha1" in out
