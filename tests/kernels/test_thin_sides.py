"""recon.kernels.thin_sides: the two-means split of neighbourhood offsets (eq. two-means).

Checked against the vectorised numpy split it replaced (written out below as the reference):
the same ``across`` and ``two_sided`` decisions on one-sheet noise, two faces a gap apart,
ties and an exact plane, with 1 and 2 threads.
"""

from __future__ import annotations

import numba
import numpy as np
import pytest

from recon.kernels.thin_sides import split_sides_kernel

SIDES_MIN, SEPARATION, GAP = 3, 5.0, 0.5


def numpy_split(offsets: np.ndarray, radius: np.ndarray, k: int):
    """The numpy version (recon.normals before the kernel): sort, cumulative sums, argmin."""
    n, k_wide = offsets.shape
    d = np.concatenate([np.zeros((n, 1)), offsets], axis=1)
    m = k_wide + 1
    s = np.sort(d, axis=1)
    c1 = np.cumsum(s, axis=1)
    c2 = np.cumsum(s * s, axis=1)
    t = np.arange(1, m)
    left_ss = c2[:, :-1] - c1[:, :-1] ** 2 / t
    right_n = m - t
    right_sum = c1[:, -1:] - c1[:, :-1]
    right_ss = (c2[:, -1:] - c2[:, :-1]) - right_sum**2 / right_n
    ss = left_ss + right_ss
    ss[:, (t < SIDES_MIN) | (right_n < SIDES_MIN)] = np.inf
    best = np.argmin(ss, axis=1)
    rows = np.arange(n)
    gap = right_sum[rows, best] / right_n[best] - c1[rows, best] / t[best]
    pooled = np.sqrt(np.maximum(ss[rows, best], 0.0) / max(m - 2, 1))
    two_sided = (gap > SEPARATION * pooled) & (gap > GAP * radius)
    threshold = 0.5 * (s[rows, best] + s[rows, best + 1])
    own_left = 0.0 < threshold
    left = offsets[:, :k] < threshold[:, None]
    return two_sided[:, None] & (left != own_left[:, None]), two_sided


def _offsets(seed: int, n: int = 4000, k_wide: int = 30):
    rng = np.random.default_rng(seed)
    noise = rng.normal(0.0, 0.02, (n, k_wide))
    # a quarter one sheet, a quarter two faces a gap apart, a quarter exact zeros and ties,
    # a quarter a narrow gap near the decision thresholds
    q = n // 4
    other = rng.random((n, k_wide)) < 0.4
    noise[q : 2 * q] += np.where(other[q : 2 * q], 1.0, 0.0)
    noise[2 * q : 3 * q] = np.round(noise[2 * q : 3 * q] * 20.0) / 20.0
    noise[2 * q] = 0.0
    noise[3 * q :] += np.where(other[3 * q :], rng.uniform(0.05, 0.4, (n - 3 * q, 1)), 0.0)
    radius = rng.uniform(0.1, 1.5, n)
    return np.ascontiguousarray(noise), radius


@pytest.mark.parametrize("threads", [1, 2])
@pytest.mark.parametrize("seed", [0, 1])
def test_split_is_the_numpy_split_bit_for_bit(seed, threads):
    offsets, radius = _offsets(seed)
    k = 10
    want_across, want_sided = numpy_split(offsets, radius, k)
    assert 0 < want_sided.sum() < len(offsets)  # both outcomes are exercised
    across = np.zeros((len(offsets), k), dtype=bool)
    sided = np.zeros(len(offsets), dtype=bool)
    before = numba.get_num_threads()
    numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
    try:
        split_sides_kernel(offsets, radius, k, SIDES_MIN, SEPARATION, GAP, across, sided)
    finally:
        numba.set_num_threads(before)
    np.testing.assert_array_equal(sided, want_sided)
    np.testing.assert_array_equal(across, want_across)


@pytest.mark.parametrize("scale", [1e-3, 1.0, 1e5])
def test_rows_at_the_span_screen_match_the_numpy_split(scale):
    """Two exact faces ``g`` apart (the point itself on the near one), radii just either side
    of ``g / GAP``: the rows that the span screen answers without a split (span well below
    ``GAP`` radii) and those just past it decide as the full numpy split does."""
    g = 0.37 * scale
    k_wide = 30
    row = np.where(np.arange(k_wide) % 3 == 0, g, 0.0)  # 10 on the far face, 20 on the near
    factors = np.array([1 - 1e-3, 1 - 1e-8, 1 - 1e-12, 1.0, 1 + 1e-12, 1 + 1e-8, 1 + 1e-3, 2.0])
    offsets = np.tile(row, (len(factors), 1))
    radius = g / GAP * factors
    want_across, want_sided = numpy_split(offsets, radius, k_wide)
    assert want_sided[:2].all() and not want_sided[-2:].any()
    across = np.zeros((len(offsets), k_wide), dtype=bool)
    sided = np.ones(len(offsets), dtype=bool)  # every row must be written
    split_sides_kernel(offsets, radius, k_wide, SIDES_MIN, SEPARATION, GAP, across, sided)
    np.testing.assert_array_equal(sided, want_sided)
    np.testing.assert_array_equal(across, want_across)


def test_span_screen_is_sure_only_of_rows_the_split_keeps_one_sided():
    """Sheets with curvature and noise, and two faces a gap apart: rows that the screen is
    sure of are one-sided by the numpy split of numpy's offsets; flat rows are sure, rows
    that span two faces are not, and a NaN row never is."""
    from recon.kernels.thin_sides import span_screen

    rng = np.random.default_rng(4)
    n, k_wide = 600, 30
    pts = rng.uniform(-1.0, 1.0, (n, 3)) * np.array([1.0, 1.0, 0.0])
    pts[:, 2] = 0.2 * pts[:, 0] ** 2 + rng.normal(0.0, 0.01, n)
    pts[n // 2 :, 0] += 4.0  # apart from the first sheet: a thin part, two faces 0.3 apart
    pts[n // 2 :, 2] += rng.choice([0.0, 0.3], n - n // 2)
    pts[7, 2] = np.nan
    nrm = np.tile([0.0, 0.0, 1.0], (n, 1))
    idx = np.argsort(np.linalg.norm(pts[:, None, :2] - pts[None, :, :2], axis=2), axis=1)
    idx = idx[:, 1 : k_wide + 1].astype(np.int32)
    rel = pts[idx] - pts[:, None, :]
    offsets = np.einsum("ijk,ik->ij", rel, nrm)
    radius = np.linalg.norm(rel[:, -1], axis=1)
    _, want_sided = numpy_split(offsets, radius, 10)
    sure = np.zeros(n, dtype=bool)
    span_screen(pts, nrm, idx, 0, GAP, sure)
    assert not (sure & want_sided).any()
    assert sure[: n // 2].sum() > n // 4  # the flat half is mostly sure
    assert want_sided.any()
    assert not sure[7]
    # nor is a row with a NaN neighbour (min and max would pass its offset over)
    with_nan = np.flatnonzero((idx == 7).any(axis=1))
    assert len(with_nan) and not sure[with_nan].any()
    part = np.zeros(n - 100, dtype=bool)  # a block of rows: row r is the point start + r
    span_screen(pts, nrm, idx[100:], 100, GAP, part)
    np.testing.assert_array_equal(part, sure[100:])
