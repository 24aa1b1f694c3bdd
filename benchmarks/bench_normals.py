"""Time normal estimation and orientation on generated clouds; prints one JSON document.

Usage::

    .venv/bin/python benchmarks/bench_normals.py [--n 100000] [--repeat 3]

Cases (all with ``n`` points, fixed seeds): a torus with 1 % Gaussian noise (of the bounding-box
diagonal), the same torus clean, an exactly planar square (random points in z = 0, the input on
which Open3D's orientation crashes) and a noisy height field (an open surface). The budget is
5 s per case for estimation + orientation at 100k points.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from recon.normals import estimate_normals, orient_normals  # noqa: E402


def torus(n: int, rng: np.random.Generator, noise: float) -> tuple[np.ndarray, np.ndarray]:
    big, small = 1.0, 0.35
    u = rng.uniform(0, 2 * np.pi, n)
    v = rng.uniform(0, 2 * np.pi, n)
    normal = np.stack([np.cos(u) * np.cos(v), np.sin(u) * np.cos(v), np.sin(v)], 1)
    centre = np.stack([big * np.cos(u), big * np.sin(u), np.zeros(n)], 1)
    pts = centre + small * normal
    diag = float(np.linalg.norm(pts.max(0) - pts.min(0)))
    return pts + rng.normal(0, noise * diag, pts.shape), normal


def plane(n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    pts = np.column_stack([rng.uniform(-0.5, 0.5, (n, 2)), np.zeros(n)])
    return pts, np.tile([0.0, 0.0, 1.0], (n, 1))


def height_field(n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    xy = rng.uniform(-1, 1, (n, 2))
    z = 0.2 * np.sin(3 * xy[:, 0]) * np.cos(2 * xy[:, 1])
    gx = 0.6 * np.cos(3 * xy[:, 0]) * np.cos(2 * xy[:, 1])
    gy = -0.4 * np.sin(3 * xy[:, 0]) * np.sin(2 * xy[:, 1])
    normal = np.column_stack([-gx, -gy, np.ones(n)])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    pts = np.column_stack([xy, z]) + rng.normal(0, 0.002, (n, 3))
    return pts, normal


def run(name: str, pts: np.ndarray, gt: np.ndarray, repeat: int, k: int) -> dict:
    best_est = best_orient = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        normals = estimate_normals(pts, k=k)
        t1 = time.perf_counter()
        oriented, info = orient_normals(pts, normals)
        t2 = time.perf_counter()
        best_est = min(best_est, t1 - t0)
        best_orient = min(best_orient, t2 - t1)
    dots = np.einsum("ij,ij->i", oriented, gt)
    return {
        "case": name,
        "n_points": int(pts.shape[0]),
        "k": k,
        "estimate_s": round(best_est, 3),
        "orient_s": round(best_orient, 3),
        "total_s": round(best_est + best_orient, 3),
        "consistent_fraction": round(float(np.mean(dots > 0)), 5),
        "median_angle_deg": round(float(np.degrees(np.median(np.arccos(np.clip(dots, -1, 1))))), 3),
        "orientation": info.as_dict(),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=100_000)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    cases = [
        ("torus-noise1", *torus(args.n, rng, 0.01), 60),
        ("torus-clean", *torus(args.n, rng, 0.0), 20),
        ("plane-exact", *plane(args.n, rng), 20),
        ("height-field-noisy", *height_field(args.n, rng), 20),
    ]
    results = [run(name, p, g, args.repeat, k) for name, p, g, k in cases]
    out = {
        "benchmark": "normals",
        "python": platform.python_version(),
        "numpy": np.__version__,
        "machine": platform.machine(),
        "results": results,
    }
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
