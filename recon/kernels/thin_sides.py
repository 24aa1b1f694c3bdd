r"""Two faces of a thin part in one neighbourhood: the 1-D two-means split of the offsets.

Used by the normal orientation (:func:`recon.normals.orient_normals`, ``normals.thin_parts``)
to find the neighbours that lie on the other face of a thin part. For point i, the offsets
along n_i of i itself (0) and of its neighbours, sorted, :math:`s_1 \le \dots \le s_m`, are
split into a left group of t and a right group of m - t values at the t of least
within-group sum of squares

.. math::
    :label: two-means

    W(t) = \Bigl(C_2(t) - \frac{C_1(t)^2}{t}\Bigr)
         + \Bigl(C_2(m) - C_2(t) - \frac{(C_1(m) - C_1(t))^2}{m - t}\Bigr),
    \qquad C_p(t) = \sum_{q \le t} s_q^p,

over the splits with at least ``sides_min`` values on each side (eq. two-means, [HW79] in one
dimension). The neighbourhood spans two faces when the group means lie more than
``separation`` pooled deviations :math:`\sqrt{W / (m - 2)}` and ``gap_ratio`` neighbourhood
radii apart.

The arithmetic is that of the numpy version it replaced (cumulative sums in order, the same
expressions, no fast-math), so the decisions are the same bit for bit; each row is its own
iteration, so any thread count gives the same result.

References
----------
.. [HW79] J. A. Hartigan, M. A. Wong. "Algorithm AS 136: A K-means clustering algorithm".
   Applied Statistics 28(1), 1979.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from .options import EXACT_JIT_OPTIONS

_PARALLEL = dict(EXACT_JIT_OPTIONS, parallel=True)


@njit(**_PARALLEL)
def split_sides_kernel(
    offsets, radius, k, sides_min, separation, gap_ratio, across, two_sided
):  # pragma: no cover - numba
    r"""Two-means split of each row's offsets (eq. two-means of the module docstring).

    Parameters
    ----------
    offsets : (n, K) float64
        Offsets along n_i of point i's K neighbours (the point itself, offset 0, is added).
    radius : (n,) float64
        Each neighbourhood's radius (distance of its last neighbour).
    k : int
        Columns of ``across`` to fill (the first k neighbours).
    sides_min : int
        Fewest values on either side of a split.
    separation, gap_ratio : float
        The group means must lie more than ``separation`` pooled deviations and more than
        ``gap_ratio * radius[i]`` apart.
    across : (n, >= k) bool, out
        Row i, column q: i's neighbourhood spans two faces and neighbour q is in the group
        without i.
    two_sided : (n,) bool, out
        Row i's neighbourhood spans two faces.
    """
    n, kw = offsets.shape
    m = kw + 1
    pooled_div = float(max(m - 2, 1))
    for i in prange(n):
        s = np.empty(m)
        s[0] = 0.0
        for q in range(kw):
            s[q + 1] = offsets[i, q]
        s.sort()
        c1 = np.empty(m)
        c2 = np.empty(m)
        c1[0] = s[0]
        c2[0] = s[0] * s[0]
        for q in range(1, m):
            c1[q] = c1[q - 1] + s[q]
            c2[q] = c2[q - 1] + s[q] * s[q]
        # argmin over the splits, first minimum (a NaN, as numpy's argmin, wins at once)
        best = 0
        best_ss = np.inf
        for j in range(m - 1):  # left group s[:j + 1]
            t = j + 1
            rn = m - t
            if t < sides_min or rn < sides_min:
                continue
            rs = c1[m - 1] - c1[j]
            ss = (c2[j] - c1[j] * c1[j] / t) + ((c2[m - 1] - c2[j]) - rs * rs / rn)
            if np.isnan(ss):
                best, best_ss = j, ss
                break
            if ss < best_ss:
                best, best_ss = j, ss
        t = best + 1
        rn = m - t
        rs = c1[m - 1] - c1[best]
        gap = rs / rn - c1[best] / t
        w = best_ss if not best_ss < 0.0 else 0.0
        pooled = np.sqrt(w / pooled_div)
        sided = (gap > separation * pooled) and (gap > gap_ratio * radius[i])
        two_sided[i] = sided
        threshold = 0.5 * (s[best] + s[best + 1])
        own_left = 0.0 < threshold
        for q in range(k):
            across[i, q] = sided and ((offsets[i, q] < threshold) != own_left)
