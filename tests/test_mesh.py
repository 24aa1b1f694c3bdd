"""recon.mesh: the helpers shared by mesh repair and the report."""

from __future__ import annotations

import numpy as np
import pytest
from mesh_shapes import icosphere, open_cylinder

from recon.kernels.mesh_tables import half_edge_order
from recon.mesh import (
    boundary_components,
    boundary_loops,
    count_edge_faces,
    face_area_vectors,
    face_components,
    face_normals,
    orientation_flips,
    ranked_fans,
    vertex_components,
    vertex_fans,
)
from recon.topology import mesh_topology


def test_loops_and_components_agree_on_a_manifold_boundary():
    v, f = open_cylinder(24, 5)
    loops = boundary_loops(f)
    assert len(loops) == 2 and all(len(lp) == 24 for lp in loops)
    assert boundary_components(*count_edge_faces(f), len(v)) == 2
    assert mesh_topology(v, f)["boundary_loops"] == 2


def test_figure_of_eight_is_one_component_but_no_simple_loop():
    # two triangles touching at vertex 0 (a bow-tie): repair sees no simple loop to fill,
    # the report counts one boundary component
    f = np.array([[0, 2, 1], [0, 3, 4]])
    assert boundary_loops(f) == []
    assert boundary_components(*count_edge_faces(f), 5) == 1


def test_ranked_fans_keep_a_bow_tie_vertex_for_its_largest_fan_then_the_lowest_label():
    # vertex 0: a lone face (the lowest fan label), a fan of two faces, another lone face
    f = np.array([[0, 1, 2], [0, 3, 4], [0, 4, 5], [0, 6, 7]])
    fan_vertex, corner_fan, rank = ranked_fans(f)
    # the fans are np.unique's rows of (vertex, fan label), the corners its inverse
    rows, inverse = np.unique(
        np.stack([f.ravel(), vertex_fans(f).ravel()], axis=1), axis=0, return_inverse=True
    )
    assert fan_vertex.tolist() == rows[:, 0].tolist()
    assert corner_fan.tolist() == inverse.reshape(-1).tolist()
    assert rank[corner_fan].reshape(-1, 3)[:, 0].tolist() == [1, 0, 0, 2]
    assert not rank[fan_vertex != 0].any()  # every other vertex has one fan
    assert [len(a) for a in ranked_fans(f[1:3])] == [4, 6, 4]  # 4 vertices, 6 corners
    assert not ranked_fans(f[1:3])[2].any()
    assert [len(a) for a in ranked_fans(np.zeros((0, 3), np.int64))] == [0, 0, 0]


def test_components_per_vertex_and_per_face():
    f = np.array([[0, 1, 2], [2, 3, 4], [5, 6, 7]])
    n, labels = vertex_components(f, 9)
    assert n == 2 and labels.tolist() == [0, 0, 0, 0, 0, 1, 1, 1, -1]
    n, face_labels = face_components(f, 9)
    assert n == 2 and face_labels.tolist() == [0, 0, 1]
    assert face_components(np.zeros((0, 3), int), 3)[0] == 0


def test_face_normals_are_unit_and_follow_the_winding():
    v, f = icosphere(1)
    n = face_normals(v, f)
    assert np.allclose(np.linalg.norm(n, axis=1), 1.0)
    centres = v[f].mean(axis=1)
    assert np.all(np.einsum("ij,ij->i", n, centres) > 0)  # outward on the icosphere
    area = face_area_vectors(v, f)
    assert np.allclose(n * np.linalg.norm(area, axis=1, keepdims=True), area)
    flat = face_normals(np.zeros((3, 3)), np.array([[0, 1, 2]]))
    assert flat.tolist() == [[0.0, 0.0, 0.0]]


def test_face_keys_are_equal_for_the_same_vertices_in_any_order_on_both_paths():
    from recon.mesh import FACE_KEY_LIMIT, face_keys

    f = np.array([[0, 1, 2], [2, 0, 1], [1, 0, 2], [0, 1, 3], [3, 2, 1]])
    for n in (4, FACE_KEY_LIMIT):  # one int64 per face, and the sorted rows above the limit
        k = face_keys(f, n)
        assert k.ndim == (1 if n < FACE_KEY_LIMIT else 2)
        same = [[bool(np.all(k[i] == k[j])) for j in range(len(f))] for i in range(len(f))]
        assert same[0][:3] == [True, True, True] and not any(same[0][3:])
        assert not same[3][4]


@pytest.mark.parametrize("n_vertices", [30, "limit"])
def test_first_faces_keeps_the_first_of_each_vertex_set_on_both_key_paths(n_vertices):
    """Above FACE_KEY_LIMIT vertices the rows are ordered by two int64 keys (np.unique of the
    rows took 10.7 s on 5.3M faces); both paths keep what a scan in face order keeps."""
    from recon.mesh import FACE_KEY_LIMIT, first_faces

    n = FACE_KEY_LIMIT if n_vertices == "limit" else n_vertices
    rng = np.random.default_rng(7)
    faces = rng.integers(0, 30, (400, 3)) * (1 if n == 30 else 66_000)  # spread over 2M
    faces = np.vstack([faces, faces[rng.integers(0, 400, 150)][:, [2, 0, 1]]])
    faces = faces[rng.permutation(len(faces))]
    seen, expected = set(), []
    for i, f in enumerate(faces.tolist()):
        if tuple(sorted(f)) not in seen:
            seen.add(tuple(sorted(f)))
            expected.append(i)
    assert first_faces(faces, n).tolist() == expected


def test_first_faces_takes_no_faces_and_int32_faces_past_the_limit():
    """Regression (a second read): past FACE_KEY_LIMIT, no faces raised an IndexError, and
    int32 faces wrapped the two-vertex key, so a face sharing its last two vertices with
    another one was dropped as a duplicate."""
    from recon.mesh import FACE_KEY_LIMIT, first_faces
    from recon.triangulate import remove_non_manifold_faces

    assert first_faces(np.zeros((0, 3), dtype=np.int64), FACE_KEY_LIMIT).tolist() == []
    assert len(remove_non_manifold_faces(np.array([[5, 5, 6]]), FACE_KEY_LIMIT)) == 0
    faces = np.array([[0, 3000, 3001], [2048, 3000, 3001]], dtype=np.int32)
    assert first_faces(faces, 2**21).tolist() == [0, 1]


def test_orientation_flips_take_the_callers_sort_of_the_half_edges():
    v, f = open_cylinder(12, 4)
    f = f.copy()
    f[::3] = f[::3, ::-1]  # orientable, not consistently wound
    flip, conflict = orientation_flips(f)
    assert flip.any() and not conflict.any()
    given = orientation_flips(f, order=half_edge_order(f, len(v)), consistent=False)
    assert np.array_equal(given[0], flip) and np.array_equal(given[1], conflict)
    assert not orientation_flips(f, consistent=True)[0].any()  # taken at its word


def test_count_edge_faces_matches_a_row_unique_of_the_face_edges():
    """The counting-sort path gives np.unique(rows)'s sorted edges and counts, skipping faces
    with a repeated vertex (random meshes with degenerate and repeated faces, and none)."""
    rng = np.random.default_rng(3)
    for _ in range(50):
        n = int(rng.integers(3, 40))
        f = rng.integers(0, n, (int(rng.integers(0, 60)), 3))
        keep = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 2] != f[:, 0])]
        a, b = keep.ravel(), np.roll(keep, -1, axis=1).ravel()
        pairs = np.stack([np.minimum(a, b), np.maximum(a, b)], axis=1).reshape(-1, 2)
        want, want_counts = np.unique(pairs, axis=0, return_counts=True)
        edges, counts = count_edge_faces(f)
        assert edges.dtype == np.int64 and counts.dtype == np.int64
        np.testing.assert_array_equal(edges, want.reshape(-1, 2))
        np.testing.assert_array_equal(counts, want_counts)


def test_runs_of_equal_gives_each_run_in_the_stable_order():
    from recon.mesh import runs_of_equal

    keys = np.array([4, 1, 4, 4, 2, 1])
    order, start, count = runs_of_equal(keys)
    assert order.tolist() == [1, 5, 4, 0, 2, 3]  # equal keys keep their input order
    assert start.tolist() == [0, 2, 3] and count.tolist() == [2, 1, 3]
    empty = runs_of_equal(np.zeros(0, dtype=np.int64))
    assert [len(a) for a in empty] == [0, 0, 0]
