"""Benchmark of the oriented-particle engine (neighbour lists + fused force/integration step).

Arrangement: N particles on a sphere (golden-angle spiral) whose radius gives the density of a
hexagonal sheet of spacing r0 = 1, so every particle has ~13 neighbours within the cutoff
(2 r0) and ~20 in the list (cutoff + skin), like a reconstructed surface. Particles are sorted
by grid cell once (``Simulation.sort_particles``), as the fit stage is expected to do.

Usage::

    .venv/bin/python benchmarks/bench_dynamics.py --particles 100000 --steps 50 --json
    .venv/bin/python benchmarks/bench_dynamics.py --sweep --json

``--json`` prints one JSON object: particles, mean_neighbors (within the cutoff),
mean_list_neighbors, steps_per_s, particle_steps_per_s, pair_interactions_per_s (neighbour-row
entries within the cutoff evaluated per second: each pair counts twice, as it is evaluated from
both rows), rebuilds, compile_seconds_cold (a subprocess with an empty NUMBA_CACHE_DIR),
compile_seconds_warm (a subprocess with the normal cache) and threads. ``--sweep`` times
N = 10k, 100k, 1M and adds the log-log slope of time per step against N.

Without ``--json`` the last line is the README's figure: pair interactions per second at the
size run, with the date, the machine's load (``os.getloadavg``, before and after the run), the
cores and the threads, so that a figure is never quoted without the conditions it was measured
in.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

_STARTUP = """
import time
t0 = time.perf_counter()
from recon.dynamics import warmup
t1 = time.perf_counter()
warmup()
t2 = time.perf_counter()
print(f"{t1 - t0:.6f} {t2 - t1:.6f}")
"""


def startup_seconds(cold: bool) -> dict[str, float]:
    """Import + warmup time in a fresh interpreter (cold: empty numba cache)."""
    env = dict(os.environ)
    with tempfile.TemporaryDirectory() as tmp:
        if cold:
            env["NUMBA_CACHE_DIR"] = tmp
        t = time.perf_counter()
        out = subprocess.run(
            [sys.executable, "-c", _STARTUP],
            cwd=ROOT,
            env=env,
            capture_output=True,
            text=True,
            check=True,
        )
        wall = time.perf_counter() - t
    imp, warm = (float(v) for v in out.stdout.split())
    return {"import": imp, "warmup": warm, "total": imp + warm, "process_wall": wall}


def sphere(n: int) -> tuple[np.ndarray, np.ndarray]:
    """n points on a sphere with hexagonal-sheet density at spacing 1, and radial normals."""
    radius = math.sqrt(n * math.sqrt(3.0) / 2.0 / (4.0 * math.pi))
    k = np.arange(n) + 0.5
    z = 1.0 - 2.0 * k / n
    rho = np.sqrt(1.0 - z * z)
    phi = k * math.pi * (3.0 - math.sqrt(5.0))
    normal = np.column_stack([rho * np.cos(phi), rho * np.sin(phi), z])
    return radius * normal, normal


def run_case(n: int, steps: int, parallel: bool | None = None) -> dict:
    """Time ``steps`` steps of an n-particle sphere (after one untimed step).

    Steps that rebuilt the neighbour list are timed too (the sphere is relaxing from a
    golden-angle spiral, so early steps move particles by up to the displacement cap); the
    median step without a rebuild is reported separately.
    """
    from recon.config import ReconConfig
    from recon.dynamics import PhysicsParams, Simulation
    from recon.state import ParticleState

    position, normal = sphere(n)
    state = ParticleState.from_points(position, normal)
    params = PhysicsParams.from_config(ReconConfig(), spacing=1.0)
    sim = Simulation(state, params, parallel=parallel)
    sim.sort_particles()
    sim.step()  # builds the list
    offsets, indices = sim.neighbors
    rows = np.repeat(np.arange(n), np.diff(offsets))
    d2 = np.sum((state.position[indices] - state.position[rows]) ** 2, axis=1)
    pairs_within = int(np.count_nonzero(d2 < params.cutoff**2))
    times = []
    rebuilt = []
    for _ in range(steps):
        t = time.perf_counter()
        stats = sim.step()
        times.append(time.perf_counter() - t)
        rebuilt.append(stats.rebuilt)
    times = np.array(times)
    rebuilt = np.array(rebuilt)
    per_step = float(times.mean())
    plain = times[~rebuilt]
    return {
        "particles": n,
        "steps": steps,
        "mean_neighbors": pairs_within / n,
        "mean_list_neighbors": len(indices) / n,
        "seconds_per_step": per_step,
        "seconds_per_step_without_rebuild": float(np.median(plain)) if plain.size else None,
        "seconds_per_step_with_rebuild": float(np.mean(times[rebuilt])) if rebuilt.any() else None,
        "steps_per_s": 1.0 / per_step,
        "particle_steps_per_s": n / per_step,
        "pair_interactions_per_s": pairs_within / per_step,
        "pair_interactions_per_s_without_rebuild": (
            pairs_within / float(np.median(plain)) if plain.size else None
        ),
        "rebuilds": int(rebuilt.sum()),
        "parallel": sim.uses_parallel(),
        "threaded_steps": sim.n_threaded_steps,
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--particles", type=int, default=100_000)
    ap.add_argument("--steps", type=int, default=50)
    ap.add_argument("--sweep", action="store_true", help="N = 10k, 100k, 1M; log-log slope")
    ap.add_argument("--serial", action="store_true", help="force the single-threaded kernels")
    ap.add_argument("--parallel", action="store_true", help="force the threaded kernels")
    ap.add_argument("--no-compile", action="store_true", help="skip the compile-time subprocesses")
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    args = ap.parse_args(argv)

    import numba

    from recon.dynamics import warmup

    parallel = True if args.parallel else (False if args.serial else None)
    result: dict = {
        "date": dt.datetime.now(dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
        "load_before": list(os.getloadavg()),
        "cores": os.cpu_count(),
    }
    if not args.no_compile:
        cold = startup_seconds(cold=True)
        warm = startup_seconds(cold=False)
        result["compile_seconds_cold"] = cold["total"]
        result["compile_seconds_warm"] = warm["total"]
        result["startup_detail"] = {"cold": cold, "warm": warm}
    warmup()
    if args.sweep:
        cases = []
        for n, steps in ((10_000, max(args.steps, 50)), (100_000, args.steps), (1_000_000, 8)):
            cases.append(run_case(n, steps, parallel))
        ns = np.array([c["particles"] for c in cases], dtype=float)
        ts = np.array([c["seconds_per_step"] for c in cases])
        plain = np.array([c["seconds_per_step_without_rebuild"] or np.nan for c in cases])
        slope = float(np.polyfit(np.log(ns), np.log(ts), 1)[0])
        result.update({"cases": cases, "loglog_slope": slope})
        if np.all(np.isfinite(plain)):
            result["loglog_slope_without_rebuild"] = float(
                np.polyfit(np.log(ns), np.log(plain), 1)[0]
            )
    else:
        result.update(run_case(args.particles, args.steps, parallel))
    result["threads"] = numba.get_num_threads()
    result["load_after"] = list(os.getloadavg())
    if args.json:
        print(json.dumps(result))
    else:
        for key, value in result.items():
            print(f"{key}: {value}")
        print(readme_line(result))
    return 0


def readme_line(result: dict) -> str:
    """The README figure: pair interactions per second with date, load, cores and threads."""
    cases = result.get("cases") or [result]
    rates = ", ".join(
        f"{c['particles']:,} particles: {c['pair_interactions_per_s']:.2e} pair interactions/s "
        f"({c['threaded_steps']}/{c['steps']} steps threaded)"
        for c in cases
    )
    load = "/".join(f"{v:.2f}" for v in result["load_before"])
    return (
        f"{rates} ({result['date']}; load average {load} (1/5/15 min) at start, "
        f"{result['load_after'][0]:.2f} at end; {result['cores']} cores, "
        f"{result['threads']} threads)"
    )


if __name__ == "__main__":
    raise SystemExit(main())
