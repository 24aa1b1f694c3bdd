r"""Nearest-point queries on a hashed cell grid built once (replaces per-round k-d trees).

A static point set (the data, or the particles of one growth round) is binned once into cubic
cells of side h (only occupied cells are stored, found through an open-addressing hash table of
their keys, as in :mod:`recon.kernels.cell_list`). A query visits the cells in shells of growing
Chebyshev radius R = 0, 1, 2, ... around its own cell c_q; every point outside the block B_R of
visited cells is at least the distance b_R(q) from q to the faces of B_R (≥ R h), so the search
stops as soon as the k-th best distance is within it:

.. math::

    d_{(k)}(q) \le b_R(q) \;\Rightarrow\; \{\,p : |p - q| < d_{(k)}\,\} \subset
    \bigcup_{|c - c_q|_\infty \le R} \mathrm{cell}(c)

(Allen & Tildesley §5.3). The result is the exact k nearest points (ties broken by index);
queries that would need more than ``max_ring`` shells are flagged, and the caller answers them
with a k-d tree. Each query writes only its own row, so the threaded loops give the same
result for any thread count.

:func:`anchor_feet_kernel` fuses the nearest-agreeing search with the foot point on the local
quadric (the anchor refresh of the fit, :meth:`recon.surface.DataSurface.anchors`):

.. math::

    x = (q - c)\cdot u,\quad y = (q - c)\cdot v,\quad
    h = a_0 + a_1 x + a_2 y + a_3 x^2 + a_4 x y + a_5 y^2,\\
    \mathrm{foot} = c + x u + y v + h n,\qquad
    m \propto n - h_x u - h_y v

(the vertical projection onto the height field of [L98] in the frame (c; u, v, n)).

References
----------
.. [AT87] M. P. Allen, D. J. Tildesley. "Computer Simulation of Liquids", §5.3 (cell lists).
.. [L98] D. Levin. "The approximation power of moving least-squares". Math. Comp. 67, 1998.
.. [ST92] R. Szeliski, D. Tonnesen. "Surface Modeling with Oriented Particle Systems".
   SIGGRAPH '92, §4.2 (spatial data structures), §7 (fitting to data).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from .cell_list import block_bound, cell_lookup, cell_table, home_cell, sort_into_cells
from .options import EXACT_JIT_OPTIONS

_PARALLEL = dict(EXACT_JIT_OPTIONS, parallel=True)

#: Shell margin: a point is taken to be at least (R - SHELL_MARGIN) h from a query outside its
#: shell R, which absorbs the rounding of the cell coordinates.
SHELL_MARGIN = 1e-6


@njit(**EXACT_JIT_OPTIONS)
def coordinate_extent(points):  # pragma: no cover - numba
    r"""Extent of the points' bounding box per axis, :math:`e_c = \max_i x_{ic} - \min_i
    x_{ic}` (c = x, y, z), in one pass: the grids' size checks before they are built.

    The same values as ``points.max(axis=0) - points.min(axis=0)``, which reduces a
    (n, 3) array along its long axis 30x slower (35 ms against 1 ms at 669,000 points).
    A NaN in a column makes that column's extent NaN, as numpy's does; an infinity makes it
    infinite or NaN, as there. ``points`` must hold at least one row.
    """
    lo = np.empty(3)
    hi = np.empty(3)
    nan = np.zeros(3, dtype=np.bool_)
    for c in range(3):
        lo[c] = points[0, c]
        hi[c] = points[0, c]
    for i in range(points.shape[0]):
        for c in range(3):
            v = points[i, c]
            if v < lo[c]:
                lo[c] = v
            elif v > hi[c]:
                hi[c] = v
            elif v != v:
                nan[c] = True
    out = hi - lo
    for c in range(3):
        if nan[c]:
            out[c] = np.nan
    return out


@njit(**EXACT_JIT_OPTIONS)
def grid_build(points, cell_size):  # pragma: no cover - numba
    """Bin ``points`` (n, 3) into occupied cells of side ``cell_size``.

    Returns
    -------
    order : (n,) int64
        Point indices sorted by cell key (ascending index within a cell).
    cell_start : (m + 1,) int64
        ``order[cell_start[c]:cell_start[c + 1]]`` are the points of occupied cell c.
    slot_key, slot_cell : (s,) int64
        Open-addressing table (s a power of two ≥ 4 m): cell key -> occupied cell, -1 = empty.
    dims : (3,) int64
        Grid dimensions.
    origin : (3,) float64
        Lower corner of the grid.
    sorted_points : (n, 3) float64
        ``points[order]``: the points of a cell lie together in memory.
    """
    n = points.shape[0]
    lo = np.zeros(3)
    for c in range(3):
        lo[c] = np.inf
    for i in range(n):
        for c in range(3):
            if points[i, c] < lo[c]:
                lo[c] = points[i, c]
    if n == 0:
        lo[:] = 0.0
    coords = np.zeros((n, 3), dtype=np.int64)
    dims = np.ones(3, dtype=np.int64)
    for i in range(n):
        for c in range(3):
            k = np.int64(math.floor((points[i, c] - lo[c]) / cell_size))
            coords[i, c] = k
            if k + 1 > dims[c]:
                dims[c] = k + 1
    order, cell_keys, cell_start, _ = sort_into_cells(coords, dims)
    slot_key, slot_cell = cell_table(cell_keys)
    sorted_points = np.empty((n, 3))
    for p in range(n):
        for c in range(3):
            sorted_points[p, c] = points[order[p], c]
    return order, cell_start, slot_key, slot_cell, dims, lo, sorted_points


@njit(inline="always", **EXACT_JIT_OPTIONS)
def _knn_one(q0, q1, q2, grid, cell_size, k, max_ring, best_d2, best_i):
    """k nearest points of one query into ``best_d2``/``best_i`` (ascending, ties by index).

    Returns the number found (< k only when the set has fewer points) and whether the result
    is exact (False: more than ``max_ring`` shells would be needed).
    """
    order, cell_start, slot_key, slot_cell, dims, lo, points = grid
    for a in range(k):
        best_d2[a] = np.inf
        best_i[a] = -1
    found = 0
    hx, hy, hz = home_cell(q0, q1, q2, dims, lo, cell_size)
    for r in range(max_ring + 1):
        for dx in range(-r, r + 1):
            for dy in range(-r, r + 1):
                edge = dx == -r or dx == r or dy == -r or dy == r
                dz = -r
                while dz <= r:
                    c = cell_lookup(hx + dx, hy + dy, hz + dz, dims, slot_key, slot_cell)
                    if c >= 0:
                        for p in range(cell_start[c], cell_start[c + 1]):
                            ex = points[p, 0] - q0
                            ey = points[p, 1] - q1
                            ez = points[p, 2] - q2
                            d2 = ex * ex + ey * ey + ez * ez
                            j = order[p]
                            if found == k and (
                                d2 > best_d2[k - 1] or (d2 == best_d2[k - 1] and j > best_i[k - 1])
                            ):
                                continue
                            b = found - 1 if found < k else k - 2
                            while b >= 0 and (
                                best_d2[b] > d2 or (best_d2[b] == d2 and best_i[b] > j)
                            ):
                                best_d2[b + 1] = best_d2[b]
                                best_i[b + 1] = best_i[b]
                                b -= 1
                            best_d2[b + 1] = d2
                            best_i[b + 1] = j
                            if found < k:
                                found += 1
                    # inner cells of the shell were visited at smaller radii
                    if edge or r == 0:
                        dz += 1
                    elif dz == -r:
                        dz = r
                    else:
                        dz += 1
        # unvisited points lie beyond the faces of the visited block of cells (faces with no
        # cells beyond them bound nothing); stop once the k-th best is within that distance
        bound = block_bound(q0, q1, q2, hx, hy, hz, r, dims, lo, cell_size)
        if bound == np.inf:
            return found, True
        if found == k:
            bound -= SHELL_MARGIN * cell_size
            if bound > 0.0 and best_d2[k - 1] <= bound * bound:
                return found, True
    return found, False


@njit(**_PARALLEL)
def knn_grid_kernel(
    query, grid, cell_size, k, max_ring, out_d, out_i, out_ok
):  # pragma: no cover - numba
    """The ``k`` nearest grid points of each query: distances ``out_d`` (m, k), indices
    ``out_i`` (m, k; inf and -1 past the number of points), ``out_ok[i]`` False where the row
    needs more than ``max_ring`` shells (answer it another way)."""
    m = query.shape[0]
    for i in prange(m):
        best_d2 = np.empty(k)
        best_i = np.empty(k, dtype=np.int64)
        found, ok = _knn_one(
            query[i, 0],
            query[i, 1],
            query[i, 2],
            grid,
            cell_size,
            k,
            max_ring,
            best_d2,
            best_i,
        )
        out_ok[i] = ok
        for a in range(k):
            out_d[i, a] = math.sqrt(best_d2[a])
            out_i[i, a] = best_i[a]


#: Relative margin of the walk's certificate (absorbs the rounding of the distances).
WALK_MARGIN = 1e-9
#: Hops after which a walk gives up (the grid answers the query).
WALK_MAX_HOPS = 64


@njit(inline="always", **EXACT_JIT_OPTIONS)
def _walk_nearest(q0, q1, q2, start, points, walk_nbr, walk_reach):
    r"""Nearest data point to q by descent on the data's neighbour table, with a certificate.

    From ``start``, move to the best of the current point's table entries (least squared
    distance, ties by index, the order of :func:`_knn_one`) while that improves. At the end
    point j with distance d, every data point p at least as near to q has
    \|p - p_j\| <= 2 d (triangle inequality); if 2 d < ``walk_reach[j]`` (the distance of j's
    last table entry, so every point nearer than it is in the table) p was compared, and j is
    the exact nearest.

    Returns
    -------
    (j, d2, certified) : the end point, its squared distance, and whether it is exact.
    """
    cur = start
    e0 = points[cur, 0] - q0
    e1 = points[cur, 1] - q1
    e2 = points[cur, 2] - q2
    cur_d2 = e0 * e0 + e1 * e1 + e2 * e2
    for _ in range(WALK_MAX_HOPS):
        nxt = cur
        nxt_d2 = cur_d2
        for a in range(walk_nbr.shape[1]):
            j = walk_nbr[cur, a]
            e0 = points[j, 0] - q0
            e1 = points[j, 1] - q1
            e2 = points[j, 2] - q2
            d2 = e0 * e0 + e1 * e1 + e2 * e2
            if d2 < nxt_d2 or (d2 == nxt_d2 and j < nxt):
                nxt = j
                nxt_d2 = d2
        if nxt == cur:
            bound = 2.0 * math.sqrt(cur_d2) * (1.0 + WALK_MARGIN)
            return cur, cur_d2, bound < walk_reach[cur] * (1.0 - WALK_MARGIN)
        cur = nxt
        cur_d2 = nxt_d2
    return cur, cur_d2, False


@njit(**_PARALLEL)
def anchor_feet_kernel(
    query,
    qnormals,
    use_normals,
    normals,
    frames,
    grid,
    cell_size,
    k,
    max_ring,
    out_foot,
    out_nrm,
    out_dist,
    out_idx,
    out_ok,
    hint,
    points,
    walk_nbr,
    walk_reach,
):  # pragma: no cover - numba
    """Nearest agreeing data point and the foot point on its local quadric, per query.

    Among the ``k`` nearest data points (in distance order) the first whose normal agrees with
    ``qnormals[i]`` (dot > 0) is taken, else the nearest (also when ``use_normals`` is False);
    ``frames`` = (plane_points, plane_normals, tangents, quadrics) of the data. Writes the foot
    point and unit normal of the quadric (module docstring), the distance to the chosen data
    point and its index. ``out_ok[i]`` False: the search needed more than ``max_ring`` shells;
    the row is not written.

    The nearest point is searched first (a 1-nearest search ends after fewer cells); only when
    it disagrees are the ``k`` nearest searched, which gives the same choice. Where
    ``hint[i] >= 0`` (a data point near the query, e.g. its previous anchor) the nearest point
    is first found by :func:`_walk_nearest` on the data ``points`` and their neighbour table
    (``walk_nbr`` (n, K) with the distances ``walk_reach`` (n,) of the last entries); the grid
    answers when the walk cannot certify its result, so the answer is the same.
    """
    plane_points, plane_normals, tangents, quadrics = frames
    m = query.shape[0]
    for i in prange(m):
        best_d2 = np.empty(k)
        best_i = np.empty(k, dtype=np.int64)
        certified = False
        if hint[i] >= 0:
            j0, d0, certified = _walk_nearest(
                query[i, 0], query[i, 1], query[i, 2], hint[i], points, walk_nbr, walk_reach
            )
            best_i[0] = j0
            best_d2[0] = d0
        # fast path: the nearest point alone (certified by the walk, or found by the grid,
        # whose shells end sooner for one) when it agrees; else the k nearest. One search
        # call site, entered at most twice: numba copies an inlined function's IR per site.
        found = 1
        ok = True
        fast = False
        for attempt in range(2):
            if attempt == 1 or not certified:
                found, ok = _knn_one(
                    query[i, 0],
                    query[i, 1],
                    query[i, 2],
                    grid,
                    cell_size,
                    1 if attempt == 0 else k,
                    max_ring,
                    best_d2,
                    best_i,
                )
            if attempt == 1:
                break
            if ok and found == 1:
                j = best_i[0]
                agrees = (
                    normals[j, 0] * qnormals[i, 0]
                    + normals[j, 1] * qnormals[i, 1]
                    + normals[j, 2] * qnormals[i, 2]
                ) > 0.0
                fast = agrees or not use_normals
            if fast:
                break
        out_ok[i] = ok
        if not ok or found == 0:
            out_ok[i] = False
            continue
        pick = 0
        if use_normals and not fast:
            for a in range(found):
                j = best_i[a]
                dot = (
                    normals[j, 0] * qnormals[i, 0]
                    + normals[j, 1] * qnormals[i, 1]
                    + normals[j, 2] * qnormals[i, 2]
                )
                if dot > 0.0:
                    pick = a
                    break
        j = best_i[pick]
        out_idx[i] = j
        out_dist[i] = math.sqrt(best_d2[pick])
        n0 = plane_normals[j, 0]
        n1 = plane_normals[j, 1]
        n2 = plane_normals[j, 2]
        u0 = tangents[j, 0]
        u1 = tangents[j, 1]
        u2 = tangents[j, 2]
        # v = n x u
        v0 = n1 * u2 - n2 * u1
        v1 = n2 * u0 - n0 * u2
        v2 = n0 * u1 - n1 * u0
        d0 = query[i, 0] - plane_points[j, 0]
        d1 = query[i, 1] - plane_points[j, 1]
        d2 = query[i, 2] - plane_points[j, 2]
        x = d0 * u0 + d1 * u1 + d2 * u2
        y = d0 * v0 + d1 * v1 + d2 * v2
        a = quadrics[j]
        h = a[0] + a[1] * x + a[2] * y + a[3] * x * x + a[4] * x * y + a[5] * y * y
        hx = a[1] + 2 * a[3] * x + a[4] * y
        hy = a[2] + a[4] * x + 2 * a[5] * y
        out_foot[i, 0] = plane_points[j, 0] + x * u0 + y * v0 + h * n0
        out_foot[i, 1] = plane_points[j, 1] + x * u1 + y * v1 + h * n1
        out_foot[i, 2] = plane_points[j, 2] + x * u2 + y * v2 + h * n2
        m0 = n0 - hx * u0 - hy * v0
        m1 = n1 - hx * u1 - hy * v1
        m2 = n2 - hx * u2 - hy * v2
        norm = math.sqrt(m0 * m0 + m1 * m1 + m2 * m2)
        out_nrm[i, 0] = m0 / norm
        out_nrm[i, 1] = m1 / norm
        out_nrm[i, 2] = m2 / norm


@njit(**_PARALLEL)
def covered_kernel(query, grid, cell_size, radius, out):  # pragma: no cover - numba
    """``out[i]`` = some point lies within ``radius`` of ``query[i]`` (the grid's side
    ``cell_size`` must be ≥ ``radius``: the 27 cells around the query's cell hold every such
    point)."""
    order, cell_start, slot_key, slot_cell, dims, lo, points = grid
    r2 = radius * radius
    m = query.shape[0]
    for i in prange(m):
        q0 = query[i, 0]
        q1 = query[i, 1]
        q2 = query[i, 2]
        x = np.int64(math.floor((q0 - lo[0]) / cell_size))
        y = np.int64(math.floor((q1 - lo[1]) / cell_size))
        z = np.int64(math.floor((q2 - lo[2]) / cell_size))
        hit = False
        for dx in range(-1, 2):
            for dy in range(-1, 2):
                for dz in range(-1, 2):
                    if hit:
                        break
                    c = cell_lookup(x + dx, y + dy, z + dz, dims, slot_key, slot_cell)
                    if c < 0:
                        continue
                    for p in range(cell_start[c], cell_start[c + 1]):
                        ex = points[p, 0] - q0
                        ey = points[p, 1] - q1
                        ez = points[p, 2] - q2
                        if ex * ex + ey * ey + ez * ez <= r2:
                            hit = True
                            break
        out[i] = hit
