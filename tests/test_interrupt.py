"""Ctrl-C during ``oprecon fit`` (and before any command's guard): exit 130, "interrupted" on
stderr, no partial or temp file."""

from __future__ import annotations

import hashlib
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from recon.io import write_points

OPRECON = Path(sys.executable).with_name("oprecon")

#: Settings that keep the dynamics busy far longer than the test waits.
ENDLESS = [
    "--set",
    "dynamics.max_steps=100000",
    "--set",
    "growth.max_rounds=1000",
    "--set",
    "growth.min_add_fraction=0",
    "--set",
    "dynamics.kinetic_tolerance=0",  # no early stop at rest
]


def _sphere(n: int) -> np.ndarray:
    rng = np.random.default_rng(7)
    p = rng.normal(size=(n, 3))
    return p / np.linalg.norm(p, axis=1, keepdims=True)


@pytest.mark.skipif(os.name != "posix", reason="SIGINT delivery to a child needs POSIX")
@pytest.mark.skipif(not OPRECON.exists(), reason="the oprecon entry point is not installed")
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_interrupt_during_dynamics_exits_130_and_leaves_nothing(tmp_path, sig):
    """Ctrl-C (and SIGTERM, as sent by ``timeout``) while the particles move."""
    src = tmp_path / "sphere.ply"
    write_points(src, _sphere(30_000))
    before = hashlib.sha256(src.read_bytes()).hexdigest()
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    cmd = [
        str(OPRECON),
        "fit",
        str(src),
        "-o",
        str(out_dir / "mesh.ply"),
        "--particles",
        str(out_dir / "particles.ply"),
        "-v",
        *ENDLESS,
    ]
    # a background job (pytest run with &) would hand the child an ignored SIGINT: restore it
    proc = subprocess.Popen(
        cmd,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    lines: list[str] = []
    in_dynamics = threading.Event()

    def read_stderr() -> None:
        assert proc.stderr is not None
        for raw in proc.stderr:
            line = raw.decode(errors="replace")
            lines.append(line)
            if "candidates" in line:  # -v: the debug log of a growth round, dynamics running
                in_dynamics.set()

    reader = threading.Thread(target=read_stderr, daemon=True)
    reader.start()
    try:
        assert in_dynamics.wait(timeout=60), "".join(lines)
        time.sleep(1.0)  # well inside the dynamics
        assert proc.poll() is None, "the fit ended before it could be interrupted"
        proc.send_signal(sig)
        code = proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    reader.join(timeout=10)
    stderr = "".join(lines)
    assert code == 130, stderr[-2000:]
    assert "interrupted" in stderr
    assert "Traceback" not in stderr
    assert os.listdir(out_dir) == []
    assert sorted(os.listdir(tmp_path)) == ["out", "sphere.ply"]
    assert hashlib.sha256(src.read_bytes()).hexdigest() == before


#: A child that runs ``oprecon ARGS...`` in-process after a set-up of the test's (``PRELUDE``).
_CHILD = """
import os, signal, sys
{prelude}
sys.argv = ["oprecon", *sys.argv[1:]]
from recon.cli.main import main
main()
"""

#: Ctrl-C after the command has finished, while the interpreter tears its modules down (the
#: 0.6-0.8 s between a fit's summary and its exit): the __del__ of an object of __main__ runs
#: then, after Python has put SIGINT's default action back.
_INTERRUPT_AT_TEARDOWN = """
class Late:
    def __del__(self, kill=os.kill, pid=os.getpid(), sig=signal.SIGINT, write=os.write):
        write(2, b"test: SIGINT during the teardown\\n")
        kill(pid, sig)

late = Late()
"""


def _run_child(prelude: str, args: list[str]) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", _CHILD.format(prelude=prelude), *args],
        capture_output=True,
        text=True,
        timeout=120,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )


@pytest.mark.skipif(os.name != "posix", reason="signals to the process need POSIX")
def test_interrupt_after_a_finished_fit_neither_kills_it_silently_nor_changes_its_outcome(
    tmp_path,
):
    """Regression: Ctrl-C in the interpreter's teardown after the fit had written its files and
    its summary killed the process by the signal (exit 130 in a shell) without a word. The run
    is complete then: its outputs stand and so does its exit code."""
    src = tmp_path / "sphere.ply"
    write_points(src, _sphere(1000))
    out = tmp_path / "m.ply"
    args = ["fit", str(src), "-o", str(out), "--set", "dynamics.max_steps=60"]
    res = _run_child(_INTERRUPT_AT_TEARDOWN, args)
    assert "test: SIGINT during the teardown" in res.stderr  # it was sent
    assert res.returncode == 0, (res.returncode, res.stderr[-2000:])
    assert "Traceback" not in res.stderr
    assert f"oprecon: wrote {out}" in res.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.ply", "m.report.json", "sphere.ply"]


@pytest.mark.skipif(os.name != "posix", reason="signals to the process need POSIX")
def test_interrupt_after_a_failed_command_keeps_its_exit_code(tmp_path):
    res = _run_child(_INTERRUPT_AT_TEARDOWN, ["fit", str(tmp_path / "no.ply"), "-o", "m.ply"])
    assert "test: SIGINT during the teardown" in res.stderr
    assert res.returncode == 2, (res.returncode, res.stderr[-2000:])
    assert res.stderr.count("oprecon: error:") == 1 and "Traceback" not in res.stderr


#: Ctrl-C in the group's own callback, after click parsed the arguments and before the
#: command runs (where click answered with "Aborted!" and exit code 1).
_INTERRUPT_IN_THE_GROUP = """
import click

def ensure_object(self, object_type, _plain=click.Context.ensure_object):
    signal.raise_signal(signal.SIGINT)
    return _plain(self, object_type)

click.Context.ensure_object = ensure_object
"""

#: Ctrl-C while the entry point imports the command line's shared module.
_INTERRUPT_AT_IMPORT = """
import importlib.abc

class Interrupt(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name == "recon.cli.common":
            sys.meta_path.remove(self)
            signal.raise_signal(signal.SIGINT)
        return None

sys.meta_path.insert(0, Interrupt())
"""


@pytest.mark.skipif(os.name != "posix", reason="signals to the process need POSIX")
@pytest.mark.parametrize(
    "prelude", [_INTERRUPT_IN_THE_GROUP, _INTERRUPT_AT_IMPORT], ids=["group", "import"]
)
def test_an_interrupt_before_the_commands_guard_exits_130_with_its_message(tmp_path, prelude):
    """Regression: click printed "Aborted!" and exited 1 (in the group), or Python printed a
    traceback (at the import), where every other interrupt exits 130 with one line."""
    res = _run_child(prelude, ["info", str(tmp_path / "missing.ply")])
    assert res.returncode == 130, (res.returncode, res.stderr[-2000:])
    assert res.stderr.strip().splitlines() == ["oprecon: interrupted"], res.stderr[-2000:]
