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

Most rows of a smooth scan never sort: the two group means lie at most the span
:math:`s_m - s_1` apart, so a row whose span is below ``gap_ratio`` radii (by a margin far
above the rounding of the means) fails the gap test whatever the split, and is one-sided at
once, with the decisions the full split would give.

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


#: A row whose offsets (the point's own 0 included) span at most ``gap_ratio`` radii, less
#: this fraction of the largest offset (far above the rounding of the group means: about
#: ``8 m^2`` ulps of it), cannot split (the group means lie at most the span apart): its
#: row is one-sided without the sort.
_SPAN_MARGIN = 1e-6


@njit(**EXACT_JIT_OPTIONS)
def _split_row(
    off, rad, k, sides_min, separation, gap_ratio, across, i, s, c1, c2
):  # pragma: no cover - numba
    """The split of one row: ``off`` (K,) offsets, ``rad`` its radius; writes ``across[i, :k]``
    and returns whether the row spans two faces (``s``, ``c1``, ``c2``: scratch of K + 1).

    Early exit: the two group means lie at most the span ``max - min`` of the values apart
    (their rounding adds far less than ``_SPAN_MARGIN`` of the largest value), so a span below
    ``gap_ratio * rad`` by that margin fails the gap test whatever the split (a NaN anywhere
    fails the span test and takes the full path, as before)."""
    kw = off.shape[0]
    m = kw + 1
    lo = 0.0
    hi = 0.0
    big = 0.0
    finite = True
    for q in range(kw):
        v = off[q]
        finite = finite and v == v  # min and max below would pass a NaN over
        lo = min(lo, v)
        hi = max(hi, v)
        big = max(big, abs(v))
    if finite and (hi - lo) + _SPAN_MARGIN * big < gap_ratio * rad:
        for q in range(k):
            across[i, q] = False
        return False
    pooled_div = float(max(m - 2, 1))
    s[0] = 0.0
    for q in range(kw):
        s[q + 1] = off[q]
    s.sort()
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
    sided = (gap > separation * pooled) and (gap > gap_ratio * rad)
    threshold = 0.5 * (s[best] + s[best + 1])
    own_left = 0.0 < threshold
    for q in range(k):
        across[i, q] = sided and ((off[q] < threshold) != own_left)
    return sided


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
    for i in prange(n):
        s = np.empty(kw + 1)
        c1 = np.empty(kw + 1)
        c2 = np.empty(kw + 1)
        two_sided[i] = _split_row(
            offsets[i], radius[i], k, sides_min, separation, gap_ratio, across, i, s, c1, c2
        )


#: :func:`span_screen`'s margin, relative to the neighbourhood's extent: far above the
#: rounding of the offsets and the radius in either arithmetic (~1e-15 of it).
_SCREEN_MARGIN = 1e-6


@njit(**_PARALLEL)
def span_screen(points, normals, idx, start, gap_ratio, sure):  # pragma: no cover - numba
    r"""Rows that certainly stay one-sided, before any offset is gathered: ``sure[r]`` when
    the offsets ``(points[idx[r, q]] - points[i]) . normals[i]`` of point ``i = start + r``
    (the point's own 0 included) span less than ``gap_ratio`` times the radius
    ``|points[idx[r, K - 1]] - points[i]|``, by ``_SCREEN_MARGIN`` of the neighbourhood's
    extent (its farthest point's distance times ``|n_i|``) on each side.

    The arithmetic here is not numpy's bit for bit (numpy's three-term dot products sum in a
    machine-dependent order), but both lie within a few roundings (~1e-15 of the extent) of
    the exact values, and the split's group means within ~1e-12 of the values (the margin of
    :func:`_split_row`): a sure row's split, from numpy's offsets, fails the gap test, so it
    is one-sided with no neighbour across, which is what the caller records without the
    gather. A NaN is never sure."""
    n, kw = idx.shape
    for r in prange(n):
        i = start + r
        px = points[i, 0]
        py = points[i, 1]
        pz = points[i, 2]
        nx = normals[i, 0]
        ny = normals[i, 1]
        nz = normals[i, 2]
        lo = 0.0
        hi = 0.0
        far = 0.0
        dx = 0.0
        dy = 0.0
        dz = 0.0
        finite = True
        for q in range(kw):
            j = idx[r, q]
            dx = points[j, 0] - px
            dy = points[j, 1] - py
            dz = points[j, 2] - pz
            v = dx * nx + dy * ny + dz * nz
            finite = finite and v == v  # min and max below would pass a NaN over
            lo = min(lo, v)
            hi = max(hi, v)
            far = max(far, dx * dx + dy * dy + dz * dz)
        rad = np.sqrt(dx * dx + dy * dy + dz * dz)
        extent = np.sqrt(far) * np.sqrt(nx * nx + ny * ny + nz * nz) + rad
        sure[r] = finite and (
            (hi - lo) + _SCREEN_MARGIN * extent < gap_ratio * rad - _SCREEN_MARGIN * extent
        )
