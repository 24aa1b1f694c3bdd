"""Peak resident memory per stage of one fit: where the fit's peak RSS comes from.

Runs ``recon.fitting.pipeline.reconstruct`` in this process on one point file, with a thread
sampling the RSS (``/proc/self/status``, every 20 ms), and wraps the stages (the shared
neighbour query, normal estimate and orientation, crease detection, local surfaces, the
schedule, the triangulation's steps, the report): per stage, wall seconds and the RSS before,
at its peak and after [MiB]. Nested stages are indented. Linux only. The last line is the
process's peak RSS (``ru_maxrss``). Use it to find what to shrink when the whole fit's peak
(``benchmarks/bench_scale.py``) is over its budget.

Example (the 1M-point torus of ``bench_scale.py``)::

    python benchmarks/bench_stage_memory.py --torus 1000000
    python benchmarks/bench_stage_memory.py ../shared/data/cases/bunny-clean/input.ply
"""

from __future__ import annotations

import argparse
import functools
import importlib
import resource
import sys
import threading
import time
from pathlib import Path
from typing import Any

#: (module, function) of the stages that are wrapped, outermost first.
STAGES = [
    ("recon.fitting.pipeline", "shared_neighbors"),
    ("recon.fitting.pipeline", "compute_normals"),
    ("recon.normals", "estimate_normals"),
    ("recon.normals", "orient_normals"),
    ("recon.fitting.pipeline", "_detect_creases"),
    ("recon.fitting.pipeline", "choose_spacing"),
    ("recon.fitting.pipeline", "run_schedule"),
    ("recon.fitting.pipeline", "_trim"),
    ("recon.fitting.pipeline", "_triangulate"),
    ("recon.fitting.pipeline", "sampling_spacing"),
    ("recon.fitting.pipeline", "triangulate_particles"),
    ("recon.triangulate", "consistent_normals"),
    ("recon.triangulate", "ball_pivoting"),
    ("recon.triangulate", "drop_overlaps"),
    ("recon.triangulate", "repair_non_manifold"),
    ("recon.triangulate", "orient_consistently"),
    ("recon.triangulate", "fill_small_holes"),
    ("recon.fitting.pipeline", "untangle"),
    ("recon.fitting.pipeline", "measure_mesh"),
    ("recon.fitting.report", "quality_report"),
    ("recon.fitting.report", "fidelity"),
]


def _rss_mib() -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS"):
                return int(line.split()[1]) / 1024.0
    return 0.0


class Sampler:
    """The highest RSS seen since the last :meth:`restart`."""

    def __init__(self) -> None:
        self.peak = _rss_mib()
        threading.Thread(target=self._run, daemon=True).start()

    def _run(self) -> None:
        while True:
            self.peak = max(self.peak, _rss_mib())
            time.sleep(0.02)


def _wrap(sampler: Sampler, module: str, name: str, depth: list[int]) -> None:
    mod = importlib.import_module(module)
    fn = getattr(mod, name)

    @functools.wraps(fn)
    def wrapped(*args: Any, **kwargs: Any) -> Any:
        before, outer = _rss_mib(), sampler.peak
        sampler.peak = before
        start = time.perf_counter()
        depth[0] += 1
        try:
            return fn(*args, **kwargs)
        finally:
            depth[0] -= 1
            peak = sampler.peak
            print(
                f"{'  ' * depth[0]}{name:<24} {time.perf_counter() - start:8.2f} s   "
                f"RSS before {before:6.0f}  peak {peak:6.0f}  after {_rss_mib():6.0f} MiB",
                flush=True,
            )
            sampler.peak = max(peak, outer)

    setattr(mod, name, wrapped)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("input", nargs="?", help="point file (or --torus N)")
    ap.add_argument("--torus", type=int, help="fit bench_scale's torus of this many points")
    args = ap.parse_args(argv)
    if (args.input is None) == (args.torus is None):
        ap.error("give a point file or --torus N")

    from recon.config import ReconConfig
    from recon.fitting import pipeline
    from recon.io import cloud_from_arrays, read_points

    sampler = Sampler()
    depth = [0]
    for module, name in STAGES:
        _wrap(sampler, module, name, depth)
    if args.torus:
        sys.path.insert(0, str(Path(__file__).resolve().parent))
        from bench_scale import sample_torus

        cloud = cloud_from_arrays(sample_torus(args.torus))
    else:
        cloud = read_points(args.input)
    print(f"input: {len(cloud.points):,} points, RSS {_rss_mib():.0f} MiB", flush=True)
    start = time.perf_counter()
    pipeline.reconstruct(cloud, ReconConfig())
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    print(f"fit {time.perf_counter() - start:.1f} s; process peak RSS {peak:.0f} MiB")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
