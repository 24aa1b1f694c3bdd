"""Connectivity tables of a triangle mesh: half-edges sorted by edge, corner fans, vertex
components and the corner pairs that may overlap; and per-face measures (area vectors,
circumradii, bounding spheres) in the bits of their NumPy expressions.

Faces are ``(F, 3)`` int64 vertex indices. Half-edge ``h = 3 i + k`` runs from corner k of
face i to corner k + 1; its undirected edge is ``(lo, hi)`` = its two vertices, smaller first.
These kernels compute, in linear time with counting sorts, the tables that
:mod:`recon.mesh` built with ``np.lexsort``, ``np.unique`` and ``scipy.sparse.csgraph``; the
results are the same arrays (integer work only, or a conservative float prefilter whose
survivors the caller tests exactly).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .options import EXACT_JIT_OPTIONS

#: Margins of :func:`overlap_candidates`: a corner pair is passed over only when it misses
#: the normals' agreement by more than ``OVERLAP_DOT_MARGIN`` (the caller's NumPy dot product
#: differs by a few ulps) or the shared angle by more than ``OVERLAP_ANGLE_MARGIN`` [rad]
#: (angles here come from :func:`fast_atan2`, within ``ATAN_ERROR`` of ``arctan2``; the shared
#: angle sums four angle differences, so it is within ``8 ATAN_ERROR``).
OVERLAP_DOT_MARGIN = 1e-9
OVERLAP_ANGLE_MARGIN = 1e-4
#: Two faces that follow each other round the vertex (one's last edge is the other's first)
#: have sectors that only touch; their pair is passed over when each corner is a proper angle
#: (sine above this) ...
WELL_SHAPED_SINE = 1e-3
#: ... in a plane whose normal is within arccos(this) of the pair's mean normal.
WELL_SHAPED_COSINE = 0.1
#: Largest error [rad] of :func:`fast_atan2` (the polynomial's is 1.7e-6).
ATAN_ERROR = 2e-6
#: ... and a pair with an edge shorter than this [length] at the shared vertex is always
#: passed on (its angles are ill-conditioned).
OVERLAP_MIN_EDGE = 1e-4


@njit(**EXACT_JIT_OPTIONS)
def _sort_half_edges(faces, n_vertices):  # pragma: no cover - numba
    """Half-edges sorted by ``(lo, hi, face)``: ``(order, start, hi_sorted)``.

    Two stable counting sorts (least significant key first): by ``hi``, then by ``lo``
    (``start[v]`` .. ``start[v + 1]`` hold the half-edges whose smaller vertex is v); linear
    in the half-edges and vertices however many faces share a vertex. ``hi_sorted`` is the
    ``hi`` of each half-edge in the order of ``order``. Half-edge ``h`` is edge ``h % 3`` of
    face ``h // 3``.
    """
    nf = faces.shape[0]
    nh = 3 * nf
    lo = np.empty(nh, dtype=np.int64)
    hi = np.empty(nh, dtype=np.int64)
    for i in range(nf):
        for k in range(3):
            a = faces[i, k]
            b = faces[i, (k + 1) % 3]
            h = 3 * i + k
            if a < b:
                lo[h] = a
                hi[h] = b
            else:
                lo[h] = b
                hi[h] = a
    # by hi, ascending h within a key (h // 3 is monotone in h: stable in the face)
    fill = np.zeros(n_vertices + 1, dtype=np.int64)
    for h in range(nh):
        fill[hi[h] + 1] += 1
    for v in range(n_vertices):
        fill[v + 1] += fill[v]
    by_hi = np.empty(nh, dtype=np.int64)
    for h in range(nh):
        by_hi[fill[hi[h]]] = h
        fill[hi[h]] += 1
    # then by lo, keeping that order within a key
    start = np.zeros(n_vertices + 1, dtype=np.int64)
    for h in range(nh):
        start[lo[h] + 1] += 1
    for v in range(n_vertices):
        start[v + 1] += start[v]
    fill[:n_vertices] = start[:-1]
    order = np.empty(nh, dtype=np.int64)
    hs = np.empty(nh, dtype=np.int64)
    for p in range(nh):
        h = by_hi[p]
        slot = fill[lo[h]]
        order[slot] = h
        hs[slot] = hi[h]
        fill[lo[h]] = slot + 1
    return order, start, hs


@njit(**EXACT_JIT_OPTIONS)
def half_edge_order(faces, n_vertices):  # pragma: no cover - numba
    """Half-edges sorted by undirected edge, then by face: ``(3 F,)`` int64.

    The same permutation as ``np.lexsort((he_face, hi, lo))`` over the half-edges (``lo``,
    ``hi`` their smaller and larger vertex, ``he_face`` their face), by counting sorts
    (:func:`_sort_half_edges`). Half-edge ``h`` is edge ``h % 3`` of face ``h // 3``.
    """
    return _sort_half_edges(faces, n_vertices)[0]


@njit(**EXACT_JIT_OPTIONS)
def edge_table(faces, n_vertices):  # pragma: no cover - numba
    """The distinct edges and each half-edge's edge: ``(keys, inverse, counts)``.

    ``keys`` ``(E,)`` int64 are ``lo * n_vertices + hi`` in ascending order, ``inverse``
    ``(3 F,)`` the index into ``keys`` of half-edge ``3 i + k``, and ``counts`` ``(E,)`` the
    number of half-edges (faces) on each edge: what ``np.unique(keys_of_half_edges,
    return_inverse=True, return_counts=True)`` gives, from :func:`_sort_half_edges`.
    """
    order, start, hs = _sort_half_edges(faces, n_vertices)
    nh = order.shape[0]
    inverse = np.empty(nh, dtype=np.int64)
    keys = np.empty(nh, dtype=np.int64)
    counts = np.zeros(nh, dtype=np.int64)
    n = -1
    last = -1
    for v in range(n_vertices):
        for i in range(start[v], start[v + 1]):
            key = v * n_vertices + hs[i]
            if n < 0 or key != last:
                n += 1
                keys[n] = key
                last = key
            inverse[order[i]] = n
            counts[n] += 1
    return keys[: n + 1].copy(), inverse, counts[: n + 1].copy()


@njit(inline="always", **EXACT_JIT_OPTIONS)
def _same_way(faces, h, g):  # pragma: no cover - numba
    """Do half-edges ``h`` and ``g`` (face ``h // 3``, corner ``h % 3``) of one edge run it
    in the same direction (lower to higher vertex, or both the other way)?"""
    up_h = faces[h // 3, h % 3] < faces[h // 3, (h % 3 + 1) % 3]
    up_g = faces[g // 3, g % 3] < faces[g // 3, (g % 3 + 1) % 3]
    return up_h == up_g


@njit(**EXACT_JIT_OPTIONS)
def winding_consistent(faces, n_vertices):  # pragma: no cover - numba
    """Do the two faces of every edge in exactly two faces run it in opposite directions?
    (:func:`recon.mesh.orientation_flips` then flips nothing.) Edges in one face or in more
    than two are not looked at. (:func:`half_edge_winding`'s answer.)"""
    return half_edge_winding(faces, n_vertices)[1]


@njit(**EXACT_JIT_OPTIONS)
def half_edge_winding(faces, n_vertices):  # pragma: no cover - numba
    """The half-edge order (:func:`half_edge_order`), whether the winding is consistent
    (:func:`winding_consistent`) and which faces have an edge in no other face (a boundary
    edge), from one sort of the half-edges: ``(order, consistent, open_face (F,) bool)``."""
    order, start, hs = _sort_half_edges(faces, n_vertices)
    open_face = np.zeros(faces.shape[0], dtype=np.bool_)
    consistent = True
    for v in range(n_vertices):
        i = start[v]
        while i < start[v + 1]:
            j = i + 1
            while j < start[v + 1] and hs[j] == hs[i]:
                j += 1
            if j - i == 1:
                open_face[order[i] // 3] = True
            elif j - i == 2 and consistent:
                consistent = not _same_way(faces, order[i], order[i + 1])
            i = j
    return order, consistent, open_face


@njit(**EXACT_JIT_OPTIONS)
def winding_and_open(faces, n_vertices):  # pragma: no cover - numba
    """:func:`winding_consistent`, and which faces have an edge in no other face (a
    boundary edge): ``(consistent, open_face (F,) bool)``, from one sort of the half-edges."""
    _, consistent, open_face = half_edge_winding(faces, n_vertices)
    return consistent, open_face


@njit(inline="always", **EXACT_JIT_OPTIONS)
def corner_cross(vertices, v, x, y):  # pragma: no cover - numba
    """The corner ``(v, x, y)``: squared lengths of ``d = x - v`` and ``e = y - v``, and
    ``d x e`` with the operations of ``np.cross`` (no fused multiply-add), so the same bits."""
    dx = vertices[x, 0] - vertices[v, 0]
    dy = vertices[x, 1] - vertices[v, 1]
    dz = vertices[x, 2] - vertices[v, 2]
    ex = vertices[y, 0] - vertices[v, 0]
    ey = vertices[y, 1] - vertices[v, 1]
    ez = vertices[y, 2] - vertices[v, 2]
    return (
        dx * dx + dy * dy + dz * dz,
        ex * ex + ey * ey + ez * ez,
        dy * ez - dz * ey,
        dz * ex - dx * ez,
        dx * ey - dy * ex,
    )


@njit(**EXACT_JIT_OPTIONS)
def area_vectors(vertices, faces):  # pragma: no cover - numba
    """Twice each face's area vector, ``(F, 3)``: ``(b - a) x (c - a)`` for face ``(a, b, c)``,
    with the operations of ``np.cross`` (no fused multiply-add), so the same bits."""
    nf = faces.shape[0]
    out = np.empty((nf, 3))
    for i in range(nf):
        _, _, out[i, 0], out[i, 1], out[i, 2] = corner_cross(
            vertices, faces[i, 0], faces[i, 1], faces[i, 2]
        )
    return out


@njit(**EXACT_JIT_OPTIONS)
def circumradii(vertices, faces):  # pragma: no cover - numba
    """Circumradius ``a b c / (2 |(p1 - p0) x (p2 - p0)|)`` of every face ``(F,)``, inf where
    the area is 0; lengths as ``np.linalg.norm`` sums the squares (in coordinate order), so
    the same bits as the NumPy expression of :func:`recon.triangulate.circumradius`."""
    nf = faces.shape[0]
    out = np.empty(nf)
    for i in range(nf):
        i0, i1, i2 = faces[i, 0], faces[i, 1], faces[i, 2]
        x0, y0, z0 = vertices[i0, 0], vertices[i0, 1], vertices[i0, 2]
        x1, y1, z1 = vertices[i1, 0], vertices[i1, 1], vertices[i1, 2]
        x2, y2, z2 = vertices[i2, 0], vertices[i2, 1], vertices[i2, 2]
        dx, dy, dz = x1 - x2, y1 - y2, z1 - z2
        a = np.sqrt(dx * dx + dy * dy + dz * dz)
        dx, dy, dz = x2 - x0, y2 - y0, z2 - z0
        b = np.sqrt(dx * dx + dy * dy + dz * dz)
        dx, dy, dz = x0 - x1, y0 - y1, z0 - z1
        c = np.sqrt(dx * dx + dy * dy + dz * dz)
        px, py, pz = x1 - x0, y1 - y0, z1 - z0
        qx, qy, qz = x2 - x0, y2 - y0, z2 - z0
        nx = py * qz - pz * qy
        ny = pz * qx - px * qz
        nz = px * qy - py * qx
        area2 = np.sqrt(nx * nx + ny * ny + nz * nz)
        out[i] = a * b * c / (2.0 * area2) if area2 > 0 else np.inf
    return out


@njit(**EXACT_JIT_OPTIONS)
def bounding_spheres(vertices, faces):  # pragma: no cover - numba
    """Each face's centroid ``(F, 3)`` and the distance from it to the farthest corner
    ``(F,)``, summed and divided as ``corners.mean(axis=1)`` and ``np.linalg.norm`` do, so
    the same bits as :func:`recon.intersections.face_spheres`."""
    nf = faces.shape[0]
    centroid = np.empty((nf, 3))
    radius = np.empty(nf)
    for i in range(nf):
        for k in range(3):
            centroid[i, k] = (
                vertices[faces[i, 0], k] + vertices[faces[i, 1], k] + vertices[faces[i, 2], k]
            ) / 3.0
        far = -np.inf
        for c in range(3):
            dx = vertices[faces[i, c], 0] - centroid[i, 0]
            dy = vertices[faces[i, c], 1] - centroid[i, 1]
            dz = vertices[faces[i, c], 2] - centroid[i, 2]
            d = np.sqrt(dx * dx + dy * dy + dz * dz)
            if d > far or np.isnan(d):
                far = d
        radius[i] = far
    return centroid, radius


@njit(**EXACT_JIT_OPTIONS)
def find_root(parent, x):  # pragma: no cover - numba
    """Root of ``x`` in the union-find forest ``parent`` (halving the path on the way)."""
    while parent[x] != x:
        parent[x] = parent[parent[x]]
        x = parent[x]
    return x


@njit(**EXACT_JIT_OPTIONS)
def union_sets(parent, x, y):  # pragma: no cover - numba
    """Join the sets of ``x`` and ``y``; the lower root stays the root (so each set's root
    is its lowest member)."""
    rx = find_root(parent, x)
    ry = find_root(parent, y)
    if rx < ry:
        parent[ry] = rx
    elif ry < rx:
        parent[rx] = ry


@njit(**EXACT_JIT_OPTIONS)
def _component_labels(parent, used):  # pragma: no cover - numba
    """Union-find components of the ``used`` items numbered 0, 1, ... in item order (a root
    is its component's lowest item); ``(count, labels)``, -1 for items not used."""
    labels = np.full(len(used), -1, dtype=np.int64)
    n = 0
    for v in range(len(used)):
        if not used[v]:
            continue
        r = find_root(parent, v)
        if r == v:
            labels[v] = n
            n += 1
        else:
            labels[v] = labels[r]
    return n, labels


@njit(inline="always", **EXACT_JIT_OPTIONS)
def _edge_corners(faces, h):  # pragma: no cover - numba
    """Half-edge ``h`` (corner ``3 f + k`` to the next corner of face ``f``): its lower and
    higher vertex, and the corners of ``f`` at each of them."""
    f = h // 3
    k = h % 3
    k1 = (k + 1) % 3
    a = faces[f, k]
    b = faces[f, k1]
    if a < b:
        return a, b, 3 * f + k, 3 * f + k1
    return b, a, 3 * f + k1, 3 * f + k


@njit(**EXACT_JIT_OPTIONS)
def fan_labels(faces, order):  # pragma: no cover - numba
    """Fan label of every face corner, ``(3 F,)`` int64 (corner ``3 i + k``).

    Two corners at one vertex share a label when their faces are joined around the vertex by
    a chain of faces sharing an edge that contains it (edges in more than two faces join all
    of their faces). ``order`` is :func:`half_edge_order`. Labels are the connected
    components of the corners numbered in order of their lowest corner, as
    ``scipy.sparse.csgraph.connected_components`` numbers them.
    """
    nf = faces.shape[0]
    nh = 3 * nf
    parent = np.arange(nh)
    i = 0
    while i < nh:
        lo0, hi0, lo_c0, hi_c0 = _edge_corners(faces, order[i])
        j = i + 1
        while j < nh:
            lo, hi, lo_c, hi_c = _edge_corners(faces, order[j])
            if lo != lo0 or hi != hi0:
                break
            union_sets(parent, lo_c0, lo_c)
            union_sets(parent, hi_c0, hi_c)
            j += 1
        i = j
    return _component_labels(parent, np.ones(nh, dtype=np.bool_))[1]


@njit(**EXACT_JIT_OPTIONS)
def fast_atan2(y, x):  # pragma: no cover - numba
    """``arctan2(y, x)`` within ``ATAN_ERROR`` [rad]: an odd degree-11 polynomial for atan on
    [0, 1] (Hastings' coefficients, error 1.7e-6) and the octant symmetries; 0 at the origin
    (signed zeros are not told apart: -0.0 counts as 0)."""
    ax = abs(x)
    ay = abs(y)
    hi = max(ax, ay)
    if hi == 0.0:
        return 0.0
    t = min(ax, ay) / hi
    t2 = t * t
    a = t * (
        0.99997726
        + t2
        * (
            -0.33262347
            + t2 * (0.19354346 + t2 * (-0.11643287 + t2 * (0.05265332 + t2 * -0.01172120)))
        )
    )
    if ay > ax:
        a = 0.5 * np.pi - a
    if x < 0.0:
        a = np.pi - a
    if y < 0.0:
        a = -a
    return a


@njit(**EXACT_JIT_OPTIONS)
def vertex_component_labels(faces, n_vertices):  # pragma: no cover - numba
    """Connected components of the vertices that faces use (a face joins its three corners):
    ``(count, labels)``, ``labels`` ``(n_vertices,)`` int64 numbered ``0 .. count - 1`` in
    order of each component's lowest vertex, -1 for a vertex no face uses (the numbering of
    ``scipy.sparse.csgraph.connected_components`` restricted to the used vertices).
    """
    parent = np.arange(n_vertices)
    used = np.zeros(n_vertices, dtype=np.bool_)
    for i in range(faces.shape[0]):
        a, b, c = faces[i, 0], faces[i, 1], faces[i, 2]
        used[a] = True
        used[b] = True
        used[c] = True
        union_sets(parent, a, b)
        union_sets(parent, b, c)
    return _component_labels(parent, used)


@njit(**EXACT_JIT_OPTIONS)
def _angle(vertices, w, v, ux, uy, uz, wx, wy, wz):  # pragma: no cover - numba
    """Angle (:func:`fast_atan2`) of ``vertices[w] - vertices[v]`` in the frame
    ``e1 = (ux, uy, uz)``, ``e2 = (wx, wy, wz)``, and its squared length."""
    dx = vertices[w, 0] - vertices[v, 0]
    dy = vertices[w, 1] - vertices[v, 1]
    dz = vertices[w, 2] - vertices[v, 2]
    y = dx * wx + dy * wy + dz * wz
    x = dx * ux + dy * uy + dz * uz
    return fast_atan2(y, x), dx * dx + dy * dy + dz * dz


@njit(**EXACT_JIT_OPTIONS)
def _well_shaped(vertices, v, x, y, mx, my, mz, min_d2):  # pragma: no cover - numba
    """Is the corner ``(v, x, y)`` a proper angle (edges of length^2 >= ``min_d2``, sine of
    the angle above ``WELL_SHAPED_SINE``) whose plane is tilted less than
    ``arccos(WELL_SHAPED_COSINE)`` from the direction ``m``? Projected along ``m`` its
    sector is then a convex angle, measured the same way round, by any rounding."""
    dd, ee, nx, ny, nz = corner_cross(vertices, v, x, y)
    if dd < min_d2 or ee < min_d2:
        return False
    nn = nx * nx + ny * ny + nz * nz
    if not nn > WELL_SHAPED_SINE * WELL_SHAPED_SINE * dd * ee:
        return False
    t = nx * mx + ny * my + nz * mz
    mm = mx * mx + my * my + mz * mz
    return t > 0.0 and t * t > WELL_SHAPED_COSINE * WELL_SHAPED_COSINE * nn * mm


@njit(**EXACT_JIT_OPTIONS)
def _turn(x, two_pi):  # pragma: no cover - numba
    """``x % two_pi`` for ``x`` in (-2 pi, 2 pi) (a difference of two angles)."""
    return x + two_pi if x < 0.0 else x


@njit(**EXACT_JIT_OPTIONS)
def overlap_candidates(vertices, faces, fn, agreement, min_angle):  # pragma: no cover - numba
    """Corner pairs ``(m, 2)`` at a shared vertex whose faces may cover the same wedge.

    The prefilter of :func:`recon.mesh.overlapping_faces`: for every pair of corners ``a < b``
    at one vertex (corner ``3 i + k``), the faces' unit normals ``fn`` must agree
    (``fn_a . fn_b > agreement``) and their angular sectors around the vertex, in the plane of
    the mean normal, must share more than ``min_angle`` [rad]. A pair is left out only when it
    fails one of these by more than its margin (``OVERLAP_DOT_MARGIN``,
    ``OVERLAP_ANGLE_MARGIN``), no sector width is within ``OVERLAP_ANGLE_MARGIN`` of 0 or
    2 pi and no edge at the vertex is shorter than ``OVERLAP_MIN_EDGE``; the pairs
    kept (the overlaps and the near misses) are tested again by the caller's exact test.
    Faces that follow each other round the vertex, wound alike, are passed over when both
    corners are well shaped (:func:`_well_shaped`): projected, two convex sectors that share
    a bounding ray share no angle, and the exact test measures that ray the same for both.
    Pairs come vertex by vertex in ascending corner order.
    """
    nf = faces.shape[0]
    nh = 3 * nf
    n_vertices = vertices.shape[0]
    start = np.zeros(n_vertices + 1, dtype=np.int64)
    for c in range(nh):
        start[faces[c // 3, c % 3] + 1] += 1
    for v in range(n_vertices):
        start[v + 1] += start[v]
    fill = start[:-1].copy()
    corners = np.empty(nh, dtype=np.int64)
    for c in range(nh):
        v = faces[c // 3, c % 3]
        corners[fill[v]] = c
        fill[v] += 1
    two_pi = 2 * np.pi
    margin = OVERLAP_ANGLE_MARGIN
    dot_margin = OVERLAP_DOT_MARGIN
    min_d2 = OVERLAP_MIN_EDGE * OVERLAP_MIN_EDGE
    out = np.empty((max(16, nf // 8), 2), dtype=np.int64)
    m_out = 0
    for v in range(n_vertices):
        for i in range(start[v], start[v + 1]):
            a = corners[i]
            fa = a // 3
            for j in range(i + 1, start[v + 1]):
                b = corners[j]
                fb = b // 3
                dot = fn[fa, 0] * fn[fb, 0] + fn[fa, 1] * fn[fb, 1] + fn[fa, 2] * fn[fb, 2]
                if dot <= agreement - dot_margin:
                    continue
                keep = dot <= agreement + dot_margin
                mx = fn[fa, 0] + fn[fb, 0]
                my = fn[fa, 1] + fn[fb, 1]
                mz = fn[fa, 2] + fn[fb, 2]
                ka, kb = a % 3, b % 3
                xa, ya = faces[fa, (ka + 1) % 3], faces[fa, (ka + 2) % 3]
                xb, yb = faces[fb, (kb + 1) % 3], faces[fb, (kb + 2) % 3]
                if (
                    not keep
                    and (ya == xb or yb == xa)
                    and _well_shaped(vertices, v, xa, ya, mx, my, mz, min_d2)
                    and _well_shaped(vertices, v, xb, yb, mx, my, mz, min_d2)
                ):
                    continue  # neighbours in the fan, wound alike: their sectors only touch
                if not keep:
                    norm = np.sqrt(mx * mx + my * my + mz * mz)
                    mx, my, mz = mx / norm, my / norm, mz / norm
                    if abs(mx) < 0.9:  # e1 = m x (1, 0, 0)
                        ux, uy, uz = 0.0, mz, -my
                    else:  # e1 = m x (0, 1, 0)
                        ux, uy, uz = -mz, 0.0, mx
                    norm = np.sqrt(ux * ux + uy * uy + uz * uz)
                    ux, uy, uz = ux / norm, uy / norm, uz / norm
                    wx = my * uz - mz * uy  # e2 = m x e1
                    wy = mz * ux - mx * uz
                    wz = mx * uy - my * ux
                    start_a, d1 = _angle(vertices, xa, v, ux, uy, uz, wx, wy, wz)
                    end_a, d2 = _angle(vertices, ya, v, ux, uy, uz, wx, wy, wz)
                    start_b, d3 = _angle(vertices, xb, v, ux, uy, uz, wx, wy, wz)
                    end_b, d4 = _angle(vertices, yb, v, ux, uy, uz, wx, wy, wz)
                    # differences of angles in [-pi, pi], taken to [0, 2 pi)
                    width_a = _turn(end_a - start_a, two_pi)
                    width_b = _turn(end_b - start_b, two_pi)
                    rel = _turn(start_b - start_a, two_pi)
                    shared = max(0.0, min(width_a - rel, width_b)) + max(
                        0.0, min(width_a, rel + width_b - two_pi)
                    )
                    keep = (
                        not (shared <= min_angle - margin)  # NaN is kept
                        or width_a < margin
                        or width_a > two_pi - margin
                        or width_b < margin
                        or width_b > two_pi - margin
                        or min(min(d1, d2), min(d3, d4)) < min_d2
                    )
                if keep:
                    if m_out == out.shape[0]:
                        grown = np.empty((2 * m_out, 2), dtype=np.int64)
                        grown[:m_out] = out
                        out = grown
                    out[m_out, 0] = a
                    out[m_out, 1] = b
                    m_out += 1
    return out[:m_out].copy()
