import numpy as np
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
