"""Scale benchmark: how the fit's time and memory grow with the input size, against a peer.

Samples one smooth closed shape (a torus, R = 1, r = 0.35, area-uniform) at several densities,
fits each with ``oprecon fit`` in a fresh process and prints, per size: wall time, the time per
phase (from the report), particles, dynamics steps, particle-steps per second, peak RSS, and,
where pymeshlab is installed (``pip install -e ".[bench]"``), the wall time and peak RSS of
screened Poisson (pymeshlab, its own normal estimation, ``--omp-wait-policy``) on the same
file, run alternately with oprecon, with medians over ``--repeats`` and the ratio. Then the
log-log slope of wall time against input size (1.0 = linear). A benchmark, not a test: the
machine is shared, so compare ratios measured in the same run rather than absolute times across
runs.

Examples::

    python benchmarks/bench_scale.py                                   # 100k, 300k, 1M points
    python benchmarks/bench_scale.py --sizes 100000 1000000 4000000 --no-peer
    python benchmarks/bench_scale.py --sizes 40000 --repeats 3 --json-out bench_output/scale.json

``--baseline DIR`` also fits every size with the source tree in DIR (e.g. ``git archive BASE |
tar -x -C DIR``), alternating with this tree, and prints its times and the ratio of each
phase (this tree / baseline): a code change measured under the same load.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parent.parent

if str(Path(__file__).resolve().parent) not in sys.path:  # the benchmarks' shared options
    sys.path.insert(0, str(Path(__file__).resolve().parent))
from shared_options import add_overrides  # noqa: E402

TORUS_R, TORUS_r = 1.0, 0.35

_PEER_CODE = r"""
import sys, pymeshlab
ms = pymeshlab.MeshSet()
ms.load_new_mesh(sys.argv[1])
ms.compute_normal_for_point_clouds(k=10)
ms.generate_surface_reconstruction_screened_poisson(depth=int(sys.argv[3]))
ms.save_current_mesh(sys.argv[2])
"""


def sample_torus(n: int, seed: int = 0) -> np.ndarray:
    """``n`` area-uniform samples of the torus (rejection on the tube angle)."""
    rng = np.random.default_rng(seed)
    out: list[np.ndarray] = []
    have = 0
    while have < n:
        m = 2 * (n - have) + 1000
        u = rng.uniform(0, 2 * np.pi, m)
        v = rng.uniform(0, 2 * np.pi, m)
        # the area element is proportional to R + r cos v
        keep = rng.uniform(0, TORUS_R + TORUS_r, m) < TORUS_R + TORUS_r * np.cos(v)
        u, v = u[keep], v[keep]
        ring = TORUS_R + TORUS_r * np.cos(v)
        pts = np.stack([ring * np.cos(u), ring * np.sin(u), TORUS_r * np.sin(v)], axis=1)
        out.append(pts)
        have += len(pts)
    return np.concatenate(out)[:n]


def _run(cmd: list[str], env: dict[str, str] | None = None) -> tuple[float, float, int]:
    """Wall seconds, peak RSS [MiB] of the child, exit code (stderr shown on failure)."""
    with tempfile.TemporaryFile() as err:
        start = time.perf_counter()
        proc = subprocess.Popen(
            cmd, stdout=subprocess.DEVNULL, stderr=err, env={**os.environ, **(env or {})}
        )
        _, status, usage = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - start
        code = os.waitstatus_to_exitcode(status)
        proc.returncode = code
        if code != 0:
            err.seek(0)
            text = err.read().decode(errors="replace")
            print(f"  failed ({code}): {' '.join(cmd[:5])} ...\n{text[-2000:]}", file=sys.stderr)
    return wall, usage.ru_maxrss / 1024.0, code


def _particle_steps(history: dict[str, list[Any]]) -> float:
    steps = np.asarray(history.get("step", []), dtype=float)
    particles = np.asarray(history.get("particles", []), dtype=float)
    if len(steps) == 0:
        return 0.0
    return float(np.sum(np.diff(np.concatenate([[0.0], steps])) * particles))


def run_oprecon(
    path: Path,
    out: Path,
    threads: int | None,
    overrides: Sequence[str] = (),
    source: Path | None = None,
) -> dict[str, Any]:
    """One ``oprecon fit`` in a fresh process; ``source``: a source tree to run instead of
    the installed one (put first on PYTHONPATH)."""
    cmd = [sys.executable, "-m", "recon.cli.main", "fit", str(path), "-o", str(out), "-q"]
    cmd += [arg for kv in overrides for arg in ("--set", kv)]
    env = {"NUMBA_NUM_THREADS": str(threads)} if threads else {}
    if source is not None:
        env["PYTHONPATH"] = os.pathsep.join([str(source), os.environ.get("PYTHONPATH", "")])
    wall, rss, code = _run(cmd, env)
    if code != 0:
        return {"wall_s": wall, "rss_mib": rss, "failed": True}
    report = json.loads(out.with_name(out.stem + ".report.json").read_text())
    steps = report["steps"]
    psteps = _particle_steps(report["history"])
    dyn_time = report["time_s"].get("grow", 0.0) + report["time_s"].get("release", 0.0)
    return {
        "wall_s": wall,
        "rss_mib": rss,
        "fit_s": report["time_total_s"],
        "phases_s": report["time_s"],
        "particles": report["particles"],
        "steps": int(sum(steps.values())),
        "particle_steps_per_s": psteps / dyn_time if dyn_time > 0 else None,
        "faces": report["topology"].get("n_faces"),
    }


def run_peer(path: Path, out: Path, depth: int, policy: str = "default") -> dict[str, Any]:
    # MeshLab's Poisson runs OpenMP threads that spin while they wait. On a loaded machine that
    # made depth 8 on 40k points take 64 s instead of 5-7 s; on a quiet one PASSIVE made it 4x
    # slower (2.2 s -> 9.4 s, 2026-11-23). So the policy is a choice, the runtime's by default.
    env = {} if policy == "default" else {"OMP_WAIT_POLICY": policy}
    cmd = [sys.executable, "-c", _PEER_CODE, str(path), str(out), str(depth)]
    wall, rss, code = _run(cmd, env)
    return {"wall_s": wall, "rss_mib": rss, "failed": code != 0}


def _have_pymeshlab() -> bool:
    try:
        import pymeshlab  # noqa: F401
    except ImportError:
        return False
    return True


def _slope(sizes: list[int], times: list[float]) -> float | None:
    if len(sizes) < 2:
        return None
    return float(np.polyfit(np.log(sizes), np.log(times), 1)[0])


def _phase_slopes(rows: list[dict[str, Any]]) -> dict[str, float]:
    """The log-log slope of each phase's time (from the reports) against the input size: a
    phase above 1 grows faster than linearly."""
    out = {}
    for phase in rows[0]["phases_s"]:
        times = [r["phases_s"].get(phase, 0.0) for r in rows]
        if all(t > 0 for t in times):
            out[phase] = _slope([r["points"] for r in rows], times)
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[100_000, 300_000, 1_000_000])
    parser.add_argument("--repeats", type=int, default=1, help="runs per method and size")
    parser.add_argument("--no-peer", action="store_true", help="skip screened Poisson")
    parser.add_argument("--peer-depth", type=int, default=10, help="screened Poisson depth")
    parser.add_argument("--peer-max", type=int, default=1_000_000, help="largest size for the peer")
    parser.add_argument("--threads", type=int, default=None, help="NUMBA_NUM_THREADS for oprecon")
    add_overrides(
        parser,
        help="passed to `oprecon fit --set` (repeatable), e.g. dynamics.max_particles=4000000 "
        "so that the largest sizes are not capped",
    )
    parser.add_argument(
        "--omp-wait-policy",
        choices=("default", "PASSIVE", "ACTIVE"),
        default="default",
        help="OMP_WAIT_POLICY for screened Poisson (default: the runtime's own; PASSIVE helps "
        "on a loaded machine)",
    )
    parser.add_argument("--json-out", type=Path)
    parser.add_argument(
        "--baseline",
        type=Path,
        default=None,
        metavar="DIR",
        help="a source tree (e.g. the base commit's `git archive`) fitted alternately with "
        "this one; prints its times and the per-phase ratio",
    )
    args = parser.parse_args(argv)

    peer = not args.no_peer and _have_pymeshlab()
    if not args.no_peer and not peer:
        print(
            'pymeshlab is not installed (pip install -e ".[bench]"): no peer column',
            file=sys.stderr,
        )
    load = os.getloadavg()[0]
    print(
        f"# bench_scale {dt.date.today().isoformat()}: {os.cpu_count()} cores, load average "
        f"{load:.2f} at start, Python {platform.python_version()}"
    )
    rows = []
    with tempfile.TemporaryDirectory(prefix="oprecon-scale-") as tmp:
        from recon.io import write_points

        for n in args.sizes:
            path = Path(tmp) / f"torus-{n}.ply"
            write_points(path, sample_torus(n))
            ours, theirs, base = [], [], []
            for _ in range(args.repeats):  # alternate: the machine's load drifts
                ours.append(
                    run_oprecon(path, Path(tmp) / f"o-{n}.ply", args.threads, args.overrides)
                )
                if args.baseline is not None:
                    base.append(
                        run_oprecon(
                            path,
                            Path(tmp) / f"b-{n}.ply",
                            args.threads,
                            args.overrides,
                            args.baseline,
                        )
                    )
                if peer and n <= args.peer_max:
                    theirs.append(
                        run_peer(
                            path, Path(tmp) / f"p-{n}.ply", args.peer_depth, args.omp_wait_policy
                        )
                    )
            ok = [r for r in ours if not r.get("failed")]
            if not ok:
                rows.append({"points": n, "failed": True})
                continue
            best = sorted(ok, key=lambda r: r["wall_s"])[len(ok) // 2]
            row = {"points": n, **best, "wall_s": statistics.median(r["wall_s"] for r in ok)}
            if theirs:
                good = [r for r in theirs if not r["failed"]]
                if good:
                    row["peer_wall_s"] = statistics.median(r["wall_s"] for r in good)
                    row["peer_rss_mib"] = max(r["rss_mib"] for r in good)
                    row["ratio"] = row["wall_s"] / row["peer_wall_s"]
            row["load_after"] = os.getloadavg()[0]
            rows.append(row)
            _print_row(row)
            good_base = [r for r in base if not r.get("failed")]
            if good_base:
                b = sorted(good_base, key=lambda r: r["wall_s"])[len(good_base) // 2]
                row["baseline"] = b
                _print_baseline(row, b)
    done = [r for r in rows if not r.get("failed")]
    slope = _slope([r["points"] for r in done], [r["wall_s"] for r in done])
    if slope is not None:
        print(f"log-log slope of wall time vs points: {slope:.3f} (1.0 = linear)")
        print("per phase: " + ", ".join(f"{k} {v:.2f}" for k, v in _phase_slopes(done).items()))
        based = [r["baseline"] | {"points": r["points"]} for r in done if "baseline" in r]
        if len(based) == len(done):
            b_slope = _slope([r["points"] for r in based], [r["wall_s"] for r in based])
            print(f"baseline: log-log slope {b_slope:.3f}")
            print(
                "baseline per phase: "
                + ", ".join(f"{k} {v:.2f}" for k, v in _phase_slopes(based).items())
            )
    if args.json_out:
        args.json_out.parent.mkdir(parents=True, exist_ok=True)
        phases = _phase_slopes(done) if slope is not None else {}
        args.json_out.write_text(
            json.dumps(
                {"rows": rows, "slope": slope, "phase_slopes": phases, "overrides": args.overrides},
                indent=1,
            )
        )
    return 0


def _print_row(r: dict[str, Any]) -> None:
    phases = ", ".join(f"{k} {v:.1f}" for k, v in r["phases_s"].items())
    pss = r.get("particle_steps_per_s")
    peer = ""
    if "peer_wall_s" in r:
        peer = (
            f" | screened Poisson {r['peer_wall_s']:.1f} s, {r['peer_rss_mib']:.0f} MiB;"
            f" ratio {r['ratio']:.2f}"
        )
    print(
        f"{r['points']:>9,d} points: {r['wall_s']:.1f} s wall ({phases}), "
        f"{r['particles']:,d} particles, {r['steps']} steps, "
        f"{pss / 1e6 if pss else float('nan'):.2f} M particle-steps/s, "
        f"{r['rss_mib']:.0f} MiB peak{peer} (load average {r['load_after']:.1f} after)",
        flush=True,
    )


def _print_baseline(r: dict[str, Any], b: dict[str, Any]) -> None:
    ratios = ", ".join(
        f"{k} {r['phases_s'][k] / v:.2f}"
        for k, v in b["phases_s"].items()
        if k in r["phases_s"] and v > 0
    )
    print(
        f"{'':>9}  baseline: {b['wall_s']:.1f} s wall, {b['particles']:,d} particles, "
        f"{b['rss_mib']:.0f} MiB peak; this / baseline: wall {r['wall_s'] / b['wall_s']:.2f} "
        f"({ratios})",
        flush=True,
    )


if __name__ == "__main__":
    sys.exit(main())
