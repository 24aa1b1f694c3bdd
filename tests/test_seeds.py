import numpy as np
from scipy.spatial import cKDTree

from recon.geometry import poisson_disk_thin
from recon.seeds import select_seeds


def _plane(n=4000, seed=0):
    rng = np.random.default_rng(seed)
    p = rng.uniform(0, 20, size=(n, 3))
    p[:, 2] = 0.0
    return p


def test_kept_points_are_at_least_radius_apart():
    p = _plane()
    keep = poisson_disk_thin(p, 1.0, np.random.default_rng(1).permutation(len(p)))
    kept = p[keep]
    d, _ = cKDTree(kept).query(kept, k=2)
    assert d[:, 1].min() >= 1.0


def test_thinning_is_maximal_every_point_near_a_kept_one():
    p = _plane()
    keep = poisson_disk_thin(p, 1.0)
    d, _ = cKDTree(p[keep]).query(p, k=1)
    assert d.max() < 1.0


def test_keep_first_forces_points():
    p = np.array([[0.0, 0, 0], [0.1, 0, 0], [5.0, 0, 0], [5.2, 0, 0]])
    keep = poisson_disk_thin(p, 1.0, np.arange(4), keep_first=2)
    assert keep.tolist() == [True, True, True, False]


def test_sparse_grid_uses_hash_path():
    # points far apart on a huge bbox: the dense grid would be enormous
    p = np.array([[0.0, 0, 0], [1e6, 0, 0], [0, 1e6, 0], [0, 0, 1e6], [0.5, 0, 0]])
    keep = poisson_disk_thin(p, 1.0)
    assert keep.tolist() == [True, True, True, True, False]


def test_select_seeds_deterministic_for_a_seed():
    p = _plane()
    a = select_seeds(p, 1.0, np.random.default_rng(7))
    b = select_seeds(p, 1.0, np.random.default_rng(7))
    c = select_seeds(p, 1.0, np.random.default_rng(8))
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)
