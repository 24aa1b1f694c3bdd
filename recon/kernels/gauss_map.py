"""Gauss-map clustering of neighbourhood normals: the per-point kernel of crease detection.

For each point the normals of its ``K`` nearest data points are clustered as *axes* (a normal
and its negative are the same axis, so the result does not depend on orientation): Lloyd
iterations of 2-means and then 3-means with the cost ``1 - |n . c|`` [WHH10]. A cluster's
centre is the normalised sum of its members' normals after flipping each to agree with the
centre; its *spread* is the median angle between its members and the centre.

For each pair of clusters ``(a, b)`` the kernel fits one plane per cluster (by PCA of the
member points) and intersects them: the crease line runs along

.. math::  d = n_a \\times n_b / |n_a \\times n_b|

through the point ``x_0`` of the line closest to the query point ``p``. The *turning angle*
(the angle between the two face normals: 0 on a plane, 90 deg on a box edge, near 180 deg on a
knife edge) is measured from the geometry, so that unoriented normals suffice: with ``u_a``
the unit direction from the line to the centroid of cluster ``a`` (perpendicular to ``d``),
the wedge angle is ``acos(u_a . u_b)`` and the turning angle is 180 deg minus it.

A pair *separates* when the axial angle between the two centres exceeds
``ratio * (spread_a + spread_b)``: two tight, distinct clusters. A smooth surface gives a
continuum of normals, whose halves lie about two spreads apart (a uniform arc: separation
Phi/2, spreads Phi/8 each), and noise widens the spreads with the separation, so this ratio is
the noise floor.

**Knife edges (eq. K1).** Past ``180 deg - min_turn`` the two faces' normal *axes* lie closer
than ``min_turn`` (a 150 deg turn: 30 deg), and within a neighbourhood radius of such an edge
every normal is a blend of both faces (the other face is within ``s sin(180 deg - turn)`` of
a point ``s`` from the edge), so the normals do not split. Where the 2-means clusters' planes
are closer than ``min_turn`` as axes, two planes are refitted to the *points* of the whole
neighbourhood by alternation (``k``-planes: each point joins the nearer plane,

.. math::  \\min_{n_c, c_c} \\sum_j \\min_c (n_c \\cdot (p_j - c_c))^2,

each plane refitted by PCA to its members, a point within a factor ``_CLEAR`` of both planes
not taking part), and the pair counts as a crease when each plane holds ``crease_share`` of the
points, their RMS distance is at most ``knife_ratio`` times the distance to one PCA plane, the
turn measured from the centroids exceeds ``min_turn`` and the line passes within ``_REACH``
neighbourhood radii (nearly parallel planes of rounding errors meet far away).

Labels: 2 (corner) when all three pairs of the 3-means separate, turn by more than the
threshold, the smallest cluster holds ``corner_share`` of the points and the third axis leaves
the plane of the other two by more than ``asin(min_det)`` (a blend of two faces' normals lies in
that plane); else 1 (crease) when
the 2-means pair does so with ``crease_share``; else 0.

References
----------
[WHH10] C. Weber, S. Hahmann, H. Hagen. "Sharp feature detection in point clouds".
        Shape Modeling International 2010, 175-186.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from .options import EXACT_JIT_OPTIONS

_PARALLEL = dict(EXACT_JIT_OPTIONS, parallel=True)
_ITERATIONS = 10
#: A point takes part in a refit of its plane (eq. K1) when the other plane is at least this
#: many times farther from it.
_CLEAR = 2.0
_REACH = 4.0


@njit(**EXACT_JIT_OPTIONS)
def _lloyd(nb, centres, m, assign):  # pragma: no cover - numba
    """Axial Lloyd iterations on the unit normals ``nb`` with ``m`` initial ``centres``.

    Stops early at a fixed point: when an update leaves every centre bit-identical, the
    iterations left would repeat it (same assignment, same sums), so the result is that of
    all ``_ITERATIONS``."""
    kk = nb.shape[0]
    previous = np.empty((m, 3))
    for _ in range(_ITERATIONS):
        previous[:, :] = centres[:m]
        for j in range(kk):
            best = -1.0
            arg = 0
            for c in range(m):
                dot = abs(
                    nb[j, 0] * centres[c, 0] + nb[j, 1] * centres[c, 1] + nb[j, 2] * centres[c, 2]
                )
                if dot > best:
                    best = dot
                    arg = c
            assign[j] = arg
        for c in range(m):
            sx = 0.0
            sy = 0.0
            sz = 0.0
            for j in range(kk):
                if assign[j] == c:
                    dot = (
                        nb[j, 0] * centres[c, 0]
                        + nb[j, 1] * centres[c, 1]
                        + nb[j, 2] * centres[c, 2]
                    )
                    s = 1.0 if dot >= 0.0 else -1.0
                    sx += s * nb[j, 0]
                    sy += s * nb[j, 1]
                    sz += s * nb[j, 2]
            norm = np.sqrt(sx * sx + sy * sy + sz * sz)
            if norm > 0.0:
                centres[c, 0] = sx / norm
                centres[c, 1] = sy / norm
                centres[c, 2] = sz / norm
        if np.all(centres[:m] == previous):
            break


@njit(**EXACT_JIT_OPTIONS)
def _clusters(nb, pts, centres, m, assign, share, spread, centroid, plane):  # pragma: no cover
    """Share, spread (median angle to the centre) and centroid per cluster; ``plane`` is set to
    the centres (:func:`_planes` refits it to the member points where it is needed)."""
    kk = nb.shape[0]
    angles = np.empty(kk)
    for c in range(m):
        cnt = 0
        cx = 0.0
        cy = 0.0
        cz = 0.0
        for j in range(kk):
            if assign[j] == c:
                dot = abs(
                    nb[j, 0] * centres[c, 0] + nb[j, 1] * centres[c, 1] + nb[j, 2] * centres[c, 2]
                )
                angles[cnt] = np.arccos(min(dot, 1.0))
                cnt += 1
                cx += pts[j, 0]
                cy += pts[j, 1]
                cz += pts[j, 2]
        share[c] = cnt / kk
        if cnt > 0:
            spread[c] = np.median(angles[:cnt])
            centroid[c, 0] = cx / cnt
            centroid[c, 1] = cy / cnt
            centroid[c, 2] = cz / cnt
        else:
            spread[c] = np.pi
            centroid[c, :] = pts[0]
        plane[c] = centres[c]


@njit(**EXACT_JIT_OPTIONS)
def _planes(pts, centres, m, assign, centroid, plane):  # pragma: no cover - numba
    """Plane normal per cluster of :func:`_clusters`: PCA of the member points about their
    centroid, signed like the centre (the centre itself, left in ``plane``, with fewer than 3
    members). Three eigen-decompositions per point of the 3-means are most of a smooth
    point's cost, and only a pair of clusters that separates needs them."""
    kk = pts.shape[0]
    for c in range(m):
        cnt = 0
        for j in range(kk):
            if assign[j] == c:
                cnt += 1
        if cnt < 3:
            continue
        cov = np.zeros((3, 3))
        r = np.empty(3)
        for j in range(kk):
            if assign[j] == c:
                for a in range(3):  # pts[j] - centroid[c], without a temporary per member
                    r[a] = pts[j, a] - centroid[c, a]
                for a in range(3):
                    for b in range(3):
                        cov[a, b] += r[a] * r[b]
        _, vec = np.linalg.eigh(cov)
        nrm = vec[:, 0].copy()
        if nrm @ centres[c] < 0.0:
            nrm = -nrm
        plane[c] = nrm


@njit(**EXACT_JIT_OPTIONS)
def _pair(p, na, nb_, ca, cb, out_d, out_x0):  # pragma: no cover - numba
    """Intersect the planes (na, ca) and (nb_, cb); return (turning angle, distance, in-face
    distance) of ``p`` and write the unit direction and the closest line point."""
    c = na[0] * nb_[0] + na[1] * nb_[1] + na[2] * nb_[2]
    dx = na[1] * nb_[2] - na[2] * nb_[1]
    dy = na[2] * nb_[0] - na[0] * nb_[2]
    dz = na[0] * nb_[1] - na[1] * nb_[0]
    dn = np.sqrt(dx * dx + dy * dy + dz * dz)
    det = 1.0 - c * c
    if dn < 1e-9 or det < 1e-12:
        return 0.0, np.inf, np.inf
    dx /= dn
    dy /= dn
    dz /= dn
    ra = na[0] * (ca[0] - p[0]) + na[1] * (ca[1] - p[1]) + na[2] * (ca[2] - p[2])
    rb = nb_[0] * (cb[0] - p[0]) + nb_[1] * (cb[1] - p[1]) + nb_[2] * (cb[2] - p[2])
    a = (ra - c * rb) / det
    b = (rb - c * ra) / det
    # scalars, not small arrays: the same operations in the same order, no allocations
    x0x = p[0] + a * na[0] + b * nb_[0]
    x0y = p[1] + a * na[1] + b * nb_[1]
    x0z = p[2] + a * na[2] + b * nb_[2]
    uax = ca[0] - x0x
    uay = ca[1] - x0y
    uaz = ca[2] - x0z
    ubx = cb[0] - x0x
    uby = cb[1] - x0y
    ubz = cb[2] - x0z
    sa = uax * dx + uay * dy + uaz * dz
    sb = ubx * dx + uby * dy + ubz * dz
    uax -= sa * dx
    uay -= sa * dy
    uaz -= sa * dz
    ubx -= sb * dx
    uby -= sb * dy
    ubz -= sb * dz
    la = np.sqrt(uax**2 + uay**2 + uaz**2)
    lb = np.sqrt(ubx**2 + uby**2 + ubz**2)
    if la == 0.0 or lb == 0.0:
        return 0.0, np.inf, np.inf
    uax /= la
    uay /= la
    uaz /= la
    ubx /= lb
    uby /= lb
    ubz /= lb
    cw = min(1.0, max(-1.0, uax * ubx + uay * uby + uaz * ubz))
    turn = np.pi - np.arccos(cw)
    rx = p[0] - x0x
    ry = p[1] - x0y
    rz = p[2] - x0z
    dist = np.sqrt(a * a + b * b + 2.0 * a * b * c)
    inface = max(
        abs(rx * uax + ry * uay + rz * uaz),
        abs(rx * ubx + ry * uby + rz * ubz),
    )
    out_d[0] = dx
    out_d[1] = dy
    out_d[2] = dz
    out_x0[0] = x0x
    out_x0[1] = x0y
    out_x0[2] = x0z
    return turn, dist, inface


@njit(**_PARALLEL)
def gauss_map_kernel(
    points,
    normals,
    variation,
    query,
    idx,
    keep,
    min_turn,
    ratio,
    crease_share,
    corner_share,
    min_det,
    knife_ratio=0.0,
):  # pragma: no cover - numba
    """Classify the points ``query`` (n, 3) from the normals of their neighbours ``idx`` (n, K)
    among ``points``.

    Only the ``keep`` neighbours of least surface ``variation`` (the PCA ratio
    ``l3 / (l1 + l2 + l3)``) are clustered: the normals of points within a normal-estimation
    radius of an edge are blends of both sides and would fill the gap between the clusters.

    Returns
    -------
    label : (n,) int8
        0 smooth, 1 crease, 2 corner.
    side : (n, 3, 3) float64
        The cluster centre normals (two for a crease, three for a corner), each signed to
        agree with the majority of its members' input normals.
    direction : (n, 3) float64
        For a crease the unit crease direction ``n1 x n2``; zero otherwise.
    turn : (n,) float64 [rad]
        Turning angle of the crease (the smallest pair's for a corner); 0 when smooth.
    inface : (n,) float64 [length]
        In-face distance from the point to its crease line (the nearest of the three pair
        lines for a corner); inf when smooth.
    corner : (n, 3) float64
        For a corner the least-squares intersection of the three planes; NaN otherwise.
    spread : (n, 2) float64 [rad]
        The spreads of the two 2-means clusters.
    foot : (n, 3) float64
        For a crease the point of its line closest to the point; NaN otherwise.
    """
    n = idx.shape[0]
    kk = keep
    label = np.zeros(n, np.int8)
    side = np.zeros((n, 3, 3))
    direction = np.zeros((n, 3))
    turn_out = np.zeros(n)
    inface_out = np.full(n, np.inf)
    corner = np.full((n, 3), np.nan)
    spread_out = np.zeros((n, 2))
    foot = np.full((n, 3), np.nan)
    for i in prange(n):
        # the ``keep`` most planar neighbours: drops the normals blended across an edge
        order = np.argsort(variation[idx[i]], kind="mergesort")[:kk]
        nb = np.empty((kk, 3))
        pts = np.empty((kk, 3))
        for j in range(kk):
            nb[j] = normals[idx[i, order[j]]]
            pts[j] = points[idx[i, order[j]]]
        # medoid axis, then the member farthest from it
        best = -1.0
        m0 = 0
        for j in range(kk):
            s = 0.0
            for q in range(kk):
                s += abs(nb[j, 0] * nb[q, 0] + nb[j, 1] * nb[q, 1] + nb[j, 2] * nb[q, 2])
            if s > best:
                best = s
                m0 = j
        centres = np.zeros((3, 3))
        centres[0] = nb[m0]
        worst = 2.0
        m1 = 0
        for j in range(kk):
            dot = abs(nb[j, 0] * nb[m0, 0] + nb[j, 1] * nb[m0, 1] + nb[j, 2] * nb[m0, 2])
            if dot < worst:
                worst = dot
                m1 = j
        centres[1] = nb[m1]
        assign = np.zeros(kk, np.int64)
        _lloyd(nb, centres, 2, assign)
        share = np.zeros(3)
        spread = np.zeros(3)
        centroid = np.zeros((3, 3))
        plane = np.zeros((3, 3))
        _clusters(nb, pts, centres, 2, assign, share, spread, centroid, plane)
        _planes(pts, centres, 2, assign, centroid, plane)  # the knife gate needs them
        spread_out[i, 0] = spread[0]
        spread_out[i, 1] = spread[1]
        d = np.zeros(3)
        x0 = np.zeros(3)
        sep2 = np.arccos(min(1.0, abs(centres[0] @ centres[1])))
        crease_ok = False
        t2 = 0.0
        dist2 = np.inf
        d2 = np.zeros(3)
        x2 = np.zeros(3)
        if min(share[0], share[1]) >= crease_share and sep2 > ratio * (spread[0] + spread[1]):
            t2, _, dist2 = _pair(query[i], centres[0], centres[1], centroid[0], centroid[1], d2, x2)
            crease_ok = t2 > min_turn
        # three clusters: the 2-means centres plus the worst-explained member
        c3 = centres.copy()
        c3[2] = nb[_worst(nb, c3, 2)]
        assign3 = np.zeros(kk, np.int64)
        _lloyd(nb, c3, 3, assign3)
        share3 = np.zeros(3)
        spread3 = np.zeros(3)
        centroid3 = np.zeros((3, 3))
        plane3 = np.zeros((3, 3))
        # a corner needs corner_share of the points in each cluster: count first, and only
        # then take the spreads and centroids (which nothing else uses)
        counts3 = np.zeros(3)
        for j in range(kk):
            counts3[assign3[j]] += 1.0
        corner_ok = min(counts3[0], min(counts3[1], counts3[2])) / kk >= corner_share
        if corner_ok:
            _clusters(nb, pts, c3, 3, assign3, share3, spread3, centroid3, plane3)
        tmin = np.inf
        dmin = np.inf
        fitted3 = False
        for a in range(3):
            if not corner_ok:
                break
            for b in range(a + 1, 3):
                sep = np.arccos(min(1.0, abs(c3[a] @ c3[b])))
                if sep <= ratio * (spread3[a] + spread3[b]):
                    corner_ok = False
                    break
                if not fitted3:  # first separated pair: the planes are needed from here on
                    _planes(pts, c3, 3, assign3, centroid3, plane3)
                    fitted3 = True
                t, _, dd = _pair(query[i], plane3[a], plane3[b], centroid3[a], centroid3[b], d, x0)
                if t <= min_turn:
                    corner_ok = False
                    break
                tmin = min(tmin, t)
                dmin = min(dmin, dd)
        if corner_ok:
            # least-squares intersection of the three planes
            mat = np.zeros((3, 3))
            rhs = np.zeros(3)
            for a in range(3):
                mat[a] = plane3[a]
                rhs[a] = plane3[a] @ centroid3[a]
            # a third axis in the plane of the other two is a blend, not a third face
            cr = np.cross(mat[0], mat[1])
            cn = np.sqrt(cr @ cr)
            if cn > 0.0 and abs(cr @ mat[2]) > min_det * cn:
                corner[i] = np.linalg.solve(mat, rhs)
                label[i] = 2
                turn_out[i] = tmin
                inface_out[i] = dmin
                _sign(nb, plane3, assign3, 3)
                side[i] = plane3
                continue
        knife = False
        if knife_ratio > 0.0:
            # a knife edge (eq. K1): two faces turning by more than 180 deg - min_turn have
            # axes closer than min_turn and the normals blended across the edge fill the gap
            # between them; two planes refitted to the whole neighbourhood's points tell it
            sep = np.arccos(min(1.0, abs(plane[0] @ plane[1])))
            # a cheap gate: the clusters' own planes fold by more than half of min_turn (on a
            # smooth surface the two halves lie on both sides of their planes' line: their
            # turn is about the angle between them)
            t0, _, _ = _pair(query[i], plane[0], plane[1], centroid[0], centroid[1], d, x0)
            if sep < min_turn and t0 > 0.5 * min_turn:
                allp = np.empty((idx.shape[1], 3))
                alln = np.empty((idx.shape[1], 3))
                for j in range(idx.shape[1]):
                    allp[j] = points[idx[i, j]]
                    alln[j] = normals[idx[i, j]]
                kp = plane[:2].copy()
                kc = centroid[:2].copy()
                member = np.zeros(idx.shape[1], np.int64)
                rms2, kshare = _two_planes(allp, kp, kc, member)
                if kshare >= crease_share and rms2 <= knife_ratio * _one_plane_rms(allp):
                    kt, kd, kin = _pair(query[i], kp[0], kp[1], kc[0], kc[1], d, x0)
                    # the line is near (within _REACH neighbourhood radii: on a thin knife
                    # the far face is in reach well away from the edge); nearly parallel
                    # planes of rounding errors meet far away
                    # (scalars: the same squares and sums, no temporary per neighbour)
                    reach = 0.0
                    for j in range(idx.shape[1]):
                        e0 = allp[j, 0] - query[i, 0]
                        e1 = allp[j, 1] - query[i, 1]
                        e2 = allp[j, 2] - query[i, 2]
                        reach = max(reach, np.sqrt(e0 * e0 + e1 * e1 + e2 * e2))
                    if kt > min_turn and kd <= _REACH * reach:
                        crease_ok = True
                        t2, dist2 = kt, kin
                        d2[:] = d
                        x2[:] = x0
                        _sign(alln, kp, member, 2)
                        plane[0] = kp[0]
                        plane[1] = kp[1]
                        knife = True
        if crease_ok:
            foot[i] = x2
            label[i] = 1
            turn_out[i] = t2
            inface_out[i] = dist2
            if not knife:  # the knife's planes are signed by all their members
                _sign(nb, plane, assign, 2)
            side[i, :2] = plane[:2]
            dx = plane[0, 1] * plane[1, 2] - plane[0, 2] * plane[1, 1]
            dy = plane[0, 2] * plane[1, 0] - plane[0, 0] * plane[1, 2]
            dz = plane[0, 0] * plane[1, 1] - plane[0, 1] * plane[1, 0]
            dn = np.sqrt(dx * dx + dy * dy + dz * dz)
            direction[i, 0] = dx / dn
            direction[i, 1] = dy / dn
            direction[i, 2] = dz / dn
    return label, side, direction, turn_out, inface_out, corner, spread_out, foot


@njit(**EXACT_JIT_OPTIONS)
def _two_planes(pts, planes, centroids, member):  # pragma: no cover - numba
    """Eq. K1: refit two planes (unit ``planes`` through ``centroids``, updated in place) to
    the points ``pts`` by alternation: each point joins the nearer plane (``member``), each
    plane is refitted by PCA (keeping its sign) to its members that the other plane is at
    least ``_CLEAR`` times farther from; stops when no point changes plane. Returns the RMS
    distance of the points to their planes and the smaller plane's share of the points (0
    when a plane keeps fewer than three such members)."""
    k = pts.shape[0]
    clear = np.zeros(k, np.bool_)
    cov = np.zeros((3, 3))
    for it in range(_ITERATIONS):
        changed = False
        for j in range(k):
            da = 0.0
            db = 0.0
            for t in range(3):
                da += planes[0, t] * (pts[j, t] - centroids[0, t])
                db += planes[1, t] * (pts[j, t] - centroids[1, t])
            da = abs(da)
            db = abs(db)
            m = 0 if da <= db else 1
            if m != member[j] or it == 0:
                changed = True
            member[j] = m
            # near the line a point fits both planes: it does not pull either
            clear[j] = max(da, db) >= _CLEAR * min(da, db)
        if not changed:
            break
        for c in range(2):
            cnt = 0
            cx = 0.0
            cy = 0.0
            cz = 0.0
            for j in range(k):
                if member[j] == c and clear[j]:
                    cx += pts[j, 0]
                    cy += pts[j, 1]
                    cz += pts[j, 2]
                    cnt += 1
            if cnt < 3:
                return np.inf, 0.0
            cx /= cnt
            cy /= cnt
            cz /= cnt
            cov[:, :] = 0.0
            for j in range(k):
                if member[j] == c and clear[j]:
                    rx = pts[j, 0] - cx
                    ry = pts[j, 1] - cy
                    rz = pts[j, 2] - cz
                    cov[0, 0] += rx * rx
                    cov[0, 1] += rx * ry
                    cov[0, 2] += rx * rz
                    cov[1, 1] += ry * ry
                    cov[1, 2] += ry * rz
                    cov[2, 2] += rz * rz
            cov[1, 0] = cov[0, 1]
            cov[2, 0] = cov[0, 2]
            cov[2, 1] = cov[1, 2]
            _, vec = np.linalg.eigh(cov)
            s = vec[0, 0] * planes[c, 0] + vec[1, 0] * planes[c, 1] + vec[2, 0] * planes[c, 2]
            sign = 1.0 if s >= 0.0 else -1.0
            for t in range(3):
                planes[c, t] = sign * vec[t, 0]
            centroids[c, 0] = cx
            centroids[c, 1] = cy
            centroids[c, 2] = cz
    sq = 0.0
    cnt0 = 0
    for j in range(k):
        c = member[j]
        cnt0 += 1 - c
        dist = 0.0
        for t in range(3):
            dist += planes[c, t] * (pts[j, t] - centroids[c, t])
        sq += dist * dist
    return np.sqrt(sq / k), min(cnt0, k - cnt0) / k


@njit(**EXACT_JIT_OPTIONS)
def _one_plane_rms(pts):  # pragma: no cover - numba
    """RMS distance of ``pts`` to their PCA plane (the root of the least eigenvalue / n).

    The centroid and the scatter matrix (the sum of the outer products ``r r^T``) are summed in
    scalars, point by point in the same order as array sums would: no temporary per point
    (the knife gate runs it for many smooth points)."""
    n = pts.shape[0]
    c0 = 0.0
    c1 = 0.0
    c2 = 0.0
    for j in range(n):
        c0 += pts[j, 0]
        c1 += pts[j, 1]
        c2 += pts[j, 2]
    c0 /= n
    c1 /= n
    c2 /= n
    s00 = 0.0
    s01 = 0.0
    s02 = 0.0
    s11 = 0.0
    s12 = 0.0
    s22 = 0.0
    for j in range(n):
        r0 = pts[j, 0] - c0
        r1 = pts[j, 1] - c1
        r2 = pts[j, 2] - c2
        s00 += r0 * r0
        s01 += r0 * r1
        s02 += r0 * r2
        s11 += r1 * r1
        s12 += r1 * r2
        s22 += r2 * r2
    cov = np.empty((3, 3))
    cov[0, 0] = s00
    cov[0, 1] = s01
    cov[0, 2] = s02
    cov[1, 0] = s01
    cov[1, 1] = s11
    cov[1, 2] = s12
    cov[2, 0] = s02
    cov[2, 1] = s12
    cov[2, 2] = s22
    return np.sqrt(max(np.linalg.eigvalsh(cov)[0], 0.0) / n)


@njit(**EXACT_JIT_OPTIONS)
def _sign(nb, centres, assign, m):  # pragma: no cover - numba
    """Sign each centre to agree with the majority of its members' input normals."""
    for c in range(m):
        s = 0.0
        for j in range(nb.shape[0]):
            if assign[j] == c:
                dot = nb[j] @ centres[c]
                s += 1.0 if dot >= 0.0 else -1.0
        if s < 0.0:
            centres[c] = -centres[c]


@njit(**EXACT_JIT_OPTIONS)
def _worst(nb, centres, m):  # pragma: no cover - numba
    """Index of the member least explained by the first ``m`` centres."""
    worst = 2.0
    arg = 0
    for j in range(nb.shape[0]):
        best = 0.0
        for c in range(m):
            best = max(best, abs(nb[j] @ centres[c]))
        if best < worst:
            worst = best
            arg = j
    return arg
