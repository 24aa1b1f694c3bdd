"""Peak memory of whole fits against the estimate of ``recon.fitting.memory``.

Generates a synthetic LiDAR scene (terrain plus a box building, georeferenced at x, y ~ 5e6,
classes 2 and 6, colours), writes it as LAZ, and runs ``oprecon fit`` on it in a fresh process
per size, reading that process's peak RSS from ``wait4``. Prints, per run, the points, r0, the
particles, the measured peak and the estimate with its error. Use it to (re)calibrate the
constants of :mod:`recon.fitting.memory` (``--fit`` prints least-squares constants).

Examples::

    python benchmarks/bench_memory.py                          # 10k .. 160k points
    python benchmarks/bench_memory.py --points 20000 80000 --spacing-factors 1 2 --fit
    python benchmarks/bench_memory.py --reading 3000000         # reading memory, --classes
    python benchmarks/bench_scale.py --sizes 100000 1000000 4000000 --no-peer --json-out s.json
    python benchmarks/bench_memory.py --points 20000 80000 --scale-json s.json --fit
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent


def scene(n: int, seed: int = 0, offset: tuple[float, float, float] = (5e6, 5e6, 200.0)):
    """Terrain (60 x 60 m, gentle waves) and a 16 x 12 x 8 m box building, area-uniform.

    Returns absolute points (n, 3), RGB uint8 (n, 3) and LAS classes (n,) (2 ground, 6
    building).
    """
    rng = np.random.default_rng(seed)
    size, bx, by, bh = 60.0, 16.0, 12.0, 8.0
    x0, y0 = 22.0, 24.0  # building corner
    roof = bx * by
    walls = 2 * (bx + by) * bh
    ground = size * size - roof
    total = roof + walls + ground
    n_roof = int(n * roof / total)
    n_walls = int(n * walls / total)
    n_ground = n - n_roof - n_walls

    def terrain(x, y):
        return 0.6 * np.sin(x / 7.0) * np.cos(y / 9.0)

    gx = rng.uniform(0, size, 2 * n_ground)
    gy = rng.uniform(0, size, 2 * n_ground)
    out = ~((gx > x0) & (gx < x0 + bx) & (gy > y0) & (gy < y0 + by))
    gx, gy = gx[out][:n_ground], gy[out][:n_ground]
    base = terrain(x0 + bx / 2, y0 + by / 2)
    ground_pts = np.stack([gx, gy, terrain(gx, gy)], axis=1)
    rx = rng.uniform(x0, x0 + bx, n_roof)
    ry = rng.uniform(y0, y0 + by, n_roof)
    roof_pts = np.stack([rx, ry, np.full(n_roof, base + bh)], axis=1)
    t = rng.uniform(0, 2 * (bx + by), n_walls)
    h = rng.uniform(base, base + bh, n_walls)
    wx = np.where(t < bx, x0 + t, np.where(t < bx + by, x0 + bx, 0.0))
    wy = np.where(t < bx, y0, np.where(t < bx + by, y0 + t - bx, 0.0))
    s = t - bx - by
    back = t >= bx + by
    wx = np.where(back, np.where(s < bx, x0 + bx - s, x0), wx)
    wy = np.where(back, np.where(s < bx, y0 + by, y0 + by - (s - bx)), wy)
    wall_pts = np.stack([wx, wy, h], axis=1)
    pts = np.concatenate([ground_pts, roof_pts, wall_pts]) + np.asarray(offset)
    cls = np.concatenate([np.full(len(ground_pts), 2), np.full(n_roof + n_walls, 6)]).astype(
        np.uint8
    )
    rgb = np.where(cls[:, None] == 2, [[40, 160, 40]], [[200, 40, 40]]).astype(np.uint8)
    return pts, rgb, cls


def write_laz(path: Path, pts: np.ndarray, rgb: np.ndarray, cls: np.ndarray) -> None:
    import laspy

    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales = np.array([0.001, 0.001, 0.001])
    header.offsets = np.floor(pts.min(axis=0))
    las = laspy.LasData(header)
    las.x, las.y, las.z = pts[:, 0], pts[:, 1], pts[:, 2]
    for j, c in enumerate(("red", "green", "blue")):
        las[c] = rgb[:, j].astype(np.uint16) * 257
    las.classification = cls
    las.write(str(path))


def run_fit(path: Path, out: Path, spacing_factor: float) -> tuple[int, dict]:
    """Fit in a fresh process; returns (peak RSS bytes, report dict)."""
    cmd = [
        str(Path(sys.executable).with_name("oprecon")),
        "fit",
        str(path),
        "-o",
        str(out),
        "--quiet",
        "--set",
        f"seeds.spacing_factor={spacing_factor}",
    ]
    proc = subprocess.Popen(cmd, cwd=ROOT)
    _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode != 0:
        raise SystemExit(f"fit failed ({proc.returncode}): {' '.join(cmd)}")
    report = json.loads(out.with_name(out.stem + ".report.json").read_text())
    return int(usage.ru_maxrss) * 1024, report


def reading_memory(n: int) -> None:
    """Peak RSS of ``read_points`` on an n-point LAZ (5 % class 6): whole, and class 6 only."""
    import laspy

    rng = np.random.default_rng(0)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "big.laz"
        header = laspy.LasHeader(point_format=3, version="1.2")
        header.scales = np.array([0.001] * 3)
        header.offsets = np.array([5e6, 5e6, 0.0])
        las = laspy.LasData(header)
        las.x = 5e6 + rng.uniform(0, 1000, n)
        las.y = 5e6 + rng.uniform(0, 1000, n)
        las.z = rng.uniform(0, 10, n)
        las.classification = np.where(rng.uniform(size=n) < 0.05, 6, 2).astype(np.uint8)
        las.write(str(path))
        del las
        for classes in ("None", "[6]"):
            code = (
                "from recon.io import read_points; "
                f"print(len(read_points({str(path)!r}, classes={classes})))"
            )
            proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE)
            _, _, usage = os.wait4(proc.pid, 0)
            kept = proc.stdout.read().decode().strip() if proc.stdout else "?"
            print(
                f"classes {classes:>5}: {kept} points kept, peak {usage.ru_maxrss / 1024:.0f} MiB"
            )


def torus_rows(path: Path) -> list[tuple]:
    """Rows (as ``main`` makes them) of the torus fits of ``bench_scale.py --json-out``: the
    point count, r0 and median spacing an untiled fit chooses for each size, and its peak."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from bench_scale import sample_torus

    from recon.config import ReconConfig
    from recon.fitting.memory import estimate_fit_memory
    from recon.fitting.scale import choose_spacing

    rows = []
    for r in json.loads(Path(path).read_text())["rows"]:
        if r.get("failed"):
            continue
        pts = sample_torus(r["points"])
        r0, _ = choose_spacing(pts, ReconConfig())
        est = estimate_fit_memory(pts, ReconConfig())
        peak = r["rss_mib"] * 2**20
        rows.append((r["points"], "torus", r0, r["particles"], est.particles, peak, est))
        print(
            f"torus {r['points']:>8,}  r0 {r0:.4f}  particles {r['particles']:>8,} (est "
            f"{est.particles:>8,})  peak {r['rss_mib']:7.0f} MiB  estimate "
            f"{est.peak_bytes / 2**20:7.0f} MiB  error {100 * (est.peak_bytes / peak - 1):+5.1f}%",
            flush=True,
        )
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, nargs="+", default=[10_000, 40_000, 160_000])
    ap.add_argument("--spacing-factors", type=float, nargs="+", default=[1.0, 2.0])
    ap.add_argument("--fit", action="store_true", help="print least-squares constants")
    ap.add_argument(
        "--reading",
        type=int,
        metavar="N",
        help="only measure reading an N-point LAZ, whole and with --classes 6 (5 %%)",
    )
    ap.add_argument(
        "--scale-json",
        type=Path,
        help="also fit the torus runs of `bench_scale.py --json-out` (their peak RSS)",
    )
    args = ap.parse_args()
    if args.reading:
        reading_memory(args.reading)
        return

    from recon.fitting.memory import estimate_peak_memory

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for n in args.points:
            pts, rgb, cls = scene(n)
            src = Path(tmp) / f"scene-{n}.laz"
            write_laz(src, pts, rgb, cls)
            for f in args.spacing_factors:
                peak, rep = run_fit(src, Path(tmp) / f"mesh-{n}-{f}.ply", f)
                est = estimate_peak_memory(
                    rep["input"]["points"], rep["spacing"], rep["input"]["median_spacing"]
                )
                rows.append((n, f, rep["spacing"], rep["particles"], est.particles, peak, est))
                err = est.peak_bytes / peak - 1.0
                print(
                    f"points {rep['input']['points']:>8,}  factor {f:4.1f}  r0 {rep['spacing']:.4f}"
                    f"  particles {rep['particles']:>8,} (est {est.particles:>8,})  peak "
                    f"{peak / 2**20:7.0f} MiB  estimate {est.peak_bytes / 2**20:7.0f} MiB  "
                    f"error {100 * err:+5.1f}%",
                    flush=True,
                )
    if args.scale_json:
        rows += torus_rows(args.scale_json)
    if args.fit:
        a = np.array([[1.0, r[0], r[4]] for r in rows])
        b = np.array([r[5] for r in rows], dtype=np.float64)
        coef, *_ = np.linalg.lstsq(a, b, rcond=None)
        print(
            f"least squares: base {coef[0] / 2**20:.0f} MiB, {coef[1]:.0f} B/point, "
            f"{coef[2]:.0f} B/particle"
        )


if __name__ == "__main__":
    main()
