"""Per-phase wall and CPU time of `oprecon fit` on one input, in-process, medians of runs.

The fit's report gives the wall time per phase (``time_s``); on a machine shared with other
jobs wall times vary 2-4x between runs, so this also accounts the process CPU time
(``time.process_time``, all threads) per phase. With ``NUMBA_NUM_THREADS=1
OMP_NUM_THREADS=1`` the CPU figures are the work done, nearly independent of the load, and two
versions can be compared one after the other (point ``PYTHONPATH`` at the other checkout).
A warm-up fit runs first (numba caches, imports); the last line is a hash of the last mesh,
to check that a change left the fit the same.

Usage::

    NUMBA_NUM_THREADS=1 OMP_NUM_THREADS=1 python benchmarks/bench_phases.py \\
        ../shared/data/cases/bunny-clean/input.ply --runs 3
"""

from __future__ import annotations

import argparse
import hashlib
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

if str(Path(__file__).resolve().parent) not in sys.path:  # the benchmarks' shared options
    sys.path.insert(0, str(Path(__file__).resolve().parent))
from shared_options import add_overrides, override_values  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("input", help="point file")
    ap.add_argument("--runs", type=int, default=3)
    add_overrides(ap)
    args = ap.parse_args(argv)

    from recon.config import ReconConfig, apply_overrides
    from recon.fitting import pipeline, schedule
    from recon.io import read_points

    clocks: list[Any] = []

    class CpuClock(schedule.Clock):
        """The fit's clock, also summing process CPU time per phase."""

        def __init__(self, limit: float | None) -> None:
            super().__init__(limit)
            self.cpu: dict[str, float] = {}
            self._cpu = time.process_time()
            clocks.append(self)

        def lap(self, phase: str) -> None:
            super().lap(phase)
            now = time.process_time()
            self.cpu[phase] = self.cpu.get(phase, 0.0) + now - self._cpu
            self._cpu = now

    pipeline.Clock = CpuClock  # the pipeline's reference to the class
    cloud = read_points(args.input)
    cfg = apply_overrides(ReconConfig(), override_values(args.overrides))
    pipeline.reconstruct(cloud, cfg)  # warm-up
    walls, cpus = [], []
    res = None
    for _ in range(max(1, args.runs)):
        res = pipeline.reconstruct(cloud, cfg)
        walls.append(dict(clocks[-1].phases))
        cpus.append(dict(clocks[-1].cpu))
    phases = list(walls[0])
    threads = os.environ.get("NUMBA_NUM_THREADS", "default")
    print(f"{args.input}: {args.runs} runs, NUMBA_NUM_THREADS={threads}, medians [s]")
    print(f"{'phase':<12} {'wall':>8} {'cpu':>8}")
    for p in phases:
        w = float(np.median([r.get(p, 0.0) for r in walls]))
        c = float(np.median([r.get(p, 0.0) for r in cpus]))
        print(f"{p:<12} {w:8.3f} {c:8.3f}")
    w_tot = float(np.median([sum(r.values()) for r in walls]))
    c_tot = float(np.median([sum(r.values()) for r in cpus]))
    print(f"{'total':<12} {w_tot:8.3f} {c_tot:8.3f}")
    rep = res.report
    print(f"steps {rep.steps.grow} grow + {rep.steps.release} release, particles {rep.particles}")
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"load average (1 min) at the end: {load:.1f}")
    digest = hashlib.sha1(res.mesh.vertices.tobytes() + res.mesh.faces.tobytes()).hexdigest()
    print(f"mesh sha1 {digest} ({len(res.mesh.faces)} faces)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
