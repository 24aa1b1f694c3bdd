"""The benchmarks' options that change what they measure."""

from __future__ import annotations

import importlib.util
import os
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


def _bench(name: str):
    spec = importlib.util.spec_from_file_location(name, ROOT / "benchmarks" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_bench_scale_prints_the_slope_of_every_phase():
    """A phase that grows as n^2 shows slope 2 while the others stay at 1 (the 4M fit's hole
    filling was found this way); a phase missing at one size has no slope."""
    rows = [
        {"points": n, "phases_s": {"grow": 1e-5 * n, "triangulate": 1e-11 * n * n, "x": 1.0}}
        for n in (100_000, 1_000_000, 4_000_000)
    ]
    rows[0]["phases_s"]["x"] = 0.0
    slopes = _bench("bench_scale")._phase_slopes(rows)
    assert slopes["grow"] == pytest.approx(1.0) and slopes["triangulate"] == pytest.approx(2.0)
    assert "x" not in slopes


def test_bench_tiles_splits_the_workers_time_by_tile():
    per_tile = [
        {"points": 100, "points_with_halo": 150, "fit_s": 2.0, "mesh_s": 0.5},
        {"points": 300, "points_with_halo": 350, "fit_s": 4.0, "mesh_s": 1.5},
    ]
    shares = _bench("bench_tiles")._tile_shares(per_tile)
    assert shares == {
        "fit_s_sum": 6.0,
        "mesh_s_sum": 2.0,
        "halo_factor": 1.25,
        "points_per_tile": 200,
    }


def test_bench_scale_passes_its_overrides_to_the_fit(monkeypatch, tmp_path):
    bench = _bench("bench_scale")
    seen = []

    def fake_run(cmd, env):
        seen.append(cmd)
        return 1.0, 10.0, 2  # a failed fit: no report to read

    monkeypatch.setattr(bench, "_run", fake_run)
    out = bench.run_oprecon(tmp_path / "in.ply", tmp_path / "o.ply", None, ["a.b=1", "c.d=2"])
    assert out["failed"]
    assert seen[0][-4:] == ["--set", "a.b=1", "--set", "c.d=2"]


def test_bench_scale_runs_a_baseline_tree_first_on_the_path(monkeypatch, tmp_path):
    """``--baseline DIR``: that tree's fit runs with DIR first on PYTHONPATH (so that its
    ``recon`` is imported, not the installed one); this tree's runs without it."""
    bench = _bench("bench_scale")
    envs = []

    def fake_run(cmd, env):
        envs.append(env)
        return 1.0, 10.0, 2

    monkeypatch.setattr(bench, "_run", fake_run)
    monkeypatch.setenv("PYTHONPATH", "elsewhere")
    bench.run_oprecon(tmp_path / "in.ply", tmp_path / "o.ply", None)
    bench.run_oprecon(tmp_path / "in.ply", tmp_path / "o.ply", None, source=tmp_path / "base")
    assert "PYTHONPATH" not in envs[0]
    assert envs[1]["PYTHONPATH"].split(os.pathsep) == [str(tmp_path / "base"), "elsewhere"]


def _row(loops, comps, watertight, genus=0, f=0.99, cd=0.001):
    return {
        "boundary_loops": loops,
        "components": comps,
        "watertight": watertight,
        "genus": genus,
        "fscore": f,
        "chamfer_l1": cd,
        "min_angle_mean": 54.0,
        "seconds": 1.0,
    }


def test_bench_seeds_judges_the_totals_over_the_seeds():
    """A branch passes when its topology totals over the seeds are no worse than the base's
    (one seed may be worse if another is better) and its mean F@1% / Chamfer-L1 are within
    the noise; each worse total is named."""
    bs = _bench("bench_seeds")
    base = bs.summarise([_row(6, 2, False), _row(5, 1, False)], genus=None)
    swapped = bs.summarise([_row(5, 1, False), _row(6, 2, False)], genus=None)
    assert bs.verdict(base, swapped, 0.002, 0.05) == []
    more = bs.summarise([_row(6, 2, False), _row(6, 1, False)], genus=None)
    assert bs.verdict(base, more, 0.002, 0.05) == ["loops"]
    closed = bs.summarise([_row(0, 1, True), _row(0, 1, True)], genus=0)
    broken = bs.summarise([_row(0, 1, True, genus=1), _row(2, 1, False)], genus=0)
    assert bs.verdict(closed, broken, 0.002, 0.05) == ["loops", "watertight", "genus"]
    worse_fit = bs.summarise([_row(0, 1, True, f=0.99, cd=0.00106)] * 2, genus=0)
    assert bs.verdict(closed, worse_fit, 0.002, 0.05) == ["CD-L1"]
    text, failed = bs.table(
        ["a", "b"], {"a": closed, "b": base}, {"a": broken, "b": swapped}, 0.002, 0.05
    )
    assert failed == 1 and "worse: loops, watertight, genus" in text and "| ok |" in text


def test_bench_quality_compiles_byte_code_even_when_python_would_not(tmp_path, monkeypatch):
    """The workers import oprecon from byte code: compile_sources writes it although
    PYTHONDONTWRITEBYTECODE (sys.dont_write_bytecode) keeps imports from doing so."""
    import importlib.util as util
    import sys

    package = tmp_path / "pkg"
    package.mkdir()
    module = package / "mod.py"
    module.write_text("X = 1\n")
    monkeypatch.setattr(sys, "dont_write_bytecode", True)
    assert not Path(util.cache_from_source(str(module))).exists()
    assert _bench_quality().compile_sources(package)
    assert Path(util.cache_from_source(str(module))).exists()


def test_bench_startup_times_the_import_and_the_fit_of_a_fresh_process(capsys):
    """bench_startup prints, per checkout, the import and import + fit medians of fresh
    processes: the fit takes longer than the import alone, and both take some time."""
    spec = importlib.util.spec_from_file_location(
        "bench_startup", ROOT / "benchmarks" / "bench_startup.py"
    )
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    assert module.main([str(ROOT / "sample_data" / "sphere-sparse.ply"), "--runs", "1"]) == 0
    row = next(x for x in capsys.readouterr().out.splitlines() if x.startswith(f"| {ROOT}"))
    import_wall, import_cpu, total_wall, total_cpu = map(float, row.strip("|").split("|")[1:])
    assert 0.0 < import_wall < total_wall
    assert 0.0 < import_cpu < total_cpu


def test_bench_startup_does_numbas_start_before_the_clock_and_times_a_second_fit(capsys):
    """``--before kernels --second``: the kernels load before the clock, and the row gains
    the second fit's wall and CPU time (a warm process: no import, no numba start)."""
    spec = importlib.util.spec_from_file_location(
        "bench_startup", ROOT / "benchmarks" / "bench_startup.py"
    )
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    sample = str(ROOT / "sample_data" / "sphere-sparse.ply")
    assert module.main([sample, "--runs", "1", "--before", "kernels", "--second"]) == 0
    out = capsys.readouterr().out
    assert "done before the clock: kernels" in out
    row = next(x for x in out.splitlines() if x.startswith(f"| {ROOT}"))
    values = list(map(float, row.strip("|").split("|")[1:]))
    assert len(values) == 6 and all(v > 0.0 for v in values)
    assert values[0] < values[2]  # the import is part of the first fit's region


def test_the_inward_share_finds_a_part_turned_inside_out():
    """An outward sphere has no area wound inward, the reversed one all of it, and with one
    cap turned over (still watertight, genus 0: only the winding tells) the cap's share."""
    import numpy as np
    import open3d as o3d

    bench = _bench("bench_thin_parts")
    m = o3d.geometry.TriangleMesh.create_sphere(radius=0.5, resolution=30)
    v = np.asarray(m.vertices) + [0.1, -0.2, 0.3]
    f = np.asarray(m.triangles, dtype=np.int64)
    sdf = bench.ellipsoid([0.1, -0.2, 0.3], [0.5, 0.5, 0.5])
    assert bench.inward_share(v, f, sdf) == 0.0
    assert bench.inward_share(v, f[:, ::-1], sdf) == 1.0
    tri = v[f]
    cap = tri.mean(axis=1)[:, 2] > 0.3 + 0.25  # the faces above z = 0.25 (about a quarter)
    turned = f.copy()
    turned[cap] = turned[cap][:, ::-1]
    area = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    expected = area[cap].sum() / area.sum()
    assert 0.1 < expected < 0.4
    assert abs(bench.inward_share(v, turned, sdf) - expected) < 1e-12
    judged = bench.judge(v, turned, tri.mean(axis=1), sdf)
    assert judged["watertight"] and judged["genus"] == 0  # the topology cannot tell
    assert judged["inward"] == bench.inward_share(v, turned, sdf)
    assert bench.judge(v, f, tri.mean(axis=1))["inward"] is None  # no implicit function
