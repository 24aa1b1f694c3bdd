"""recon.kernels.mesh_tables: the counting-sort tables equal the NumPy/SciPy ones they replace."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import sparse
from scipy.sparse import csgraph

from recon.kernels.mesh_tables import (
    ATAN_ERROR,
    area_vectors,
    bounding_spheres,
    circumradii,
    edge_table,
    fan_labels,
    fast_atan2,
    half_edge_order,
    half_edge_winding,
    overlap_candidates,
    vertex_component_labels,
    winding_and_open,
    winding_consistent,
)
from recon.mesh import face_normals
from tests.mesh_shapes import grid


def _sheet(seed: int, n: int = 5, extra: int = 6) -> tuple[np.ndarray, np.ndarray]:
    """A jittered n x n grid sheet with random diagonals, some faces flipped and a few random
    extra faces (over-shared edges, bow-ties, overlaps), shuffled."""
    r = np.random.default_rng(seed)
    xs, ys = np.meshgrid(np.arange(n), np.arange(n))
    v = np.stack([xs.ravel(), ys.ravel(), np.zeros(n * n)], axis=1).astype(float)
    v += 0.2 * r.normal(size=v.shape)
    f = []
    for i in range(n - 1):
        for j in range(n - 1):
            a, b, c, d = i * n + j, i * n + j + 1, (i + 1) * n + j, (i + 1) * n + j + 1
            f += [[a, b, d], [a, d, c]] if r.random() < 0.5 else [[a, b, c], [b, d, c]]
    f = np.array(f)
    # two more faces on the first face's edge (over-shared), apart from its corners
    far = [x for x in (0, n - 1, n * n - n, n * n - 1) if x not in f[0]][:2]
    fins = [[f[0, 0], f[0, 1], far[0]], [f[0, 1], f[0, 0], far[1]]]
    f = np.vstack([f, fins, r.integers(0, n * n, size=(extra, 3))])
    f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])]
    flip = r.random(len(f)) < 0.2
    f[flip] = f[flip][:, ::-1]
    return v, np.ascontiguousarray(f[r.permutation(len(f))], dtype=np.int64)


def _half_edges(f: np.ndarray):
    a, b = f.ravel(), np.roll(f, -1, axis=1).ravel()
    return np.minimum(a, b), np.maximum(a, b), np.repeat(np.arange(len(f)), 3), a < b


@pytest.mark.parametrize("seed", range(4))
def test_half_edge_order_and_edge_table_equal_lexsort_and_unique(seed):
    v, f = _sheet(seed)
    lo, hi, face, _ = _half_edges(f)
    assert np.array_equal(half_edge_order(f, len(v)), np.lexsort((face, hi, lo)))
    keys, inverse, counts = edge_table(f, len(v))
    ref = np.unique(lo * len(v) + hi, return_inverse=True, return_counts=True)
    for got, want in zip((keys, inverse, counts), ref, strict=True):
        assert np.array_equal(got, want)
    assert counts.max() > 2  # the extra faces made over-shared edges: the test sees them


def test_half_edge_order_around_a_vertex_of_many_faces_equals_lexsort():
    """A shuffled fan of 3,000 faces round vertex 0 (a cone's tip, a disk meshed from its
    centre): one bucket of 6,000 half-edges, which a per-bucket insertion sort took quadratic
    time over; the two counting sorts give lexsort's permutation in linear time."""
    n = 3000
    ring = np.arange(1, n + 1)
    f = np.column_stack([np.zeros(n, dtype=np.int64), ring, np.roll(ring, -1)])
    f = np.ascontiguousarray(f[np.random.default_rng(5).permutation(n)], dtype=np.int64)
    lo, hi, face, _ = _half_edges(f)
    assert np.array_equal(half_edge_order(f, n + 1), np.lexsort((face, hi, lo)))


def _reference_fans(f: np.ndarray) -> np.ndarray:
    """The corner-graph components of the NumPy/SciPy ``vertex_fans`` this kernel replaced."""
    lo, hi, face, forward = _half_edges(f)
    corner = np.tile(np.arange(3), len(f))
    order = np.lexsort((face, hi, lo))
    same = (lo[order][1:] == lo[order][:-1]) & (hi[order][1:] == hi[order][:-1])
    a, b = order[:-1][same], order[1:][same]
    c_here, c_next = face * 3 + corner, face * 3 + (corner + 1) % 3
    w_lo, w_hi = np.where(forward, c_here, c_next), np.where(forward, c_next, c_here)
    rows, cols = np.concatenate([w_lo[a], w_hi[a]]), np.concatenate([w_lo[b], w_hi[b]])
    graph = sparse.coo_matrix((np.ones(len(rows)), (rows, cols)), (3 * len(f),) * 2)
    return csgraph.connected_components(graph, directed=False)[1]


@pytest.mark.parametrize("seed", range(4))
def test_fan_labels_equal_the_corner_graph_components(seed):
    v, f = _sheet(seed)
    labels = fan_labels(f, half_edge_order(f, len(v)))
    assert np.array_equal(labels, _reference_fans(f))
    # the extra faces made bow-ties: more fans than used vertices
    assert labels.max() + 1 > len(np.unique(f))


def test_a_pinch_between_two_closed_fans_is_two_fans():
    # two tetrahedra sharing vertex 0 only: vertex 0 has two closed fans
    f = np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]])
    f = np.vstack([f, np.where(f == 0, 0, f + 3)])
    labels = fan_labels(f, half_edge_order(f, 7)).reshape(-1, 3)
    assert len(np.unique(labels[f == 0])) == 2


def test_fast_atan2_is_within_its_error():
    r = np.random.default_rng(3)
    y, x = r.normal(size=(2, 400))
    y[:5], x[3:8] = 0.0, 0.0
    got = np.array([fast_atan2(a, b) for a, b in zip(y, x, strict=True)])
    err = np.abs(got - np.arctan2(y, x))
    err = np.minimum(err, 2 * np.pi - err)  # +-pi on the negative x axis
    assert err.max() <= ATAN_ERROR


def _exact_overlaps(v: np.ndarray, f: np.ndarray, agreement: float, angle: float) -> set:
    """Every corner pair at a shared vertex whose sectors share more than ``angle``, by the
    definition (:func:`recon.mesh.overlapping_faces`), pair by pair."""
    fn = face_normals(v, f)
    out = set()
    for a in range(3 * len(f)):
        for b in range(a + 1, 3 * len(f)):
            fa, ka, fb, kb = a // 3, a % 3, b // 3, b % 3
            if f[fa, ka] != f[fb, kb] or fn[fa] @ fn[fb] <= agreement:
                continue
            m = (fn[fa] + fn[fb]) / np.linalg.norm(fn[fa] + fn[fb])
            e1 = np.cross(m, [1.0, 0, 0] if abs(m[0]) < 0.9 else [0, 1.0, 0])
            e1 /= np.linalg.norm(e1)
            e2 = np.cross(m, e1)

            def ang(w, here=v[f[fa, ka]], e1=e1, e2=e2):
                return np.arctan2((v[w] - here) @ e2, (v[w] - here) @ e1)

            sa, sb = ang(f[fa, (ka + 1) % 3]), ang(f[fb, (kb + 1) % 3])
            wa = (ang(f[fa, (ka + 2) % 3]) - sa) % (2 * np.pi)
            wb = (ang(f[fb, (kb + 2) % 3]) - sb) % (2 * np.pi)
            rel = (sb - sa) % (2 * np.pi)
            shared = max(0.0, min(wa - rel, wb)) + max(0.0, min(wa, rel + wb - 2 * np.pi))
            if shared > angle:
                out.add((a, b))
    return out


@pytest.mark.parametrize("seed", range(3))
def test_overlap_candidates_keep_every_overlap(seed):
    v, f = _sheet(seed, n=4, extra=4)
    fn = face_normals(v, f)
    got = {tuple(p) for p in overlap_candidates(v, f, fn, 0.5, 0.1).tolist()}
    want = _exact_overlaps(v, f, 0.5, 0.1)
    assert want <= got
    assert len(got) < 3 * len(want) + 3  # a prefilter: the clear misses are left out


def test_overlap_candidates_find_none_on_a_clean_sheet_and_both_diagonals_of_a_quad():
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    f = np.array([[0, 1, 2], [0, 2, 3]])
    assert len(overlap_candidates(v, f, face_normals(v, f), 0.5, 0.1)) == 0
    f = np.array([[0, 1, 2], [0, 2, 3], [0, 1, 3]])
    pairs = overlap_candidates(v, f, face_normals(v, f), 0.5, 0.1)
    assert {(a // 3, b // 3) for a, b in pairs.tolist()} >= {(0, 2), (1, 2)}


@pytest.mark.parametrize("seed", range(3))
def test_vertex_component_labels_equal_csgraph_numbering(seed):
    r = np.random.default_rng(seed)
    # four groups of faces over their own ten vertices, vertex numbers shuffled
    f = np.vstack([10 * g + r.integers(0, 10, size=(3, 3)) for g in range(4)])
    f = r.permutation(45)[f]
    n = 45  # some vertices unused
    count, labels = vertex_component_labels(f, n)
    rows, cols = np.r_[f[:, 0], f[:, 1]], np.r_[f[:, 1], f[:, 2]]
    graph = sparse.coo_matrix((np.ones(len(rows)), (rows, cols)), (n, n))
    _, ref = csgraph.connected_components(graph, directed=False)
    used = np.zeros(n, dtype=bool)
    used[f.ravel()] = True
    comps, compact = np.unique(ref[used], return_inverse=True)
    assert count == len(comps) > 1
    assert np.array_equal(labels[used], compact)
    assert np.all(labels[~used] == -1)


def test_area_vectors_are_the_bits_of_np_cross():
    r = np.random.default_rng(4)
    v = r.normal(size=(30, 3)) * 1e3
    f = r.integers(0, 30, size=(50, 3))
    p = v[f]
    want = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    assert np.array_equal(area_vectors(v, f).view(np.int64), want.view(np.int64))


def test_neighbours_in_a_fan_are_passed_over_unless_they_fold():
    # a flat fan of 6 round vertex 0: no pair overlaps and none is a candidate
    ang = np.linspace(0, 2 * np.pi, 7)[:-1]
    v = np.vstack([[0, 0, 0], np.stack([np.cos(ang), np.sin(ang), 0 * ang], axis=1)])
    f = np.array([[0, 1 + k, 1 + (k + 1) % 6] for k in range(6)])
    assert len(overlap_candidates(v, f, face_normals(v, f), 0.5, 0.1)) == 0
    # a sliver at the vertex (sine below WELL_SHAPED_SINE) is always tested
    v[2] = v[1] + [1e-5, 1e-5, 0.0]
    pairs = overlap_candidates(v, f, face_normals(v, f), 0.5, 0.1)
    assert (0, 3) in {tuple(p) for p in pairs.tolist()}  # corners at vertex 0 of faces 0, 1


def test_circumradii_and_bounding_spheres_are_the_bits_of_numpy():
    r = np.random.default_rng(5)
    v = r.normal(size=(30, 3)) * 1e2
    f = np.vstack([r.integers(0, 30, size=(50, 3)), [[3, 3, 4]]])  # and a degenerate face
    p = v[f]
    a = np.linalg.norm(p[:, 1] - p[:, 2], axis=1)
    b = np.linalg.norm(p[:, 2] - p[:, 0], axis=1)
    c = np.linalg.norm(p[:, 0] - p[:, 1], axis=1)
    area2 = np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        want = np.where(area2 > 0, a * b * c / (2.0 * area2), np.inf)
    assert np.array_equal(circumradii(v, f).view(np.int64), want.view(np.int64))
    assert circumradii(v, f)[-1] == np.inf
    centroid = p.mean(axis=1)
    radius = np.linalg.norm(p - centroid[:, None, :], axis=2).max(axis=1)
    got_c, got_r = bounding_spheres(v, f)
    assert np.array_equal(got_c.view(np.int64), centroid.view(np.int64))
    assert np.array_equal(got_r.view(np.int64), radius.view(np.int64))


def test_winding_consistent_sees_one_flipped_face():
    v, f = grid(3, 3)  # consistently wound, facing +z
    f = np.ascontiguousarray(f, dtype=np.int64)
    assert winding_consistent(f, len(v))
    flipped = f.copy()
    flipped[4] = flipped[4, ::-1]
    assert not winding_consistent(flipped, len(v))
    # a face on an over-shared edge is not looked at there
    fin = np.vstack([f, [[f[4, 1], f[4, 0], len(v)]]])
    assert winding_consistent(fin, len(v) + 1)


@pytest.mark.parametrize("seed", range(3))
def test_winding_and_open_agree_with_the_edge_counts(seed):
    v, f = _sheet(seed)
    consistent, open_face = winding_and_open(f, len(v))
    assert consistent == winding_consistent(f, len(v))
    _, inverse, counts = np.unique(
        np.sort(f[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1) @ [len(v), 1],
        return_inverse=True,
        return_counts=True,
    )
    want = (counts[inverse] == 1).reshape(-1, 3).any(axis=1)
    assert np.array_equal(open_face, want) and want.any() and not want.all()
    # the same from the sort that also gives the half-edge order
    order, consistent_too, open_too = half_edge_winding(f, len(v))
    assert np.array_equal(order, half_edge_order(f, len(v)))
    assert consistent_too == consistent and np.array_equal(open_too, open_face)
