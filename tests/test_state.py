"""ParticleState: struct of arrays, amortised growth, removal, pinning, copies."""

from __future__ import annotations

import numpy as np
import pytest

from recon.state import ParticleState


def _points(k, offset=0.0):
    p = np.zeros((k, 3))
    p[:, 0] = np.arange(k) + offset
    return p


def _normals(k):
    rng = np.random.default_rng(k)
    n = rng.normal(size=(k, 3))
    return n / np.linalg.norm(n, axis=1)[:, None]


def test_from_points_shapes_dtypes_and_normals():
    n = _normals(5)
    s = ParticleState.from_points(_points(5), n, pinned=True)
    assert s.n == len(s) == 5
    assert s.position.shape == (5, 3) and s.position.dtype == np.float64
    assert s.orientation.shape == (5, 4)
    assert s.velocity.shape == s.angular_velocity.shape == (5, 3)
    assert s.is_pinned.dtype == np.bool_ and s.is_pinned.all()
    assert s.is_oriented.all()
    np.testing.assert_array_equal(s.mass, 1.0)
    np.testing.assert_array_equal(s.inertia, 1.0)
    np.testing.assert_allclose(s.normal, n, atol=1e-14)
    np.testing.assert_allclose(np.linalg.norm(s.orientation, axis=1), 1.0, atol=1e-15)


def test_add_returns_indices_and_growth_is_amortised():
    s = ParticleState(capacity=0)
    reallocations = 0
    capacity = s.capacity
    for k in range(2000):
        idx = s.add(_points(1, k), [[0.0, 0.0, 1.0]])
        assert idx.tolist() == [k]
        if s.capacity != capacity:
            reallocations += 1
            capacity = s.capacity
    assert s.n == 2000
    # geometric growth: O(log n) reallocations, not O(n)
    assert reallocations <= 20
    np.testing.assert_array_equal(s.position[:, 0], np.arange(2000))


def test_add_without_normals_gives_unoriented_particles():
    s = ParticleState.from_points(_points(3), _normals(3))
    idx = s.add(_points(2, 10), None, pinned=[True, False])
    assert idx.tolist() == [3, 4]
    assert s.is_oriented.tolist() == [True, True, True, False, False]
    assert s.is_pinned.tolist() == [False, False, False, True, False]


def test_remove_compacts_in_order():
    s = ParticleState.from_points(_points(6), _normals(6))
    s.velocity[:] = np.arange(18).reshape(6, 3)
    normals = s.normal
    keep = np.array([True, False, True, True, False, True])
    s.remove(keep)
    assert s.n == 4
    np.testing.assert_array_equal(s.position[:, 0], [0, 2, 3, 5])
    np.testing.assert_array_equal(s.velocity, np.arange(18).reshape(6, 3)[keep])
    np.testing.assert_allclose(s.normal, normals[keep])
    with pytest.raises(ValueError, match="boolean mask of shape"):
        s.remove(np.ones(3, dtype=bool))


def test_set_pinned_stops_particles_and_accepts_masks():
    s = ParticleState.from_points(_points(4), _normals(4))
    s.velocity[:] = 1.0
    s.angular_velocity[:] = 1.0
    s.set_pinned(np.array([True, False, True, False]))
    assert s.is_pinned.tolist() == [True, False, True, False]
    np.testing.assert_array_equal(s.velocity[[0, 2]], 0.0)
    np.testing.assert_array_equal(s.velocity[[1, 3]], 1.0)
    s.set_pinned(False)
    assert not s.is_pinned.any()


def test_copy_is_independent():
    s = ParticleState.from_points(_points(3), _normals(3))
    c = s.copy()
    c.position[0, 0] = 99.0
    c.add(_points(1), [[0.0, 0.0, 1.0]])
    assert s.position[0, 0] == 0.0 and s.n == 3 and c.n == 4


def test_reorder_permutes_every_array():
    s = ParticleState.from_points(_points(4), _normals(4), pinned=[True, False, False, False])
    normals = s.normal
    s.reorder(np.array([3, 0, 2, 1]))
    np.testing.assert_array_equal(s.position[:, 0], [3, 0, 2, 1])
    assert s.is_pinned.tolist() == [False, True, False, False]
    np.testing.assert_allclose(s.normal, normals[[3, 0, 2, 1]])


@pytest.mark.parametrize(
    "order",
    [[0, 0, 2, 1], [0, 1, 2, 4], [-1, 0, 1, 2], [0, 1, 2], [0.0, 1.0, 2.0, 3.0], [[0, 1, 2, 3]]],
    ids=["repeated", "past the end", "negative", "short", "float", "2-D"],
)
def test_reorder_rejects_what_is_not_a_permutation(order):
    s = ParticleState.from_points(_points(4), _normals(4))
    before = s.position.copy()
    with pytest.raises(ValueError, match="expected a permutation of 4 indices"):
        s.reorder(np.array(order))
    np.testing.assert_array_equal(s.position, before)


def test_reorder_of_no_particles_is_allowed():
    s = ParticleState.from_points(np.zeros((0, 3)), None)
    s.reorder(np.zeros(0, dtype=np.int64))
    assert s.n == 0


def test_input_validation_names_the_problem():
    with pytest.raises(ValueError, match=r"positions: expected shape \(n, 3\)"):
        ParticleState.from_points(np.zeros((3, 2)), None)
    with pytest.raises(ValueError, match="normals: expected 3 rows"):
        ParticleState.from_points(np.zeros((3, 3)), np.ones((2, 3)))
    with pytest.raises(ValueError, match="not finite"):
        ParticleState.from_points([[0.0, np.nan, 0.0]], None)
    with pytest.raises(ValueError, match="zero"):
        ParticleState.from_points(np.zeros((1, 3)), np.zeros((1, 3)))
