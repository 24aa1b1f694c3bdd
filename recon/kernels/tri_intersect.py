"""Triangle-triangle intersection tests for finding self-intersections of a mesh.

Two triangles that share no vertex intersect when an edge of one crosses the other: the
segment ``p + t (q - p)``, ``0 <= t <= 1``, meets the triangle ``(a, b, c)`` at barycentric
``(u, v)`` with ``u, v >= 0`` and ``u + v <= 1`` (Möller & Trumbore 1997, eq. 4-5, solved by
Cramer's rule). Coplanar triangles intersect when they overlap in their plane (2-D edge
crossings and point-in-triangle tests on the projection that drops the normal's largest
component).

Open3D's ``get_self_intersecting_triangles`` also reports coplanar triangles that do not
overlap (Open3D issues #5117 and #6462), which happens on exactly planar scans: there the two
finders differ, and this one is right.

References
----------
.. [MT97] T. Möller, B. Trumbore. "Fast, minimum storage ray-triangle intersection". Journal
   of Graphics Tools 2(1), 1997.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from .options import EXACT_JIT_OPTIONS

#: Tolerance of the crossing test (in barycentric and segment parameters): a segment through
#: an edge or a corner of the triangle, or ending on it, counts as crossing (faces that touch
#: intersect; faces sharing a vertex are not tested at all).
EPS = 1e-12
#: Faces are coplanar when the smaller one's corners lie within this fraction of the larger
#: one's size (the square root of twice its area) off its plane.
COPLANAR = 1e-9


@njit(**EXACT_JIT_OPTIONS)
def segment_crosses_triangle(p, q, a, b, c):  # pragma: no cover - numba
    """Does the segment ``p -> q`` cross triangle ``(a, b, c)`` (MT97 eq. 4-5)?

    Solves ``p + t (q - p) = a + u (b - a) + v (c - a)`` and tests ``0 <= t <= 1``,
    ``u, v >= 0``, ``u + v <= 1`` (within ``EPS``): a segment through the triangle's border
    counts. A segment parallel to the triangle's plane never crosses it.
    """
    d0, d1, d2 = q[0] - p[0], q[1] - p[1], q[2] - p[2]
    e10, e11, e12 = b[0] - a[0], b[1] - a[1], b[2] - a[2]
    e20, e21, e22 = c[0] - a[0], c[1] - a[1], c[2] - a[2]
    # h = d x e2, det = e1 . h
    h0 = d1 * e22 - d2 * e21
    h1 = d2 * e20 - d0 * e22
    h2 = d0 * e21 - d1 * e20
    det = e10 * h0 + e11 * h1 + e12 * h2
    scale = (e10 * e10 + e11 * e11 + e12 * e12) * (d0 * d0 + d1 * d1 + d2 * d2)
    if det * det <= 1e-24 * scale * (e20 * e20 + e21 * e21 + e22 * e22) + 1e-300:
        return False
    inv = 1.0 / det
    s0, s1, s2 = p[0] - a[0], p[1] - a[1], p[2] - a[2]
    u = (s0 * h0 + s1 * h1 + s2 * h2) * inv
    if u < -EPS or u > 1.0 + EPS:
        return False
    # k = s x e1
    k0 = s1 * e12 - s2 * e11
    k1 = s2 * e10 - s0 * e12
    k2 = s0 * e11 - s1 * e10
    v = (d0 * k0 + d1 * k1 + d2 * k2) * inv
    if v < -EPS or u + v > 1.0 + EPS:
        return False
    t = (e20 * k0 + e21 * k1 + e22 * k2) * inv
    return -EPS <= t <= 1.0 + EPS


@njit(**EXACT_JIT_OPTIONS)
def _orient2d(ax, ay, bx, by, cx, cy):  # pragma: no cover - numba
    """Twice the signed area of the 2-D triangle ``(a, b, c)``."""
    return (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)


@njit(**EXACT_JIT_OPTIONS)
def _inside2d(px, py, t):  # pragma: no cover - numba
    """Is the 2-D point inside (or on) the 2-D triangle ``t`` (3 x 2)?"""
    d0 = _orient2d(t[0, 0], t[0, 1], t[1, 0], t[1, 1], px, py)
    d1 = _orient2d(t[1, 0], t[1, 1], t[2, 0], t[2, 1], px, py)
    d2 = _orient2d(t[2, 0], t[2, 1], t[0, 0], t[0, 1], px, py)
    has_neg = d0 < 0 or d1 < 0 or d2 < 0
    has_pos = d0 > 0 or d1 > 0 or d2 > 0
    return not (has_neg and has_pos)


@njit(**EXACT_JIT_OPTIONS)
def coplanar_overlap(a, b, axis):  # pragma: no cover - numba
    """Do two coplanar triangles ``a``, ``b`` (3 x 3) overlap? They are projected onto the
    coordinate plane that drops ``axis`` (the plane normal's largest component); they overlap
    when two edges cross or a corner of one lies in the other."""
    u = (axis + 1) % 3
    v = (axis + 2) % 3
    ta = np.empty((3, 2))
    tb = np.empty((3, 2))
    for k in range(3):
        ta[k, 0], ta[k, 1] = a[k, u], a[k, v]
        tb[k, 0], tb[k, 1] = b[k, u], b[k, v]
    for i in range(3):
        p0x, p0y, p1x, p1y = ta[i, 0], ta[i, 1], ta[(i + 1) % 3, 0], ta[(i + 1) % 3, 1]
        for j in range(3):
            q0x, q0y, q1x, q1y = tb[j, 0], tb[j, 1], tb[(j + 1) % 3, 0], tb[(j + 1) % 3, 1]
            d1 = _orient2d(p0x, p0y, p1x, p1y, q0x, q0y)
            d2 = _orient2d(p0x, p0y, p1x, p1y, q1x, q1y)
            d3 = _orient2d(q0x, q0y, q1x, q1y, p0x, p0y)
            d4 = _orient2d(q0x, q0y, q1x, q1y, p1x, p1y)
            if d1 * d2 < 0 and d3 * d4 < 0:
                return True
    return _inside2d(ta[0, 0], ta[0, 1], tb) or _inside2d(tb[0, 0], tb[0, 1], ta)


@njit(**EXACT_JIT_OPTIONS)
def triangles_intersect(vertices, f, g):  # pragma: no cover - numba
    """Do faces ``f`` and ``g`` (vertex index triples, no shared vertex) intersect?

    True when one of the six edges crosses the other face (:func:`segment_crosses_triangle`),
    or, for coplanar faces (every corner of the smaller face within ``COPLANAR`` times the
    larger face's size off the larger face's plane), when they overlap in that plane
    (:func:`coplanar_overlap`). The larger face gives the plane, so the answer does not depend
    on the order of ``f`` and ``g``.
    """
    a = np.empty((3, 3))
    b = np.empty((3, 3))
    for k in range(3):
        for c in range(3):
            a[k, c] = vertices[f[k], c]
            b[k, c] = vertices[g[k], c]
    n = np.cross(a[1] - a[0], a[2] - a[0])
    m = np.cross(b[1] - b[0], b[2] - b[0])
    if np.dot(m, m) > np.dot(n, n):  # the plane of the larger face
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
        a, b, c = vertices[t[0]], vertices[t[1]], vertices[t[2]]
        for k in range(3):
            if segment_crosses_triangle(vertices[s[k]], vertices[s[(k + 1) % 3]], a, b, c):
                return True
    return False


@njit(parallel=True, **EXACT_JIT_OPTIONS)
def pairs_intersect(vertices, faces, pairs, out):  # pragma: no cover - numba
    """``out[m] = True`` when candidate face pair ``pairs[m]`` intersects; pairs sharing a
    vertex are skipped (``False``)."""
    for m in prange(pairs.shape[0]):
        f = faces[pairs[m, 0]]
        g = faces[pairs[m, 1]]
        shared = False
        for i in range(3):
            for j in range(3):
                if f[i] == g[j]:
                    shared = True
        out[m] = False if shared else triangles_intersect(vertices, f, g)
