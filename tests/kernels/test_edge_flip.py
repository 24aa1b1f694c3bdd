"""recon.kernels.edge_flip: angle-raising flips keep the connectivity's topology."""

import numpy as np

from recon.remesh.improve import flip_edges, twin_half_edges
from recon.topology import mesh_topology, triangle_quality
from tests.mesh_shapes import grid


def _thin_quad():
    # a flat rhombus split along its long diagonal: two slivers; the short one is Delaunay
    v = np.array([[0, 0, 0], [4, 0, 0], [2, 0.5, 0], [2, -0.5, 0]], float)
    f = np.array([[0, 1, 2], [1, 0, 3]])
    return v, f


def test_flip_replaces_the_long_diagonal():
    v, f = _thin_quad()
    out, n = flip_edges(v, f)
    assert n == 1
    assert sorted(map(sorted, out.tolist())) == [[0, 2, 3], [1, 2, 3]]
    # winding kept: both faces still face +z
    n_out = np.cross(v[out[:, 1]] - v[out[:, 0]], v[out[:, 2]] - v[out[:, 0]])
    assert np.all(n_out[:, 2] > 0)


def test_locked_edge_and_folded_pair_are_not_flipped():
    v, f = _thin_quad()
    assert flip_edges(v, f, np.array([[1, 0]]))[1] == 0  # the diagonal is a feature line
    folded = v.copy()
    folded[3, 2] = 1.5  # the pair is bent by ~70 degrees: flipping would cut across the bend
    assert flip_edges(folded, f)[1] == 0


def test_flips_raise_the_worst_angle_and_keep_topology():
    v, f = grid(8, 8)
    rng = np.random.default_rng(1)
    v[:, :2] += rng.uniform(-0.04, 0.04, size=(len(v), 2)) * ((v[:, :2] > 0) & (v[:, :2] < 1)).all(
        axis=1, keepdims=True
    )
    v[:, 0] *= 3.0  # stretched: many diagonals are the long ones
    out, n = flip_edges(v, f)
    assert n > 0
    before, after = mesh_topology(v, f), mesh_topology(v, out)
    for key in ("n_faces", "n_edges", "boundary_loops", "euler_characteristic", "components"):
        assert before[key] == after[key]
    assert after["non_manifold_edges"] == 0 and after["consistently_oriented"]
    assert (
        triangle_quality(v, out)["min_angle_min_deg"] > triangle_quality(v, f)["min_angle_min_deg"]
    )
    twin = twin_half_edges(out, len(v))
    inner = np.flatnonzero(twin >= 0)
    assert np.array_equal(twin[twin[inner]], inner)  # twins pair up


def test_a_missing_feature_edge_is_recovered_by_a_flip():
    # the pair is bent (no angle flip would be made), but (2, 3) is a feature line: flipped
    v, f = _thin_quad()
    v = v.copy()
    v[[2, 3], 2] = -1.0
    assert flip_edges(v, f)[1] == 0
    out, n = flip_edges(v, f, np.array([[3, 2]]))
    assert n == 1 and sorted(map(sorted, out.tolist())) == [[0, 2, 3], [1, 2, 3]]


def _valence_deviation(faces, n):
    twin = twin_half_edges(faces, n)
    val = np.bincount(faces.ravel(), minlength=n)
    target = np.full(n, 6)
    boundary = faces.ravel()[twin < 0]
    val[boundary] += 1  # faces around a boundary vertex are one fewer than its edges
    target[boundary] = 4
    used = np.bincount(faces.ravel(), minlength=n) > 0
    return int(np.sum(((val - target) ** 2)[used]))


def test_valence_flips_lower_the_valence_deviation_without_slivers():
    # a grid with alternating diagonals has valence 4 and 8 vertices; flips can make it 6
    v, f = grid(8, 8)
    f = f.copy()
    n = len(f) // 2
    idx = np.arange(n)
    cells = idx[(idx // 8 + idx % 8) % 2 == 1]  # the other diagonal in every other cell
    a, b, c = f[cells].T
    d = f[n + cells, 2]
    f[cells] = np.stack([a, b, d], axis=1)
    f[n + cells] = np.stack([b, c, d], axis=1)
    before = _valence_deviation(f, len(v))
    angle_only, _ = flip_edges(v, f)
    out, k = flip_edges(v, f, valence_min_angle=30.0)
    assert k > 0
    assert _valence_deviation(out, len(v)) < min(before, _valence_deviation(angle_only, len(v)))
    assert triangle_quality(v, out)["min_angle_min_deg"] >= 30.0 - 1e-9
    t0, t1 = mesh_topology(v, f), mesh_topology(v, out)
    assert t1["euler_characteristic"] == t0["euler_characteristic"]
    assert t1["non_manifold_edges"] == 0 and t1["consistently_oriented"]


def test_a_kept_flipper_matches_fresh_flips_round_after_round():
    # the twins and locks the kernel updates in place must equal those rebuilt from scratch
    from recon.remesh.improve import EdgeFlipper

    v, f = grid(10, 10)
    rng = np.random.default_rng(4)
    inner = ((v[:, :2] > 0) & (v[:, :2] < 1)).all(axis=1)
    lines = np.array([[0, 1], [1, 2]])
    kept = EdgeFlipper(len(v), f, lines)
    fresh = f.copy()
    total = 0
    for _ in range(4):
        v[inner, :2] += rng.uniform(-0.03, 0.03, size=(int(inner.sum()), 2))
        n = kept.flip(v, 30.0)
        fresh, m = flip_edges(v, fresh, lines, 30.0)
        assert n == m
        total += n
        np.testing.assert_array_equal(kept.faces, fresh)
        np.testing.assert_array_equal(kept.twin, twin_half_edges(fresh, len(v)))
    assert total > 0


def test_neighbour_centroids_count_each_shared_face():
    from scipy import sparse

    from recon.remesh.improve import neighbour_centroids

    v, f = grid(5, 4)
    v = v + np.random.default_rng(0).normal(scale=0.01, size=v.shape)
    e = f[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    rows, cols = np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]]
    adj = sparse.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(len(v), len(v)))
    want = (adj @ v) / np.asarray(adj.sum(axis=1))
    np.testing.assert_allclose(neighbour_centroids(v, f), want, rtol=0, atol=1e-14)
