"""The cell-grid queries (recon.kernels.grid_query) against the k-d tree they replace."""

import numpy as np
import pytest
from scipy.spatial import cKDTree

from recon.neighbors import PointGrid
from recon.surface import DataSurface


def _sphere(n, radius=10.0, seed=0):
    rng = np.random.default_rng(seed)
    p = rng.normal(size=(n, 3))
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    return radius * p * rng.uniform(0.95, 1.05, (n, 1))  # no distance ties from the centre


def _queries(points, seed=1, sigma=0.4):
    rng = np.random.default_rng(seed)
    q = points[: len(points) // 4] + rng.normal(scale=sigma, size=(len(points) // 4, 3))
    # far outside the grid on every side, inside the empty middle, on a data point
    far = np.array([[100.0, 0, 0], [-80.0, 50, 3], [0.0, 0, -60], [0.0, 0, 0], points[5]])
    return np.vstack([q, far])


@pytest.mark.parametrize("k", [1, 3, 8])
@pytest.mark.parametrize("cell", [0.3, 1.0, 4.0])
def test_k_nearest_equal_the_kd_tree(k, cell):
    pts = _sphere(1500)
    q = _queries(pts)
    d, i = PointGrid(pts, cell).query(q, k=k)
    d_ref, i_ref = cKDTree(pts).query(q, k=k)
    assert np.array_equal(i, i_ref)
    assert np.allclose(d, d_ref, rtol=0, atol=1e-12)


def test_more_neighbours_than_points_pad_like_the_kd_tree():
    pts = _sphere(5)
    q = np.array([[0.0, 0.0, 9.0], [50.0, 0.0, 0.0]])
    d, i = PointGrid(pts, 1.0).query(q, k=8)
    d_ref, i_ref = cKDTree(pts).query(q, k=8)
    assert np.array_equal(i, i_ref)
    assert np.array_equal(np.isinf(d), np.isinf(d_ref))
    assert np.allclose(d[np.isfinite(d)], d_ref[np.isfinite(d_ref)])


def test_queries_beyond_the_search_shells_fall_back_to_the_tree():
    # a tiny cell: the far queries need more shells than the grid searches
    pts = _sphere(400)
    g = PointGrid(pts, 0.05)
    q = np.array([[30.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    d, i = g.query(q, k=2)
    d_ref, i_ref = cKDTree(pts).query(q, k=2)
    assert g._tree is not None  # the fallback was used
    assert np.array_equal(i, i_ref)
    assert np.allclose(d, d_ref)


@pytest.mark.parametrize("radius", [0.2, 0.65, 1.5])
def test_covered_equals_a_radius_test_on_the_tree(radius):
    pts = _sphere(2000)
    q = _queries(pts, sigma=0.8)
    got = PointGrid(pts, radius).covered(q, radius)
    d, _ = cKDTree(pts).query(q, k=1)
    assert got.dtype == bool
    assert np.array_equal(got, d <= radius)
    assert 0 < got.sum() < len(q)  # the test can fail both ways


def test_covered_with_a_radius_above_the_cell_uses_the_distances():
    pts = _sphere(500)
    q = _queries(pts, sigma=1.0)
    got = PointGrid(pts, 0.5).covered(q, 1.2)
    d, _ = cKDTree(pts).query(q, k=1)
    assert np.array_equal(got, d <= 1.2)


def _two_sheets(n=1500, gap=0.6, seed=0):
    """Two parallel noisy planes with opposed normals (a thin part), in units of r0."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-12, 12, (n, 2))
    z = 0.3 * np.sin(0.3 * xy[:, 0]) + rng.normal(0, 0.02, n)
    top = np.column_stack([xy, z + gap / 2])
    bottom = np.column_stack([xy[::-1], z[::-1] - gap / 2])
    pts = np.vstack([top, bottom])
    nrm = np.vstack([np.tile([0, 0, 1.0], (n, 1)), np.tile([0, 0, -1.0], (n, 1))])
    return pts, nrm


@pytest.mark.parametrize("with_normals", [True, False])
def test_anchor_feet_equal_the_tree_and_numpy_version(with_normals):
    pts, nrm = _two_sheets()
    s = DataSurface.build(pts, nrm, k=16)
    rng = np.random.default_rng(3)
    q = pts[::7] + rng.normal(scale=0.3, size=(len(pts[::7]), 3))
    q = np.vstack([q, [[60.0, 0.0, 0.0]]])  # far: answered by the tree
    qn = np.where(rng.uniform(size=(len(q), 1)) < 0.5, 1.0, -1.0) * np.array([0, 0, 1.0])
    normals = qn if with_normals else None
    foot, n, dist = s.anchors(q, normals)
    foot_ref, n_ref, dist_ref, idx_ref = s._anchors_tree(q, normals)
    assert np.allclose(foot, foot_ref, rtol=0, atol=1e-12)
    assert np.allclose(n, n_ref, rtol=0, atol=1e-12)
    assert np.allclose(dist, dist_ref, rtol=0, atol=1e-12)
    side = np.sign(foot[:-1, 2] - 0.3 * np.sin(0.3 * foot[:-1, 0]))
    agree = np.mean(side == qn[:-1, 2])
    if with_normals:  # the sheet the normal agrees with (when among the 8 nearest)
        assert agree > 0.9
    else:  # the nearest sheet, whatever the normal
        assert agree < 0.8


def test_nearest_on_the_grid_equals_the_tree():
    pts, nrm = _two_sheets(800)
    s = DataSurface.build(pts, nrm, k=16)
    q = _queries(pts)
    d, i = s.nearest(q)
    d_ref, i_ref = s.tree.query(q, k=1)
    assert np.array_equal(i, i_ref)
    assert np.allclose(d, d_ref)


def test_local_quadrics_are_the_same_on_one_and_two_threads():
    # fit_quadrics_kernel is threaded (each point writes its own rows): no thread-count effect
    from recon.kernels.local_surface import fit_quadrics_kernel
    from recon.kernels.options import thread_count

    pts = _sphere(3000)
    nrm = pts / np.linalg.norm(pts, axis=1, keepdims=True)
    _, idx = cKDTree(pts).query(pts, k=16)
    outs = []
    for threads in (1, 2):
        out = (np.zeros((3000, 3)), np.zeros((3000, 3)), np.zeros((3000, 3)))
        out += (np.zeros((3000, 6)), np.zeros(3000))
        with thread_count(threads):
            fit_quadrics_kernel(pts, nrm, idx.astype(np.int64), *out)
        outs.append(out)
    for a, b in zip(*outs, strict=True):
        assert np.array_equal(a, b)
    assert np.median(np.einsum("ij,ij->i", outs[0][1], nrm)) > 0.9  # normals follow the sphere


def test_coordinate_extent_is_numpys_max_minus_min():
    from recon.kernels.grid_query import coordinate_extent

    rng = np.random.default_rng(7)
    for p in (rng.normal(size=(1, 3)), rng.normal(size=(5000, 3)) * [1.0, 1e-3, 1e4]):
        assert np.array_equal(coordinate_extent(p), p.max(axis=0) - p.min(axis=0))


@pytest.mark.parametrize("first", [False, True], ids=["later-row", "first-row"])
def test_coordinate_extent_propagates_nan_and_infinity_as_numpy(first):
    from recon.kernels.grid_query import coordinate_extent

    p = np.random.default_rng(8).normal(size=(50, 3))
    row = 0 if first else 20
    p[row, 0] = np.nan
    p[row + 1, 1] = np.inf
    p[row + 2, 2] = -np.inf
    with np.errstate(invalid="ignore"):
        expected = p.max(axis=0) - p.min(axis=0)
    got = coordinate_extent(p)
    assert np.isnan(got[0]) and np.isnan(expected[0])
    assert got[1] == expected[1] == np.inf and got[2] == expected[2] == np.inf
