"""Small analytic meshes for the metrics, topology, render and compare/report tests.

Every builder returns ``(vertices (V, 3) float64, faces (F, 3) int64)`` with outward (or +z)
facing, consistently wound triangles unless its docstring says otherwise.
"""

from __future__ import annotations

import numpy as np


def tetrahedron() -> tuple[np.ndarray, np.ndarray]:
    """Corner tetrahedron, outward winding: V=4, E=6, F=4, chi=2."""
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=np.float64)
    f = np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]], dtype=np.int64)
    return v, f


def icosphere(subdivisions: int = 3, radius: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Icosahedron split ``subdivisions`` times, vertices projected on the sphere."""
    t = (1.0 + 5**0.5) / 2.0
    v = np.array(
        [[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t],
         [0, -1, -t], [0, 1, -t], [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]],
        dtype=np.float64,
    )  # fmt: skip
    f = np.array(
        [[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4],
         [11, 10, 2], [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8],
         [3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]],
        dtype=np.int64,
    )  # fmt: skip
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    for _ in range(subdivisions):
        edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
        uniq, inv = np.unique(edges, axis=0, return_inverse=True)
        mid = v[uniq].mean(axis=1)
        mid /= np.linalg.norm(mid, axis=1, keepdims=True)
        m = inv.reshape(3, -1).T + len(v)  # midpoints of edges 01, 12, 20 per face
        v = np.concatenate([v, mid])
        a, b, c = f.T
        ab, bc, ca = m.T
        f = np.concatenate(
            [np.stack(x, axis=1) for x in ((a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca))]
        )
    return v * radius, f


def grid(nx: int = 10, ny: int = 10, size: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Flat square ``[0, size]^2`` in z = 0 split into ``2 nx ny`` triangles facing +z."""
    x, y = np.meshgrid(np.linspace(0, size, nx + 1), np.linspace(0, size, ny + 1), indexing="ij")
    v = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)
    idx = np.arange((nx + 1) * (ny + 1)).reshape(nx + 1, ny + 1)
    a, b = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel()
    c, d = idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    f = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return v, f


def _periodic_grid(n_u: int, n_v: int, wrap_v: bool) -> np.ndarray:
    """Faces of an ``n_u`` (periodic) by ``n_v`` grid, periodic in v too when ``wrap_v``."""
    rows = n_v if wrap_v else n_v - 1
    i, j = np.meshgrid(np.arange(n_u), np.arange(rows), indexing="ij")
    i, j = i.ravel(), j.ravel()
    i1, j1 = (i + 1) % n_u, (j + 1) % n_v
    a, b, c, d = i * n_v + j, i1 * n_v + j, i1 * n_v + j1, i * n_v + j1
    return np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)]).astype(np.int64)


def torus(
    n_major: int = 32, n_minor: int = 12, major: float = 1.0, minor: float = 0.35
) -> tuple[np.ndarray, np.ndarray]:
    """Torus grid around the z axis (genus 1, chi 0)."""
    u, w = np.meshgrid(
        np.linspace(0, 2 * np.pi, n_major, endpoint=False),
        np.linspace(0, 2 * np.pi, n_minor, endpoint=False),
        indexing="ij",
    )
    r = major + minor * np.cos(w)
    v = np.stack([r * np.cos(u), r * np.sin(u), minor * np.sin(w)], axis=-1).reshape(-1, 3)
    return v, _periodic_grid(n_major, n_minor, wrap_v=True)


def open_cylinder(n_around: int = 24, n_height: int = 5) -> tuple[np.ndarray, np.ndarray]:
    """Unit-radius tube of height 1 without caps: 2 boundary loops, chi 0."""
    u, h = np.meshgrid(
        np.linspace(0, 2 * np.pi, n_around, endpoint=False),
        np.linspace(0, 1, n_height),
        indexing="ij",
    )
    v = np.stack([np.cos(u), np.sin(u), h], axis=-1).reshape(-1, 3)
    return v, _periodic_grid(n_around, n_height, wrap_v=False)


def mobius(n: int = 24, width: float = 0.3) -> tuple[np.ndarray, np.ndarray]:
    """Moebius strip: one boundary loop, not orientable."""
    u = np.linspace(0, 2 * np.pi, n, endpoint=False)
    s = np.array([-width, width])
    uu, ss = np.meshgrid(u, s, indexing="ij")
    r = 1 + ss * np.cos(uu / 2)
    v = np.stack([r * np.cos(uu), r * np.sin(uu), ss * np.sin(uu / 2)], -1).reshape(-1, 3)
    f = []
    for i in range(n):
        a, b = 2 * i, 2 * i + 1
        if i < n - 1:
            c, d = 2 * i + 2, 2 * i + 3
        else:  # the half twist: the strip closes with its two edges swapped
            c, d = 1, 0
        f += [[a, c, d], [a, d, b]]
    return v, np.array(f, dtype=np.int64)


def wedge_points(turn_deg: float, n: int = 4000, seed: int = 0) -> np.ndarray:
    """Points on two unit squares sharing the edge along y (x = 0, |y| <= 1/2): face A in
    z = 0 at x < 0, face B turned up by ``turn_deg`` about the y axis (``n`` on each)."""
    rng = np.random.default_rng(seed)
    a = np.radians(turn_deg)
    u = rng.uniform(0.0, 1.0, (n, 2)) - [0.0, 0.5]
    v = rng.uniform(0.0, 1.0, (n, 2)) - [0.0, 0.5]
    face_a = np.c_[-u[:, 0], u[:, 1], np.zeros(n)]
    face_b = np.c_[v[:, 0] * np.cos(a), v[:, 1], v[:, 0] * np.sin(a)]
    return np.r_[face_a, face_b]


def thin_wedge(angle_deg: float = 30.0, length: float = 1.0, height: float = 0.5):
    """A closed prism over a right triangle with a knife edge of ``angle_deg`` (legs
    ``length`` along x and ``length * tan(angle)`` along y, height along z), faces outward:
    bench_machined's ``wedge`` without its subdivided caps."""
    w = length * np.tan(np.radians(angle_deg))
    base = np.array([[0.0, 0.0], [length, 0.0], [0.0, w]])
    v = np.r_[np.c_[base, np.zeros(3)], np.c_[base, np.full(3, height)]]
    f = [[0, 2, 1], [3, 4, 5], [0, 1, 4], [0, 4, 3], [1, 2, 5], [1, 5, 4], [2, 0, 3], [2, 3, 5]]
    return v, np.array(f, dtype=np.int64)


def sphere_with_tunnel(radius: float = 6.0, gap: float = 3.0) -> tuple[np.ndarray, np.ndarray]:
    """:func:`icosphere` (edges ~0.9) with a tunnel: two faces about ``gap`` edges apart
    replaced by a three-sided tube between their corners (one handle, orientable, every edge
    in two faces). The tube's two cycles are about 2 x ``gap`` edges long."""
    v, f = icosphere(3, radius)
    centre = v[f].mean(axis=1)
    a = int(np.argmax(centre[:, 0]))
    edge = float(np.linalg.norm(v[f[a, 0]] - v[f[a, 1]]))
    d = np.linalg.norm(centre - centre[a], axis=1)
    far = np.flatnonzero(~np.isin(f, f[a]).any(axis=1) & (d > gap * edge))
    b = int(far[np.argmin(d[far])])
    keep = np.ones(len(f), dtype=bool)
    keep[[a, b]] = False
    tube = []
    for i in range(3):  # quad i joins a_i -> a_(i+1) to b_(-i) -> b_(1-i): orientable
        a0, a1 = f[a, i], f[a, (i + 1) % 3]
        bx, by = f[b, (-i) % 3], f[b, (1 - i) % 3]
        tube += [[a0, a1, bx], [a0, bx, by]]
    return v, np.vstack([f[keep], np.array(tube, dtype=np.int64)])


def flat_ellipsoid(n: int, axes, seed: int, noise: float) -> tuple[np.ndarray, np.ndarray]:
    """Area-uniform samples of an ellipsoid (with noise) and its outward normals."""
    rng = np.random.default_rng(seed)
    axes = np.asarray(axes, dtype=float)
    u = rng.normal(size=(20 * n, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    # the map u -> axes * u scales the area element by prod(axes) * |u / axes|
    scale = np.linalg.norm(u / axes, axis=1)
    u = u[rng.uniform(size=len(u)) < scale / scale.max()][:n]
    gt = u / axes
    gt /= np.linalg.norm(gt, axis=1, keepdims=True)
    return u * axes + rng.normal(scale=noise, size=u.shape), gt
