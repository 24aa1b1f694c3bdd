"""Start-up inside a fit: a fresh process's import of the pipeline and its first fit.

``bench_quality.py`` times ``from recon.fitting import reconstruct`` and ``reconstruct()`` in a
fresh worker, so a fresh process's costs count: compiling modules without byte code, numba's
set-up and its first cache loads. This runs that timed region in fresh processes, alternating
between checkouts (``--trees``, each put first on ``PYTHONPATH`` and run as it is, with or
without byte code; default: this one), and prints
the medians of the import and of the whole region, wall and CPU (all threads), with the load.
``--kernel-loads`` instead prints, for one fresh process, the time to load each of the fit's
kernels from numba's cache in turn (:data:`recon.kernels.warm.FIT_KERNELS`). ``--before``
does part of numba's start before the clock, to see what it costs the first fit: ``registries``
initialises numba's target context (its numpy, linalg and typed-container support), ``kernels``
also loads every kernel of the fit from the cache; ``--second`` times a second fit in the same
process too (a warm process: what is left is the fit itself).

Examples (``BASE``: another checkout to compare with, e.g. ``git worktree add BASE main``)::

    NUMBA_NUM_THREADS=1 OMP_NUM_THREADS=1 python benchmarks/bench_startup.py \\
        ../shared/data/cases/bunny-clean/input.ply --runs 5 --trees BASE .
    python benchmarks/bench_startup.py ../shared/data/cases/bunny-clean/input.ply --kernel-loads
    for b in none registries kernels; do python benchmarks/bench_startup.py \\
        ../shared/data/cases/bunny-clean/input.ply --runs 3 --before $b --second; done
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

#: The timed region, as in ``bench_quality.run_method`` (what it imports before its clock
#: starts is imported first here too).
_REGION = """
import sys, time
import open3d
from recon.config import ReconConfig
from recon.io import read_points
cloud = read_points(sys.argv[1])
if sys.argv[2] in ("registries", "kernels"):
    from numba.core.registry import cpu_target
    cpu_target.target_context.refresh()
if sys.argv[2] == "kernels":
    from recon.kernels import warm
    warm.load_cached(warm.resolve(warm.FIT_KERNELS))
t0, c0 = time.perf_counter(), time.process_time()
from recon.fitting import reconstruct
t1, c1 = time.perf_counter(), time.process_time()
reconstruct(cloud, ReconConfig())
t2, c2 = time.perf_counter(), time.process_time()
print("TIMES", t1 - t0, c1 - c0, t2 - t0, c2 - c0)
if sys.argv[3] == "1":
    reconstruct(cloud, ReconConfig())
    print("SECOND", time.perf_counter() - t2, time.process_time() - c2)
"""

_LOADS = """
import importlib, time
from recon.fitting import reconstruct
from recon.kernels import warm
for name in warm.FIT_KERNELS:
    module, function = name.rsplit(".", 1)
    kernel = getattr(importlib.import_module("recon.kernels." + module), function)
    t = time.perf_counter()
    sigs = warm.cached_signatures(kernel)
    index = time.perf_counter() - t
    for sig in sigs:
        kernel.compile(sig)
    print(f"{name:40s} {len(sigs)} sig  index {index * 1e3:6.1f} ms  total "
          f"{(time.perf_counter() - t) * 1e3:6.1f} ms")
"""


def _run(tree: Path, code: str, args: list[str]) -> str:
    """stdout of ``code`` in a fresh interpreter with ``tree`` first on the import path (also
    its working directory: ``python -c`` puts that before ``PYTHONPATH``)."""
    path = [str(tree), *filter(None, os.environ.get("PYTHONPATH", "").split(os.pathsep))]
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(path))
    out = subprocess.run(
        [sys.executable, "-c", code, *args],
        env=env,
        cwd=tree,
        capture_output=True,
        text=True,
        check=False,
    )
    if out.returncode != 0:
        raise RuntimeError(out.stderr[-2000:])
    return out.stdout


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("input", help="point file")
    ap.add_argument("--runs", type=int, default=3, help="fresh processes per checkout")
    ap.add_argument("--trees", nargs="*", type=Path, default=[ROOT], help="checkouts to compare")
    ap.add_argument("--kernel-loads", action="store_true")
    ap.add_argument(
        "--before",
        choices=("none", "registries", "kernels"),
        default="none",
        help="numba's start done before the clock (see above)",
    )
    ap.add_argument("--second", action="store_true", help="also time a second fit per process")
    args = ap.parse_args(argv)
    if args.kernel_loads:
        print(_run(args.trees[0], _LOADS, []), end="")
        return 0
    times: dict[Path, list[list[float]]] = {t.resolve(): [] for t in args.trees}
    for _ in range(max(1, args.runs)):  # A B A B: a change of load hits every checkout
        for tree in times:
            region_args = [str(Path(args.input).resolve()), args.before, str(int(args.second))]
            out = _run(tree, _REGION, region_args)
            line = next(x for x in out.splitlines() if "TIMES" in x)
            row = [float(v) for v in line.split()[1:]]
            if args.second:
                row += [
                    float(v) for v in next(x for x in out.splitlines() if "SECOND" in x).split()[1:]
                ]
            times[tree].append(row)
    threads = os.environ.get("NUMBA_NUM_THREADS", "default")
    print(
        f"{args.input}: {args.runs} fresh processes each, NUMBA_NUM_THREADS={threads}, "
        f"done before the clock: {args.before}, medians"
    )
    head = "| checkout | import wall | import CPU | import + fit wall | import + fit CPU |"
    print(head + (" second fit wall | second fit CPU |" if args.second else ""))
    print("|---|---:|---:|---:|---:|" + ("---:|---:|" if args.second else ""))
    for tree, rows in times.items():
        med = [statistics.median(col) for col in zip(*rows, strict=True)]
        print(f"| {tree} | " + " | ".join(f"{m:.3f}" for m in med) + " |")
    print(f"load average (1 min) at the end: {os.getloadavg()[0]:.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
