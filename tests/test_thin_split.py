"""The two faces of a thin part: the taper rule of :func:`recon.thin_split.thin_sides`."""

from __future__ import annotations

import numpy as np
import pytest
from mesh_shapes import flat_ellipsoid
from scipy.spatial import cKDTree

from recon.normals import estimate_normals
from recon.thin_split import (
    SIDES_K,
    TAPER_MIN_STRONG,
    _unlinked_taper,
    across_neighbours,
    thin_sides,
)


def _split(points: np.ndarray, **kw) -> tuple[np.ndarray, np.ndarray]:
    _, idx = cKDTree(points).query(points, SIDES_K + 1)
    return thin_sides(points, estimate_normals(points, k=20), idx[:, 1:], SIDES_K, **kw)


@pytest.mark.parametrize("seed", range(2))
def test_a_blade_thinner_than_the_gap_everywhere_is_left_as_the_full_gap_leaves_it(seed):
    """The knife of bench_thin_parts at 3,000 points: 0.024 thick in the middle, about one
    sample spacing, so no patch of its neighbourhoods splits at the full gap. The taper rule
    then adds nothing (the part is meshed as one layer, F@1% 0.999 against 0.980-0.985
    with the gap at 0.2 everywhere), though the smaller gap alone finds hundreds of rows."""
    points, _ = flat_ellipsoid(3000, (1.0, 0.3, 0.012), seed, noise=0.001)
    full = _split(points, taper_gap=0.0)
    tapered = _split(points)
    small = _split(points, gap=0.2, taper_gap=0.0)
    assert full[1].sum() < TAPER_MIN_STRONG
    assert np.array_equal(tapered[0], full[0]) and np.array_equal(tapered[1], full[1])
    assert small[1].sum() > 300


@pytest.mark.parametrize("seed", range(2))
def test_a_blade_thick_in_its_middle_keeps_its_faces_apart_where_it_tapers(seed):
    """The knife at 5,000 points: its middle splits at the full gap, and every row that
    splits at the smaller gap along its taper is joined to it, so the taper rule gives what
    the smaller gap alone gives there; nothing it finds lies outside what that gap finds."""
    points, _ = flat_ellipsoid(5000, (1.0, 0.3, 0.012), seed, noise=0.001)
    full = _split(points, taper_gap=0.0)
    tapered = _split(points)
    small = _split(points, gap=0.2, taper_gap=0.0)
    assert full[1].sum() >= 5 * TAPER_MIN_STRONG
    assert not (tapered[1] & ~small[1]).any() and not (full[1] & ~tapered[1]).any()
    r = np.hypot(points[:, 0], points[:, 1] / 0.3)
    band = (r > 0.5) & (r < 0.9)  # faces under half a neighbourhood radius apart
    assert tapered[1][band].sum() > 0.9 * small[1][band].sum() > 5 * full[1][band].sum()
    assert np.array_equal(tapered[0][tapered[1]], small[0][tapered[1]])


def test_unlinked_taper_rows_need_a_patch_of_strong_rows():
    """Rows 0-19 are linked in a chain, rows 20-39 in another, rows 40-44 stand alone: a
    chain with TAPER_MIN_STRONG strong rows keeps its other rows, one with one fewer loses
    them; a strong row is always kept; one-sided rows are never returned."""
    n = 50
    idx = np.repeat(np.arange(n)[:, None], 2, axis=1)  # each row's neighbours: itself
    for lo, hi in ((0, 20), (20, 40)):
        for i in range(lo, hi):
            idx[i] = (max(i - 1, lo), min(i + 1, hi - 1))
    two_sided = np.zeros(n, dtype=bool)
    two_sided[:45] = True
    strong = np.zeros(n, dtype=bool)
    strong[:TAPER_MIN_STRONG] = True
    strong[20 : 20 + TAPER_MIN_STRONG - 1] = True
    strong[40] = True
    weak = _unlinked_taper(idx, two_sided, strong)
    expected = np.r_[np.arange(20 + TAPER_MIN_STRONG - 1, 40), np.arange(41, 45)]
    assert np.array_equal(weak, expected)
    assert len(_unlinked_taper(idx, np.zeros(n, dtype=bool), strong)) == 0


def test_thin_sides_without_the_taper_is_across_neighbours_in_blocks():
    """With the taper off, the whole-cloud split is the block split of across_neighbours, in
    any block size."""
    points, _ = flat_ellipsoid(2000, (1.0, 0.3, 0.03), 4, noise=0.001)
    normals = estimate_normals(points, k=20)
    _, idx = cKDTree(points).query(points, SIDES_K + 1)
    ref = across_neighbours(points, normals, idx[:, 1:], 10)
    assert ref[1].sum() > 100
    for chunk in (2000, 333):
        got = thin_sides(points, normals, idx[:, 1:], 10, taper_gap=0.0, chunk=chunk)
        assert np.array_equal(got[0], ref[0]) and np.array_equal(got[1], ref[1])
