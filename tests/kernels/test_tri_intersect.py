"""The segment-triangle and triangle-triangle crossing tests (MT97)."""

from __future__ import annotations

import numpy as np
import pytest
from numba import njit

from recon.kernels.tri_intersect import (
    COPLANAR,
    coplanar_overlap,
    faces_cross,
    order_free,
    pairs_intersect,
    segment_crosses_triangle,
    triangles_intersect,
)

TRI = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 2.0, 0.0]])


@pytest.mark.parametrize(
    ("p", "q", "expected"),
    [
        ([0.5, 0.5, -1.0], [0.5, 0.5, 1.0], True),  # through the inside
        ([0.5, 0.5, 0.1], [0.5, 0.5, 1.0], False),  # stops short of the plane
        ([3.0, 3.0, -1.0], [3.0, 3.0, 1.0], False),  # misses beside the triangle
        ([0.5, 0.5, 0.0], [1.0, 0.5, 0.0], False),  # in the plane: not a transversal crossing
        ([0.0, 0.0, -1.0], [0.0, 0.0, 1.0], True),  # through a corner
        ([1.0, 1.0, -1.0], [1.0, 1.0, 1.0], True),  # through the hypotenuse
        ([1.01, 1.0, -1.0], [1.01, 1.0, 1.0], False),  # just beside it
        ([0.5, 0.5, 0.0], [0.5, 0.5, 1.0], True),  # ending on the triangle: they touch
    ],
)
def test_segment_crosses_triangle(p, q, expected):
    a, b, c = TRI
    assert bool(segment_crosses_triangle(np.array(p), np.array(q), a, b, c)) == expected


def test_triangles_intersect_either_way_round():
    v = np.vstack([TRI, [[0.5, 0.5, -1.0], [0.5, 0.5, 1.0], [-2.0, -2.0, 0.5]]])
    f, g = np.array([0, 1, 2]), np.array([3, 4, 5])
    assert triangles_intersect(v, f, g) and triangles_intersect(v, g, f)
    v[3:, 0] += 5.0  # moved aside
    assert not triangles_intersect(v, f, g)


def test_pairs_sharing_a_vertex_are_skipped():
    v = np.vstack([TRI, [[0.5, 0.5, -1.0], [0.5, 0.5, 1.0]]])
    faces = np.array([[0, 1, 2], [3, 4, 0]], dtype=np.int64)
    out = np.ones(1, dtype=np.bool_)
    pairs_intersect(v, faces, np.array([[0, 1]], dtype=np.int64), out)
    assert not out[0]


def _pair(a, b) -> bool:
    v = np.vstack([a, b]).astype(float)
    return bool(triangles_intersect(v, np.array([0, 1, 2]), np.array([3, 4, 5])))


def test_coplanar_triangles_intersect_only_when_they_overlap():
    a = [[0, 0, 0], [2, 0, 0], [0, 2, 0]]
    assert _pair(a, [[0.5, 0.5, 0], [3, 0.5, 0], [0.5, 3, 0]])  # corner inside, edges cross
    assert _pair(a, [[0.2, 0.2, 0], [0.6, 0.2, 0], [0.2, 0.6, 0]])  # wholly inside
    assert _pair([[0.2, 0.2, 0], [0.6, 0.2, 0], [0.2, 0.6, 0]], a)  # ... either way round
    assert not _pair(a, [[1.5, 1.5, 0], [3, 1.5, 0], [1.5, 3, 0]])  # beside the hypotenuse


def test_coplanar_neighbours_of_an_exact_plane_do_not_intersect():
    # two faces of a fit of an exactly planar face (lblock-clean, y = 0): Open3D reports
    # them as intersecting (its issues #5117, #6462); they are disjoint
    a = [[0.32778, 0.0, 0.34773], [0.34193, 0.0, 0.35346], [0.33052, 0.0, 0.36205]]
    b = [[0.31572, 0.0, 0.36016], [0.32996, 0.0, 0.37587], [0.31512, 0.0, 0.37731]]
    assert not _pair(a, b)


@njit(fastmath=False, error_model="numpy")
def _first_version(vertices, f, g):  # pragma: no cover - numba
    """The test as it was before ``faces_cross`` (allocating, every dot product by
    ``np.dot``): the reference whose answers it must give."""
    a = np.empty((3, 3))
    b = np.empty((3, 3))
    for k in range(3):
        for c in range(3):
            a[k, c] = vertices[f[k], c]
            b[k, c] = vertices[g[k], c]
    n = np.cross(a[1] - a[0], a[2] - a[0])
    m = np.cross(b[1] - b[0], b[2] - b[0])
    if np.dot(m, m) > np.dot(n, n):
        a, b, n = b, a, m
    nn = np.sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2])
    if nn > 0:
        coplanar = True
        for k in range(3):
            if abs(np.dot(n, b[k] - a[0])) > COPLANAR * nn * np.sqrt(nn):
                coplanar = False
        if coplanar:
            axis = 0
            if abs(n[1]) > abs(n[axis]):
                axis = 1
            if abs(n[2]) > abs(n[axis]):
                axis = 2
            return coplanar_overlap(a, b, axis)
    for side in range(2):
        s = f if side == 0 else g
        t = g if side == 0 else f
        p, q, r = vertices[t[0]], vertices[t[1]], vertices[t[2]]
        for k in range(3):
            if segment_crosses_triangle(vertices[s[k]], vertices[s[(k + 1) % 3]], p, q, r):
                return True
    return False


@njit(fastmath=False, error_model="numpy")
def _both(vertices, faces, pairs, new, old):  # pragma: no cover - numba
    work = np.empty((3, 3))
    for m in range(pairs.shape[0]):
        f, g = faces[pairs[m, 0]], faces[pairs[m, 1]]
        new[m] = faces_cross(vertices, f, g, work)
        old[m] = _first_version(vertices, f, g)


def _thresholds(rng: np.random.Generator, n: int) -> np.ndarray:
    """Pairs of faces whose sizes tie, or whose corners lie off the other's plane by just the
    coplanarity limit: the comparisons the fast sums leave to ``np.dot``."""
    out = []
    for k in range(n):
        a = rng.normal(size=(3, 3))
        shift = rng.normal(size=3)
        if k % 2:  # the same triangle moved: the squared cross products tie
            b = a + shift
        else:  # a corner off a's plane by the coplanarity limit (up to rounding)
            normal = np.cross(a[1] - a[0], a[2] - a[0])
            nn = np.linalg.norm(normal)
            b = 0.3 * rng.normal(size=(3, 3)) + a.mean(axis=0)
            b -= np.outer((b - a[0]) @ normal / nn**2, normal)  # into a's plane
            b[rng.integers(3)] += normal / nn * (COPLANAR * np.sqrt(nn)) * rng.choice([-1, 1])
        out += [a, b]
    return np.vstack(out)


@pytest.mark.parametrize(
    "kind", ["random", "planar", "near-planar", "grid", "far", "scales", "ties"]
)
def test_faces_cross_answers_as_the_first_version(kind):
    """The allocation-free test sums the dot products in order where that decides a
    comparison by a wide margin, and asks ``np.dot`` otherwise: the same answer as the
    first version for every pair, either way round (a tie of sizes included, where the
    order can matter), on crossings, coplanar faces and comparisons at their limits."""
    rng = np.random.default_rng(["random", "planar", "near-planar", "grid", "far"].count(kind))
    m = 600
    if kind == "random":
        v = rng.normal(size=(3 * m, 3))
    elif kind == "planar":
        v = rng.normal(size=(3 * m, 3)) * [1.0, 1.0, 0.0]
    elif kind == "near-planar":
        v = rng.normal(size=(3 * m, 3)) * [1.0, 1.0, 1e-9]
    elif kind == "grid":  # exact ties, exactly coplanar, touching faces
        v = rng.integers(0, 4, size=(3 * m, 3)).astype(float) * [1.0, 1.0, 0.5]
    elif kind == "far":
        v = 1e3 + 1e-5 * rng.normal(size=(3 * m, 3))
    elif kind == "scales":
        v = rng.normal(size=(3 * m, 3)) * 10.0 ** rng.choice([-160.0, -80.0, 0.0, 100.0, 150.0])
    else:
        v = _thresholds(rng, m // 2)
    faces = np.arange(len(v), dtype=np.int64).reshape(-1, 3)
    pairs = rng.integers(0, len(faces), size=(6000, 2))
    if kind == "ties":
        pairs = np.vstack([pairs, np.arange(len(faces)).reshape(-1, 2)])  # a with its b
    pairs = np.vstack([pairs, pairs[:, ::-1]])
    pairs = pairs[pairs[:, 0] != pairs[:, 1]]
    new, old = np.zeros(len(pairs), dtype=bool), np.zeros(len(pairs), dtype=bool)
    _both(v, faces, pairs, new, old)
    assert old.any() and not old.all()  # the pairs mean something
    np.testing.assert_array_equal(new, old)


def test_order_free_finds_the_faces_whose_sizes_may_tie():
    tri = TRI
    apart = np.vstack([tri, tri + [5.0, 0.0, 0.0]])  # the same size, no shared vertex
    assert not order_free(apart, np.array([[0, 1, 2], [3, 4, 5]]), 1e-12, 16)
    # the same size but sharing a vertex: never tested, so the order cannot matter
    assert order_free(apart, np.array([[0, 1, 2], [0, 4, 5]]), 1e-12, 16)
    apart[4, 0] += 1e-6  # sizes a little apart
    assert order_free(apart, np.array([[0, 1, 2], [3, 4, 5]]), 1e-12, 16)
    # degenerate faces (zero cross products) give no plane either way; non-finite ones may
    line = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0], [5, 0, 0], [6, 0, 0], [7, 0, 0]])
    assert order_free(line, np.array([[0, 1, 2], [3, 4, 5]]), 1e-12, 16)
    assert not order_free(np.vstack([tri, [[np.nan, 0, 0]]]), np.array([[0, 1, 3]]), 1e-12, 16)
