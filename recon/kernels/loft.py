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
    """
    m, n = pa.shape[0], pb.shape[0]
    cost = np.full((m, n), np.inf)
    came = np.zeros((m, n), dtype=np.int8)
    cost[0, 0] = np.sqrt(((pa[0] - pb[0]) ** 2).sum())
    for i in range(m):
        for j in range(n):
            if i > 0:
                c = cost[i - 1, j] + np.sqrt(((pa[i] - pb[j]) ** 2).sum())
                if c < cost[i, j]:
                    cost[i, j] = c
                    came[i, j] = 0
            if j > 0:
                c = cost[i, j - 1] + np.sqrt(((pa[i] - pb[j]) ** 2).sum())
                if c < cost[i, j]:
                    cost[i, j] = c
                    came[i, j] = 1
    i, j = m - 1, n - 1
    for k in range(m + n - 3, -1, -1):
        steps[k] = came[i, j]
        if came[i, j] == 0:
            i -= 1
        else:
            j -= 1
    return cost[m - 1, n - 1]
