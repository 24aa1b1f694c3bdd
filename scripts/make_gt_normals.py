"""Make the ground-truth normal files used by tests/test_normals.py.

For every point of a development case, the normal of the nearest triangle of the case's
ground-truth mesh (Open3D ``RaycastingScene.compute_closest_points``; face normals of the GT
mesh, which is consistently oriented outward). Stored as ``int8`` (unit vector x 127, rounded;
angular error < 0.5 degrees) in point order of ``recon.io.read_points``, to keep the bundled
sample data small.

Usage (from the repository root; needs the development data set beside the checkout)::

    .venv/bin/python scripts/make_gt_normals.py --data ../shared/data \\
        bunny-clean bunny-noise1 --out sample_data

writes ``sample_data/<case>-gt-normals.npy``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import open3d as o3d

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from recon.io import read_mesh, read_points  # noqa: E402


def nearest_triangle_normals(
    vertices: np.ndarray, faces: np.ndarray, points: np.ndarray
) -> np.ndarray:
    """Unit normal of the triangle nearest to each point, (n, 3) float64."""
    mesh = o3d.t.geometry.TriangleMesh()
    mesh.vertex.positions = o3d.core.Tensor(vertices.astype(np.float32))
    mesh.triangle.indices = o3d.core.Tensor(faces.astype(np.int32))
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(mesh)
    result = scene.compute_closest_points(o3d.core.Tensor(points.astype(np.float32)))
    tri = result["primitive_ids"].numpy().astype(np.int64)
    a, b, c = (vertices[faces[:, i]] for i in range(3))
    face_normals = np.cross(b - a, c - a)
    face_normals /= np.linalg.norm(face_normals, axis=1, keepdims=True)
    return face_normals[tri]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("cases", nargs="+", help="case ids, e.g. bunny-clean")
    parser.add_argument("--data", type=Path, default=Path("../shared/data"))
    parser.add_argument("--out", type=Path, default=Path("sample_data"))
    args = parser.parse_args()
    for case in args.cases:
        meta = json.loads((args.data / "cases" / case / "meta.json").read_text())
        cloud = read_points(args.data / "cases" / case / "input.ply")
        if cloud.info["n_duplicates_merged"] or cloud.info["n_nonfinite_dropped"]:
            raise SystemExit(f"{case}: points were merged or dropped; rows would not match")
        vertices, faces = read_mesh(args.data / meta["gt"])
        normals = nearest_triangle_normals(vertices, faces, cloud.absolute_points())
        quantised = np.round(normals * 127.0).astype(np.int8)
        out = args.out / f"{case}-gt-normals.npy"
        np.save(out, quantised)
        print(f"{out}: {quantised.shape[0]} normals from {meta['gt']}")


if __name__ == "__main__":
    main()
