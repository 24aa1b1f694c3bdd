"""recon.geometry: hand-checkable sizes, spacing and planes."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from scipy.spatial import cKDTree

from recon.geometry import (
    as_points,
    bbox_diagonal,
    fit_plane,
    median_nearest_neighbor_distance,
    snap_to_precision,
    surround_distances,
    unit_vectors,
)


def grid(n: int = 10, step: float = 1.0) -> np.ndarray:
    i, j = np.meshgrid(np.arange(n) * step, np.arange(n) * step)
    return np.column_stack([i.ravel(), j.ravel(), np.zeros(n * n)])


def test_bbox_diagonal():
    assert bbox_diagonal(np.array([[0.0, 0, 0], [3, 4, 12]])) == 13.0
    assert bbox_diagonal(np.zeros((0, 3))) == 0.0
    assert bbox_diagonal(grid(3) + 5e6) == pytest.approx(np.sqrt(8.0))


@pytest.mark.parametrize("step", [1e-6, 1.0, 1e3])
def test_median_nn_on_grid_any_scale(step):
    assert median_nearest_neighbor_distance(
        grid(10, step), rng=np.random.default_rng(0)
    ) == pytest.approx(step)


def test_median_nn_sampling_is_deterministic():
    rng = np.random.default_rng(0)
    p = rng.uniform(size=(5000, 3))
    a = median_nearest_neighbor_distance(p, sample=500, rng=np.random.default_rng(0))
    b = median_nearest_neighbor_distance(p, sample=500, rng=np.random.default_rng(0))
    full = median_nearest_neighbor_distance(p, sample=None, rng=np.random.default_rng(0))
    assert a == b
    assert a == pytest.approx(full, rel=0.1)
    c = median_nearest_neighbor_distance(p, sample=500, rng=np.random.default_rng(5))
    assert c == pytest.approx(full, rel=0.1)


def test_median_nn_needs_two_points():
    with pytest.raises(ValueError, match="at least 2"):
        median_nearest_neighbor_distance(np.zeros((1, 3)), rng=np.random.default_rng(0))


def test_fit_plane():
    p = grid(5)
    rot = np.linalg.qr(np.random.default_rng(1).normal(size=(3, 3)))[0]
    q = p @ rot.T + [1.0, 2.0, 3.0]
    centroid, normal, sv = fit_plane(q)
    np.testing.assert_allclose(centroid, rot @ [2.0, 2.0, 0.0] + [1, 2, 3], atol=1e-12)
    assert abs(normal @ (rot @ [0, 0, 1.0])) == pytest.approx(1.0)
    assert sv[2] == pytest.approx(0.0, abs=1e-9) and sv[0] > 0


def test_unit_vectors_and_as_points():
    v = unit_vectors(np.array([[3.0, 4.0, 0.0], [0.0, 0.0, 0.0]]))
    np.testing.assert_allclose(v, [[0.6, 0.8, 0.0], [0.0, 0.0, 0.0]])
    with pytest.raises(ValueError, match=r"expected shape \(n, 3\), got \(4, 2\)"):
        as_points(np.zeros((4, 2)))


def test_as_points_is_the_one_validator():
    from recon.errors import InputError

    assert as_points([1.0, 2.0, 3.0], allow_single=True).shape == (1, 3)
    with pytest.raises(ValueError, match=r"normals: expected 2 rows, got 3"):
        as_points(np.zeros((3, 3)), "normals", rows=2)
    bad = np.zeros((4, 3))
    bad[2, 1] = np.nan
    as_points(bad)  # finiteness is checked only when asked
    with pytest.raises(InputError, match=r"points: row 2 is not finite"):
        as_points(bad, finite=True, error=InputError)


def test_median_spacing_from_known_nearest_distances_is_the_queried_one():
    """Given each point's distance to its nearest other point (the fit's shared query), the
    median spacing takes the same sample of them and gives the tree's value, exactly."""
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(5)
    pts = rng.normal(size=(3000, 3))
    pts[1] = pts[0]  # a repeated point: distance 0
    nearest = cKDTree(pts).query(pts, k=2)[0][:, 1]
    for sample in (None, 500):
        want = median_nearest_neighbor_distance(pts, sample, rng=np.random.default_rng(1))
        got = median_nearest_neighbor_distance(
            pts, sample, rng=np.random.default_rng(1), nearest=nearest
        )
        assert got == want
    wrong = median_nearest_neighbor_distance(
        pts, 500, rng=np.random.default_rng(1), nearest=2 * nearest
    )
    assert wrong == 2 * want  # the given distances are used, not queried again


def test_snap_to_precision_drops_the_digits_below_the_largest_coordinates_ulp():
    """Rounding residues near 0 (far below the precision of the mesh's coordinates) become
    exact zeros, so a face on the plane y = 0 is exactly flat; nothing moves by more than
    half an ulp of the largest coordinate, the largest are unchanged, and snapping twice is
    snapping once."""
    x = np.random.default_rng(3).normal(scale=0.4, size=(500, 3))
    x[:50, 1] = np.random.default_rng(4).normal(scale=1e-18, size=50)  # residues on y = 0
    x[50:60, 1] = 0.0
    y = snap_to_precision(x)
    ulp = np.spacing(np.abs(x).max())
    assert np.all(y[:60, 1] == 0.0)
    assert np.abs(y - x).max() <= 0.5 * ulp
    big = np.abs(x) >= 2.0 ** (np.frexp(np.abs(x).max())[1] - 1)  # the largest's binade
    np.testing.assert_array_equal(y[big], x[big])
    np.testing.assert_array_equal(snap_to_precision(y), y)
    assert not np.signbit(y[:60, 1]).any()  # negative residues become 0.0, not -0.0
    # near the largest double the quantum is still a power of two (no overflow to inf/NaN)
    huge = snap_to_precision(np.array([[1e308, 1.0, -1e-19]]))
    assert np.isfinite(huge).all() and huge[0, 0] == 1e308 and not huge[0, 1:].any()
    assert snap_to_precision(np.zeros((0, 3))).shape == (0, 3)
    np.testing.assert_array_equal(snap_to_precision(np.zeros((2, 3))), np.zeros((2, 3)))


def _lines(gap: float, step: float = 1.0, n: int = 40) -> np.ndarray:
    """Points ``step`` apart along lines ``gap`` apart (a square patch)."""
    x, y = np.meshgrid(np.arange(0.0, n * step, step), np.arange(0.0, n * step, gap))
    return np.c_[x.ravel(), y.ravel(), np.zeros(x.size)]


@pytest.mark.parametrize("gap", [2.0, 3.0, 6.0, 30.0])
def test_surround_distance_of_scan_lines_is_the_gap_between_them(gap):
    """Up to 16 spacings among the 32 nearest; beyond, among the 256 nearest (a tester's
    lines 50 times denser along than across measured 0.32 of their gap)."""
    pts = _lines(gap, n=120)
    inner = np.flatnonzero(  # on the inner lines, away from the ends
        (np.abs(pts[:, 0] - 60.0) < 5.0) & (np.abs(pts[:, 1] - pts[:, 1].mean()) < gap)
    )
    d = surround_distances(pts, inner, cKDTree(pts))
    np.testing.assert_allclose(d, gap)


def test_surround_distance_of_random_samples_is_about_3_4_nearest_distances():
    """The constant the scan-line rule (recon.fitting.scale.SURROUND_RATIO = 4) stays above."""
    rng = np.random.default_rng(1)
    pts = np.c_[rng.uniform(0, 10, (40_000, 2)), np.zeros(40_000)]
    rows = rng.choice(len(pts), 2000, replace=False)
    tree = cKDTree(pts)
    ratio = np.nanmedian(surround_distances(pts, rows, tree)) / np.median(
        tree.query(pts[rows], 2)[0][:, 1]
    )
    assert 3.2 < ratio < 3.7, ratio


def test_surround_distance_of_points_on_one_line_is_the_last_neighbours():
    """Never surrounded, even among 8 x k: NaN (no warning from a flat PCA). Regression: a
    lower bound (the 8 k-th, the k-th) made two lines 0.3 apart 0.81 apart, and a strip two
    rows wide, every point of it on a border, scan lines (no triangle)."""
    pts = np.c_[np.arange(100.0), np.zeros(100), np.zeros(100)]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        d = surround_distances(pts, np.array([50]), cKDTree(pts), k=8)
    assert np.isnan(d[0])
    assert surround_distances(pts, np.array([], dtype=int), cKDTree(pts)).shape == (0,)
