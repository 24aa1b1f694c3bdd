r"""Local surface kernels: tangent frames, quadric fits and angular gaps (S&T92 §7).

Used by :mod:`recon.surface` (the data seen as a surface) and by the growing rule
(:mod:`recon.kernels.growth_rules`).

References
----------
.. [ST92] R. Szeliski, D. Tonnesen. "Surface Modeling with Oriented Particle Systems".
   SIGGRAPH '92, §7.
.. [H92] Hoppe, DeRose, Duchamp, McDonald, Stuetzle. "Surface reconstruction from unorganized
   points". SIGGRAPH 1992 (tangent planes by PCA of k nearest neighbours).
.. [L98] D. Levin. "The approximation power of moving least-squares". Math. Comp. 67, 1998.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from .options import EXACT_JIT_OPTIONS

_PARALLEL = dict(EXACT_JIT_OPTIONS, parallel=True)


@njit(**EXACT_JIT_OPTIONS)
def select_agreeing(normals, idx, k):  # pragma: no cover - numba
    """The first ``k`` neighbours of each row of ``idx`` whose normals agree with the row's.

    Row i keeps, in order, the entries q of ``idx[i]`` with ``normals[q] . normals[i] > 0``
    (the data of the same sheet: the other side of a thin part has opposed normals), up to
    ``k``; when fewer than ``k`` agree, the row is padded by repeating its agreeing entries
    (which leaves the centroid and the least-squares fits unchanged up to weights). Rows with
    fewer than 3 agreeing entries keep their first ``k`` entries unfiltered.
    """
    n, m = idx.shape
    out = np.empty((n, k), dtype=np.int64)
    for i in range(n):
        c = 0
        for a in range(m):
            q = idx[i, a]
            dot = (
                normals[q, 0] * normals[i, 0]
                + normals[q, 1] * normals[i, 1]
                + normals[q, 2] * normals[i, 2]
            )
            if dot > 0.0:
                out[i, c] = q
                c += 1
                if c == k:
                    break
        if c < 3:
            for a in range(k):
                out[i, a] = idx[i, a]
            continue
        for a in range(c, k):
            out[i, a] = out[i, a - c]
    return out


@njit(**_PARALLEL)
def fit_quadrics_kernel(
    points, normals, idx, out_p, out_n, out_u, out_a, out_r
):  # pragma: no cover - numba
    r"""PCA frame and least-squares quadric height field of each neighbourhood [H92, L98].

    For point i with neighbours N_i (``idx[i]``, itself included; :func:`select_agreeing`
    keeps the points of the same sheet): centroid c, frame normal the
    least-variance axis (flipped to agree with ``normals[i]``), tangent u the largest-variance
    axis and v = n x u; then, with x, y, z the coordinates of p - c in (u, v, n),

    .. math::

        \min_a \sum_{p \in N_i} \bigl(z - (a_0 + a_1 x + a_2 y + a_3 x^2 + a_4 x y
            + a_5 y^2)\bigr)^2

    solved on x, y scaled by the largest principal deviation, with a small ridge (1e-6 of the
    trace's first entry). Writes centroid, normal, tangent, coefficients and the RMS residual
    into ``out_p``, ``out_n``, ``out_u``, ``out_a``, ``out_r`` (row i). Threaded over the
    points; each iteration writes only its own rows, so any thread count gives the same result.
    """
    n, k = idx.shape
    for i in prange(n):
        # (scalar loops: the array expressions' arithmetic in the same order, without a
        # temporary array per neighbour)
        c = np.zeros(3)
        for a in range(k):
            q = idx[i, a]
            for r in range(3):
                c[r] += points[q, r]
        c /= k
        cov = np.zeros((3, 3))
        d = np.empty(3)
        for a in range(k):
            q = idx[i, a]
            for r in range(3):
                d[r] = points[q, r] - c[r]
            for r in range(3):
                for s in range(r, 3):  # d[s] * d[r] is the same product: mirrored below
                    cov[r, s] += d[r] * d[s]
        for r in range(3):
            for s in range(r):
                cov[r, s] = cov[s, r]
        cov /= k
        w, vec = np.linalg.eigh(cov)
        nn = vec[:, 0].copy()
        if nn[0] * normals[i, 0] + nn[1] * normals[i, 1] + nn[2] * normals[i, 2] < 0.0:
            nn = -nn
        u = vec[:, 2].copy()
        v = np.cross(nn, u)
        # least squares height field over the frame (c; u, v, nn)
        ata = np.zeros((6, 6))
        atb = np.zeros(6)
        row = np.zeros(6)
        scale = max(np.sqrt(w[2]), 1e-12)
        for a in range(k):
            q = idx[i, a]
            for r in range(3):
                d[r] = points[q, r] - c[r]
            x = (d[0] * u[0] + d[1] * u[1] + d[2] * u[2]) / scale
            y = (d[0] * v[0] + d[1] * v[1] + d[2] * v[2]) / scale
            z = d[0] * nn[0] + d[1] * nn[1] + d[2] * nn[2]
            row[0] = 1.0
            row[1] = x
            row[2] = y
            row[3] = x * x
            row[4] = x * y
            row[5] = y * y
            for r in range(6):
                atb[r] += row[r] * z
                for s in range(r, 6):  # row[s] * row[r] is the same product: mirrored
                    ata[r, s] += row[r] * row[s]
        for r in range(6):
            for s in range(r):
                ata[r, s] = ata[s, r]
        ridge = 1e-6 * (ata[0, 0] + 1e-12)
        for r in range(6):
            ata[r, r] += ridge
        coef = np.linalg.solve(ata, atb)
        # undo the scaling of x, y
        coef[1] /= scale
        coef[2] /= scale
        coef[3] /= scale * scale
        coef[4] /= scale * scale
        coef[5] /= scale * scale
        res = 0.0
        for a in range(k):
            q = idx[i, a]
            for r in range(3):
                d[r] = points[q, r] - c[r]
            x = d[0] * u[0] + d[1] * u[1] + d[2] * u[2]
            y = d[0] * v[0] + d[1] * v[1] + d[2] * v[2]
            z = d[0] * nn[0] + d[1] * nn[1] + d[2] * nn[2]
            h = (
                coef[0]
                + coef[1] * x
                + coef[2] * y
                + coef[3] * x * x
                + coef[4] * x * y
                + coef[5] * y * y
            )
            res += (z - h) ** 2
        out_p[i] = c
        out_n[i] = nn
        out_u[i] = u
        out_a[i] = coef
        out_r[i] = np.sqrt(res / k)


@njit(inline="always", **EXACT_JIT_OPTIONS)
def tangent_frame_xyz(n0, n1, n2):  # pragma: no cover - numba
    """Two unit tangents u, v completing the unit normal n = (n0, n1, n2) to a right-handed
    frame, as six floats (u0, u1, u2, v0, v1, v2).

    u is the x axis (or the y axis when n is within ~25 deg of x) projected onto the tangent
    plane and normalised; v = n x u. Scalars only: no temporaries in loops over many points.
    """
    if abs(n0) < 0.9:
        t0, t1, t2 = 1.0, 0.0, 0.0
    else:
        t0, t1, t2 = 0.0, 1.0, 0.0
    dot = t0 * n0 + t1 * n1 + t2 * n2
    u0 = t0 - dot * n0
    u1 = t1 - dot * n1
    u2 = t2 - dot * n2
    norm = np.sqrt(u0**2 + u1**2 + u2**2)
    u0 /= norm
    u1 /= norm
    u2 /= norm
    return u0, u1, u2, n1 * u2 - n2 * u1, n2 * u0 - n0 * u2, n0 * u1 - n1 * u0


@njit(**_PARALLEL)
def max_angular_gap_kernel(cands, normals, points, nbr_idx, nbr_count):  # pragma: no cover
    """Largest angle [rad] between successive neighbour directions in each tangent plane.

    Row i: the points ``points[nbr_idx[i, :nbr_count[i]]]`` seen from ``cands[i]`` in the
    frame :func:`tangent_frame_xyz` of ``normals[i]``; their polar angles are sorted and the widest
    gap (wrapping around 2 pi) is returned. Fewer than 3 neighbours give 2 pi. Rows are
    independent: threaded, the same result for any thread count.
    """
    m = cands.shape[0]
    out = np.full(m, 2.0 * np.pi)
    for i in prange(m):
        cnt = nbr_count[i]
        if cnt < 3:
            continue
        u0, u1, u2, v0, v1, v2 = tangent_frame_xyz(normals[i, 0], normals[i, 1], normals[i, 2])
        ang = np.zeros(cnt)
        for a in range(cnt):
            j = nbr_idx[i, a]
            d0 = points[j, 0] - cands[i, 0]
            d1 = points[j, 1] - cands[i, 1]
            d2 = points[j, 2] - cands[i, 2]
            ang[a] = np.arctan2(d0 * v0 + d1 * v1 + d2 * v2, d0 * u0 + d1 * u1 + d2 * u2)
        ang.sort()
        gap = ang[0] + 2.0 * np.pi - ang[cnt - 1]
        for a in range(1, cnt):
            g = ang[a] - ang[a - 1]
            if g > gap:
                gap = g
        out[i] = gap
    return out
