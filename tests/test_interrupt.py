"""Ctrl-C during ``oprecon fit``: exit 130, "interrupted" on stderr, no partial or temp file."""

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
