"""Small closed meshes with known handles, for the topology tests."""

from __future__ import annotations

import numpy as np
import open3d as o3d


def icosphere(radius: float = 6.0, levels: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """A closed genus-0 sphere of near-equal triangles (edges ~0.9 at the defaults)."""
    m = o3d.geometry.TriangleMesh.create_icosahedron(radius).subdivide_midpoint(levels)
    v = np.asarray(m.vertices)
    v = radius * v / np.linalg.norm(v, axis=1, keepdims=True)
    return v, np.asarray(m.triangles).astype(np.int64)


def sphere_with_tunnel(radius: float = 6.0) -> tuple[np.ndarray, np.ndarray]:
    """:func:`icosphere` with a tunnel: two faces about three edges apart replaced by a
    three-sided tube between their corners (one handle, orientable, every edge in two
    faces). The tube's two cycles are a few edges long."""
    v, f = icosphere(radius)
    centre = v[f].mean(axis=1)
    a = int(np.argmax(centre[:, 0]))
    edge = float(np.linalg.norm(v[f[a, 0]] - v[f[a, 1]]))
    d = np.linalg.norm(centre - centre[a], axis=1)
    far = np.flatnonzero(~np.isin(f, f[a]).any(axis=1) & (d > 3.0 * edge))
    b = int(far[np.argmin(d[far])])
    keep = np.ones(len(f), dtype=bool)
    keep[[a, b]] = False
    tube = []
    for i in range(3):  # quad i joins a_i -> a_(i+1) to b_(-i) -> b_(1-i): orientable
        a0, a1 = f[a, i], f[a, (i + 1) % 3]
        bx, by = f[b, (-i) % 3], f[b, (1 - i) % 3]
        tube += [[a0, a1, bx], [a0, bx, by]]
    return v, np.vstack([f[keep], np.array(tube, dtype=np.int64)])


def torus(major: float, minor: float, n_major: int, n_minor: int) -> tuple[np.ndarray, np.ndarray]:
    """A closed genus-1 torus: a grid of ``n_major`` x ``n_minor`` quads, two triangles each."""
    u = 2 * np.pi * np.arange(n_major) / n_major
    w = 2 * np.pi * np.arange(n_minor) / n_minor
    uu, ww = np.meshgrid(u, w, indexing="ij")
    ring = major + minor * np.cos(ww)
    v = np.stack([ring * np.cos(uu), ring * np.sin(uu), minor * np.sin(ww)], -1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(n_major), np.arange(n_minor), indexing="ij")
    p = i * n_minor + j
    q = ((i + 1) % n_major) * n_minor + j
    r = ((i + 1) % n_major) * n_minor + (j + 1) % n_minor
    s = i * n_minor + (j + 1) % n_minor
    f = np.concatenate(
        [np.stack([p, q, r], -1).reshape(-1, 3), np.stack([p, r, s], -1).reshape(-1, 3)]
    )
    return v, f.astype(np.int64)
