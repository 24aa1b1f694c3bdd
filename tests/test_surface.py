import numpy as np
import pytest
from scipy.spatial import cKDTree

from recon.surface import DataSurface, max_angular_gap


def _noisy_plane(n=3000, sigma=0.05, seed=0):
    rng = np.random.default_rng(seed)
    p = np.column_stack([rng.uniform(-10, 10, n), rng.uniform(-10, 10, n), rng.normal(0, sigma, n)])
    nrm = np.tile([0.0, 0.0, 1.0], (n, 1))
    return p, nrm


def test_local_planes_average_noise_and_keep_orientation():
    p, nrm = _noisy_plane()
    s = DataSurface.build(p, nrm, k=30)
    assert np.all(s.plane_normals[:, 2] > 0.95)
    # plane centroids are much closer to z=0 than the raw samples
    assert np.abs(s.plane_points[:, 2]).mean() < 0.5 * np.abs(p[:, 2]).mean()
    assert 0.02 < s.noise < 0.08


def test_project_puts_points_on_the_plane():
    p, nrm = _noisy_plane(sigma=0.0)
    s = DataSurface.build(p, nrm)
    q = np.array([[0.3, 0.2, 0.7], [1.0, -2.0, -0.4]])
    proj, n, off = s.project(q)
    assert np.allclose(proj[:, 2], 0.0, atol=1e-9)
    assert np.allclose(off, [0.7, -0.4])


def test_angular_gap_inside_vs_past_the_boundary():
    g = np.stack(np.meshgrid(np.arange(-10, 11.0), np.arange(-10, 11.0)), -1).reshape(-1, 2)
    pts = np.column_stack([g, np.zeros(len(g))])
    hole = np.linalg.norm(pts[:, :2], axis=1) < 2.5
    pts = pts[~hole]
    tree = cKDTree(pts)
    up = np.array([[0.0, 0.0, 1.0]] * 2)
    centers = np.array([[0.0, 0.0, 0.0], [10.8, 0.0, 0.0]])  # hole centre; past the edge
    gap = max_angular_gap(centers, up, tree, pts, radius=5.0)
    assert gap[0] < np.deg2rad(90)
    assert gap[1] >= np.pi
    # one radius per centre: the hole's centre sees no data within 2 (a full turn's gap)
    # and the rim all round within 5; the same as one radius for each
    each = max_angular_gap(centers[[0, 0]], up, tree, pts, radius=np.array([2.0, 5.0]))
    assert each[0] == pytest.approx(2 * np.pi) and each[1] == pytest.approx(gap[0])
    assert each[0] == pytest.approx(max_angular_gap(centers[:1], up[:1], tree, pts, 2.0)[0])


def _thin_slab(thickness=1.0, spacing=0.5, half=6.0):
    """Two parallel sheets at z = +-thickness/2 (normalised units), normals pointing out."""
    g = np.arange(-half, half + 1e-9, spacing)
    xy = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    top = np.column_stack([xy, np.full(len(xy), 0.5 * thickness)])
    bottom = np.column_stack([xy + 0.5 * spacing, np.full(len(xy), -0.5 * thickness)])
    pts = np.vstack([top, bottom])
    nrm = np.vstack([np.tile([0.0, 0, 1], (len(xy), 1)), np.tile([0.0, 0, -1], (len(xy), 1))])
    return pts, nrm


def test_local_fits_of_a_thin_slab_stay_on_their_own_sheet():
    """Regression: a neighbourhood spanning both sides of a thin part put the local surface in
    the middle of the part, pulling both sheets onto one (plate-noise025)."""
    pts, nrm = _thin_slab()
    s = DataSurface.build(pts, nrm, k=30)  # 30 neighbours reach across the 1 r0 gap
    inner = np.all(np.abs(pts[:, :2]) < 4.0, axis=1)
    assert np.allclose(s.plane_points[inner, 2], pts[inner, 2], atol=1e-9)
    assert np.all(np.einsum("ij,ij->i", s.plane_normals, nrm) > 0.99)
    assert s.noise < 1e-6


def test_anchors_follow_the_sheet_the_particle_belongs_to():
    pts, nrm = _thin_slab()
    s = DataSurface.build(pts, nrm, k=30)
    q = np.array([[0.1, 0.2, 0.3], [0.1, 0.2, 0.3]])  # nearer the top sheet
    foot, n, _ = s.anchors(q, np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]]))
    assert foot[0, 2] == pytest.approx(0.5) and n[0, 2] > 0.99
    assert foot[1, 2] == pytest.approx(-0.5) and n[1, 2] < -0.99
    # without normals: the nearest data point decides
    foot, _, _ = s.anchors(q)
    assert np.allclose(foot[:, 2], 0.5)


def test_feature_spacing_small_on_thin_parts_large_on_flat_ones():
    from recon.surface import feature_spacing

    pts, nrm = _thin_slab(thickness=1.2, half=8.0)
    thin = feature_spacing(DataSurface.build(pts, nrm, k=12), 0.5, 1.5)
    p, n = _noisy_plane(sigma=0.0)
    flat = feature_spacing(DataSurface.build(p * 0.6, n, k=12), 0.5, 1.5)
    inner = np.all(np.abs(pts[:, :2]) < 5.0, axis=1)
    # epsilon x half the thickness = 0.3 r0, floored at the data spacing 0.5
    assert np.allclose(thin[inner], 0.5)
    assert np.all((flat >= 0.5) & (flat <= 1.5))
    assert np.median(flat) == pytest.approx(1.5)


def test_anchor_hints_give_the_same_anchors():
    """A walk from a hint (near, far, or a duplicate's twin) ends on the exact nearest data
    point, ties by index, or hands the query to the grid: the anchors never change."""
    rng = np.random.default_rng(4)
    xy = rng.uniform(-10, 10, (4000, 2))
    p = np.column_stack([xy, 0.03 * (xy**2).sum(axis=1) + rng.normal(0, 0.05, len(xy))])
    p[::50] = p[1::50]  # duplicates: ties broken by index
    nrm = np.tile([0.0, 0.0, 1.0], (len(p), 1))
    s = DataSurface.build(p, nrm, k=20)
    q = p[rng.integers(0, len(p), 3000)] + rng.normal(0, 0.3, (3000, 3))
    q[:10] += [0.0, 0.0, 5.0]  # far off the data: the walk cannot prove its result
    qn = np.tile([0.0, 0.0, 1.0], (len(q), 1))
    qn[::7] *= -1.0  # disagreeing normals: the k nearest are searched
    exact = s.anchors(q, qn, with_index=True)
    _, near = cKDTree(p).query(q)
    for hint in (near, rng.integers(0, len(p), len(q)), np.full(len(q), -1)):
        got = s.anchors(q, qn, hint=hint, with_index=True)
        for a, b in zip(got, exact, strict=True):
            np.testing.assert_array_equal(a, b)


def test_walk_certifies_only_what_its_table_covers():
    from recon.kernels.grid_query import _walk_nearest

    g = np.stack(np.meshgrid(np.arange(10.0), np.arange(10.0)), -1).reshape(-1, 2)
    pts = np.column_stack([g, np.zeros(len(g))])
    _, nbr = cKDTree(pts).query(pts, k=9)
    nbr = nbr.astype(np.int32)
    reach = np.full(len(pts), np.sqrt(2.0))  # the 8 around a point and itself
    j, d2, ok = _walk_nearest(7.2, 6.9, 0.1, 0, pts, nbr, reach)
    assert (j, ok) == (7 * 10 + 7, True) and d2 == pytest.approx(0.04 + 0.01 + 0.01)
    # 0.8 off the grid: a point as near could lie beyond the table (2 d > its reach)
    assert _walk_nearest(7.2, 6.9, 0.8, 0, pts, nbr, reach)[2] is False


def test_anchor_hints_give_the_same_anchors_with_one_neighbour(monkeypatch):
    """With k = 1 (the nearest point, whatever its normal) the kernel's walk, grid and the
    k-d tree agree too, for agreeing and disagreeing normals, with and without hints. (It
    guards the answers, not how many searches give them.)"""
    import recon.surface as surface

    rng = np.random.default_rng(6)
    xy = rng.uniform(-10, 10, (3000, 2))
    p = np.column_stack([xy, 0.03 * (xy**2).sum(axis=1) + rng.normal(0, 0.05, len(xy))])
    nrm = np.tile([0.0, 0.0, 1.0], (len(p), 1))
    s = DataSurface.build(p, nrm, k=20)
    assert s.grid.cell_size > 0.0  # the grid as usual (its cell from the 8th neighbours)
    monkeypatch.setattr(surface, "AGREE_K", 1)
    q = p[rng.integers(0, len(p), 2000)] + rng.normal(0, 0.3, (2000, 3))
    q[:10] += [0.0, 0.0, 5.0]
    qn = np.tile([0.0, 0.0, 1.0], (len(q), 1))
    qn[::3] *= -1.0
    _, near = cKDTree(p).query(q)
    for normals in (qn, None):
        tree = s._anchors_tree(q, normals)
        np.testing.assert_array_equal(tree[3], near)  # one neighbour: the nearest point
        for hint in (near, None):
            got = s.anchors(q, normals, hint=hint, with_index=True)
            for a, b in zip(got, tree, strict=True):
                np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)
