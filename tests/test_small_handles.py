"""Cutting small handles out of a mesh (recon.small_handles)."""

import numpy as np
import open3d as o3d
import pytest

from recon.intersections import self_intersections
from recon.kernels.mesh_tables import winding_consistent
from recon.mesh import boundary_loops, handle_count
from recon.small_handles import (
    SMALL_HANDLE_REACH,
    _rim_distance,
    cut_small_handles,
    without_small_handles,
)
from recon.triangulate import TriangulationResult
from tests.mesh_shapes import open_cylinder, sphere_with_tunnel, torus


def _o3d(v, f):
    m = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(v), o3d.utility.Vector3iVector(f))
    m.remove_unreferenced_vertices()
    return m


def test_a_tunnel_is_cut_and_the_sphere_comes_back_closed_and_manifold():
    v, f = sphere_with_tunnel()
    assert handle_count(f, len(v)) == (1, 0, 1)
    edge = float(np.median(np.linalg.norm(v[f[:, 0]] - v[f[:, 1]], axis=1)))
    cut, n = cut_small_handles(v, f, 3 * edge)
    assert n == 1
    assert handle_count(cut, len(v)) == (1, 0, 0)
    m = _o3d(v, cut)
    assert m.is_watertight() and m.is_vertex_manifold() and m.is_orientable()
    assert winding_consistent(cut, len(v))  # the patch is wound as the faces round it
    assert len(self_intersections(v, cut)) == 0
    # the patch replaced a small ball: most of the sphere is untouched
    assert len(cut) > 0.95 * len(f)


def test_without_small_handles_drops_the_cut_vertices_and_says_so():
    v, f = sphere_with_tunnel()
    n = v / np.linalg.norm(v, axis=1, keepdims=True)
    edge = float(np.median(np.linalg.norm(v[f[:, 0]] - v[f[:, 1]], axis=1)))
    result = TriangulationResult(v / edge, f, n, {"holes_filled": 0}, np.zeros(len(v), bool))
    out = without_small_handles(result)
    assert out.stats["small_handles_cut"] == 1 and out.stats["holes_filled"] == 0
    assert len(out.vertices) < len(v) and len(out.normals) == len(out.crease) == len(out.vertices)
    assert np.all(np.bincount(out.faces.ravel(), minlength=len(out.vertices)) > 0)
    assert handle_count(out.faces, len(out.vertices)) == (1, 0, 0)


def test_the_handle_of_a_ring_stays():
    # edges ~1 (r0): the tube's cycle is 19 long, the hole's 44
    v, f = torus(64, 20, 10.0, 3.0)
    result = TriangulationResult(v, f, v * 0 + [0.0, 0.0, 1.0], {})
    assert without_small_handles(result) is result
    assert cut_small_handles(v, f, SMALL_HANDLE_REACH)[1] == 0


def test_a_tunnel_seven_spacings_long_is_cut_at_the_default_reach():
    """Regression (held-out eared shape, 5,000 points, seed 0): the tunnel at an ear's base
    fitted in a geodesic ball of 5 r0, not of 3 r0, and was kept as a handle."""
    v, f = sphere_with_tunnel(gap=7.0)
    edge = float(np.median(np.linalg.norm(v[f[:, 0]] - v[f[:, 1]], axis=1)))
    assert cut_small_handles(v / edge, f, 3.0)[1] == 0  # wider than the old reach
    n = v / np.linalg.norm(v, axis=1, keepdims=True)
    out = without_small_handles(TriangulationResult(v / edge, f, n, {}, np.zeros(len(v), bool)))
    assert out.stats["small_handles_cut"] == 1
    assert handle_count(out.faces, len(out.vertices)) == (1, 0, 0)
    assert len(self_intersections(out.vertices, out.faces)) == 0


def _thin_ring():
    # a tube 1.26 round (5 edges of 0.25) on a ring 12.6 round (24 edges of 0.52): no ball
    # of radius 1 holds the handle, but one wraps round the tube
    return torus(24, 5, 2.0, 0.2)


def test_a_handle_is_cut_at_a_thin_stalk_only_when_the_tunnel_beside_it_is_short():
    """The held-out eared shape (5,000 points, seed 12): an ear joined to the head by two
    thin stalks, the window between them ~20 r0 round: no ball of 5 r0 holds that handle.
    A ball round one stalk is an annulus; cutting it there is right when the tunnel is no
    longer round than the largest hole hole-filling closes, and wrong on a true ring."""
    v, f = _thin_ring()
    assert handle_count(f, len(v)) == (1, 0, 1)
    assert cut_small_handles(v, f, 1.0)[1] == 0  # not a small handle
    assert cut_small_handles(v, f, 1.0, tunnel_perimeter=11.0)[1] == 0  # the ring is longer
    cut, n = cut_small_handles(v, f, 1.0, tunnel_perimeter=13.0)
    assert n == 1
    assert handle_count(cut, len(v)) == (1, 0, 0)
    m = _o3d(v, cut)
    assert m.is_watertight() and m.is_vertex_manifold() and m.is_orientable()
    assert winding_consistent(cut, len(v))
    assert len(self_intersections(v, cut)) == 0
    assert len(cut) > 0.9 * len(f)  # one stalk's ball went, not the ring


def test_the_path_between_two_rims_runs_along_the_mesh_up_to_a_limit():
    # the stalk test's measure: the two rims of a tube 6 long are 6 apart along it; past the
    # limit, or with no path at all (a stalk whose cut splits the mesh), the tunnel is "long"
    v, f = open_cylinder(6, 12)
    v = v * [0.2, 0.2, 6.0]
    loops = boundary_loops(f)
    assert len(loops) == 2
    assert _rim_distance(v, f, loops[0], loops[1], 7.0) == pytest.approx(6.0)
    assert _rim_distance(v, f, loops[0], loops[1], 5.0) == np.inf
    apart = np.vstack([f, f + len(v)])
    both = np.vstack([v, v + [5.0, 0.0, 0.0]])
    assert _rim_distance(both, apart, loops[0], loops[1] + len(v), 50.0) == np.inf


def _face_rows(faces: np.ndarray) -> set[tuple[int, ...]]:
    return set(map(tuple, np.sort(faces, axis=1).tolist()))


def test_a_cut_removes_only_the_editable_faces():
    """A tile of a tiled fit may cut a handle only where the faces are its own and away from
    its seams (``editable``); a ball that holds any other face is not cut."""
    v, f = sphere_with_tunnel()
    edge = float(np.median(np.linalg.norm(v[f[:, 0]] - v[f[:, 1]], axis=1)))
    x = v / edge
    centroid = x[f].mean(axis=1)
    tunnel = centroid[len(f) - 6 :].mean(axis=0)  # the tube's six faces come last
    near = np.linalg.norm(centroid - tunnel, axis=1) < 8.0
    assert cut_small_handles(x, f, 5.0, editable=~near)[1] == 0  # the tunnel is held
    assert cut_small_handles(x, f, 5.0, editable=np.zeros(len(f), bool))[1] == 0
    cut, n = cut_small_handles(x, f, 5.0, editable=near)
    assert n == 1 and handle_count(cut, len(v)) == (1, 0, 0)
    assert _face_rows(f[~near]) <= _face_rows(cut)  # every held face is still there
    m = _o3d(v, cut)
    assert m.is_watertight() and m.is_vertex_manifold()
    # with every face editable, the same cut as without the mask
    every = cut_small_handles(x, f, 5.0, editable=np.ones(len(f), bool))[0]
    assert np.array_equal(every, cut_small_handles(x, f, 5.0)[0])
