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


def test_polish_and_untangle_keeps_the_mesh_that_crosses_least(monkeypatch):
    """The choice itself, with the polish and untangling replaced by stand-ins that mark
    which mesh they saw: the polished mesh where nothing crosses; on crossings, the held
    retry or the unpolished mesh, whichever leaves fewer, the polished ones on a tie; the
    stats say which was kept and how many vertices were held."""
    import recon.polish as polish_module

    v, f = grid(6, 6)
    base = TriangulationResult(v, f, np.tile([0.0, 0.0, 1.0], (len(v), 1)))
    held_seen = []

    def fake_polish(result, surface, rounds, flips=True, fixed=None):
        tag = 1.0 if fixed is None else 2.0
        if fixed is not None:
            held_seen.append(int(np.count_nonzero(fixed)))
        return TriangulationResult(result.vertices + [0.0, 0.0, tag], result.faces, result.normals)

    def run(left_by_tag):
        def fake_untangle(vertices, faces, fixed=None):
            return vertices, 5, left_by_tag[float(vertices[0, 2])]

        monkeypatch.setattr(polish_module, "polish", fake_polish)
        monkeypatch.setattr(polish_module, "untangle", fake_untangle)
        monkeypatch.setattr(
            polish_module, "self_intersections", lambda vertices, faces: np.array([[0, 1]])
        )
        mesh, found, left = polish_module.polish_and_untangle(base, None, 2)
        return mesh.stats["polish_kept"], mesh.stats["polish_held"], left

    assert run({1.0: 0, 2.0: 0, 0.0: 0}) == ("polished", 0, 0)
    assert not held_seen  # no retry where nothing crosses
    kept, held, left = run({1.0: 3, 2.0: 1, 0.0: 2})
    assert (kept, left) == ("held", 1) and held == held_seen[-1] > 6  # 2 rings round 2 faces
    assert run({1.0: 3, 2.0: 2, 0.0: 0})[::2] == ("unpolished", 0)
    assert run({1.0: 1, 2.0: 1, 0.0: 1})[::2] == ("polished", 1)  # a tie: the polished


def test_polish_and_untangle_cuts_small_handles_only_when_asked():
    """The untiled fit cuts a tunnel a few spacings across after the polish; a tile (which
    must keep its vertices: tests/test_tiling.py) asks it not to."""
    import recon.polish as polish_module
    from recon.mesh import handle_count
    from tests.mesh_shapes import sphere_with_tunnel

    v, f = sphere_with_tunnel()
    edge = float(np.median(np.linalg.norm(v[f[:, 0]] - v[f[:, 1]], axis=1)))
    v = v / edge  # the mesh in spacings, as a fit's particle mesh is in r0
    mesh = TriangulationResult(v, f, v / np.linalg.norm(v, axis=1, keepdims=True), {})
    cut, _, _ = polish_module.polish_and_untangle(mesh, None, 0)
    kept, _, _ = polish_module.polish_and_untangle(mesh, None, 0, cut_handles=False)
    assert handle_count(cut.faces, len(cut.vertices))[2] == 0
    assert cut.stats["small_handles_cut"] == 1
    assert len(kept.vertices) == len(v) and np.array_equal(kept.faces, f)
    assert handle_count(kept.faces, len(kept.vertices))[2] == 1


def test_the_polish_moves_no_vertex_farther_than_its_reach():
    """Regression (a sphere with 5 % outliers; many copies of one point): the polish carried
    vertices beside a face hanging off a stray particle, or onto a degenerate local quadric,
    hundreds to billions of edge lengths away; now no vertex goes farther than POLISH_REACH
    median edge lengths from its particle."""
    from recon.intersections import median_edge
    from recon.polish import POLISH_REACH

    v, f = grid(8, 8)
    far = 4 * 9 + 4  # an interior vertex, held far off in the plane
    v[far] = [50.0, 50.0, 0.0]
    normals = np.tile([0.0, 0.0, 1.0], (len(v), 1))
    held = np.zeros(len(v), bool)
    held[far] = True
    res = polish(TriangulationResult(v, f, normals), None, 2, flips=False, fixed=held)
    moved = np.linalg.norm(res.vertices - v, axis=1)
    assert moved.max() <= POLISH_REACH * median_edge(v, f) * (1 + 1e-12)
    assert moved.max() > 0.1  # the neighbours of the far vertex did move, up to the reach
