"""recon.remesh: closest points, feature lines, constraints, topology, bad input."""

import numpy as np
import pytest

from recon.errors import InputError
from recon.io import read_mesh
from recon.remesh import RemeshOptions, remesh
from recon.remesh.mesh_check import check_mesh
from recon.remesh.surface import MeshSurface, closest_on_triangles, feature_lines
from recon.topology import mesh_topology
from tests.mesh_shapes import grid, icosphere, mobius, torus

SAMPLE = "sample_data/lblock-gt.ply"


def square_with_hole(n_around: int = 48, n_radial: int = 6, hole: float = 0.2):
    """Unit square centred at 0 in z = 0 with a circular hole: 2 boundary loops, 4 corners.

    Rings run from the hole's circle to the square's outline at the same angle, so the
    triangles are stretched (a badly shaped input)."""
    theta = np.linspace(0, 2 * np.pi, n_around, endpoint=False)
    c, s = np.cos(theta), np.sin(theta)
    outer = 0.5 * np.stack([c, s], 1) / np.maximum(np.abs(c), np.abs(s))[:, None]
    inner = hole * np.stack([c, s], 1)
    t = np.linspace(0, 1, n_radial)
    xy = inner[:, None] + t[None, :, None] * (outer - inner)[:, None]
    v = np.concatenate([xy.reshape(-1, 2), np.zeros((n_around * n_radial, 1))], axis=1)
    i, j = np.meshgrid(np.arange(n_around), np.arange(n_radial - 1), indexing="ij")
    i, j = i.ravel(), j.ravel()
    i1 = (i + 1) % n_around
    a, b, cc, d = i * n_radial + j, i1 * n_radial + j, i1 * n_radial + j + 1, i * n_radial + j + 1
    f = np.concatenate([np.stack([a, b, cc], 1), np.stack([a, cc, d], 1)])
    return v, f.astype(np.int64)


def _brute_closest(p, v, f):
    best = np.full(len(p), np.inf)
    out = np.zeros_like(p)
    for tri in v[f]:
        foot = closest_on_triangles(p, np.broadcast_to(tri, (len(p), 3, 3)), p)
        d = np.linalg.norm(foot - p, axis=1)
        better = d < best
        best[better], out[better] = d[better], foot[better]
    return out, best


def test_closest_point_projection_is_exact():
    v, f = icosphere(1)
    rng = np.random.default_rng(0)
    p = rng.normal(size=(300, 3)) * 0.8
    foot, face, normal = MeshSurface(v, f).closest(p)
    ref, dist = _brute_closest(p, v, f)
    np.testing.assert_allclose(np.linalg.norm(foot - p, axis=1), dist, atol=1e-6)
    np.testing.assert_allclose(foot, ref, atol=1e-5)
    # the foot lies on the face reported, and the normal is that face's unit normal
    tri = v[f[face]]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    np.testing.assert_allclose(np.einsum("ij,ij->i", foot - tri[:, 0], n), 0, atol=1e-12)
    np.testing.assert_allclose(normal, n)


def test_closest_on_triangle_regions():
    tri = np.array([[[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]] * 4)
    p = np.array([[0.2, 0.2, 1.0], [-1, -1, 0], [0.5, -2, 3], [2, 2, 0]])
    foot = closest_on_triangles(p, tri, p)
    np.testing.assert_allclose(foot, [[0.2, 0.2, 0], [0, 0, 0], [0.5, 0, 0], [0.5, 0.5, 0]])


def test_feature_lines_of_a_square_and_a_block():
    v, f = grid(4, 4)
    lines = feature_lines(v, f, None, 50.0)
    assert lines.n_boundary_edges == 16 and lines.n_crease_edges == 0
    assert sorted(map(tuple, v[lines.corners][:, :2].tolist())) == [(0, 0), (0, 1), (1, 0), (1, 1)]
    assert len(lines.chains) == 4 and lines.chain_is_boundary.all()
    # a closed mesh without crease angle has no lines; with one, the L block's 18 crease lines
    vb, fb = read_mesh(SAMPLE)
    assert feature_lines(vb, fb, None, 50.0).empty
    block = feature_lines(vb, fb, 40.0, 40.0)
    assert len(block.corners) == 12 and len(block.chains) == 18
    assert block.n_boundary_edges == 0


def test_feature_line_projection_stays_on_its_own_line():
    v, f = grid(4, 4)
    lines = feature_lines(v, f, None, 50.0)
    p = np.array([[0.5, -0.2, 0.3], [0.5, 0.3, 0.0]])
    bottom = [i for i, c in enumerate(lines.chains) if np.allclose(v[c][:, 1], 0)][0]
    left = [i for i, c in enumerate(lines.chains) if np.allclose(v[c][:, 0], 0)][0]
    out = lines.project(p, np.array([bottom, left]))
    np.testing.assert_allclose(out, [[0.5, 0, 0], [0, 0.3, 0]], atol=1e-12)


def _on_segments(points, seg):
    a, b = seg[None, :, 0], seg[None, :, 1]
    d = b - a
    t = np.clip(
        np.einsum("psk,psk->ps", points[:, None] - a, d) / np.einsum("psk,psk->ps", d, d), 0, 1
    )
    foot = a + t[..., None] * d
    return np.linalg.norm(foot - points[:, None], axis=2).min(axis=1)


def test_square_with_hole_keeps_boundaries_corners_and_topology():
    v, f = square_with_hole()
    r = remesh(v, f, RemeshOptions(spacing=0.05))
    out_v, out_f = r.vertices, r.faces
    topo = mesh_topology(out_v, out_f)
    assert r.report["topology_preserved"]
    assert topo["boundary_loops"] == 2 and topo["components"] == 1
    assert topo["non_manifold_edges"] == 0
    np.testing.assert_allclose(out_v[:, 2], 0, atol=1e-12)  # on the (planar) input
    # every boundary vertex lies on the input's boundary polylines, and the corners are kept
    lines = feature_lines(v, f, None, 50.0)
    edges = np.sort(out_f[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    uniq, cnt = np.unique(edges, axis=0, return_counts=True)
    bverts = np.unique(uniq[cnt == 1])
    assert _on_segments(out_v[bverts], lines.segments).max() < 1e-9
    for corner in ([0.5, 0.5, 0], [-0.5, 0.5, 0], [0.5, -0.5, 0], [-0.5, -0.5, 0]):
        assert np.linalg.norm(out_v - corner, axis=1).min() < 1e-12
    q = r.report["output"]["triangle_quality"]
    assert q["min_angle_mean_deg"] > r.report["input"]["triangle_quality"]["min_angle_mean_deg"]


def test_torus_keeps_its_genus_and_faces_hits_the_target():
    v, f = torus(48, 16)
    r = remesh(v, f, RemeshOptions(faces=1500))
    topo = mesh_topology(r.vertices, r.faces)
    assert topo["genus"] == 1 and topo["watertight"] and r.report["topology_preserved"]
    assert abs(len(r.faces) - 1500) <= 0.05 * 1500
    d = r.report["distance"]
    assert d["hausdorff95_relative"] < 0.01


def test_crease_vertices_stay_on_crease_lines_and_corners_are_kept():
    v, f = read_mesh(SAMPLE)
    r = remesh(v, f, RemeshOptions(crease_angle=40.0, spacing=0.08))
    lines = feature_lines(v, f, 40.0, 40.0)
    for corner in v[lines.corners]:
        assert np.linalg.norm(r.vertices - corner, axis=1).min() < 1e-9
    # vertices within 1 % of the spacing of a crease line sit exactly on it (they slid on it)
    d = _on_segments(r.vertices, lines.segments)
    near = d < 0.0008
    assert (
        near.sum() >= 0.5 * sum(lines.chain_length(v, i) for i in range(len(lines.chains))) / 0.08
    )
    assert d[near].max() < 1e-9
    assert r.report["topology_preserved"]


def test_same_seed_same_mesh():
    v, f = torus(32, 12)
    a = remesh(v, f, RemeshOptions(seed=3))
    b = remesh(v, f, RemeshOptions(seed=3))
    np.testing.assert_array_equal(a.faces, b.faces)
    np.testing.assert_array_equal(a.vertices, b.vertices)


def test_bad_input_is_refused_with_the_defect_named():
    v, f = icosphere(1)
    with pytest.raises(InputError, match="no faces"):
        check_mesh(v, np.zeros((0, 3), dtype=np.int64), "cloud.ply")
    with pytest.raises(InputError, match="empty"):
        check_mesh(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64), "e.ply")
    # three faces on one edge
    vn = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1]], float)
    fn = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]])
    with pytest.raises(InputError, match="nm.ply: non-manifold"):
        check_mesh(vn, fn, "nm.ply")
    vm, fm = mobius()
    with pytest.raises(InputError, match="not orientable"):
        check_mesh(vm, fm, "m.ply")
    # a sphere pierced by a triangle
    spike = np.array([[0, 0, 0.0], [2, 0.1, 0], [2, -0.1, 0.05]])
    vs = np.vstack([v, spike])
    fs = np.vstack([f, [[len(v), len(v) + 1, len(v) + 2]]])
    with pytest.raises(InputError, match="s.ply: self-intersecting"):
        check_mesh(vs, fs, "s.ply")


def test_repairable_defects_are_repaired_and_listed():
    v, f = grid(6, 6)
    # duplicate every vertex of the second half of the faces, and add a degenerate face
    v2 = np.vstack([v, v])
    f2 = f.copy()
    f2[len(f) // 2 :] += len(v)
    f2 = np.vstack([f2, [[0, 0, 1]]])
    checked = check_mesh(v2, f2, "g.ply")
    text = " ".join(checked.repairs)
    assert "merged" in text and "degenerate" in text
    assert len(checked.vertices) == len(v)
    topo = mesh_topology(checked.vertices, checked.faces)
    assert topo["boundary_loops"] == 1 and topo["components"] == 1
    # inconsistent winding is re-wound
    f3 = f.copy()
    f3[::3] = f3[::3, ::-1]
    checked = check_mesh(v, f3, "w.ply", intersections=False)
    assert any("re-wound" in r for r in checked.repairs)
    assert mesh_topology(checked.vertices, checked.faces)["consistently_oriented"]


def test_area_samples_lie_on_their_faces():
    v, f = icosphere(1)
    s = MeshSurface(v, f)
    p, face = s.sample(500, np.random.default_rng(0))
    tri = v[f[face]]
    foot = closest_on_triangles(p, tri, p)
    np.testing.assert_allclose(foot, p, atol=1e-12)
    assert len(np.unique(face)) > 0.8 * len(f)


def test_adaptive_spacing_is_finer_where_curved_and_graded():
    from recon.remesh.pipeline import GRADATION, grade, spacing_field

    v, f = icosphere(3)
    v = v * [1.0, 1.0, 0.3]  # an oblate ellipsoid: curved rim, flat poles
    s = MeshSurface(v, f)
    h = spacing_field(s, 0.1, 0.02, 0.5)
    rim = np.abs(v[:, 2]) < 0.05
    poles = np.abs(v[:, 2]) > 0.28
    assert h[rim].max() < h[poles].min()
    assert h.min() >= 0.02 - 1e-12 and h.max() <= 0.5 + 1e-12
    e = np.unique(np.sort(f[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1), axis=0)
    length = np.linalg.norm(v[e[:, 0]] - v[e[:, 1]], axis=1)
    assert np.all(np.abs(h[e[:, 0]] - h[e[:, 1]]) <= GRADATION * length + 1e-12)
    raw = np.linspace(0.1, 1.0, len(v))
    graded = grade(raw, v, e, 0.5)
    assert np.all(graded <= raw) and np.any(graded < raw)


def test_adaptive_remesh_uses_fewer_faces_on_flat_parts():
    v, f = icosphere(3)
    v = v * [1.0, 1.0, 0.3]
    uniform = remesh(v, f, RemeshOptions(spacing=0.08))
    adaptive = remesh(v, f, RemeshOptions(spacing=0.08, adaptive=True))
    assert adaptive.report["topology_preserved"] and uniform.report["topology_preserved"]
    assert len(adaptive.faces) < 0.8 * len(uniform.faces)
    lo, hi = adaptive.report["spacing_range"]
    assert lo < hi


def test_topology_preserved_compares_components_loops_and_euler():
    from recon.remesh.pipeline import topology_preserved

    base = {
        "components": 1,
        "boundary_loops": 2,
        "euler_characteristic": 0,
        "non_manifold_edges": 0,
        "non_manifold_vertices": 0,
    }
    assert topology_preserved(base, dict(base))
    for key, value in (
        ("components", 2),
        ("boundary_loops", 1),
        ("euler_characteristic", -2),
        ("non_manifold_edges", 1),
    ):
        assert not topology_preserved(base, {**base, key: value})


def test_adaptive_with_a_face_budget_hits_it():
    v, f = icosphere(3)
    v = v * [1.0, 1.0, 0.3]
    r = remesh(v, f, RemeshOptions(faces=800, adaptive=True))
    assert abs(len(r.faces) - 800) <= 40


def test_every_component_is_kept_even_a_small_one():
    v1, f1 = torus(32, 12)
    v2, f2 = icosphere(2, 0.15)
    v = np.vstack([v1, v2 + [3.0, 0.0, 0.0]])
    f = np.vstack([f1, f2 + len(v1)])
    r = remesh(v, f, RemeshOptions(spacing=0.08))
    topo = mesh_topology(r.vertices, r.faces)
    assert topo["components"] == 2 and topo["genus"] == 1 and topo["watertight"]
    assert r.report["topology_preserved"]


def test_bow_tie_input_is_split_not_refused_as_self_intersecting():
    # two tetrahedra sharing one vertex: a bow-tie, repaired by one copy per fan (the copies
    # coincide, so the crossing test must run before the split)
    t_v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float)
    t_f = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    v = np.vstack([t_v, -t_v[1:]])
    f = np.vstack([t_f, np.where(t_f == 0, 0, t_f + 3)[:, ::-1]])
    checked = check_mesh(v, f, "bowtie.ply")
    assert any("bow-tie" in r for r in checked.repairs)
    assert len(checked.vertices) == len(v) + 1


def test_crossing_pairs_from_edges_agree_with_the_face_pair_search():
    from recon.intersections import self_intersections
    from recon.remesh.mesh_check import crossing_pairs
    from recon.remesh.surface import edge_faces

    # two overlapping spheres cross along a circle; a third apart crosses nothing
    v1, f1 = icosphere(2)
    rot = np.array([[0.8, -0.6, 0.0], [0.6, 0.8, 0.0], [0.0, 0.0, 1.0]])
    v = np.vstack([v1, v1 @ rot.T + [0.7, 0.3, 0.1], v1 + [5.0, 0.0, 0.0]])
    f = np.vstack([f1, f1 + len(v1), f1 + 2 * len(v1)])
    edges, _, f0, f1e = edge_faces(f, len(v))
    got = crossing_pairs(v, f, edges, f0, f1e)
    want = self_intersections(v, f)
    assert len(want) > 20
    assert {tuple(p) for p in got.tolist()} == {tuple(p) for p in want.tolist()}
    assert not np.isin(got, np.arange(2 * len(f1), 3 * len(f1))).any()
    # a sphere alone: none
    e1, _, a0, a1 = edge_faces(f1, len(v1))
    assert len(crossing_pairs(v1, f1, e1, a0, a1)) == 0


def test_absolute_curvature_of_a_sphere_and_a_cylinder():
    from recon.remesh.pipeline import absolute_curvature

    v, f = icosphere(5)
    v = 2.0 * v
    k = absolute_curvature(v, MeshSurface(v, f).vertex_normal, 0.3)
    np.testing.assert_allclose(k, 2 * 0.5, rtol=0.02)  # two principal curvatures 1/R
    th, z = np.meshgrid(np.linspace(0, 2 * np.pi, 200, endpoint=False), np.linspace(0, 3, 120))
    p = np.stack([0.5 * np.cos(th), 0.5 * np.sin(th), z], -1).reshape(-1, 3)
    n = np.stack([np.cos(th), np.sin(th), 0 * th], -1).reshape(-1, 3)
    mid = (p[:, 2] > 0.5) & (p[:, 2] < 2.5)
    k = absolute_curvature(p, n, 0.2)
    np.testing.assert_allclose(k[mid], 1 / 0.5, rtol=0.05)  # one principal curvature 1/r
    # noise finer than the reach does not count: a noisy plane stays near flat
    rng = np.random.default_rng(0)
    q = np.c_[rng.uniform(0, 10, (4000, 2)), 0.005 * rng.standard_normal(4000)]
    inner = (q[:, :2] > 1).all(1) & (q[:, :2] < 9).all(1)
    k = absolute_curvature(q, np.tile([0.0, 0.0, 1.0], (len(q), 1)), 1.0)
    assert np.median(k[inner]) < 0.1


def test_relax_returns_the_particles_in_the_order_given():
    # relax sorts by grid cell internally; corners are matched to the input's by their order
    from recon.remesh.relax import place_feature_particles, relax, seed

    v, f = square_with_hole()
    s = MeshSurface(v / 0.1, f)
    lines = feature_lines(s.vertices, f, None, 50.0)
    p0 = seed(s, place_feature_particles(s, lines, None), 60, None, np.random.default_rng(0))
    p1 = relax(s, lines, p0, 10, None)
    np.testing.assert_array_equal(p1.kind, p0.kind)
    np.testing.assert_array_equal(p1.chain, p0.chain)
    corners = p0.kind == 2
    np.testing.assert_array_equal(p1.position[corners], p0.position[corners])
    assert np.linalg.norm(p1.position - p0.position, axis=1).max() < 1.0


def test_remesh_trusts_the_input_orientation_and_guesses_nothing(caplog):
    # the particles take their normals from the oriented input faces; re-signing them as if
    # they came from a point cloud cost ~10 % of the time and logged a "guess" about them
    v, f = icosphere(3)
    with caplog.at_level("INFO"):
        r = remesh(v, f, RemeshOptions(spacing=0.15))
    assert not [m for m in caplog.messages if "guess" in m]
    centroid = r.vertices[r.faces].mean(axis=1)
    a, b, c = (r.vertices[r.faces[:, i]] for i in range(3))
    assert np.all(np.einsum("ij,ij->i", np.cross(b - a, c - a), centroid) > 0)
