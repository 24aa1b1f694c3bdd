"""Threads under control: ``--threads`` / the ``threads`` key, the OpenMP wait policy, threads
per batch item, and meshes that do not depend on the thread count."""

from __future__ import annotations

import contextlib
import importlib
import json
import os
from pathlib import Path

import numba
import numpy as np
import pytest
import recon.cli.batch as cli_batch
from click.testing import CliRunner
from recon.cli.main import app

from recon import batch
from recon.batch.resume import config_hash
from recon.batch.supervise import THREAD_ENV, _child_env
from recon.config import ReconConfig, apply_overrides, load_config
from recon.errors import ConfigError
from recon.kernels import options
from recon.kernels.options import query_workers, thread_count, usable_threads

ROOT = Path(__file__).resolve().parents[1]
SPHERE = ROOT / "sample_data" / "sphere-sparse.ply"
POOL = int(numba.config.NUMBA_NUM_THREADS)
WAIT_VARS = ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT")
batch_run = importlib.import_module("recon.batch.run")
needs_two = pytest.mark.skipif(POOL < 2, reason="numba has fewer than 2 threads here")


@pytest.fixture
def clean_env(monkeypatch):
    """The thread variables unset (and restored after the test: the CLI sets them)."""
    for var in (*THREAD_ENV, *WAIT_VARS):
        monkeypatch.delenv(var, raising=False)
    return monkeypatch


@pytest.fixture
def set_calls(monkeypatch):
    """The ``threads`` of every fit (or normals run): thread_count's argument, then the count
    numba had inside."""
    import recon.fitting.pipeline

    calls: list[tuple[int | None, int]] = []
    real = options.thread_count

    @contextlib.contextmanager
    def spy(threads):
        with real(threads) as n:
            calls.append((threads, numba.get_num_threads()))
            yield n

    monkeypatch.setattr(recon.fitting.pipeline, "thread_count", spy)
    monkeypatch.setattr(options, "thread_count", spy)
    return calls


# --------------------------------------------------------------------------------------------
# the library


def test_thread_count_sets_caps_and_restores():
    before = numba.get_num_threads()
    with thread_count(1) as n:
        assert n == 1 and numba.get_num_threads() == 1 and query_workers() == 1
    assert numba.get_num_threads() == before
    with thread_count(POOL + 5) as n:
        assert n == POOL == numba.get_num_threads()  # capped by numba's pool
    with thread_count(None) as n:
        assert n == before == numba.get_num_threads()
    with pytest.raises(RuntimeError), thread_count(1):
        raise RuntimeError("a failing fit")
    assert numba.get_num_threads() == before
    assert usable_threads(None) == POOL and usable_threads(1) == 1


def test_threads_key_is_validated_and_does_not_change_the_batch_fingerprint():
    assert ReconConfig().threads is None
    assert load_config(None, ["threads=2"]).threads == 2
    with pytest.raises(ConfigError, match="threads"):
        load_config(None, ["threads=0"])
    cfg = ReconConfig()
    assert config_hash(apply_overrides(cfg, {"threads": 1})) == config_hash(cfg)
    assert config_hash(apply_overrides(cfg, {"seed": 1})) != config_hash(cfg)


def _force_threaded_kernels(monkeypatch) -> None:
    """Use the threaded kernels even on a small sample (normally from 30,000 particles)."""
    import recon.dynamics
    import recon.forces
    import recon.neighbors

    for mod in (recon.neighbors, recon.dynamics, recon.forces):
        monkeypatch.setattr(mod, "PARALLEL_MIN_PARTICLES", 0)
    monkeypatch.setattr(recon.dynamics, "ALWAYS_THREADED", 0)


@needs_two
def test_fit_is_byte_identical_with_one_and_two_threads(tmp_path, monkeypatch):
    from recon.fitting import fit_file

    _force_threaded_kernels(monkeypatch)
    meshes, seen = {}, {}
    for n in (1, 2):
        counts: set[int] = set()
        cfg = load_config(None, [f"threads={n}", "seed=3"])
        out = tmp_path / f"t{n}.ply"
        fit_file(
            SPHERE,
            out,
            cfg,
            particles_path=tmp_path / f"p{n}.ply",
            on_progress=lambda phase, info, c=counts: c.add(numba.get_num_threads()),
        )
        meshes[n] = (out.read_bytes(), (tmp_path / f"p{n}.ply").read_bytes())
        seen[n] = counts
    assert seen == {1: {1}, 2: {2}}  # the fit really ran with that many threads
    assert meshes[1] == meshes[2]


# --------------------------------------------------------------------------------------------
# the commands


def invoke(*args: str):
    return CliRunner().invoke(app, list(args))


@needs_two
def test_cli_fit_threads_same_mesh_and_environment(tmp_path, clean_env, set_calls):
    out = {}
    for n in (1, 2):
        out[n] = tmp_path / f"m{n}.ply"
        result = invoke("fit", str(SPHERE), "-o", str(out[n]), "--quiet", "--threads", str(n))
        assert result.exit_code == 0, result.output
        assert os.environ["OMP_NUM_THREADS"] == os.environ["OPENBLAS_NUM_THREADS"] == str(n)
        report = json.loads(out[n].with_suffix(".report.json").read_text())
        assert report["config"]["threads"] == n
    assert set_calls == [(1, 1), (2, 2)]
    assert out[1].read_bytes() == out[2].read_bytes()


def test_cli_fit_without_threads_leaves_numba_alone(tmp_path, clean_env, set_calls):
    result = invoke("fit", str(SPHERE), "-o", str(tmp_path / "m.ply"), "--quiet")
    assert result.exit_code == 0, result.output
    assert set_calls == [(None, POOL)]
    assert "OMP_NUM_THREADS" not in os.environ and "OMP_WAIT_POLICY" not in os.environ


def test_cli_threads_from_the_config_key(tmp_path, clean_env, set_calls):
    args = ["-o", str(tmp_path / "m.ply"), "--quiet", "--set", "threads=1"]
    assert invoke("fit", str(SPHERE), *args).exit_code == 0
    assert set_calls == [(1, 1)]


def test_cli_normals_threads(tmp_path, clean_env, set_calls):
    result = invoke("normals", str(SPHERE), "-o", str(tmp_path / "n.ply"), "--threads", "1")
    assert result.exit_code == 0, result.output
    assert set_calls == [(1, 1)]
    assert os.environ["OMP_NUM_THREADS"] == "1"


@pytest.mark.parametrize("command", ["fit", "normals", "batch"])
def test_cli_bad_threads_exit_2_and_help_gives_the_default(tmp_path, command):
    args = [command, str(SPHERE), "--threads", "0"]
    if command != "batch":
        args += ["-o", str(tmp_path / "x.ply")]
    result = invoke(*args)
    assert result.exit_code == 2 and "--threads" in result.output
    text = " ".join(invoke(command, "--help").output.split())
    assert "--threads N" in text
    assert ("cores // items at a time" if command == "batch" else "Default: all usable cores") in (
        text
    )


# --------------------------------------------------------------------------------------------
# batch: threads per item


def test_child_env_default_keeps_the_users_values_and_threads_overrides(clean_env):
    env = _child_env(1)
    assert all(env[v] == "1" for v in THREAD_ENV) and "OMP_WAIT_POLICY" not in env
    clean_env.setenv("NUMBA_NUM_THREADS", "7")
    env = _child_env(1)
    assert env["NUMBA_NUM_THREADS"] == "7" and env["OMP_NUM_THREADS"] == "1"
    assert _child_env(3, force=True)["NUMBA_NUM_THREADS"] == "3"


def env_job(spec: dict, on_progress) -> dict:
    """A fake job (run in the child) that writes its thread settings as its mesh."""
    seen = {v: os.environ.get(v) for v in THREAD_ENV}
    seen["numba"] = numba.get_num_threads()
    for mesh in spec["meshes"]:
        Path(mesh).write_text(json.dumps(seen))
    report = {"particles": 1, "topology": {"n_faces": 1}, "coverage": 1.0}
    Path(spec["report"]).write_text(json.dumps(report))
    return batch.metrics_from_report(report)


def _batch_env(tmp_path: Path, monkeypatch, *args: str) -> dict[str, dict]:
    for name in ("a", "b"):
        np.savetxt(tmp_path / f"{name}.xyz", np.eye(3) + (name == "b"))
    path = tmp_path / "batch.yaml"
    path.write_text("inputs: ['*.xyz']\noutput_dir: out\n")

    def run_env_job(plan, **kw):
        return batch.run_batch(plan, job=env_job, **kw)

    monkeypatch.setattr(cli_batch, "run_batch", run_env_job)
    result = invoke("batch", str(path), "--quiet", "--force", *args)
    assert result.exit_code == 0, result.output
    return {n: json.loads((tmp_path / "out" / f"{n}.ply").read_text()) for n in ("a", "b")}


def test_batch_threads_per_item_default_is_cores_over_jobs(tmp_path, clean_env, monkeypatch):
    monkeypatch.setattr(batch_run, "default_jobs", lambda: 4)
    seen = _batch_env(tmp_path, monkeypatch, "--jobs", "2")
    for env in seen.values():
        assert env["NUMBA_NUM_THREADS"] == env["OMP_NUM_THREADS"] == "2"  # 4 cores / 2 jobs
        assert env["numba"] == 2
    seen = _batch_env(tmp_path, monkeypatch, "--jobs", "8")
    assert {env["NUMBA_NUM_THREADS"] for env in seen.values()} == {"2"}  # 2 items at a time
    monkeypatch.setattr(batch_run, "default_jobs", lambda: 1)
    seen = _batch_env(tmp_path, monkeypatch, "--jobs", "2")
    assert {env["NUMBA_NUM_THREADS"] for env in seen.values()} == {"1"}  # at least 1


def test_batch_threads_option_sets_every_item(tmp_path, clean_env, monkeypatch):
    clean_env.setenv("NUMBA_NUM_THREADS", "5")  # the user's environment; --threads wins
    seen = _batch_env(tmp_path, monkeypatch, "--jobs", "2", "--threads", "1")
    for env in seen.values():
        assert all(env[v] == "1" for v in THREAD_ENV) and env["numba"] == 1


def test_threads_limit_every_kd_tree_query_of_a_fit(monkeypatch):
    """Regression: coverage, growth and the data-surface queries used ``workers=-1`` (every
    core) whatever ``threads`` said, so parallel batch items oversubscribed the machine."""
    import scipy.spatial

    import recon.fitting.schedule
    import recon.geometry
    import recon.growth
    import recon.normals
    import recon.surface
    from recon.fitting import reconstruct
    from recon.io import read_points

    seen: list[int] = []

    class RecordingTree(scipy.spatial.cKDTree):
        def query(self, *args, **kwargs):
            seen.append(kwargs.get("workers", 1))
            return super().query(*args, **kwargs)

    for module in (
        recon.fitting.schedule,
        recon.geometry,
        recon.growth,
        recon.normals,
        recon.surface,
    ):
        monkeypatch.setattr(module, "cKDTree", RecordingTree)
    cloud = read_points(SPHERE)
    reconstruct(cloud, apply_overrides(ReconConfig(), {"threads": 1}))
    assert seen and set(seen) == {1}, sorted(set(seen))


def _threads_of_quality_report(monkeypatch) -> list[str]:
    """The names of the threads that :func:`recon.fitting.report.quality_report` runs in,
    call by call, from now on."""
    import threading

    import recon.fitting.report as report

    where: list[str] = []
    real = report.quality_report

    def spy(*args, **kwargs):
        where.append(threading.current_thread().name)
        return real(*args, **kwargs)

    monkeypatch.setattr(report, "quality_report", spy)
    return where


@needs_two
def test_report_measures_the_mesh_in_two_threads_with_the_same_figures(monkeypatch):
    """With two threads the report's topology and triangle quality run in a second thread
    beside the distances (:func:`recon.fitting.report.measure_mesh`); with one, in the fit's
    thread. Every measure is the same either way."""
    import threading

    from recon.fitting import reconstruct
    from recon.io import read_points

    where = _threads_of_quality_report(monkeypatch)
    cloud = read_points(SPHERE)
    keys = ("topology", "triangle_quality", "mesh_bbox_diag", "fidelity", "mesh_to_input")
    measures = {}
    for n in (1, 2):
        d = reconstruct(cloud, apply_overrides(ReconConfig(), {"threads": n})).report.to_dict()
        measures[n] = {key: d[key] for key in keys}
    assert where[0] == threading.current_thread().name
    assert where[1].startswith("oprecon-report")
    assert measures[1] == measures[2]


@needs_two
def test_a_large_mesh_is_measured_in_the_fits_thread(monkeypatch):
    """Topology and triangle quality beside the distances add their peaks: above
    ``CONCURRENT_REPORT_FACES`` faces (a 1M-point fit measured 2.27 GiB that way against its
    2 GiB budget) both run in the fit's thread, one after the other."""
    import threading

    import recon.fitting.report as report
    from recon.fitting import reconstruct
    from recon.io import read_points

    where = _threads_of_quality_report(monkeypatch)
    monkeypatch.setattr(report, "CONCURRENT_REPORT_FACES", 10)
    reconstruct(read_points(SPHERE), apply_overrides(ReconConfig(), {"threads": 2}))
    assert where == [threading.current_thread().name]


@pytest.mark.parametrize(
    ("env", "expected"),
    [
        ({}, "omp"),  # OpenMP tried first: no TBB probe (30-60 ms, and a warning when too old)
        ({"NUMBA_THREADING_LAYER_PRIORITY": "workqueue omp tbb"}, "workqueue"),  # the user's
        ({"NUMBA_THREADING_LAYER": "workqueue"}, "tbb"),  # a named layer: numba's own order
    ],
)
def test_threading_layer_order_prefers_openmp_unless_the_environment_says(env, expected):
    """The layer numba tries first at the first threaded kernel of a process: OpenMP, unless
    the user chose a layer or an order."""
    import subprocess
    import sys

    base = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_THREADING_LAYER")}
    code = "import numba, recon.kernels.options\nprint(numba.config.THREADING_LAYER_PRIORITY[0])"
    out = subprocess.run(
        [sys.executable, "-c", code], env={**base, **env}, capture_output=True, text=True
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.split()[-1] == expected
