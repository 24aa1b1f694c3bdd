"""recon.polish: the fit's flips and tangential smoothing after triangulation (the fits
themselves: tests/test_pipeline.py)."""

import numpy as np

from recon.polish import polish
from recon.triangulate import TriangulationResult
from tests.mesh_shapes import grid


def test_polish_without_a_surface_moves_in_the_tangent_planes_only():
    v, f = grid(8, 8)
    rng = np.random.default_rng(3)
    v[:, :2] += rng.uniform(-0.02, 0.02, size=(len(v), 2))
    normals = np.tile([0.0, 0.0, 1.0], (len(v), 1))
    held = np.zeros(len(v), bool)
    held[:5] = True
    res = polish(TriangulationResult(v, f, normals), None, 2, flips=False, fixed=held)
    np.testing.assert_array_equal(res.faces, f)
    np.testing.assert_array_equal(res.vertices[:5], v[:5])
    assert np.all(res.vertices[:, 2] == 0.0)
    rim = (np.min(v[:, :2], axis=1) < 0.05) | (np.max(v[:, :2], axis=1) > 0.95)
    np.testing.assert_array_equal(res.vertices[rim], v[rim])  # boundary vertices stay
    assert np.abs(res.vertices - v).max() > 1e-3
