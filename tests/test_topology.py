"""Hand-checkable cases for recon.topology (counts verifiable on paper)."""

from __future__ import annotations

import numpy as np
import pytest
from mesh_shapes import grid, icosphere, mobius, open_cylinder, tetrahedron, torus

from recon.errors import InputError
from recon.topology import mesh_topology, topology_and_quality, triangle_quality, validate_mesh

TRIANGLE = (np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float), np.array([[0, 1, 2]]))


def test_single_triangle():
    t = mesh_topology(*TRIANGLE)
    assert t["n_vertices"] == 3 and t["n_faces"] == 1 and t["n_edges"] == 3
    assert t["boundary_edges"] == 3
    assert t["boundary_loops"] == 1
    assert t["components"] == 1
    assert t["euler_characteristic"] == 1
    assert t["watertight"] is False
    assert t["genus"] is None
    assert t["non_manifold_edges"] == 0 and t["non_manifold_vertices"] == 0


def test_tetrahedron_is_closed_genus_0():
    t = mesh_topology(*tetrahedron())
    assert t["watertight"] is True
    assert t["consistently_oriented"] is True and t["orientable"] is True
    assert t["euler_characteristic"] == 2
    assert t["genus"] == 0
    assert t["n_edges"] == 6 and t["boundary_edges"] == 0 and t["boundary_loops"] == 0


def test_icosphere_genus_0():
    t = mesh_topology(*icosphere(2))
    assert (t["watertight"], t["genus"], t["euler_characteristic"]) == (True, 0, 2)


def test_torus_grid_genus_1():
    t = mesh_topology(*torus(16, 8))
    assert t["watertight"] is True
    assert t["euler_characteristic"] == 0
    assert t["genus"] == 1
    assert t["components"] == 1


def test_two_tori_and_a_sphere_sum_genus():
    v1, f1 = torus(12, 6)
    v2, f2 = torus(12, 6)
    v3, f3 = tetrahedron()
    v = np.concatenate([v1, v2 + 5, v3 - 5])
    f = np.concatenate([f1, f2 + len(v1), f3 + len(v1) + len(v2)])
    t = mesh_topology(v, f)
    assert t["components"] == 3
    assert t["genus"] == 2
    assert t["euler_characteristic"] == 0 + 0 + 2


def test_non_manifold_edge():
    # Two triangles share edge 0-1 as a proper strip; a third triangle hangs off the same edge.
    v = np.array([[0, 0, 0], [1, 0, 0], [0.5, 1, 0], [0.5, -1, 0], [0.5, 0, 1]], float)
    f = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]])
    t = mesh_topology(v, f)
    assert t["non_manifold_edges"] == 1
    assert t["boundary_edges"] == 6
    assert t["watertight"] is False
    assert t["non_manifold_vertices"] == 0  # its ends are reported through the edge


def test_bow_tie_non_manifold_vertex():
    v = np.array([[0, 0, 0], [1, 1, 0], [1, -1, 0], [-1, 1, 0], [-1, -1, 0]], float)
    f = np.array([[0, 2, 1], [0, 3, 4]])
    t = mesh_topology(v, f)
    assert t["non_manifold_vertices"] == 1
    assert t["non_manifold_edges"] == 0
    assert t["components"] == 1  # vertex-connected
    assert t["boundary_edges"] == 6
    assert t["boundary_loops"] == 1  # one figure-of-eight walk


def test_open_cylinder_has_two_loops():
    v, f = open_cylinder(24, 5)
    t = mesh_topology(v, f)
    assert t["boundary_loops"] == 2
    assert t["boundary_edges"] == 48
    assert t["euler_characteristic"] == 0
    assert t["non_manifold_vertices"] == 0
    assert t["genus"] is None


def test_grid_is_a_disk():
    t = mesh_topology(*grid(5, 4))
    assert (t["boundary_loops"], t["boundary_edges"], t["euler_characteristic"]) == (1, 18, 1)


def test_inconsistent_orientation_is_detected_and_orientable():
    v, f = icosphere(1)
    f = f.copy()
    f[[3, 17]] = f[[3, 17]][:, ::-1]
    t = mesh_topology(v, f)
    assert t["consistently_oriented"] is False
    assert t["orientable"] is True
    assert t["watertight"] is True and t["genus"] == 0


def test_mobius_strip_is_not_orientable():
    t = mesh_topology(*mobius(24))
    assert t["orientable"] is False
    assert t["consistently_oriented"] is False
    assert t["boundary_loops"] == 1
    assert t["euler_characteristic"] == 0


def test_degenerate_duplicate_and_unreferenced():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0], [9, 9, 9]], float)
    f = np.array([[0, 1, 2], [0, 1, 3], [0, 0, 2], [2, 1, 0]])  # collinear, repeated, duplicate
    t = mesh_topology(v, f)
    assert t["degenerate_faces"] == 2
    assert t["duplicate_faces"] == 1
    assert t["unreferenced_vertices"] == 1


def test_empty_mesh():
    t = mesh_topology(np.zeros((4, 3)), np.zeros((0, 3), int))
    assert t["n_faces"] == 0 and t["components"] == 0 and t["unreferenced_vertices"] == 4
    assert triangle_quality(np.zeros((4, 3)), np.zeros((0, 3), int))["n_measured"] == 0


def test_equilateral_triangle_quality():
    v = np.array([[0, 0, 0], [2, 0, 0], [1, 3**0.5, 0]])
    q = triangle_quality(v, [[0, 1, 2]])
    assert q["min_angle_mean_deg"] == pytest.approx(60.0)
    assert q["min_angle_p5_deg"] == pytest.approx(60.0)
    assert q["max_angle_max_deg"] == pytest.approx(60.0)
    assert q["aspect_ratio_max"] == pytest.approx(1.0)
    assert q["edge_length_mean"] == pytest.approx(2.0)
    assert q["edge_length_cv"] == pytest.approx(0.0, abs=1e-12)


def test_right_isoceles_triangle_quality():
    q = triangle_quality(*TRIANGLE)
    assert q["min_angle_min_deg"] == pytest.approx(45.0)
    assert q["max_angle_max_deg"] == pytest.approx(90.0)
    # R = sqrt(2)/2, r = (2 - sqrt(2))/2 -> R / 2r = 1 / (2 (sqrt(2) - 1))
    assert q["aspect_ratio_max"] == pytest.approx(1 / (2 * (2**0.5 - 1)))


def test_degenerate_faces_are_skipped_by_quality():
    v = np.array([[0, 0, 0], [2, 0, 0], [1, 3**0.5, 0], [4, 0, 0]])
    q = triangle_quality(v, [[0, 1, 2], [0, 1, 3]])
    assert q["n_measured"] == 1 and q["min_angle_min_deg"] == pytest.approx(60.0)


@pytest.mark.parametrize(
    ("vertices", "faces", "match"),
    [
        (np.zeros((3, 2)), [[0, 1, 2]], r"shape \(V, 3\)"),
        (np.zeros((3, 3)), [[0, 1, 2, 0]], r"shape \(F, 3\)"),
        (np.zeros((3, 3)), [[0, 1, 3]], r"\[0, 3\)"),
        (np.full((3, 3), np.nan), [[0, 1, 2]], "non-finite"),
        (np.zeros((3, 3)), [[0, 1, 1.5]], "integer"),
    ],
)
def test_bad_input_names_expected_and_received(vertices, faces, match):
    with pytest.raises(InputError, match=match):
        validate_mesh(vertices, faces)


@pytest.mark.parametrize("seed", [0, 1])
def test_random_flips_keep_orientability(seed):
    rng = np.random.default_rng(seed)
    for (v, f), orientable in ((torus(20, 10), True), (mobius(30), False)):
        f = f.copy()
        flip = rng.random(len(f)) < 0.3
        f[flip] = f[flip][:, ::-1]
        t = mesh_topology(v, f[rng.permutation(len(f))])
        assert t["orientable"] is orientable
        assert t["consistently_oriented"] is False


def test_pinched_closed_surfaces_are_not_watertight():
    # two tetrahedra sharing one vertex: every edge has two faces, but the shared vertex has
    # two fans, so the standard definition (and Open3D's is_vertex_manifold) says no
    v = np.array(
        [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [-1, 0, 0], [0, -1, 0], [0, 0, -1]], float
    )
    f = np.array(
        [[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2], [0, 4, 5], [0, 6, 4], [4, 6, 5], [0, 5, 6]]
    )
    t = mesh_topology(v, f)
    assert t["boundary_edges"] == 0 and t["non_manifold_edges"] == 0
    assert t["non_manifold_vertices"] == 1
    assert t["watertight"] is False and t["genus"] is None


@pytest.mark.parametrize("shape", [tetrahedron, lambda: icosphere(2), lambda: grid(4, 3)])
def test_topology_and_quality_is_both_measures(shape):
    v, f = shape()
    f = np.vstack([f, f[:1], [[0, 0, 1]]])  # a duplicate and a repeated-index face
    topo, quality = topology_and_quality(v, f)
    assert topo == mesh_topology(v, f)
    assert quality == triangle_quality(v, f)
    assert topo["duplicate_faces"] == 1 and topo["degenerate_faces"] == 1


@pytest.mark.parametrize("scale", [1e-90, 1e-30, 2.0**-40, 1e30, 1e160])
def test_measures_do_not_depend_on_the_units(scale):
    """Regression: a mesh 1e-90 across had its squared areas underflow, every face counted
    degenerate and no angle measured (``fit`` then crashed formatting None). Angles, ratios
    and counts are the same at any scale; lengths scale with it."""
    v, f = icosphere(2)
    topo, qual = topology_and_quality(v, f)
    topo_s, qual_s = topology_and_quality(v * scale, f)
    for key in ("min_angle_mean_deg", "min_angle_min_deg", "aspect_ratio_max", "n_measured"):
        assert qual_s[key] == pytest.approx(qual[key], rel=1e-12), key
    assert qual_s["edge_length_mean"] == pytest.approx(qual["edge_length_mean"] * scale, rel=1e-12)
    assert topo_s == topo
    assert triangle_quality(v * scale, f) == qual_s
    assert mesh_topology(v * scale, f) == topo_s
    # lengths of a mesh with a hole scale with it
    g, gf = grid(4, 4)
    assert mesh_topology(g * scale, gf)["largest_hole_perimeter"] == pytest.approx(
        mesh_topology(g, gf)["largest_hole_perimeter"] * scale, rel=1e-12
    )
