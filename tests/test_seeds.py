import numpy as np
import pytest
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


# ------------------------------------------------------------------- coincident after projection

OCTAHEDRON = np.array(
    [[1.0, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], dtype=np.float64
)


def test_seeds_that_coincide_after_projection_are_dropped_keeping_the_first(caplog):
    """Regression: on an octahedron every PCA normal is the same axis (the neighbourhoods,
    all six points, have an isotropic covariance), the local surface of every point is the
    plane through the centre, and the two points on that axis both projected to the centre:
    two seed particles at one place, and the dynamics diverged with a message blaming
    duplicate points in the input."""
    import logging

    from recon.seeds import seed_particles
    from recon.surface import DataSurface

    normals = np.tile([1.0, 0.0, 0.0], (6, 1))
    surface = DataSurface.build(OCTAHEDRON, normals, k=20)
    idx = select_seeds(surface.points, 1.0, np.random.default_rng(0))
    pos, _, _ = surface.project(surface.points[idx], surface.normals[idx])
    assert cKDTree(pos).query(pos, k=2)[0][:, 1].min() < 1e-9  # the defect: two at one place
    with caplog.at_level(logging.WARNING, logger="recon.seeds"):
        got, got_pos, got_nrm = seed_particles(surface, 1.0, np.random.default_rng(0))
    first = {tuple(np.round(p, 9)): i for i, p in reversed(list(zip(idx, pos, strict=True)))}
    assert sorted(got.tolist()) == sorted(first.values())  # the first of each place kept
    assert len(got) == 5 and cKDTree(got_pos).query(got_pos, k=2)[0][:, 1].min() > 0.5
    np.testing.assert_array_equal(
        got_nrm, surface.project(surface.points[got], surface.normals[got])[1]
    )
    assert "1 of 6 seed particles" in caplog.text and "too few points" in caplog.text


def test_seed_particles_are_select_seeds_projected_on_ordinary_data():
    """Nothing is dropped, and nothing changes, where the projection moves the seeds by less
    than half the spacing: the check costs nothing on ordinary data."""
    from recon.seeds import seed_particles
    from recon.surface import DataSurface

    rng = np.random.default_rng(3)
    p = rng.normal(size=(3000, 3))
    p = 8.0 * p / np.linalg.norm(p, axis=1, keepdims=True)
    p += rng.normal(scale=0.05, size=p.shape)
    surface = DataSurface.build(p, p / np.linalg.norm(p, axis=1, keepdims=True), k=20)
    idx = select_seeds(surface.points, 1.0, np.random.default_rng(5))
    pos, nrm, _ = surface.project(surface.points[idx], surface.normals[idx])
    got, got_pos, got_nrm = seed_particles(surface, 1.0, np.random.default_rng(5))
    np.testing.assert_array_equal(got, idx)
    np.testing.assert_array_equal(got_pos, pos)
    np.testing.assert_array_equal(got_nrm, nrm)


def test_distinct_seeds_keeps_the_first_of_each_place():
    from recon.seeds import distinct_seeds

    pos = np.array([[0.0, 0, 0], [3, 0, 0], [0, 0, 1e-7], [3, 0, 0], [0, 0, 0], [6, 0, 0]])
    offsets = np.array([0.6, 0.6, 0.6, 0.0, 0.0, 0.0])  # each pair has a member that moved
    assert distinct_seeds(pos, offsets, 1.0).tolist() == [True, True, False, False, False, True]
    assert distinct_seeds(pos[:2], np.zeros(2), 1.0).tolist() == [True, True]


_PHI = (1 + 5**0.5) / 2
TINY_SYMMETRIC = {
    "octahedron": OCTAHEDRON,
    "cube": np.array([[x, y, z] for x in (0.0, 1) for y in (0.0, 1) for z in (0.0, 1)]),
    "icosahedron": np.array(
        [p for a in (-1, 1) for b in (-_PHI, _PHI) for p in ([0, a, b], [a, b, 0], [b, 0, a])],
        dtype=np.float64,
    ),
}


@pytest.mark.parametrize("name", sorted(TINY_SYMMETRIC))
def test_tiny_symmetric_inputs_fit_a_mesh(name):
    """Regression: a cube's 8 corners, an octahedron, an icosahedron stopped with a
    DivergenceError blaming duplicate points (two seeds projected to one place)."""
    import recon

    result = recon.fit(TINY_SYMMETRIC[name])
    assert len(result.mesh.faces) > 0
