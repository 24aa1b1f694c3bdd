"""The topology guarantee after triangulation, checked by an independent implementation.

Small bundled fits at defaults: our report's topology must agree with Open3D's
``is_edge_manifold`` / ``is_vertex_manifold`` / ``is_watertight`` (Open3D also rejects
self-intersections, so ``is_watertight`` may only be stricter), closed shapes come out
watertight and outward, and a real boundary survives hole filling.
"""

from pathlib import Path

import numpy as np
import open3d as o3d
import pytest

from recon.config import ReconConfig
from recon.fitting import reconstruct
from recon.intersections import self_intersections
from recon.io import read_points
from recon.mesh import face_area_vectors

SAMPLE = Path(__file__).resolve().parent.parent / "sample_data"


@pytest.fixture(scope="module")
def fits():
    out = {}
    for name in ("sphere-sparse", "bunny-sparse", "square_hole-sparse"):
        out[name] = reconstruct(read_points(SAMPLE / f"{name}.ply"), ReconConfig())
    return out


def _open3d(mesh):
    return o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(mesh.vertices),
        o3d.utility.Vector3iVector(mesh.faces.astype(np.int32)),
    )


@pytest.mark.parametrize("name", ["sphere-sparse", "bunny-sparse", "square_hole-sparse"])
def test_report_agrees_with_open3d(fits, name):
    res = fits[name]
    topo = res.report.topology
    m = _open3d(res.mesh)
    assert m.is_vertex_manifold() == (topo.non_manifold_vertices == 0)
    assert m.is_edge_manifold(allow_boundary_edges=True) == (topo.non_manifold_edges == 0)
    assert m.is_edge_manifold(allow_boundary_edges=False) == (
        topo.non_manifold_edges == 0 and topo.boundary_edges == 0
    )
    if m.is_watertight():
        assert topo.watertight
    # the guarantee: never a non-manifold edge or vertex, always one winding, no crossing
    assert topo.non_manifold_edges == 0 and topo.non_manifold_vertices == 0
    assert topo.consistently_oriented
    assert res.report.triangulation.self_intersections_left == 0
    assert len(self_intersections(res.mesh.vertices, res.mesh.faces)) == 0


def test_closed_sparse_sphere_is_watertight_for_open3d_and_outward(fits):
    res = fits["sphere-sparse"]
    topo = res.report.topology
    assert topo.watertight and topo.genus == 0 and topo.components == 1
    assert _open3d(res.mesh).is_watertight()
    # outward: positive signed volume
    v, f = res.mesh.vertices - res.mesh.vertices.mean(axis=0), res.mesh.faces
    assert np.einsum("ij,ij->", v[f[:, 0]], face_area_vectors(v, f)) > 0
    assert res.report.topology.largest_hole_r0 == 0.0


def test_closed_sparse_bunny_is_watertight_with_genus_0(fits):
    """bunny-sparse (2,000 points): the slits at an ear tip and at the bottom, narrow seams
    whose inside the coverage test at r0 (about one point spacing here) missed, are closed."""
    res = fits["bunny-sparse"]
    topo = res.report.topology
    assert topo.watertight and topo.genus == 0 and topo.components == 1
    assert _open3d(res.mesh).is_watertight()


def test_hole_filling_keeps_the_real_boundary_of_a_sparse_square(fits):
    topo = fits["square_hole-sparse"].report.topology
    assert topo.boundary_loops == 2  # the outer rim and the real hole
    # the largest remaining hole is the outer rim: far wider than max_gap, in r0
    assert topo.largest_hole_r0 > 10


@pytest.mark.parametrize("seed", [0, 1])
def test_thin_wedge_comes_out_closed_with_genus_0(seed):
    """A closed prism with a 30 deg knife edge (bench_machined's held-out ``wedge``, 10,000
    points). Near the tip both faces lie within one neighbourhood: particles there carried
    the other face's normal, or a plain dot product turned them over (the faces' normals are
    150 deg apart), and ball pivoting bridged the two faces: a hole (seed 0) or a handle,
    genus 1 (seed 1). Particle signs now come from reflected dot products, and faces joining
    opposed sheets are dropped where that removes a handle."""
    from mesh_shapes import thin_wedge

    from recon.io import cloud_from_arrays
    from recon.metrics import sample_surface

    v, f = thin_wedge()
    pts, _ = sample_surface(v, f, 10_000, seed=seed)
    res = reconstruct(cloud_from_arrays(pts), ReconConfig())
    topo = res.report.topology
    assert topo.watertight and topo.components == 1 and topo.genus == 0
    m = _open3d(res.mesh)
    assert m.is_vertex_manifold() and m.is_edge_manifold(allow_boundary_edges=False)
