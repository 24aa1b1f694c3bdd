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
