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


def test_the_polish_leaves_no_crossing_the_unpolished_mesh_does_not_have():
    """Regression: the held-out knife (an ellipsoidal blade whose edge thins to nothing, 40,000
    points, scan seed 2, fit seed 0): the polish's moves left 4 crossing face pairs near the
    blade's edge that untangling did not clear, where the unpolished mesh had none."""
    import recon
    from benchmarks.bench_thin_parts import make_scan
    from recon.intersections import self_intersections

    points, _, _ = make_scan("knife", 40_000, 0.0005, 2)
    res = recon.fit(points)
    assert len(self_intersections(res.mesh.vertices, res.mesh.faces)) == 0
    assert res.report.topology.watertight
