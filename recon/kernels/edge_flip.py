r"""Edge flips that raise the smallest angle of a triangle mesh (intrinsic Delaunay flips).

An interior edge (a, b) with opposite corners c (in face a b c) and d (in face b a d) is flipped
to (c, d) when the two triangles a d c and d b c have a larger smallest angle than a b c and
b a d. In the plane this is Lawson's flip toward the Delaunay triangulation, which maximises the
smallest angle; on a surface the same local test is used, with two guards:

* the new edge must not exist already (that would make the mesh non-manifold), and
* the new triangles must face the way the old ones did: their unit normals must agree with the
  old pair's mean normal by at least ``min_normal_dot`` (no fold across a ridge), and the old
  pair must be near flat (``min_flat_dot``), so that a flip never cuts across a bend.

The connectivity (manifold, orientation, genus, boundary loops) is unchanged by a flip: the
quad a d b c keeps its outline and winding. Locked edges (feature lines) are never flipped, and a
flip that creates a *wanted* edge (a missing piece of a feature line) is always made.

.. math::

    \text{flip } (a, b) \to (c, d) \iff
    \min\angle(a d c, d b c) > \min\angle(a b c, b a d) + \varepsilon

References
----------
.. [L77] C. L. Lawson. "Software for C1 surface interpolation". Mathematical Software III, 1977.
.. [BK04] M. Botsch, L. Kobbelt. "A remeshing approach to multiresolution modeling". SGP 2004
   (flips inside isotropic remeshing).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .options import EXACT_JIT_OPTIONS


@njit(**EXACT_JIT_OPTIONS)
def _min_angle_cos(p, q, r):  # pragma: no cover - numba
    """Largest cosine among the three angles of triangle p q r (= cosine of its smallest angle)."""
    best = -1.0
    for k in range(3):
        if k == 0:
            o, u, w = p, q, r
        elif k == 1:
            o, u, w = q, r, p
        else:
            o, u, w = r, p, q
        ux, uy, uz = u[0] - o[0], u[1] - o[1], u[2] - o[2]
        wx, wy, wz = w[0] - o[0], w[1] - o[1], w[2] - o[2]
        lu = np.sqrt(ux * ux + uy * uy + uz * uz)
        lw = np.sqrt(wx * wx + wy * wy + wz * wz)
        if lu <= 0.0 or lw <= 0.0:
            return 1.0
        c = (ux * wx + uy * wy + uz * wz) / (lu * lw)
        if c > best:
            best = c
    return best


@njit(**EXACT_JIT_OPTIONS)
def _unit_normal(p, q, r):  # pragma: no cover - numba
    ux, uy, uz = q[0] - p[0], q[1] - p[1], q[2] - p[2]
    wx, wy, wz = r[0] - p[0], r[1] - p[1], r[2] - p[2]
    nx, ny, nz = uy * wz - uz * wy, uz * wx - ux * wz, ux * wy - uy * wx
    ln = np.sqrt(nx * nx + ny * ny + nz * nz)
    out = np.zeros(3)
    if ln > 0.0:
        out[0], out[1], out[2] = nx / ln, ny / ln, nz / ln
    return out


@njit(**EXACT_JIT_OPTIONS)
def _improves(pa, pb, pc, pd, min_normal_dot, min_flat_dot, eps):  # pragma: no cover - numba
    """Does flipping (a, b) -> (c, d) raise the smallest angle without a fold?"""
    old = max(_min_angle_cos(pa, pb, pc), _min_angle_cos(pb, pa, pd))
    new = max(_min_angle_cos(pa, pd, pc), _min_angle_cos(pd, pb, pc))
    if not new < old - eps:
        return False
    n1, n2 = _unit_normal(pa, pb, pc), _unit_normal(pb, pa, pd)
    if n1[0] * n2[0] + n1[1] * n2[1] + n1[2] * n2[2] < min_flat_dot:
        return False
    mean = n1 + n2
    lm = np.sqrt(mean[0] ** 2 + mean[1] ** 2 + mean[2] ** 2)
    if lm <= 0.0:
        return False
    mean /= lm
    m1, m2 = _unit_normal(pa, pd, pc), _unit_normal(pd, pb, pc)
    return not (
        m1[0] * mean[0] + m1[1] * mean[1] + m1[2] * mean[2] < min_normal_dot
        or m2[0] * mean[0] + m2[1] * mean[1] + m2[2] * mean[2] < min_normal_dot
    )


@njit(**EXACT_JIT_OPTIONS)
def _valence_better(
    pa, pb, pc, pd, da, db, dc, dd, min_normal_dot, min_flat_dot, eps, valence_min_cos
):  # pragma: no cover - numba
    """The valence mode's test; ``da``... are the valences' deviations from their targets.

    A pair with an angle below the floor (cosine above ``valence_min_cos``) is flipped when
    that raises its smallest angle; otherwise a flip must lower the squared valence deviation
    (or keep it and raise the smallest angle) and keep every angle above the floor. Both rules
    lower (deviation, -smallest angle) lexicographically or lift a pair above the floor, so
    the flips do not cycle.
    """
    old = max(_min_angle_cos(pa, pb, pc), _min_angle_cos(pb, pa, pd))
    if old > valence_min_cos:
        return _improves(pa, pb, pc, pd, min_normal_dot, min_flat_dot, eps)
    new = max(_min_angle_cos(pa, pd, pc), _min_angle_cos(pd, pb, pc))
    if new > valence_min_cos:
        return False
    dev_old = da * da + db * db + dc * dc + dd * dd
    dev_new = (da - 1) ** 2 + (db - 1) ** 2 + (dc + 1) ** 2 + (dd + 1) ** 2
    if dev_new > dev_old or (dev_new == dev_old and not new < old - eps):
        return False
    return _improves(pa, pb, pc, pd, min_normal_dot, min_flat_dot, -2.0)


@njit(**EXACT_JIT_OPTIONS)
def flip_edges_kernel(
    vertices,
    faces,
    opposite,
    locked,
    wanted,
    target,
    min_normal_dot,
    min_flat_dot,
    eps,
    max_passes,
    valence_min_cos,
):  # pragma: no cover - numba
    """Flip edges in place until no flip raises the smallest angle (or ``max_passes``).

    Parameters
    ----------
    vertices : (V, 3) float64
    faces : (F, 3) int64
        Modified in place.
    opposite : (3 F,) int64
        Half-edge ``3 f + k`` (corner k -> k + 1 of face f) -> its twin half-edge, -1 on the
        boundary. Modified in place.
    locked : (3 F,) bool
        Half-edges that must not be flipped (both halves of an edge set). Modified in place.
    wanted : (k,) int64
        Keys ``lo * V + hi`` of edges that should exist (feature lines): a flip that creates
        one is made whatever the angles and the fold guards say, and the edge is then locked.
    min_normal_dot, min_flat_dot : float64
        Fold guards (module docstring).
    eps : float64
        Smallest gain in the cosine of the smallest angle for a flip.
    max_passes : int
    target : (V,) int64
        Ideal valence of each vertex (6 inside, 4 on a boundary). Used when
        ``valence_min_cos < 1``: a flip is also made when it lowers the valences' squared
        deviation from their targets and leaves no angle below ``arccos(valence_min_cos)``.
    valence_min_cos : float64
        1 for angle flips only.

    Returns
    -------
    int : number of flips.
    """
    n_f = faces.shape[0]
    n_v = vertices.shape[0]
    edges = dict()
    for f in range(n_f):
        for k in range(3):
            a = faces[f, k]
            b = faces[f, (k + 1) % 3]
            lo, hi = min(a, b), max(a, b)
            edges[lo * n_v + hi] = True
    want = dict()
    for k in range(wanted.shape[0]):
        want[wanted[k]] = True
    has_wanted = wanted.shape[0] > 0
    valence = np.zeros(n_v, dtype=np.int64)
    for f in range(n_f):
        for k in range(3):
            valence[faces[f, k]] += 1
    # faces around a vertex = its valence inside; one less than the valence on a boundary
    for h in range(3 * n_f):
        if opposite[h] < 0:
            valence[faces[h // 3, h % 3]] += 1
    total = 0
    # after the first pass only edges of faces that a flip changed (or bordered) are tried
    dirty = np.ones(n_f, dtype=np.bool_)
    for _ in range(max_passes):
        flips = 0
        touched = np.zeros(n_f, dtype=np.bool_)
        for h in range(3 * n_f):
            o = opposite[h]
            if o < h or locked[h]:
                continue
            f, k = h // 3, h % 3
            g, m = o // 3, o % 3
            if not (dirty[f] or dirty[g]):
                continue
            a = faces[f, k]
            b = faces[f, (k + 1) % 3]
            c = faces[f, (k + 2) % 3]
            d = faces[g, (m + 2) % 3]
            if c == d:
                continue
            key = min(c, d) * n_v + max(c, d)
            pa, pb, pc, pd = vertices[a], vertices[b], vertices[c], vertices[d]
            forced = has_wanted and key in want
            if not forced:
                if valence_min_cos >= 1.0:
                    better = _improves(pa, pb, pc, pd, min_normal_dot, min_flat_dot, eps)
                else:
                    better = _valence_better(
                        pa, pb, pc, pd, valence[a] - target[a], valence[b] - target[b],
                        valence[c] - target[c], valence[d] - target[d], min_normal_dot,
                        min_flat_dot, eps, valence_min_cos,
                    )  # fmt: skip
                if not better:
                    continue
            if key in edges:  # the new edge exists elsewhere: the flip would be non-manifold
                continue
            # outer half-edges before the flip: b->c (f), c->a (f), a->d (g), d->b (g)
            h_bc, h_ca = 3 * f + (k + 1) % 3, 3 * f + (k + 2) % 3
            h_ad, h_db = 3 * g + (m + 1) % 3, 3 * g + (m + 2) % 3
            o_bc, o_ca, o_ad, o_db = (
                opposite[h_bc],
                opposite[h_ca],
                opposite[h_ad],
                opposite[h_db],
            )
            l_bc, l_ca, l_ad, l_db = locked[h_bc], locked[h_ca], locked[h_ad], locked[h_db]
            # new faces: f = (a, d, c), g = (d, b, c); half-edges 3f+0 a->d, 3f+1 d->c,
            # 3f+2 c->a, 3g+0 d->b, 3g+1 b->c, 3g+2 c->d
            faces[f, 0], faces[f, 1], faces[f, 2] = a, d, c
            faces[g, 0], faces[g, 1], faces[g, 2] = d, b, c
            news = (3 * f, 3 * f + 2, 3 * g, 3 * g + 1)
            olds = (o_ad, o_ca, o_db, o_bc)
            locks = (l_ad, l_ca, l_db, l_bc)
            touched[f] = True
            touched[g] = True
            for i in range(4):
                opposite[news[i]] = olds[i]
                locked[news[i]] = locks[i]
                if olds[i] >= 0:
                    opposite[olds[i]] = news[i]
                    touched[olds[i] // 3] = True
            opposite[3 * f + 1] = 3 * g + 2
            opposite[3 * g + 2] = 3 * f + 1
            locked[3 * f + 1] = forced
            locked[3 * g + 2] = forced
            valence[a] -= 1
            valence[b] -= 1
            valence[c] += 1
            valence[d] += 1
            del edges[min(a, b) * n_v + max(a, b)]
            edges[key] = True
            flips += 1
        total += flips
        if flips == 0:
            break
        dirty = touched
    return total
