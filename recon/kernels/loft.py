"""The strip of least diagonal length between two closed polylines (contour stitching).

References
----------
.. [F77] H. Fuchs, Z. M. Kedem, S. P. Uselton. "Optimal surface reconstruction from planar
   contours". Communications of the ACM 20(10), 1977 (the strip as a shortest path through
   the grid of vertex pairs).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .options import EXACT_JIT_OPTIONS


@njit(**EXACT_JIT_OPTIONS)
def loft_path_kernel(pa, pb, steps):  # pragma: no cover - numba
    """Cheapest strip between open polylines ``pa`` (m points) and ``pb`` (n points).

    Grid node (i, j) is the edge between ``pa[i]`` and ``pb[j]``; a step from (i, j) to
    (i + 1, j) adds the triangle (a_i, a_i+1, b_j) and costs ``|a_i+1 - b_j|``, one to
    (i, j + 1) the triangle (a_i, b_j+1, b_j) at ``|a_i - b_j+1|`` (F77's shortest path, with
    the new edge's length as the cost). Writes ``steps[k]`` = 0 (advance a) or 1 (advance b)
    for the m + n - 2 steps from (0, 0) to (m - 1, n - 1) and returns the total cost.

    The costs are kept for two rows of the grid only (the step into a node comes from the
    row above or the node before it); the grid of moves, one byte a node, is what the walk
    back needs: m x n bytes (9 m n with the whole cost grid: 3.6 GB for two rims of 20,000).
    """
    m, n = pa.shape[0], pb.shape[0]
    above = np.full(n, np.inf)
    cost = np.full(n, np.inf)
    came = np.zeros((m, n), dtype=np.int8)
    for i in range(m):
        for j in range(n):
            # |a_i - b_j|, summed in the order of ((a - b) ** 2).sum(): the same bits
            dx = pa[i, 0] - pb[j, 0]
            dy = pa[i, 1] - pb[j, 1]
            dz = pa[i, 2] - pb[j, 2]
            d = np.sqrt(dx * dx + dy * dy + dz * dz)
            best = d if i == 0 and j == 0 else np.inf
            if i > 0:
                c = above[j] + d
                if c < best:
                    best = c
                    came[i, j] = 0
            if j > 0:
                c = cost[j - 1] + d
                if c < best:
                    best = c
                    came[i, j] = 1
            cost[j] = best
        above, cost = cost, above
    total = above[n - 1]  # the last row, swapped up
    i, j = m - 1, n - 1
    for k in range(m + n - 3, -1, -1):
        steps[k] = came[i, j]
        if came[i, j] == 0:
            i -= 1
        else:
            j -= 1
    return total
