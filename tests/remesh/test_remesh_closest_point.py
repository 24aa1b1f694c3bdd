"""The cell grid over triangles (recon.kernels.closest_point) gives the exact closest point."""

import numpy as np

from recon.kernels.closest_point import closest_points_kernel, triangle_grid_build
from recon.remesh.surface import MeshSurface, closest_on_triangles
from tests.mesh_shapes import icosphere
from tests.test_remesh import _brute_closest as _brute


def _mixed_mesh():
    """A fine icosphere, one large triangle far across it and one degenerate (a segment)."""
    v, f = icosphere(3)
    big = np.array([[-3.0, -3.0, 1.5], [3.0, -2.0, 1.2], [0.0, 3.0, 2.5]])
    seg = np.array([[2.0, 2.0, -2.0], [2.5, 2.0, -2.0], [3.0, 2.0, -2.0]])
    n = len(v)
    v = np.vstack([v, big, seg])
    f = np.vstack([f, [[n, n + 1, n + 2], [n + 3, n + 4, n + 5]]])
    return v, f


def test_grid_closest_points_match_brute_force_at_every_distance():
    v, f = _mixed_mesh()
    rng = np.random.default_rng(1)
    # near the sphere, near the big triangle, near the segment, and far away
    p = np.vstack(
        [
            rng.normal(size=(200, 3)) * 0.02 + icosphere(3)[0][rng.integers(0, 600, 200)],
            rng.uniform(-3, 3, size=(100, 3)) * [1, 1, 0.2] + [0, 0, 1.8],
            rng.normal(size=(50, 3)) * 0.3 + [2.5, 2.0, -2.0],
            rng.normal(size=(100, 3)) * 10.0,
        ]
    )
    ref, dist = _brute(p, v, f)
    for cell in (0.05, 0.3, 2.0):
        grid = triangle_grid_build(v, f, cell)
        foot = np.full((len(p), 3), np.nan)
        face = np.full(len(p), -1)
        ok = np.zeros(len(p), dtype=bool)
        closest_points_kernel(p, grid, cell, 10_000, foot, face, ok)
        assert ok.all()
        np.testing.assert_allclose(np.linalg.norm(foot - p, axis=1), dist, rtol=0, atol=1e-12)
        # the foot lies on the face reported
        on = closest_on_triangles(foot, v[f[face]], foot)
        np.testing.assert_allclose(on, foot, atol=1e-12)


def test_far_queries_are_flagged_not_guessed():
    v, f = icosphere(2)
    cell = 0.1
    grid = triangle_grid_build(v, f, cell)
    p = np.array([[0.0, 0.0, 1.0 + 0.01], [0.0, 0.0, 5.0]])  # near, far (40 cells away)
    foot = np.zeros((2, 3))
    face = np.zeros(2, dtype=np.int64)
    ok = np.zeros(2, dtype=bool)
    closest_points_kernel(p, grid, cell, 2, foot, face, ok)
    assert ok.tolist() == [True, False]


def test_mesh_surface_answers_far_points_too():
    v, f = _mixed_mesh()
    rng = np.random.default_rng(2)
    p = rng.normal(size=(300, 3)) * 5.0
    foot, face, normal = MeshSurface(v, f).closest(p)
    _, dist = _brute(p, v, f)
    # far points go to Embree (float32, refined in float64 on the face it found)
    np.testing.assert_allclose(np.linalg.norm(foot - p, axis=1), dist, atol=1e-5)
