"""Time normal estimation and orientation on generated clouds; prints one JSON document.

Usage::

    .venv/bin/python benchmarks/bench_normals.py [--n 100000] [--repeat 3]
    .venv/bin/python benchmarks/bench_normals.py --dev-data ../shared/data   # + accuracy per case

Cases (all with ``n`` points, fixed seeds): a torus with 1 % Gaussian noise (of the bounding-box
diagonal), the same torus clean, an exactly planar square (random points in z = 0, the input on
which Open3D's orientation crashes) and a noisy height field (an open surface). The budget is
5 s per case for estimation + orientation at 100k points.

With ``--dev-data`` the development cases are measured too: ``compute_normals`` with the default
configuration (k = 80 for the ``noise1`` cases), against the normal of the nearest GT triangle.
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


def dev_cases(data: Path, k_noisy: int) -> list[dict]:
    """Accuracy of ``compute_normals`` on every development case against its GT mesh."""
    import json as _json

    sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "scripts"))
    from make_gt_normals import nearest_triangle_normals

    from recon.config import NormalsConfig
    from recon.io import read_mesh, read_points
    from recon.normals import compute_normals

    rows = []
    meshes: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for meta_path in sorted((data / "cases").glob("*/meta.json")):
        meta = _json.loads(meta_path.read_text())
        cloud = read_points(data / meta["input"])
        if meta["gt"] not in meshes:
            meshes[meta["gt"]] = read_mesh(data / meta["gt"])
        gt = nearest_triangle_normals(*meshes[meta["gt"]], cloud.absolute_points())
        k = k_noisy if meta["defect"] == "noise1" else 20
        t0 = time.perf_counter()
        normals, info = compute_normals(cloud, NormalsConfig(k=k))
        elapsed = time.perf_counter() - t0
        dots = np.einsum("ij,ij->i", normals, gt)
        if meta["kind"] == "open":  # only consistency matters: either side is right
            dots = dots * np.sign(np.sum(dots))
        rows.append(
            {
                "case": meta["id"],
                "kind": meta["kind"],
                "n_points": len(cloud),
                "k": k,
                "source": info["source"],
                "time_s": round(elapsed, 3),
                "consistent_fraction": round(float(np.mean(dots > 0)), 5),
                "median_angle_deg": round(
                    float(np.degrees(np.median(np.arccos(np.clip(dots, -1, 1))))), 3
                ),
                "components": info.get("n_components"),
                "guessed": info.get("n_guessed"),
                "rules": info.get("component_methods"),
            }
        )
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=100_000)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--dev-data", type=Path, help="development data set folder")
    parser.add_argument("--k-noisy", type=int, default=80, help="k for the noise1 dev cases")
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
    if args.dev_data is not None:
        out["dev_cases"] = dev_cases(args.dev_data, args.k_noisy)
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
