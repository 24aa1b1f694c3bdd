"""OpenMP wait policy: ``oprecon fit`` with and without ``OMP_WAIT_POLICY=PASSIVE``.

numba runs its threaded kernels on the ``omp`` threading layer (GNU OpenMP here). Idle GNU
OpenMP threads spin for a while before they sleep; on a shared machine that spinning takes CPU
from the other processes (and from our own main thread). This runs the same fit alternately
with GNU OpenMP's default policy (A) and ``PASSIVE`` (B) and prints the medians of wall time
and of the report's ``time_total_s``, with the load average before each run.

Example::

    python benchmarks/bench_wait_policy.py sample_data/bunny-clean.ply --runs 4
    python benchmarks/bench_wait_policy.py sample_data/bunny-clean.ply --concurrent 2 --threads 2
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def run(
    input_path: Path, out: Path, policy: str | None, threads: int | None, concurrent: int = 1
) -> dict:
    """``concurrent`` fits at once (as parallel batch items); wall of the slowest, mean fit."""
    env = dict(os.environ)
    env.pop("OMP_WAIT_POLICY", None)
    env.pop("GOMP_SPINCOUNT", None)
    if policy:
        env["OMP_WAIT_POLICY"] = policy
    else:
        # GNU OpenMP's own default (spin 300,000 times, then sleep), spelled out
        env["GOMP_SPINCOUNT"] = "300000"
    cmd = [str(Path(sys.executable).parent / "oprecon"), "fit", str(input_path), "-o", str(out)]
    cmd += ["--quiet", "--json"]
    if threads:
        cmd += ["--threads", str(threads)]
    load = os.getloadavg()[0]
    t0 = time.perf_counter()
    procs = [
        subprocess.Popen(
            [*cmd[:4], str(out.with_name(f"{out.stem}-{k}.ply")), *cmd[5:]],
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for k in range(concurrent)
    ]
    outputs = [p.communicate() for p in procs]
    wall = time.perf_counter() - t0
    fits = []
    for p, (stdout, stderr) in zip(procs, outputs, strict=True):
        if p.returncode != 0:
            raise SystemExit(f"fit failed ({p.returncode}): {stderr[-2000:]}")
        fits.append(json.loads(stdout)["time_total_s"])
    return {"wall": wall, "fit": statistics.mean(fits), "load": load}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("input", type=Path)
    parser.add_argument("--runs", type=int, default=3, help="runs of each (alternating)")
    parser.add_argument("--threads", type=int, default=None, help="--threads for the fit")
    parser.add_argument(
        "--concurrent", type=int, default=1, help="fits at once (as parallel batch items)"
    )
    args = parser.parse_args()
    results: dict[str, list[dict]] = {"default": [], "PASSIVE": []}
    with tempfile.TemporaryDirectory() as tmp:
        run(args.input, Path(tmp) / "warm.ply", None, args.threads)  # numba cache, file cache
        for i in range(args.runs):
            for name in ("default", "PASSIVE"):
                r = run(
                    args.input,
                    Path(tmp) / f"{name}.ply",
                    None if name == "default" else name,
                    args.threads,
                    args.concurrent,
                )
                results[name].append(r)
                print(
                    f"run {i + 1} {name:>7}: wall {r['wall']:6.2f} s  fit {r['fit']:6.2f} s  "
                    f"load {r['load']:.2f}",
                    flush=True,
                )
    med = {
        k: {m: statistics.median(r[m] for r in v) for m in ("wall", "fit", "load")}
        for k, v in results.items()
    }
    for k, v in med.items():
        w, f, ld = v["wall"], v["fit"], v["load"]
        print(f"median {k:>7}: wall {w:6.2f} s  fit {f:6.2f} s  load {ld:.2f}")
    print(
        f"PASSIVE / default: wall {med['PASSIVE']['wall'] / med['default']['wall']:.2f}  "
        f"fit {med['PASSIVE']['fit'] / med['default']['fit']:.2f}"
    )


if __name__ == "__main__":
    main()
