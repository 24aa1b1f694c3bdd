"""Seed particles: Poisson-disk thinning of the data, pinned in position and frame.

S&T92 §7 starts a reconstruction from particles placed at the sample locations with their
position and orientation fixed; growth then fills between them. Dense inputs are thinned first so
that seeds sit about one rest spacing apart (otherwise the pinned seeds fight the spacing
potential). Every input point still counts for coverage and fidelity.

References
----------
[ST92] Szeliski & Tonnesen 1992, §7.
[B07]  R. Bridson. "Fast Poisson disk sampling in arbitrary dimensions". SIGGRAPH sketches 2007
       (the grid with cell size r / sqrt(3) so each cell holds at most one sample).
"""

from __future__ import annotations

import numba as nb
import numpy as np


@nb.njit(cache=True)
def _poisson_disk_kernel(points, order, radius, keep_first):  # pragma: no cover - numba
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


def poisson_disk_thin(
    points: np.ndarray, radius: float, order: np.ndarray | None = None, keep_first: int = 0
) -> np.ndarray:
    """Greedy Poisson-disk selection: keep a point unless a kept point lies within ``radius``.

    Parameters
    ----------
    points : (n, 3) float64 [length]
    radius : float [length]
    order : (n,) int, optional
        Visiting order (a permutation). Earlier points win. Default: index order.
    keep_first : int
        The first ``keep_first`` points of ``order`` are kept unconditionally (used to accept new
        candidates against existing particles placed first in the order).

    Returns
    -------
    keep : (n,) bool
        Kept points are pairwise at least ``radius`` apart (except among the forced ones).
    """
    points = np.ascontiguousarray(points, dtype=np.float64)
    if order is None:
        order = np.arange(len(points), dtype=np.int64)
    if radius <= 0:
        raise ValueError(f"radius must be > 0, got {radius}")
    return _poisson_disk_kernel(
        points, np.ascontiguousarray(order, dtype=np.int64), float(radius), int(keep_first)
    )


def select_seeds(points: np.ndarray, spacing: float, rng: np.random.Generator) -> np.ndarray:
    """Indices of seed points: a Poisson-disk subset of ``points`` at ``spacing``.

    The visiting order is a permutation drawn from ``rng``, so a fixed seed gives fixed seeds.
    """
    order = rng.permutation(len(points))
    keep = poisson_disk_thin(points, spacing, order)
    return np.flatnonzero(keep)
