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

The grid search runs the test on tens of pairs per face: :func:`faces_cross` does it on a
scratch array, reading corners in place (the same arithmetic as the allocating
:func:`triangles_intersect`), and decides its comparisons of dot products on the products
summed in order unless that is too close to call (then by ``np.dot``, as ever).

References
----------
.. [MT97] T. Möller, B. Trumbore. "Fast, minimum storage ray-triangle intersection". Journal
   of Graphics Tools 2(1), 1997.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from .mesh_tables import corner_cross
from .options import EXACT_JIT_OPTIONS

#: Tolerance of the crossing test (in barycentric and segment parameters): a segment through
#: an edge or a corner of the triangle, or ending on it, counts as crossing (faces that touch
#: intersect; faces sharing a vertex are not tested at all).
EPS = 1e-12
#: Faces are coplanar when the smaller one's corners lie within this fraction of the larger
#: one's size (the square root of twice its area) off its plane.
COPLANAR = 1e-9
#: Relative margin (of the sum of the products' magnitudes) within which a dot product's
#: comparison is left to ``np.dot`` itself (:func:`_dot_exceeds`).
DOT_MARGIN = 1e-12
#: ... and always when the products' magnitudes sum to this or more (a sum might overflow).
SUM_LIMIT = 1e290


@njit(**EXACT_JIT_OPTIONS)
def segment_crosses_triangle(p, q, a, b, c):  # pragma: no cover - numba
    """Does the segment ``p -> q`` cross triangle ``(a, b, c)`` (MT97 eq. 4-5)?

    Solves ``p + t (q - p) = a + u (b - a) + v (c - a)`` and tests ``0 <= t <= 1``,
    ``u, v >= 0``, ``u + v <= 1`` (within ``EPS``): a segment through the triangle's border
    counts. A segment parallel to the triangle's plane never crosses it.
    """
    points = np.empty((5, 3))
    for k in range(3):
        points[0, k], points[1, k], points[2, k] = p[k], q[k], a[k]
        points[3, k], points[4, k] = b[k], c[k]
    return _segment_crosses(points, 0, 1, 2, 3, 4)


@njit(**EXACT_JIT_OPTIONS)
def _segment_crosses(x, ip, iq, ia, ib, ic):  # pragma: no cover - numba
    """:func:`segment_crosses_triangle` of the points ``x[ip]``, ... (rows of ``x``), read in
    place: the triangle tests run it six times per pair of faces."""
    d0, d1, d2 = x[iq, 0] - x[ip, 0], x[iq, 1] - x[ip, 1], x[iq, 2] - x[ip, 2]
    e10, e11, e12 = x[ib, 0] - x[ia, 0], x[ib, 1] - x[ia, 1], x[ib, 2] - x[ia, 2]
    e20, e21, e22 = x[ic, 0] - x[ia, 0], x[ic, 1] - x[ia, 1], x[ic, 2] - x[ia, 2]
    # h = d x e2, det = e1 . h
    h0 = d1 * e22 - d2 * e21
    h1 = d2 * e20 - d0 * e22
    h2 = d0 * e21 - d1 * e20
    det = e10 * h0 + e11 * h1 + e12 * h2
    scale = (e10 * e10 + e11 * e11 + e12 * e12) * (d0 * d0 + d1 * d1 + d2 * d2)
    if det * det <= 1e-24 * scale * (e20 * e20 + e21 * e21 + e22 * e22) + 1e-300:
        return False
    inv = 1.0 / det
    s0, s1, s2 = x[ip, 0] - x[ia, 0], x[ip, 1] - x[ia, 1], x[ip, 2] - x[ia, 2]
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
    on the order of ``f`` and ``g`` (but on a tie of their sizes, ``f`` gives it).
    """
    return faces_cross(vertices, f, g, np.empty((3, 3)))


@njit(**EXACT_JIT_OPTIONS)
def _dot_exceeds(x, y, bound, work):  # pragma: no cover - numba
    """``abs(np.dot(x, y)) > bound`` for 3-vectors, as NumPy's (BLAS) dot decides it, without
    calling it unless the sum in order decides it too narrowly: any order of summing three
    products (fused or not) lies within 3.4e-16 times the sum of their magnitudes of the exact
    sum, so the two differ by far less than ``DOT_MARGIN`` times it. ``x`` and ``y`` are rows
    of ``work``."""
    p0, p1, p2 = work[x, 0] * work[y, 0], work[x, 1] * work[y, 1], work[x, 2] * work[y, 2]
    t = abs(p0 + p1 + p2)
    size = abs(p0) + abs(p1) + abs(p2)
    if size < SUM_LIMIT:  # (and not NaN) no sum can overflow; 1e-290 covers underflow
        slack = DOT_MARGIN * size + 1e-290
        if t > bound + slack:
            return True
        if t < bound - slack:
            return False
    return abs(np.dot(work[x], work[y])) > bound  # too close to call (or out of range)


@njit(**EXACT_JIT_OPTIONS)
def faces_cross(vertices, f, g, work):  # pragma: no cover - numba
    """:func:`triangles_intersect` with ``work`` (3, 3) float64 as scratch: the same
    arithmetic, without allocating (the grid search tests tens of pairs per face).

    Its comparisons of NumPy dot products (which call BLAS) are made on the products summed
    in order where that decides them with a wide margin (:func:`_dot_exceeds`), else by
    ``np.dot`` itself: the same answers."""
    fa, fb, fc = f[0], f[1], f[2]
    ga, gb, gc = g[0], g[1], g[2]
    # n = (a1 - a0) x (a2 - a0) of f, m of g: the component order of np.cross
    for row in range(2):
        i0, i1, i2 = (fa, fb, fc) if row == 0 else (ga, gb, gc)
        _, _, work[row, 0], work[row, 1], work[row, 2] = corner_cross(vertices, i0, i1, i2)
    # the plane of the larger face: np.dot(m, m) > np.dot(n, n) (f's on a tie)
    qn = work[0, 0] * work[0, 0] + work[0, 1] * work[0, 1] + work[0, 2] * work[0, 2]
    qm = work[1, 0] * work[1, 0] + work[1, 1] * work[1, 1] + work[1, 2] * work[1, 2]
    larger = -1
    if qn + qm < SUM_LIMIT:  # (and not NaN) see _dot_exceeds
        slack = DOT_MARGIN * (qn + qm) + 1e-290
        if qm > qn + slack:
            larger = 1
        elif qm < qn - slack:
            larger = 0
    if larger < 0:  # too close to call (or out of range)
        larger = 1 if np.dot(work[1], work[1]) > np.dot(work[0], work[0]) else 0
    pa, pb, pc = (fa, fb, fc) if larger == 0 else (ga, gb, gc)  # the plane's face (a)
    qa, qb, qc = (ga, gb, gc) if larger == 0 else (fa, fb, fc)  # the other (b)
    n0, n1, n2 = work[larger, 0], work[larger, 1], work[larger, 2]
    nn = np.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
    if nn > 0:
        coplanar = True
        limit = COPLANAR * nn * np.sqrt(nn)
        for k in range(3):
            corner = qa if k == 0 else qb if k == 1 else qc
            for c in range(3):
                work[2, c] = vertices[corner, c] - vertices[pa, c]
            if _dot_exceeds(larger, 2, limit, work):
                coplanar = False
        if coplanar:
            axis = 0
            if abs(n1) > abs(n0):
                axis = 1
            if abs(n2) > abs(n0 if axis == 0 else n1):
                axis = 2
            a = np.empty((3, 3))
            b = np.empty((3, 3))
            for c in range(3):
                a[0, c], a[1, c], a[2, c] = vertices[pa, c], vertices[pb, c], vertices[pc, c]
                b[0, c], b[1, c], b[2, c] = vertices[qa, c], vertices[qb, c], vertices[qc, c]
            return coplanar_overlap(a, b, axis)
    # an edge of f through g, then an edge of g through f
    if (
        _segment_crosses(vertices, fa, fb, ga, gb, gc)
        or _segment_crosses(vertices, fb, fc, ga, gb, gc)
        or _segment_crosses(vertices, fc, fa, ga, gb, gc)
    ):
        return True
    return (
        _segment_crosses(vertices, ga, gb, fa, fb, fc)
        or _segment_crosses(vertices, gb, gc, fa, fb, fc)
        or _segment_crosses(vertices, gc, ga, fa, fb, fc)
    )


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
        out[m] = False if shared else faces_cross(vertices, f, g, np.empty((3, 3)))


@njit(**EXACT_JIT_OPTIONS)
def order_free(vertices, faces, margin, run_limit):  # pragma: no cover - numba
    """Whether :func:`triangles_intersect` answers every pair of ``faces`` that share no
    vertex the same either way round.

    The larger face (squared cross product, ``np.dot(n, n)``) gives the coplanarity plane,
    the first argument on a tie; everything else in the test is symmetric. So the order can
    matter only for two faces whose squared cross products tie, and this is False when those
    of two faces sharing no vertex lie within ``margin`` (relative, far above the rounding of
    any way to sum three squares) of each other, when one is below 1e-280 but not zero (it
    could round to zero or not), when one is not finite, or when more than ``run_limit``
    faces lie within the margin of one another (a flat grid: not worth sorting out). A zero
    one gives no plane either way (all three squares round to zero, however summed).
    """
    nf = faces.shape[0]
    q = np.empty(nf)
    for i in range(nf):
        _, _, n0, n1, n2 = corner_cross(vertices, faces[i, 0], faces[i, 1], faces[i, 2])
        q[i] = n0 * n0 + n1 * n1 + n2 * n2
        if not np.isfinite(q[i]):
            return False
    order = np.argsort(q)
    k = 0
    while k < nf and q[order[k]] == 0.0:
        k += 1
    if k < nf and q[order[k]] < 1e-280:
        return False
    while k < nf - 1:
        if q[order[k + 1]] - q[order[k]] > margin * q[order[k + 1]]:
            k += 1
            continue
        end = k + 1  # a run of faces whose products may tie: k .. end
        while end < nf - 1 and q[order[end + 1]] - q[order[end]] <= margin * q[order[end + 1]]:
            end += 1
        if end - k + 1 > run_limit:
            return False
        for a in range(k, end + 1):
            for b in range(a + 1, end + 1):
                shared = False
                for s in range(3):
                    for t in range(3):
                        if faces[order[a], s] == faces[order[b], t]:
                            shared = True
                if not shared:
                    return False
        k = end + 1
    return True
