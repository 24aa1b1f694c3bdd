"""Greedy Poisson-disk thinning on a uniform or hashed grid.

Points are visited in a given order; a point is kept unless an already kept point lies closer
than the radius. Kept points are binned into cells of side r, so only the 27 surrounding cells
are searched. A grid whose dense cell count would exceed ~4 n is replaced by a hash table of
linked lists (an outlier far from the rest must not allocate a huge grid); hash collisions only
add candidates that the distance test then rejects.

References
----------
.. [B07] R. Bridson. "Fast Poisson disk sampling in arbitrary dimensions". SIGGRAPH sketches
   2007 (a background grid so each test looks at a bounded number of cells).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .options import EXACT_JIT_OPTIONS


@njit(**EXACT_JIT_OPTIONS)
def poisson_disk_kernel(points, order, radius, keep_first):  # pragma: no cover - numba
    """Greedy Poisson-disk selection in visiting order [B07] (see the module docstring).

    Parameters
    ----------
    points : (n, 3) float64
    order : (n,) int64
        Visiting order (a permutation); earlier points win.
    radius : float64
        Minimum distance between kept points [length], > 0.
    keep_first : int
        The first ``keep_first`` points of ``order`` are kept unconditionally.

    Returns
    -------
    keep : (n,) bool
    """
    n = points.shape[0]
    keep = np.zeros(n, dtype=np.bool_)
    if n == 0:
        return keep
    lo = points[0].copy()
    hi = points[0].copy()
    for i in range(n):
        for d in range(3):
            lo[d] = min(lo[d], points[i, d])
            hi[d] = max(hi[d], points[i, d])
    cell = radius
    # cell counts in floating point first: a far outlier must not overflow int64 (the product
    # of three large dims wraps around, which would index the dense grid out of bounds)
    max_dim = 2.0**40
    dims = np.empty(3, dtype=np.int64)
    n_cells_f = 1.0
    for d in range(3):
        dim_f = min(np.floor((hi[d] - lo[d]) / cell) + 1.0, max_dim)
        dims[d] = int(dim_f)
        n_cells_f *= dim_f
    # hash grid: each cell keeps a linked list of accepted points
    use_hash = n_cells_f > 4 * n + 1024
    n_cells = dims[0] * dims[1] * dims[2] if not use_hash else 0
    table_size = 1
    while table_size < 2 * n:
        table_size *= 2
    if use_hash:
        head = np.full(table_size, -1, dtype=np.int64)
    else:
        head = np.full(n_cells, -1, dtype=np.int64)
    nxt = np.full(n, -1, dtype=np.int64)
    r2 = radius * radius
    for a in range(n):
        i = order[a]
        cx = int(min((points[i, 0] - lo[0]) / cell, max_dim - 1.0))
        cy = int(min((points[i, 1] - lo[1]) / cell, max_dim - 1.0))
        cz = int(min((points[i, 2] - lo[2]) / cell, max_dim - 1.0))
        ok = True
        if not (keep_first > 0 and a < keep_first):
            for dx in range(-1, 2):
                x = cx + dx
                if x < 0 or x >= dims[0] or not ok:
                    continue
                for dy in range(-1, 2):
                    y = cy + dy
                    if y < 0 or y >= dims[1] or not ok:
                        continue
                    for dz in range(-1, 2):
                        z = cz + dz
                        if z < 0 or z >= dims[2]:
                            continue
                        key = (x * dims[1] + y) * dims[2] + z
                        if use_hash:
                            key = (key * 2654435761) & (table_size - 1)  # >= 0 even on wrap-around
                        j = head[key]
                        while j >= 0:
                            if (points[j, 0] - points[i, 0]) ** 2 + (
                                points[j, 1] - points[i, 1]
                            ) ** 2 + (points[j, 2] - points[i, 2]) ** 2 < r2:
                                # hash collisions only add false candidates; the distance
                                # test above settles them
                                ok = False
                                break
                            j = nxt[j]
                        if not ok:
                            break
        if ok:
            keep[i] = True
            key = (cx * dims[1] + cy) * dims[2] + cz
            if use_hash:
                key = (key * 2654435761) & (table_size - 1)  # >= 0 even on wrap-around
            nxt[i] = head[key]
            head[key] = i
    return keep


@njit(**EXACT_JIT_OPTIONS)
def poisson_disk_graded_kernel(points, order, radius, keep_first):  # pragma: no cover - numba
    """Greedy Poisson-disk selection with a radius per point [B07]: point i is kept unless a
    kept point j lies closer than (r_i + r_j) / 2, so the kept density follows 1 / r².

    Kept points are binned into cells of side max(r) (every conflicting pair lies in
    neighbouring cells), on a hashed grid as in :func:`poisson_disk_kernel`.

    Parameters
    ----------
    points : (n, 3) float64
    order : (n,) int64
        Visiting order (a permutation); earlier points win.
    radius : (n,) float64
        Radius per point [length], > 0.
    keep_first : int
        The first ``keep_first`` points of ``order`` are kept unconditionally.

    Returns
    -------
    keep : (n,) bool
    """
    n = points.shape[0]
    keep = np.zeros(n, dtype=np.bool_)
    if n == 0:
        return keep
    lo = points[0].copy()
    cell = radius[0]
    for i in range(n):
        cell = max(cell, radius[i])
        for d in range(3):
            lo[d] = min(lo[d], points[i, d])
    table_size = 1
    while table_size < 2 * n:
        table_size *= 2
    head = np.full(table_size, -1, dtype=np.int64)
    nxt = np.full(n, -1, dtype=np.int64)
    for a in range(n):
        i = order[a]
        cx = int((points[i, 0] - lo[0]) / cell)
        cy = int((points[i, 1] - lo[1]) / cell)
        cz = int((points[i, 2] - lo[2]) / cell)
        ok = True
        if not (keep_first > 0 and a < keep_first):
            for dx in range(-1, 2):
                if not ok:
                    break
                for dy in range(-1, 2):
                    if not ok:
                        break
                    for dz in range(-1, 2):
                        key = (((cx + dx) * 73856093) ^ ((cy + dy) * 19349663)) ^ (
                            (cz + dz) * 83492791
                        )
                        j = head[key & (table_size - 1)]
                        while j >= 0:
                            r = 0.5 * (radius[i] + radius[j])
                            if (points[j, 0] - points[i, 0]) ** 2 + (
                                points[j, 1] - points[i, 1]
                            ) ** 2 + (points[j, 2] - points[i, 2]) ** 2 < r * r:
                                ok = False
                                break
                            j = nxt[j]
                        if not ok:
                            break
        if ok:
            keep[i] = True
            key = ((cx * 73856093) ^ (cy * 19349663)) ^ (cz * 83492791)
            key = key & (table_size - 1)
            nxt[i] = head[key]
            head[key] = i
    return keep
