"""Tangent frames and the angular-gap support test (recon.kernels.local_surface)."""

import numba
import numpy as np
import pytest

from recon.kernels.local_surface import max_angular_gap_kernel, tangent_frame_xyz


def _normals(n, seed=0):
    rng = np.random.default_rng(seed)
    v = rng.normal(size=(n, 3))
    v[:5] = [[1, 0, 0], [-1, 0, 0], [0.95, 0.3, 0.1], [0, 0, 1], [0.9, -0.43589, 0]]
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def test_tangent_frame_is_orthonormal_and_right_handed():
    for n in _normals(300):
        u0, u1, u2, v0, v1, v2 = tangent_frame_xyz(n[0], n[1], n[2])
        u, v = np.array([u0, u1, u2]), np.array([v0, v1, v2])
        assert abs(u @ n) < 1e-12 and abs(v @ n) < 1e-12 and abs(u @ v) < 1e-12
        assert np.linalg.norm(u) == pytest.approx(1.0, abs=1e-12)
        np.testing.assert_allclose(np.cross(n, u), v, atol=1e-15)
        # u is the x axis in the tangent plane, or the y axis near x (then u has no x part
        # beyond the projection)
        axis = np.array([1.0, 0, 0]) if abs(n[0]) < 0.9 else np.array([0.0, 1, 0])
        assert u @ axis > 0.0


def _ring(centre, normal, count, radius=1.0, missing=()):
    u0, u1, u2, v0, v1, v2 = tangent_frame_xyz(*normal)
    u, v = np.array([u0, u1, u2]), np.array([v0, v1, v2])
    th = 2 * np.pi * np.arange(count) / count
    keep = np.setdiff1d(np.arange(count), missing)
    return centre + radius * (np.cos(th[keep, None]) * u + np.sin(th[keep, None]) * v)


def test_angular_gap_of_rings_half_rings_and_too_few_points():
    n = np.array([0.0, 0.6, 0.8])
    c = np.array([1.0, 2.0, 3.0])
    full = _ring(c, n, 8)
    half = _ring(c, n, 8, missing=[5, 6, 7])  # 5 of 8 directions: a gap of 4 steps
    few = _ring(c, n, 8)[:2]
    points = np.vstack([full, half, few])
    idx = np.zeros((3, 8), dtype=np.int64)
    idx[0], idx[1, :5], idx[2, :2] = np.arange(8), 8 + np.arange(5), 13 + np.arange(2)
    centres, normals = np.tile(c, (3, 1)), np.tile(n, (3, 1))
    gap = max_angular_gap_kernel(centres, normals, points, idx, np.array([8, 5, 2]))
    np.testing.assert_allclose(gap, [np.pi / 4, np.pi, 2 * np.pi], atol=1e-12)


@pytest.mark.skipif(numba.config.DISABLE_JIT, reason="thread counts need the JIT")
def test_angular_gap_is_the_same_for_any_thread_count():
    rng = np.random.default_rng(3)
    m, k = 4000, 24
    centres = rng.uniform(0, 5, (m, 3))
    points = rng.uniform(-1, 6, (3000, 3))
    idx = rng.integers(0, len(points), (m, k))
    count = rng.integers(0, k + 1, m)
    normals = _normals(m, 4)
    before = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        one = max_angular_gap_kernel(centres, normals, points, idx, count)
        numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
        many = max_angular_gap_kernel(centres, normals, points, idx, count)
    finally:
        numba.set_num_threads(before)
    assert np.array_equal(one, many)
