"""Triangle-triangle intersection tests for finding self-intersections of a mesh.

Two triangles that share no vertex intersect when an edge of one crosses the other: the
segment ``p + t (q - p)``, ``0 <= t <= 1``, meets the triangle ``(a, b, c)`` at barycentric
``(u, v)`` with ``u, v >= 0`` and ``u + v <= 1`` (Möller & Trumbore 1997, eq. 4-5, solved by
Cramer's rule). Coplanar overlaps are not reported (the crossing is then not transversal).

References
----------
.. [MT97] T. Möller, B. Trumbore. "Fast, minimum storage ray-triangle intersection". Journal
   of Graphics Tools 2(1), 1997.
"""

from __future__ import annotations

from numba import njit, prange

from .options import EXACT_JIT_OPTIONS

#: Tolerance of the crossing test (in barycentric and segment parameters): a segment through
#: an edge or a corner of the triangle, or ending on it, counts as crossing (faces that touch
#: intersect; faces sharing a vertex are not tested at all).
EPS = 1e-12


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
def triangles_intersect(vertices, f, g):  # pragma: no cover - numba
    """Do faces ``f`` and ``g`` (vertex index triples, no shared vertex) intersect?

    True when one of the six edges crosses the other face (:func:`segment_crosses_triangle`).
    """
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
