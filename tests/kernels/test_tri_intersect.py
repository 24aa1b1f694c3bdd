"""The segment-triangle and triangle-triangle crossing tests (MT97)."""

from __future__ import annotations

import numpy as np
import pytest

from recon.kernels.tri_intersect import (
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
