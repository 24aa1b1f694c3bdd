"""``oprecon batch``: exit codes, dry run, and end-to-end runs of the real fit on tiny inputs.

The inputs are generated here: a few hundred points on a unit sphere and on a square, with
``dynamics.max_steps`` kept small so that every fit takes a second or two.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import recon.cli.batch as cli_batch
from click.testing import CliRunner
from recon.cli.main import app

from recon import batch

FAST = "set:\n  dynamics.max_steps: 200\n"


def sphere_points(n: int = 400, seed: int = 0) -> np.ndarray:
    v = np.random.default_rng(seed).normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def plane_points(n: int = 300, seed: int = 1) -> np.ndarray:
    xy = np.random.default_rng(seed).uniform(-1.0, 1.0, size=(n, 2))
    return np.column_stack([xy, np.zeros(n)])


def write_xyz(path: Path, points: np.ndarray) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savetxt(path, points, fmt="%.8f")
    return path


def invoke(*args: str):
    return CliRunner().invoke(app, ["batch", *args])


def summary(out: Path) -> dict[str, dict]:
    doc = json.loads((out / "batch_summary.json").read_text())
    return {item["name"]: item for item in doc["items"]}


def statuses(out: Path) -> dict[str, str]:
    return {name: item["status"] for name, item in summary(out).items()}


@pytest.fixture
def shapes(tmp_path: Path) -> Path:
    """Two tiny inputs sharing a stem (``a/shape.xyz`` a sphere, ``b/shape.xyz`` a square)."""
    write_xyz(tmp_path / "a" / "shape.xyz", sphere_points())
    write_xyz(tmp_path / "b" / "shape.xyz", plane_points())
    return tmp_path


# --------------------------------------------------------------------------------------------
# without running a fit


def test_batch_is_a_registered_command():
    result = CliRunner().invoke(app, ["batch", "--help"])
    assert result.exit_code == 0
    assert "--executor" in result.output and "--dry-run" in result.output


def test_invalid_batch_file_exits_2_naming_the_key_and_line(tmp_path):
    path = tmp_path / "b.yaml"
    path.write_text(
        "inputs: [a.xyz]\noutput_dir: out\noverrides:\n  - match: a\n    set: {dynamics.dtt: 0.1}\n"
    )
    result = invoke(str(path))
    assert result.exit_code == 2
    assert "line 5: overrides[0].set.dynamics.dtt: unknown key" in result.stderr
    assert "did you mean" in result.stderr
    assert not (tmp_path / "out").exists()

    path.write_text("inputs: [a.xyz]\nouput_dir: out\n")
    result = invoke(str(path))
    assert result.exit_code == 2
    assert "line 2: ouput_dir: unknown key (did you mean 'output_dir'?)" in result.stderr

    result = invoke(str(tmp_path / "missing.yaml"))
    assert result.exit_code == 2
    assert "no such configuration file" in result.stderr


def test_usage_errors_exit_2(tmp_path):
    path = tmp_path / "b.yaml"
    path.write_text("inputs: [a.xyz]\noutput_dir: out\n")
    result = invoke(str(path), "--scheduler", "tcp://127.0.0.1:1")
    assert result.exit_code == 2
    assert "--scheduler needs --executor dask" in result.stderr
    assert invoke(str(path), "--jobs", "0").exit_code == 2
    result = invoke(str(path), "--set", "dynamics.dt=9")
    assert result.exit_code == 2 and "out of range" in result.stderr


def test_dry_run_runs_nothing_and_says_why(shapes):
    path = shapes / "batch.yaml"
    path.write_text(
        "inputs: ['*/shape.xyz', gone.xyz]\noutput_dir: out\n"
        "overrides:\n  - match: b/shape.xyz\n    set: {dynamics.dt: 0.1}\n"
    )
    result = invoke(str(path), "--dry-run")
    assert result.exit_code == 1  # an input is missing
    lines = result.output.splitlines()
    assert "3 item(s), 2 to run, 0 up to date, 1 failing" in lines[0]
    rows = {line.split()[1]: line.split() for line in lines[2:]}
    assert rows["a_shape"][0] == "run" and rows["a_shape"][3] == "-"
    assert rows["b_shape"][0] == "run" and rows["b_shape"][3] == "0"
    assert rows["gone"][0] == "fail" and "no such file" in lines[-1]
    assert not (shapes / "out").exists()


def test_example_batch_file_is_valid():
    example = Path(cli_batch.__file__).parent.parent / "configs" / "examples" / "batch_example.yaml"
    result = invoke(str(example), "--dry-run")
    assert result.exit_code == 0, result.output + result.stderr
    assert "bunny-sparse" in result.output


def test_missing_dask_exits_2_with_the_install_hint(shapes, monkeypatch):
    path = shapes / "batch.yaml"
    path.write_text("inputs: ['*/shape.xyz']\noutput_dir: out\n")
    monkeypatch.setitem(sys.modules, "dask", None)
    monkeypatch.setitem(sys.modules, "dask.distributed", None)
    result = invoke(str(path), "--executor", "dask")
    assert result.exit_code == 2
    assert 'pip install "oprecon[distributed]"' in result.stderr


def test_a_first_run_says_it_compiles_the_kernels_first_unless_the_cluster_is_remote(
    shapes, monkeypatch
):
    from recon.kernels import warm

    path = shapes / "batch.yaml"
    path.write_text("inputs: ['*/shape.xyz']\noutput_dir: out\n")
    monkeypatch.setattr(warm, "uncached", lambda names=(): ["pair_loop.step_particles"])
    monkeypatch.setitem(sys.modules, "dask", None)  # stops the run where the items would start
    monkeypatch.setitem(sys.modules, "dask.distributed", None)
    local = invoke(str(path), "--executor", "dask")
    remote = invoke(str(path), "--executor", "dask", "--scheduler", "tcp://127.0.0.1:1")
    assert local.exit_code == remote.exit_code == 2
    assert "compiling the numba kernels first" in local.stderr
    assert "compiling" not in remote.stderr


@pytest.mark.parametrize("address", ["notaurl", "tcp://scheduler-host"])
def test_a_scheduler_address_without_a_port_is_refused_by_name(shapes, address):
    """Regression: Dask's ValueError ("missing port number") came with a traceback and exit 1,
    after its half-made client waited 40 s to close."""
    pytest.importorskip("dask.distributed")
    path = shapes / "batch.yaml"
    path.write_text("inputs: ['*/shape.xyz']\noutput_dir: out\n")
    result = invoke(str(path), "--executor", "dask", "--scheduler", address)
    assert result.exit_code == 2, result.output
    assert "Traceback" not in result.output
    assert f"--scheduler '{address}': not a Dask scheduler address" in result.stderr
    assert "missing port" in result.stderr


def test_an_item_time_limit_of_nan_is_refused_by_name(shapes):
    path = shapes / "batch.yaml"
    path.write_text("inputs: ['*/shape.xyz']\noutput_dir: out\n")
    result = invoke(str(path), "--item-time-limit", "nan", "--dry-run")
    assert result.exit_code == 2, result.output
    assert "--item-time-limit" in result.stderr and "got nan" in result.stderr
    assert "dynamics.time_limit" not in result.stderr


def hang_job(spec: dict, on_progress) -> dict:
    """A fake job that writes a partial output and never finishes (runs in the child)."""
    from recon.io import atomic_output

    with atomic_output(spec["meshes"][0]) as tmp:
        tmp.write_text("partial")
        on_progress("grow", {"step": 1, "particles": 3, "coverage": 0.1})
        time.sleep(3600)
    return {}


def test_ctrl_c_exits_130_and_leaves_no_partial_files(shapes, monkeypatch):
    path = shapes / "batch.yaml"
    path.write_text("inputs: ['*/shape.xyz']\noutput_dir: out\n")

    def interrupting_run(plan, *, on_event, **kw):
        def ctrl_c(event: batch.BatchEvent) -> None:
            on_event(event)  # the command's progress display
            if event.kind == "progress":
                raise KeyboardInterrupt  # as if Ctrl-C arrived while the items run

        return batch.run_batch(plan, job=hang_job, on_event=ctrl_c, **kw)

    monkeypatch.setattr(cli_batch, "run_batch", interrupting_run)
    result = invoke(str(path), "--jobs", "2")
    assert result.exit_code == 130
    assert "oprecon: interrupted" in result.stderr
    out = shapes / "out"
    assert set(statuses(out).values()) == {"interrupted"}
    assert sorted(p.name for p in out.iterdir()) == ["batch_summary.csv", "batch_summary.json"]


# --------------------------------------------------------------------------------------------
# end to end, with the real fit


def test_end_to_end_missing_input_resume_and_changed_override(shapes):
    path = shapes / "batch.yaml"
    text = (
        "inputs: ['*/shape.xyz', missing.xyz]\noutput_dir: out\nformats: [ply, obj]\n"
        + FAST
        + "overrides:\n  - match: b/shape.xyz\n    set: {{dynamics.dt: {dt}}}\n"
    )
    path.write_text(text.format(dt=0.2))
    result = invoke(str(path), "--jobs", "2")
    assert result.exit_code == 1, result.stderr
    out = shapes / "out"
    assert statuses(out) == {"a_shape": "ok", "b_shape": "ok", "missing": "failed"}, result.stderr
    rows = summary(out)
    assert "missing.xyz: no such file" in rows["missing"]["error"]
    for name in ("a_shape", "b_shape"):
        for suffix in (".ply", ".obj", ".report.json", ".batch.json"):
            assert (out / f"{name}{suffix}").is_file()
        assert rows[name]["particles"] > 0 and rows[name]["faces"] > 0
        assert 0 < rows[name]["coverage"] <= 1 and rows[name]["fidelity_mean"] >= 0
    assert "missing.xyz: no such file" in result.stderr  # the table
    assert "2 ok, 1 failed" in result.stderr
    assert "missing" in (out / "batch_summary.csv").read_text()
    assert not list(out.glob(".*.tmp*"))
    first_mtime = (out / "a_shape.ply").stat().st_mtime_ns

    # the second run skips the finished items
    result = invoke(str(path))
    assert result.exit_code == 1
    assert statuses(out) == {"a_shape": "skipped", "b_shape": "skipped", "missing": "failed"}
    assert (out / "a_shape.ply").stat().st_mtime_ns == first_mtime

    # a changed override re-runs only the item it matches
    path.write_text(text.format(dt=0.15))
    dry = invoke(str(path), "--dry-run")
    assert "configuration changed" in dry.output and "up to date" in dry.output
    result = invoke(str(path), "-q")
    assert statuses(out) == {"a_shape": "skipped", "b_shape": "ok", "missing": "failed"}
    assert (out / "a_shape.ply").stat().st_mtime_ns == first_mtime
    report = json.loads((out / "b_shape.report.json").read_text())
    assert report["config"]["dynamics"]["dt"] == 0.15
    assert result.stderr.strip().splitlines() == [
        f"oprecon: failed: missing: {shapes / 'missing.xyz'}: no such file"
    ]


def test_end_to_end_time_limit_gives_timeout_and_spares_the_others(shapes):
    path = shapes / "batch.yaml"
    path.write_text(
        "inputs: ['*/shape.xyz']\noutput_dir: out\n"
        + FAST
        + "overrides:\n  - match: a_shape\n    set: {dynamics.time_limit: 0.001}\n"
    )
    result = invoke(str(path), "--jobs", "2")
    assert result.exit_code == 1
    rows = summary(shapes / "out")
    assert rows["a_shape"]["status"] == "timeout", rows["a_shape"]
    assert "time limit" in rows["a_shape"]["error"]
    assert rows["b_shape"]["status"] == "ok"
    assert not (shapes / "out" / "a_shape.ply").exists()
    assert not list((shapes / "out").glob(".*.tmp*"))


def test_end_to_end_local_cluster_matches_the_process_pool(shapes):
    pytest.importorskip("dask.distributed")
    text = "inputs: ['*/shape.xyz', gone.xyz]\noutput_dir: {out}\n" + FAST
    (shapes / "local.yaml").write_text(text.format(out="local"))
    (shapes / "dask.yaml").write_text(text.format(out="dask"))
    local = invoke(str(shapes / "local.yaml"), "--jobs", "2")
    on_dask = invoke(str(shapes / "dask.yaml"), "--executor", "dask", "--jobs", "1")
    assert local.exit_code == on_dask.exit_code == 1, on_dask.stderr
    assert (
        statuses(shapes / "dask")
        == statuses(shapes / "local")
        == {"a_shape": "ok", "b_shape": "ok", "gone": "failed"}
    )
    local_rows, dask_rows = summary(shapes / "local"), summary(shapes / "dask")
    for name in ("a_shape", "b_shape"):  # same seed, same config: the same mesh
        assert dask_rows[name]["faces"] == local_rows[name]["faces"]
    # resume is shared: the cluster's results count as done for a local re-run
    again = invoke(str(shapes / "dask.yaml"))
    assert again.exit_code == 1
    assert statuses(shapes / "dask")["a_shape"] == "skipped"
