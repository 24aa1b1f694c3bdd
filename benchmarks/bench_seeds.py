"""Base against branch over several seeds: is a change's topology no worse than seed noise?

Every fit's random realisation follows ``seed`` (the seeds' visiting order, the coverage
sample), and on open or sparse cases the boundary loops and components change with it (face-scan
at seeds 0-3: 6/2, 5/1, 7/1, 6/2 loops/components). One seed cannot tell a change from that
noise. This runs ``benchmarks/bench_quality.py --methods oprecon`` of two trees (the base, e.g.
``git archive BASE | tar -x -C DIR``, and this checkout) for every seed, alternating base and
branch, and prints per case the totals over the seeds:

    loops, components (sums), watertight (count), right genus (count, closed cases), the means
    of F@1 %, Chamfer-L1 and the minimum angle, the median time.

A case passes when its loop and component totals are not higher than the base's, its watertight
and right-genus counts not lower, its mean F@1 % at most ``--f-tol`` lower and its mean
Chamfer-L1 at most ``--cd-tol`` (relative) higher; the last line counts the cases that fail.
The base's rows can be kept (``--cache DIR``) and reused by later runs against the same base.

Examples::

    python benchmarks/bench_seeds.py --base DIR --cases face-scan face-sparse --seeds 0 1 2 3
    python benchmarks/bench_seeds.py --base . --branch-set dynamics.relax_steps=10 \\
        --cases face-scan bunny-clean        # a config change in one tree
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parent.parent


def run_tree(
    tree: Path,
    cases: list[str],
    seed: int,
    overrides: list[str],
    data: Path,
) -> dict[str, dict[str, Any]]:
    """Rows of ``tree``'s bench_quality (oprecon only) at one seed: ``{case: row}``."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "rows.json"
        cmd = [
            sys.executable,
            str(tree / "benchmarks" / "bench_quality.py"),
            "--methods",
            "oprecon",
            "--data",
            str(data),
            "--json-out",
            str(out),
            "--set",
            f"seed={seed}",
            *[a for o in overrides for a in ("--set", o)],
            "--cases",
            *cases,
        ]
        env = dict(os.environ, PYTHONPATH=str(tree))
        subprocess.run(cmd, cwd=tree, env=env, check=True, stdout=subprocess.DEVNULL)
        results = json.loads(out.read_text())
    return {case: rows[0] for case, rows in results.items()}


def cache_key(tree: Path, case: str, seed: int, overrides: list[str]) -> str:
    text = json.dumps([str(tree.resolve()), case, seed, sorted(overrides)])
    return hashlib.sha1(text.encode()).hexdigest()[:16]


def summarise(rows: list[dict[str, Any]], genus: int | None) -> dict[str, Any]:
    """Totals and means over the seeds' rows of one case and one tree."""
    ok = [r for r in rows if "error" not in r]
    return {
        "errors": len(rows) - len(ok),
        "loops": sum(r["boundary_loops"] for r in ok),
        "comps": sum(r["components"] for r in ok),
        "watertight": sum(bool(r["watertight"]) for r in ok),
        "genus_ok": None if genus is None else sum(r["genus"] == genus for r in ok),
        "per_seed": [f"{r['boundary_loops']}/{r['components']}" for r in ok],
        "fscore": float(np.mean([r["fscore"] for r in ok])) if ok else float("nan"),
        "chamfer": float(np.mean([r["chamfer_l1"] for r in ok])) if ok else float("nan"),
        "min_angle": float(np.mean([r["min_angle_mean"] for r in ok])) if ok else float("nan"),
        "seconds": float(np.median([r["seconds"] for r in ok])) if ok else float("nan"),
    }


def verdict(base: dict[str, Any], new: dict[str, Any], f_tol: float, cd_tol: float) -> list[str]:
    """What is worse in ``new`` than in ``base`` (empty: the case passes)."""
    worse = []
    if new["errors"] > base["errors"]:
        worse.append("errors")
    if new["loops"] > base["loops"]:
        worse.append("loops")
    if new["comps"] > base["comps"]:
        worse.append("comps")
    if new["watertight"] < base["watertight"]:
        worse.append("watertight")
    if base["genus_ok"] is not None and new["genus_ok"] < base["genus_ok"]:
        worse.append("genus")
    if new["fscore"] < base["fscore"] - f_tol:
        worse.append("F@1%")
    if new["chamfer"] > base["chamfer"] * (1.0 + cd_tol):
        worse.append("CD-L1")
    return worse


def table(
    cases: list[str], base: dict[str, Any], new: dict[str, Any], f_tol: float, cd_tol: float
) -> tuple[str, int]:
    head = (
        "| case | tree | loops/comps per seed | loops | comps | watertight | right genus | "
        "F@1% | CD-L1 | min angle | time s | verdict |\n"
        "|---|---|---|---|---|---|---|---|---|---|---|---|\n"
    )
    lines, failed = [], 0
    for case in cases:
        worse = verdict(base[case], new[case], f_tol, cd_tol)
        failed += bool(worse)
        for name, s in (("base", base[case]), ("branch", new[case])):
            genus = "–" if s["genus_ok"] is None else str(s["genus_ok"])
            mark = "" if name == "base" else ("worse: " + ", ".join(worse) if worse else "ok")
            lines.append(
                f"| {case} | {name} | {' '.join(s['per_seed'])} | {s['loops']} | {s['comps']} "
                f"| {s['watertight']} | {genus} | {s['fscore']:.4f} | {s['chamfer']:.5f} "
                f"| {s['min_angle']:.1f} | {s['seconds']:.2f} | {mark} |"
            )
    return head + "\n".join(lines) + "\n", failed


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--base", type=Path, required=True, help="the base tree (a checkout)")
    ap.add_argument("--cases", nargs="+", required=True)
    ap.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2, 3])
    ap.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data")
    ap.add_argument("--base-set", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--branch-set", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--cache", type=Path, help="keep and reuse the base's rows here")
    ap.add_argument("--f-tol", type=float, default=0.002, help="F@1%% noise (absolute)")
    ap.add_argument("--cd-tol", type=float, default=0.05, help="Chamfer-L1 noise (relative)")
    ap.add_argument("--json-out", type=Path)
    args = ap.parse_args(argv)
    manifest = json.loads((args.data / "manifest.json").read_text())
    meta = {c["id"]: c for c in manifest["cases"]}
    unknown = [c for c in args.cases if c not in meta]
    if unknown:
        print(f"unknown cases: {' '.join(unknown)}", file=sys.stderr)
        return 2
    rows: dict[str, dict[str, list]] = {"base": {}, "branch": {}}
    for seed in args.seeds:
        for side, tree, over in (
            ("base", args.base, args.base_set),
            ("branch", ROOT, args.branch_set),
        ):
            todo, got = list(args.cases), {}
            if side == "base" and args.cache:
                for case in args.cases:
                    f = args.cache / f"{cache_key(tree, case, seed, over)}.json"
                    if f.exists():
                        got[case] = json.loads(f.read_text())
                todo = [c for c in args.cases if c not in got]
            if todo:
                got.update(run_tree(tree, todo, seed, over, args.data))
            if side == "base" and args.cache:
                args.cache.mkdir(parents=True, exist_ok=True)
                for case in todo:
                    f = args.cache / f"{cache_key(tree, case, seed, over)}.json"
                    f.write_text(json.dumps(got[case]))
            for case in args.cases:
                rows[side].setdefault(case, []).append(got[case])
            print(f"seed {seed} {side}: done", file=sys.stderr, flush=True)
    genus = {c: meta[c].get("genus") if meta[c]["kind"] == "closed" else None for c in args.cases}
    summary = {
        side: {case: summarise(rows[side][case], genus[case]) for case in args.cases}
        for side in rows
    }
    text, failed = table(args.cases, summary["base"], summary["branch"], args.f_tol, args.cd_tol)
    print(text)
    print(f"{failed} of {len(args.cases)} cases worse than the base over seeds {args.seeds}")
    if args.json_out:
        args.json_out.write_text(json.dumps({"rows": rows, "summary": summary}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
