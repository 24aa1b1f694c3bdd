"""Tiled fits (issue #14): seams against the untiled fit, and scaling on a Dask LocalCluster.

``seams`` (default): an N-point synthetic scene (``benchmarks/scenes.py``: terrain, buildings,
tree crowns, open boundary, exact ground truth) fitted whole and cut into >= 8 tiles. Prints
boundary loops, non-manifold edges, Chamfer-L1 and F@1% against the ground truth, and time,
for both.

``restitch``: stitches again the tiles of a ``seams`` run whose work folder ``--keep-work``
kept (the same scene: same ``--points`` and ``--seed``) and prints what ``seams`` prints for
the tiled mesh: a stitch experiment takes minutes instead of a refit.

``scale``: writes an N-point LAZ scene per size (a larger N is a larger area at the same
density), fits it in tiles of a fixed side on a 2-worker Dask LocalCluster
(``--executor dask --jobs 2``), and prints wall time, points/s, tiles, and the peak RSS of the
coordinating process and of each worker (sampled every 0.2 s over the process tree), every
boundary loop of the mesh (as ``seams``), then the slope of log(time) against log(points).

``tasks``: runs ``--count`` N trivial tasks (one per count, each on a fresh 2-worker Dask
LocalCluster) through the tiled fit's scheduling loop (``recon.tiling.executors``) and
prints the coordinating process's RSS growth per task after a warm-up and the records of
finished tasks it holds (the scheduler runs in it); ``--default-records`` keeps Dask's own
limits (``DASK_RECORDS`` not applied) for the comparison.

Examples::

    python benchmarks/bench_tiles.py seams --points 1000000
    python benchmarks/bench_tiles.py seams --points 1000000 --only untiled --keep out/
    python benchmarks/bench_tiles.py seams --points 1000000 --only tiled --keep out/
    python benchmarks/bench_tiles.py seams --points 1000000 --only tiled --keep-work out/work
    python benchmarks/bench_tiles.py restitch --points 1000000 --keep-work out/work
    python benchmarks/bench_tiles.py scale --points 250000 500000 1000000
    python benchmarks/bench_tiles.py scale --points 10000000 --tile-size 100
    python benchmarks/bench_tiles.py scale --points 1000000 --keep-work out/scale
    python benchmarks/bench_tiles.py scale --points 300000 --untiled
    python benchmarks/bench_tiles.py tasks --count 2000 8000
    python benchmarks/bench_tiles.py tasks --count 2000 8000 --default-records
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))

from scenes import Scene, write_laz  # noqa: E402

OPRECON = [sys.executable, "-m", "recon.cli.main"]
#: Where ``scale`` puts its scenes (georeferenced-like coordinates).
SCALE_OFFSET = (5e6, 5e6, 200.0)


def _oprecon() -> list[str]:
    exe = Path(sys.executable).with_name("oprecon")
    return [str(exe)] if exe.exists() else OPRECON


class TreeRss:
    """Peak RSS of a process and of each of its descendants, sampled in a thread."""

    def __init__(self, pid: int, every: float = 0.2) -> None:
        import psutil

        self.root = psutil.Process(pid)
        self.every = every
        self.peak: dict[int, int] = {}
        self.names: dict[int, str] = {}
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        import psutil

        while not self.stop.is_set():
            try:
                procs = [self.root, *self.root.children(recursive=True)]
            except psutil.Error:
                break
            for p in procs:
                try:
                    rss = p.memory_info().rss
                    self.peak[p.pid] = max(self.peak.get(p.pid, 0), rss)
                    if p.pid not in self.names:
                        self.names[p.pid] = " ".join(p.cmdline()[:3])
                except psutil.Error:
                    pass
            time.sleep(self.every)

    def close(self) -> tuple[int, list[int]]:
        """(peak of the root, peaks of the descendants that were workers)."""
        self.stop.set()
        self.thread.join()
        root = self.peak.get(self.root.pid, 0)
        workers = [
            v
            for pid, v in self.peak.items()
            if pid != self.root.pid and "resource_tracker" not in self.names.get(pid, "")
        ]
        return root, sorted(workers, reverse=True)


def run_fit(args: list[str], env: dict | None = None) -> tuple[float, int, list[int], int]:
    """Run ``oprecon fit ...``; wall seconds, coordinator peak RSS, worker peaks, exit code."""
    t0 = time.perf_counter()
    proc = subprocess.Popen(
        [*_oprecon(), "fit", *args, "-q"],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    rss = TreeRss(proc.pid)
    _, err = proc.communicate()
    wall = time.perf_counter() - t0
    root, workers = rss.close()
    if proc.returncode != 0:
        print(err, file=sys.stderr)
    return wall, root, workers, proc.returncode


def mesh_scores(mesh: Path, truth: np.ndarray) -> dict:
    from recon.io import read_mesh
    from recon.metrics import compare_meshes
    from recon.topology import mesh_topology

    v, f = read_mesh(mesh)
    topo = mesh_topology(v, f)
    cmp = compare_meshes((v, f), (truth, None), n_samples=len(truth))
    return {
        "vertices": topo["n_vertices"],
        "faces": topo["n_faces"],
        "boundary_loops": topo["boundary_loops"],
        "non_manifold_edges": topo["non_manifold_edges"],
        "non_manifold_vertices": topo["non_manifold_vertices"],
        "duplicate_faces": topo["duplicate_faces"],
        "chamfer_l1": cmp["chamfer_l1"],
        "fscore": cmp["fscore"],
    }


def loop_table(mesh: Path, grid_lo: np.ndarray | None, size: float | None) -> list[dict]:
    """Every boundary loop: edges, perimeter, centroid and distance to the nearest seam [m]."""
    from scipy import sparse
    from scipy.sparse import csgraph

    from recon.io import read_mesh
    from recon.mesh import count_edge_faces

    v, f = read_mesh(mesh)
    edges, counts = count_edge_faces(f)
    b = edges[counts == 1]
    if len(b) == 0:
        return []
    g = sparse.coo_matrix((np.ones(len(b)), (b[:, 0], b[:, 1])), (len(v), len(v)))
    _, lab = csgraph.connected_components(g, directed=False)
    out = []
    for c in np.unique(lab[b[:, 0]]):
        e = b[lab[b[:, 0]] == c]
        mid = v[e].mean(axis=1)
        seam = float("nan")
        if grid_lo is not None and size:
            u = (mid[:, :2] - grid_lo[:2]) / size
            seam = float((np.abs(u - np.round(u)) * size).min())
        out.append(
            {
                "edges": len(e),
                "perimeter_m": float(np.linalg.norm(v[e[:, 0]] - v[e[:, 1]], axis=1).sum()),
                "centroid": [round(float(x), 2) for x in mid.mean(axis=0)],
                "seam_m": seam,
            }
        )
    return sorted(out, key=lambda r: -r["perimeter_m"])


def seams(ns: argparse.Namespace) -> int:
    n = ns.points[0]
    scene = Scene.for_points(n, seed=ns.seed)
    pts, cls = scene.sample(n, seed=ns.seed + 1, noise=ns.noise)
    truth = scene.ground_truth(ns.truth)
    tiles_per_side = ns.tiles_per_side
    size = scene.side / tiles_per_side * 1.0001
    tiled_name = f"tiled {tiles_per_side}x{tiles_per_side}"
    runs = [("untiled", []), (tiled_name, ["--tile-size", f"{size:.6f}", "--jobs", str(ns.jobs)])]
    runs = [r for r in runs if ns.only is None or r[0].split()[0] == ns.only]
    keep = Path(ns.keep) if ns.keep else None
    tag = f"seams-{n}-s{ns.seed}-t{tiles_per_side}"
    with tempfile.TemporaryDirectory(prefix="bench_tiles_", dir=ns.workdir) as tmp:
        d = keep if keep is not None else Path(tmp)
        d.mkdir(parents=True, exist_ok=True)
        src = Path(tmp) / "scene.laz"
        write_laz(src, pts, cls)
        rows = {}
        for name, extra in runs:
            out = d / f"{tag}-{name.split()[0]}.ply"
            env = None
            if ns.keep_work and name != "untiled":
                env = {**os.environ, "OPRECON_KEEP_TILES": str(Path(ns.keep_work).resolve())}
            args = [str(src), "-o", str(out), *extra, *ns.fit_args]
            wall, root, workers, code = run_fit(args, env)
            if code != 0:
                return code
            row = mesh_scores(out, truth)
            report = json.loads(out.with_suffix(".report.json").read_text())
            row.update(
                time_s=wall,
                tiles=report.get("tiles", {}).get("count", 1),
                peak_rss_gib=max([root, *workers]) / 2**30,
            )
            print(f"{name}: {json.dumps(row)}", flush=True)
            tiles = report.get("tiles")
            lo = np.asarray(tiles["per_tile"][0]["bounds"][0]) if tiles else pts.min(axis=0)
            row["loops"] = loop_table(out, lo, size)
            for loop in row["loops"]:
                print(f"  loop {json.dumps(loop)}", flush=True)
            rows[name] = row
            if keep is not None:
                out.with_suffix(".row.json").write_text(json.dumps(row))
    if keep is not None:  # the other run of an earlier --only invocation, same scene
        for name in ("untiled", tiled_name):
            saved = keep / f"{tag}-{name.split()[0]}.row.json"
            if name not in rows and saved.exists():
                rows[name] = json.loads(saved.read_text())
                print(f"{name} (from {saved.name}): {json.dumps(rows[name])}")
    rows = {k: rows[k] for k in ("untiled", tiled_name) if k in rows}
    if len(rows) < 2:
        return 0
    base = rows["untiled"]
    tiled = rows[next(k for k in rows if k != "untiled")]
    print()
    print(
        f"scene: {n:,} points, {scene.side:.0f} m square, {len(scene.buildings)} buildings, "
        f"{len(scene.trees)} trees; noise {ns.noise} m; truth {len(truth):,} points"
    )
    print("| run | tiles | boundary loops | non-manifold edges | Chamfer-L1 [m] | F@1% | time s |")
    print("|---|---|---|---|---|---|---|")
    for name, r in rows.items():
        print(
            f"| {name} | {r['tiles']} | {r['boundary_loops']} | {r['non_manifold_edges']} | "
            f"{r['chamfer_l1']:.4f} | {r['fscore']:.4f} | {r['time_s']:.0f} |"
        )
    dc = tiled["chamfer_l1"] / base["chamfer_l1"] - 1
    df = tiled["fscore"] - base["fscore"]
    print(
        f"\nChamfer-L1 tiled vs untiled: {100 * dc:+.2f} % (goal within 2 %); "
        f"F@1%: {df:+.4f} (goal within 0.002)"
    )
    ok = (
        abs(dc) <= 0.02
        and abs(df) <= 0.002
        and tiled["non_manifold_edges"] == 0
        and tiled["boundary_loops"] == base["boundary_loops"]
    )
    print("seamless goals met" if ok else "seamless goals NOT met")
    return 0


def restitch(ns: argparse.Namespace) -> int:
    import pickle

    from recon.tiling.run import STITCH_INPUTS
    from recon.tiling.run import restitch as stitch_again

    work = Path(ns.keep_work)
    grid = pickle.loads((work / STITCH_INPUTS).read_bytes())[0]
    # a scale run's scene lies at SCALE_OFFSET, a seams run's at the origin
    offset = SCALE_OFFSET if grid.lo[0] > 0.5 * SCALE_OFFSET[0] else (0.0, 0.0, 0.0)
    scene = Scene.for_points(ns.points[0], seed=ns.seed, offset=offset)
    truth = scene.ground_truth(ns.truth)
    out = work / "restitched.ply"
    t0 = time.perf_counter()
    stitched = stitch_again(work, out)
    row = mesh_scores(out, truth)
    row.update(stitch_s=time.perf_counter() - t0, repair=stitched["repair"])
    print(f"restitched: {json.dumps(row)}", flush=True)
    for loop in loop_table(out, np.asarray(grid.lo), grid.size):
        print(f"  loop {json.dumps(loop)}", flush=True)
    return 0


def scale(ns: argparse.Namespace) -> int:
    rows = []
    for n in ns.points:
        scene = Scene.for_points(n, seed=ns.seed, offset=SCALE_OFFSET)
        with tempfile.TemporaryDirectory(prefix="bench_tiles_", dir=ns.workdir) as tmp:
            d = Path(tmp)
            src = d / "scene.laz"
            t0 = time.perf_counter()
            # write in parts so that the generator does not hold 10M points twice
            pts, cls = scene.sample(n, seed=ns.seed + 1, noise=ns.noise)
            write_laz(src, pts, cls)
            del pts, cls
            t_write = time.perf_counter() - t0
            out = d / "mesh.ply"
            args = [
                str(src),
                "-o",
                str(out),
                "--tile-size",
                str(ns.tile_size),
                "--jobs",
                "2",
                "--executor",
                ns.executor,
                *ns.fit_args,
            ]
            env = None
            if ns.keep_work:
                keep = Path(ns.keep_work).resolve() / str(n)
                env = {**os.environ, "OPRECON_KEEP_TILES": str(keep)}
            wall, root, workers, code = run_fit(args, env)
            if code != 0:
                return code
            report = json.loads(out.with_suffix(".report.json").read_text())
            row = {
                "points": n,
                "side_m": scene.side,
                "tiles": report["tiles"]["count"],
                "wall_s": wall,
                "points_per_s": n / wall,
                "coordinator_gib": root / 2**30,
                # the coordinator's own peak in each phase (split ... write) [MiB]
                "coordinator_mib_after": report["tiles"]["coordinator"].get("peak_rss_mib"),
                "worker_gib": [w / 2**30 for w in workers[:2]],
                "tile_s_mean": report["tiles"]["time_per_tile"]["mean"],
                "phases_s": {k: round(v, 1) for k, v in report["timings"].items()},
                **_tile_shares(report["tiles"]["per_tile"]),
                "write_laz_s": t_write,
                "non_manifold_edges": report["topology"]["non_manifold_edges"],
                "boundary_loops": report["topology"]["boundary_loops"],
            }
            if ns.untiled:  # the same scene fitted whole: the tiled path's overhead per point
                whole, _, _, code = run_fit([str(src), "-o", str(d / "whole.ply"), *ns.fit_args])
                if code != 0:
                    return code
                row["untiled_wall_s"] = whole
                row["tiled_over_untiled"] = wall / whole
            rows.append(row)
            print(json.dumps(row), flush=True)
            lo = np.asarray(report["tiles"]["per_tile"][0]["bounds"][0])
            for loop in loop_table(out, lo, ns.tile_size):
                print(f"  loop {json.dumps(loop)}", flush=True)
    print()
    _table(
        ["points", "tiles", "wall s", "points/s", "coordinator peak GiB", "worker peak GiB"],
        [
            [
                f"{r['points']:,}",
                r["tiles"],
                f"{r['wall_s']:.0f}",
                f"{r['points_per_s']:,.0f}",
                f"{r['coordinator_gib']:.2f}",
                ", ".join(f"{w:.2f}" for w in r["worker_gib"]),
            ]
            for r in rows
        ],
    )
    for a, b in zip(rows, rows[1:], strict=False):
        slope = math.log(b["wall_s"] / a["wall_s"]) / math.log(b["points"] / a["points"])
        print(f"slope {a['points']:,} -> {b['points']:,}: {slope:.2f} (goal <= 1.1)")
    return 0


def tasks(ns: argparse.Namespace) -> int:
    import gc

    import psutil

    from recon.batch import executors as batch_executors
    from recon.tiling.executors import held_records, run_tasks, tile_runner

    if ns.default_records:
        batch_executors.DASK_RECORDS = {}
    me = psutil.Process()

    def rss() -> int:
        gc.collect()
        return me.memory_info().rss

    rows = []
    for n in ns.count:
        with tile_runner("dask", 2) as runner:

            def run(count: int, runner=runner) -> None:
                jobs = {t: (abs, (-t,)) for t in range(count)}
                run_tasks(runner, "tasks", jobs, str, on_result=lambda t, r: None)

            run(ns.warmup)
            base = rss()
            t0 = time.perf_counter()
            run(n)
            wall = time.perf_counter() - t0
            grown = rss() - base
            row = {
                "tasks": n,
                "rss_growth_mib": grown / 2**20,
                "bytes_per_task": grown / n,
                "tasks_per_s": n / wall,
                "held": held_records(runner),
            }
        rows.append(row)
        print(json.dumps(row), flush=True)
    print()
    records = "distributed's defaults" if ns.default_records else "DASK_RECORDS"
    print(f"records of finished tasks: {records}")
    _table(
        ["tasks", "coordinator RSS growth MiB", "bytes / task", "tasks/s"],
        [
            [
                f"{r['tasks']:,}",
                f"{r['rss_growth_mib']:.1f}",
                f"{r['bytes_per_task']:,.0f}",
                f"{r['tasks_per_s']:.0f}",
            ]
            for r in rows
        ],
    )
    for a, b in zip(rows, rows[1:], strict=False):
        per = (b["rss_growth_mib"] - a["rss_growth_mib"]) * 2**20 / (b["tasks"] - a["tasks"])
        print(f"growth {a['tasks']:,} -> {b['tasks']:,} tasks: {per:,.0f} bytes per task")
    return 0


def _table(header: list[str], rows: list[list]) -> None:
    """Print a Markdown table."""
    print("| " + " | ".join(header) + " |")
    print("|" + "---|" * len(header))
    for r in rows:
        print("| " + " | ".join(str(c) for c in r) + " |")


def _tile_shares(per_tile: list[dict]) -> dict:
    """Where a tiled fit's worker time goes: the tiles' fit and mesh seconds summed, the
    fitted points over the core points (the halo's share of the work) and points per tile."""
    core = sum(t["points"] for t in per_tile)
    fitted = sum(t.get("points_with_halo", t["points"]) for t in per_tile)
    return {
        "fit_s_sum": round(sum(t["fit_s"] for t in per_tile), 1),
        "mesh_s_sum": round(sum(t["mesh_s"] for t in per_tile), 1),
        "halo_factor": round(fitted / max(core, 1), 3),
        "points_per_tile": round(core / max(len(per_tile), 1)),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "mode", choices=["seams", "restitch", "scale", "tasks"], nargs="?", default="seams"
    )
    ap.add_argument("--points", type=int, nargs="+", default=None)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--count", type=int, nargs="+", default=[2000, 8000], help="tasks: task counts")
    ap.add_argument("--warmup", type=int, default=50, help="tasks: tasks before the baseline")
    ap.add_argument(
        "--default-records",
        action="store_true",
        help="tasks: keep Dask's limits on the records of finished tasks",
    )
    ap.add_argument("--noise", type=float, default=0.02, help="[m] along the normal")
    ap.add_argument("--truth", type=int, default=2_000_000, help="ground-truth points")
    ap.add_argument("--tiles-per-side", type=int, default=3, help="seams: tiles per side")
    ap.add_argument("--tile-size", type=float, default=100.0, help="scale: tile side [m]")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument(
        "--untiled",
        action="store_true",
        help="scale: also fit each scene whole and print the tiled/untiled time ratio",
    )
    ap.add_argument("--executor", default="dask", choices=["local", "dask"])
    ap.add_argument("--workdir", default=None, help="folder for the scenes and meshes")
    ap.add_argument(
        "--only",
        choices=["untiled", "tiled"],
        default=None,
        help="seams: run one of the two fits (with --keep, compared with the other's saved row)",
    )
    ap.add_argument(
        "--keep",
        default=None,
        help="seams: folder that keeps the meshes, reports and each run's row (JSON)",
    )
    ap.add_argument(
        "--keep-work",
        default=None,
        help="seams, scale: folder that receives the tiled fits' work folders (scale: one "
        "per size, named by the point count); restitch: such a work folder",
    )
    ap.add_argument(
        "--fit-arg",
        dest="fit_args",
        action="append",
        default=[],
        help="extra argument for oprecon fit (repeatable)",
    )
    ns = ap.parse_args(argv)
    if ns.points is None:
        ns.points = [1_000_000] if ns.mode != "scale" else [250_000, 500_000, 1_000_000]
    os.environ.setdefault("PYTHONWARNINGS", "ignore")
    return {"seams": seams, "restitch": restitch, "scale": scale, "tasks": tasks}[ns.mode](ns)


if __name__ == "__main__":
    sys.exit(main())
