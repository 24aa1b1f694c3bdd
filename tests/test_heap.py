"""Freed memory kept for reuse (recon.heap): in a process of its own, through the commands."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from recon.cli.main import app

from recon import heap
from recon.io import write_points

ROOT = Path(__file__).resolve().parents[1]

# a child that applies the policy, then frees a touched 128 MiB array and prints how much of
# it is still resident
_CHILD = """
import numpy as np
from recon.heap import keep_freed_memory
def rss():
    line = next(x for x in open('/proc/self/status') if x.startswith('VmRSS'))
    return int(line.split()[1]) / 1024
ok = keep_freed_memory()
before = rss()
block = np.ones(2**24)
del block
print(ok, rss() - before)
"""


def _child_env(**extra: str) -> dict[str, str]:
    """This environment without the variables that decide the policy (glibc's malloc)."""
    drop = {*heap.GLIBC_MALLOC_ENV, heap.OPT_OUT_ENV, "GLIBC_TUNABLES", "LD_PRELOAD"}
    env = {k: v for k, v in os.environ.items() if k not in drop}
    env["PYTHONPATH"] = str(ROOT)
    return {**env, **extra}


def _held_after_free(**extra: str) -> tuple[bool, float]:
    proc = subprocess.run(
        [sys.executable, "-c", _CHILD], env=_child_env(**extra), capture_output=True, text=True
    )
    assert proc.returncode == 0, proc.stderr
    ok, held = proc.stdout.split()
    return ok == "True", float(held)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc only")
def test_a_freed_block_stays_resident_for_reuse_unless_the_user_opts_out():
    """With the policy, a freed 128 MiB array stays in the process (the next one reuses its
    pages instead of faulting them in again); with OPRECON_MALLOC=system, or glibc's own
    variables set, the C library returns it as usual."""
    ok, held = _held_after_free()
    assert ok and held > 96, held
    for extra in ({"OPRECON_MALLOC": "system"}, {"MALLOC_TRIM_THRESHOLD_": "131072"}):
        ok, held = _held_after_free(**extra)
        assert not ok and held < 32, (extra, held)


def test_the_environment_decides_who_sets_the_policy(caplog):
    assert heap._user_tuned({}) is None
    assert heap._user_tuned({"OPRECON_MALLOC": "System"}) == "OPRECON_MALLOC"
    assert heap._user_tuned({"MALLOC_MMAP_MAX_": "0"}) == "MALLOC_MMAP_MAX_"
    tunables = "glibc.cpu.x86_ibt=on:glibc.malloc.trim_threshold=0"
    assert heap._user_tuned({"GLIBC_TUNABLES": tunables}) == "GLIBC_TUNABLES"
    # tunables of other parts of glibc's malloc leave the policy to oprecon
    assert heap._user_tuned({"GLIBC_TUNABLES": "glibc.malloc.arena_max=2"}) is None
    preload = "/usr/lib/x86_64-linux-gnu/libjemalloc.so.2"
    assert heap._user_tuned({"LD_PRELOAD": preload}) == "LD_PRELOAD"
    assert heap._user_tuned({"LD_PRELOAD": "libfaketime.so"}) is None
    assert heap._user_tuned({"OPRECON_MALLOC": "keep"}) is None
    assert "OPRECON_MALLOC=keep is not understood" in caplog.text


class _FakeLibc:
    def __init__(self) -> None:
        self.calls: list[tuple[int, int]] = []

    def mallopt(self, param: int, value: int) -> int:
        self.calls.append((param, value))
        return 1


@pytest.fixture
def fake_libc(monkeypatch):
    """recon.heap talks to a recorder instead of the C library (the pytest process keeps
    its own allocator)."""
    libc = _FakeLibc()
    for var in (*heap.GLIBC_MALLOC_ENV, heap.OPT_OUT_ENV, "GLIBC_TUNABLES", "LD_PRELOAD"):
        monkeypatch.delenv(var, raising=False)
    monkeypatch.setattr(heap, "_glibc", lambda: libc)
    monkeypatch.setattr(heap, "_applied", False)
    return libc


EXPECTED = [(heap.M_MMAP_MAX, 0), (heap.M_TRIM_THRESHOLD, heap.TRIM_THRESHOLD_MAX)]


def _sphere(tmp_path: Path) -> Path:
    p = np.random.default_rng(0).normal(size=(800, 3))
    path = tmp_path / "sphere.ply"
    write_points(path, p / np.linalg.norm(p, axis=1, keepdims=True))
    return path


def test_fit_and_normals_set_the_policy_once(tmp_path, fake_libc):
    src = _sphere(tmp_path)
    args = ["fit", str(src), "-o", str(tmp_path / "m.ply"), "-q"]
    res = CliRunner().invoke(app, [*args, "--set", "seeds.min_particles=0"])
    assert res.exit_code == 0, res.output
    assert fake_libc.calls == EXPECTED
    res = CliRunner().invoke(app, ["normals", str(src), "-o", str(tmp_path / "n.ply"), "-q"])
    assert res.exit_code == 0, res.output
    assert fake_libc.calls == EXPECTED  # already in effect: not set twice


def test_normals_and_remesh_set_the_policy(tmp_path, fake_libc, monkeypatch):
    src = _sphere(tmp_path)
    res = CliRunner().invoke(app, ["normals", str(src), "-o", str(tmp_path / "n.ply"), "-q"])
    assert res.exit_code == 0, res.output
    assert fake_libc.calls == EXPECTED
    monkeypatch.setattr(heap, "_applied", False)
    fake_libc.calls.clear()
    mesh = ROOT / "sample_data" / "lblock-gt.ply"
    args = ["remesh", str(mesh), "-o", str(tmp_path / "r.ply"), "--faces", "500", "-q"]
    res = CliRunner().invoke(app, [*args, "--steps", "5"])
    assert res.exit_code == 0, res.output
    assert fake_libc.calls == EXPECTED


def test_a_tiled_fit_leaves_the_allocator_alone(tmp_path, fake_libc, monkeypatch):
    """The tiled coordinator measures its memory phase by phase (recon/tiling/run.py):
    the policy is set only once the command knows that it runs one fit."""
    from recon.cli import fit as fit_command

    monkeypatch.setattr(fit_command, "_fit_tiles", lambda *a, **k: True)  # tiled, done
    src = _sphere(tmp_path)
    args = ["fit", str(src), "-o", str(tmp_path / "m.ply"), "-q", "--tile-size", "1"]
    res = CliRunner().invoke(app, args)
    assert res.exit_code == 0, res.output
    assert fake_libc.calls == []
    monkeypatch.setattr(fit_command, "_fit_tiles", lambda *a, **k: False)  # one fit will do
    args = ["fit", str(src), "-o", str(tmp_path / "m.ply"), "-q", "--tiles", "auto"]
    res = CliRunner().invoke(app, [*args, "--set", "seeds.min_particles=0"])
    assert res.exit_code == 0, res.output
    assert fake_libc.calls == EXPECTED


def test_a_refusal_leaves_the_policy_unapplied(monkeypatch, fake_libc):
    monkeypatch.setattr(fake_libc, "mallopt", lambda p, v: fake_libc.calls.append((p, v)) or 0)
    assert heap.keep_freed_memory() is False
    assert heap._applied is False
    assert fake_libc.calls == [(heap.M_MMAP_MAX, 0)]


def test_half_the_policy_is_undone(monkeypatch, fake_libc):
    """M_MMAP_MAX = 0 without the trim threshold is slower than glibc's defaults: when the
    second call is refused, the first is put back."""

    def mallopt(param: int, value: int) -> int:
        fake_libc.calls.append((param, value))
        return 0 if param == heap.M_TRIM_THRESHOLD else 1

    monkeypatch.setattr(fake_libc, "mallopt", mallopt)
    assert heap.keep_freed_memory() is False
    assert fake_libc.calls == [*EXPECTED, (heap.M_MMAP_MAX, heap.MMAP_MAX_DEFAULT)]
