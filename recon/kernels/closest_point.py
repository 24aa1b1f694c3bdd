r"""Exact closest points on a triangle mesh through a hashed cell grid over its triangles.

Every triangle is registered in each cubic cell of side h that its bounding box overlaps and
its plane passes through (only occupied cells are stored, found through the open-addressing
hash table of :mod:`recon.kernels.cell_list`). A query visits the cells in shells of growing
Chebyshev radius R = 0, 1, 2, ... around its own cell, skipping any cell whose box lies
farther than the best distance found so far, and stops once that distance is within the
distance b_R(q) from q to the faces of the visited block B_R: a triangle registered in no
cell of B_R does not meet B_R, so

.. math::

    d(q, T) \ge b_R(q) \quad \text{for every triangle } T \text{ not registered in } B_R,

and the result is the exact closest point over all triangles (ties: the lower face index).
The closest point on one triangle is the Voronoi-region case analysis of [E05] §5.1.5, in
float64. Queries that would need more than ``max_ring`` shells are flagged for the caller to
answer another way. Each query writes only its own row, so the threaded loop gives the same
result for any thread count.

References
----------
.. [E05] C. Ericson. "Real-Time Collision Detection". Morgan Kaufmann 2005, §5.1.5 (closest
   point on a triangle), §5.2.3 (plane-box overlap), §7.1 (uniform grids).
.. [AT87] M. P. Allen, D. J. Tildesley. "Computer Simulation of Liquids", §5.3 (cell lists).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from .cell_list import block_bound, cell_lookup, cell_table, home_cell, sort_into_cells
from .options import EXACT_JIT_OPTIONS

_PARALLEL = dict(EXACT_JIT_OPTIONS, parallel=True)

#: Shell margin (fraction of a cell): absorbs the rounding of the cell coordinates in the bound.
SHELL_MARGIN = 1e-9


@njit(inline="always", **EXACT_JIT_OPTIONS)
def _plane_meets_box(n0, n1, n2, d, c0, c1, c2, half):
    """Does the plane n . x = d meet the cube of centre c and half side ``half``? ([E05] §5.2.3)"""
    r = half * (abs(n0) + abs(n1) + abs(n2))
    s = n0 * c0 + n1 * c1 + n2 * c2 - d
    return abs(s) <= r * (1.0 + 1e-9) + 1e-12 * half


@njit(**EXACT_JIT_OPTIONS)
def _cells_of(vertices, faces, cell_size, lo, count_only, out_coords, out_tri):  # pragma: no cover
    """Register every triangle in the cells its bounding box overlaps and its plane meets.

    With ``count_only`` returns the number of registrations; else writes them to
    ``out_coords`` (k, 3) and ``out_tri`` (k,) and returns k."""
    k = 0
    half = 0.5 * cell_size
    for t in range(faces.shape[0]):
        a = vertices[faces[t, 0]]
        b = vertices[faces[t, 1]]
        c = vertices[faces[t, 2]]
        e1 = b - a
        e2 = c - a
        n0 = e1[1] * e2[2] - e1[2] * e2[1]
        n1 = e1[2] * e2[0] - e1[0] * e2[2]
        n2 = e1[0] * e2[1] - e1[1] * e2[0]
        nn = math.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
        flat = nn > 0.0
        if flat:
            n0 /= nn
            n1 /= nn
            n2 /= nn
        d = n0 * a[0] + n1 * a[1] + n2 * a[2]
        lo_c = np.empty(3, dtype=np.int64)
        hi_c = np.empty(3, dtype=np.int64)
        for ax in range(3):
            mn = min(a[ax], b[ax], c[ax])
            mx = max(a[ax], b[ax], c[ax])
            lo_c[ax] = np.int64(math.floor((mn - lo[ax]) / cell_size))
            hi_c[ax] = np.int64(math.floor((mx - lo[ax]) / cell_size))
        for x in range(lo_c[0], hi_c[0] + 1):
            for y in range(lo_c[1], hi_c[1] + 1):
                for z in range(lo_c[2], hi_c[2] + 1):
                    if flat:
                        cx = lo[0] + (x + 0.5) * cell_size
                        cy = lo[1] + (y + 0.5) * cell_size
                        cz = lo[2] + (z + 0.5) * cell_size
                        if not _plane_meets_box(n0, n1, n2, d, cx, cy, cz, half):
                            continue
                    if not count_only:
                        out_coords[k, 0] = x
                        out_coords[k, 1] = y
                        out_coords[k, 2] = z
                        out_tri[k] = t
                    k += 1
    return k


@njit(**EXACT_JIT_OPTIONS)
def registrations(vertices, faces, cell_size):  # pragma: no cover - numba
    """How many (cell, triangle) entries a grid of side ``cell_size`` would hold."""
    lo = np.empty(3)
    for ax in range(3):
        lo[ax] = vertices[:, ax].min()
    dummy_c = np.zeros((0, 3), dtype=np.int64)
    dummy_t = np.zeros(0, dtype=np.int64)
    return _cells_of(vertices, faces, cell_size, lo, True, dummy_c, dummy_t)


@njit(**EXACT_JIT_OPTIONS)
def triangle_grid_build(vertices, faces, cell_size):  # pragma: no cover - numba
    """Bin the triangles into occupied cells of side ``cell_size`` (module docstring).

    Returns
    -------
    tri : (k,) int64
        Triangle of every entry, grouped by cell.
    corners : (k, 9) float64
        The entry's triangle's corners, in entry order (no indirection in the query loop).
    spheres : (k, 4) float64
        Centre and radius of a sphere around the entry's triangle (a quick lower bound).
    cell_start : (m + 1,) int64
        ``tri[cell_start[c]:cell_start[c + 1]]`` are the triangles of occupied cell c.
    slot_key, slot_cell : (s,) int64
        Open-addressing table (s a power of two ≥ 4 m): cell key -> occupied cell, -1 = empty.
    dims : (3,) int64
        Grid dimensions.
    origin : (3,) float64
        Lower corner of the grid.
    """
    lo = np.empty(3)
    hi = np.empty(3)
    for ax in range(3):
        lo[ax] = vertices[:, ax].min()
        hi[ax] = vertices[:, ax].max()
    dims = np.empty(3, dtype=np.int64)
    for ax in range(3):
        dims[ax] = np.int64(math.floor((hi[ax] - lo[ax]) / cell_size)) + 1
    dummy_c = np.zeros((0, 3), dtype=np.int64)
    dummy_t = np.zeros(0, dtype=np.int64)
    k = _cells_of(vertices, faces, cell_size, lo, True, dummy_c, dummy_t)
    coords = np.empty((k, 3), dtype=np.int64)
    tri_of = np.empty(k, dtype=np.int64)
    _cells_of(vertices, faces, cell_size, lo, False, coords, tri_of)
    order, cell_keys, cell_start, _ = sort_into_cells(coords, dims)
    tri = tri_of[order]
    corners = np.empty((k, 9))
    spheres = np.empty((k, 4))
    for e in range(k):
        t = tri[e]
        for j in range(3):
            for ax in range(3):
                corners[e, 3 * j + ax] = vertices[faces[t, j], ax]
        r2 = 0.0
        for ax in range(3):
            spheres[e, ax] = (corners[e, ax] + corners[e, 3 + ax] + corners[e, 6 + ax]) / 3.0
        for j in range(3):
            d2 = 0.0
            for ax in range(3):
                d2 += (corners[e, 3 * j + ax] - spheres[e, ax]) ** 2
            r2 = max(r2, d2)
        spheres[e, 3] = math.sqrt(r2) * (1.0 + 1e-12)
    slot_key, slot_cell = cell_table(cell_keys)
    return tri, corners, spheres, cell_start, slot_key, slot_cell, dims, lo


@njit(inline="always", **EXACT_JIT_OPTIONS)
def closest_on_triangle(p0, p1, p2, a, b, c):  # pragma: no cover - numba
    """Closest point to p on triangle (a, b, c) ([E05] §5.1.5), as three floats; a, b, c are
    3-sequences (array rows)."""
    ab0, ab1, ab2 = b[0] - a[0], b[1] - a[1], b[2] - a[2]
    ac0, ac1, ac2 = c[0] - a[0], c[1] - a[1], c[2] - a[2]
    ap0, ap1, ap2 = p0 - a[0], p1 - a[1], p2 - a[2]
    d1 = ab0 * ap0 + ab1 * ap1 + ab2 * ap2
    d2 = ac0 * ap0 + ac1 * ap1 + ac2 * ap2
    if d1 <= 0.0 and d2 <= 0.0:
        return a[0], a[1], a[2]
    bp0, bp1, bp2 = p0 - b[0], p1 - b[1], p2 - b[2]
    d3 = ab0 * bp0 + ab1 * bp1 + ab2 * bp2
    d4 = ac0 * bp0 + ac1 * bp1 + ac2 * bp2
    if d3 >= 0.0 and d4 <= d3:
        return b[0], b[1], b[2]
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        v = d1 / (d1 - d3)
        return a[0] + v * ab0, a[1] + v * ab1, a[2] + v * ab2
    cp0, cp1, cp2 = p0 - c[0], p1 - c[1], p2 - c[2]
    d5 = ab0 * cp0 + ab1 * cp1 + ab2 * cp2
    d6 = ac0 * cp0 + ac1 * cp1 + ac2 * cp2
    if d6 >= 0.0 and d5 <= d6:
        return c[0], c[1], c[2]
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        w = d2 / (d2 - d6)
        return a[0] + w * ac0, a[1] + w * ac1, a[2] + w * ac2
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
        w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        return b[0] + w * (c[0] - b[0]), b[1] + w * (c[1] - b[1]), b[2] + w * (c[2] - b[2])
    denom = va + vb + vc
    if denom == 0.0:  # degenerate triangle: its vertices bound it
        return a[0], a[1], a[2]
    v = vb / denom
    w = vc / denom
    return (
        a[0] + ab0 * v + ac0 * w,
        a[1] + ab1 * v + ac1 * w,
        a[2] + ab2 * v + ac2 * w,
    )


@njit(**_PARALLEL)
def closest_points_kernel(
    query, grid, cell_size, max_ring, out_foot, out_face, out_ok
):  # pragma: no cover - numba
    """Exact closest point on the mesh of every query (module docstring): the foot
    ``out_foot`` (m, 3), its face ``out_face`` (m,), ``out_ok[i]`` False where the search
    would need more than ``max_ring`` shells (the row is then not written)."""
    tri, corners, spheres, cell_start, slot_key, slot_cell, dims, lo = grid
    m = query.shape[0]
    for i in prange(m):
        q0, q1, q2 = query[i, 0], query[i, 1], query[i, 2]
        hx, hy, hz = home_cell(q0, q1, q2, dims, lo, cell_size)
        best = np.inf
        bf = -1
        f0 = 0.0
        f1 = 0.0
        f2 = 0.0
        ok = False
        for r in range(max_ring + 1):
            for dx in range(-r, r + 1):
                for dy in range(-r, r + 1):
                    shell = dx == -r or dx == r or dy == -r or dy == r
                    dz = -r
                    while dz <= r:
                        x, y, z = hx + dx, hy + dy, hz + dz
                        # squared distance from q to the cell's box
                        g = 0.0
                        for ax in range(3):
                            qa = q0 if ax == 0 else (q1 if ax == 1 else q2)
                            ca = x if ax == 0 else (y if ax == 1 else z)
                            b0 = lo[ax] + ca * cell_size
                            if qa < b0:
                                g += (b0 - qa) * (b0 - qa)
                            elif qa > b0 + cell_size:
                                g += (qa - b0 - cell_size) * (qa - b0 - cell_size)
                        if g <= best:
                            cc = cell_lookup(x, y, z, dims, slot_key, slot_cell)
                            if cc >= 0:
                                for e in range(cell_start[cc], cell_start[cc + 1]):
                                    t = tri[e]
                                    s0 = spheres[e, 0] - q0
                                    s1 = spheres[e, 1] - q1
                                    s2 = spheres[e, 2] - q2
                                    lb = math.sqrt(s0 * s0 + s1 * s1 + s2 * s2) - spheres[e, 3]
                                    if lb > 0.0 and lb * lb > best:
                                        continue
                                    row = corners[e]
                                    p0, p1, p2 = closest_on_triangle(
                                        q0, q1, q2, row[0:3], row[3:6], row[6:9]
                                    )
                                    d2 = (p0 - q0) ** 2 + (p1 - q1) ** 2 + (p2 - q2) ** 2
                                    if d2 < best or (d2 == best and t < bf):
                                        best = d2
                                        bf = t
                                        f0, f1, f2 = p0, p1, p2
                        # inner cells of the shell were visited at smaller radii
                        if shell or r == 0:
                            dz += 1
                        elif dz == -r:
                            dz = r
                        else:
                            dz += 1
            # unvisited triangles lie beyond the faces of the visited block (faces with no
            # cells beyond them bound nothing)
            bound = block_bound(q0, q1, q2, hx, hy, hz, r, dims, lo, cell_size)
            if bound == np.inf:
                ok = bf >= 0
                break
            bound -= SHELL_MARGIN * cell_size
            if bf >= 0 and bound > 0.0 and best <= bound * bound:
                ok = True
                break
        out_ok[i] = ok
        if ok:
            out_foot[i, 0] = f0
            out_foot[i, 1] = f1
            out_foot[i, 2] = f2
            out_face[i] = bf
