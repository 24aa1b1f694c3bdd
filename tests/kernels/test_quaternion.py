"""Quaternion frames: normal extraction, rotation by the exponential map, frames from normals."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from recon.kernels.quaternion import (
    normals_from_quaternions,
    quaternion_multiply,
    quaternion_normal,
    quaternions_from_normals,
    rotate_quaternion,
)


def _scipy(q):
    """scipy uses (x, y, z, w)."""
    return Rotation.from_quat([q[1], q[2], q[3], q[0]])


def test_normal_is_third_column_of_rotation_matrix():
    rng = np.random.default_rng(0)
    q = rng.normal(size=(50, 4))
    q /= np.linalg.norm(q, axis=1)[:, None]
    expected = np.array([_scipy(row).as_matrix()[:, 2] for row in q])
    np.testing.assert_allclose(normals_from_quaternions(q), expected, atol=1e-14)
    for row, e in zip(q, expected, strict=True):
        np.testing.assert_allclose(quaternion_normal(*row), e, atol=1e-14)


def test_multiply_matches_scipy_composition():
    rng = np.random.default_rng(1)
    a, b = rng.normal(size=(2, 4))
    a /= np.linalg.norm(a)
    b /= np.linalg.norm(b)
    c = np.array(quaternion_multiply(*a, *b))
    np.testing.assert_allclose(
        _scipy(c).as_matrix(), (_scipy(a) * _scipy(b)).as_matrix(), atol=1e-14
    )


@pytest.mark.parametrize("angle", [0.0, 1e-12, 1e-6, 0.3, 2.5])
def test_rotation_by_world_vector(angle):
    rng = np.random.default_rng(2)
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    theta = angle * axis
    out = np.array(rotate_quaternion(*q, *theta))
    assert abs(np.linalg.norm(out) - 1.0) < 1e-15
    expected = (Rotation.from_rotvec(theta) * _scipy(q)).as_matrix()
    np.testing.assert_allclose(_scipy(out).as_matrix(), expected, atol=1e-13)
    # first order: the normal turns by theta x n
    n0 = np.array(quaternion_normal(*q))
    n1 = np.array(quaternion_normal(*out))
    np.testing.assert_allclose(n1, Rotation.from_rotvec(theta).apply(n0), atol=1e-13)


def test_frames_from_normals_round_trip_including_poles():
    rng = np.random.default_rng(3)
    n = rng.normal(size=(200, 3))
    n = np.vstack([n, [[0, 0, 1.0], [0, 0, -1.0], [1e-17, 0, -1.0], [0, 1e-9, -1.0]]])
    q = quaternions_from_normals(n)
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-15)
    np.testing.assert_allclose(
        normals_from_quaternions(q), n / np.linalg.norm(n, axis=1)[:, None], atol=1e-12
    )
    # deterministic
    np.testing.assert_array_equal(q, quaternions_from_normals(n))


def test_frames_from_normals_rejects_zero_vectors():
    with pytest.raises(ValueError, match="row 1"):
        quaternions_from_normals([[0, 0, 1.0], [0, 0, 0]])
