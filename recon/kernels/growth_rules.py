"""Growing rule of the particle sheet: candidate positions in angular gaps (S&T92 §6).

References
----------
.. [ST92] R. Szeliski, D. Tonnesen. "Surface Modeling with Oriented Particle Systems".
   SIGGRAPH '92, §6 "Adding and deleting particles".
.. [T00] D. Tonnesen. PhD thesis, §4.7.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from .local_surface import tangent_frame_xyz
from .options import EXACT_JIT_OPTIONS

_PARALLEL = dict(EXACT_JIT_OPTIONS, parallel=True)

MAX_PER_PARTICLE = 6
"""Candidates per particle and round: an isolated particle grows a hexagon of six."""


@njit(**_PARALLEL)
def grow_kernel(
    pos, nrm, offsets, indices, min_nb, max_nb, gap_angle, gap_step, out, count
):  # pragma: no cover - numba
    """Growing rule (S&T92 §6): candidates in the angular gaps of sparse particles.

    A particle i with ``min_nb <= m <= max_nb`` neighbours (CSR ``offsets``, ``indices``)
    sorts the polar angles of its neighbours in its tangent frame; every gap wider than
    ``gap_angle`` [rad] gets ``max(1, round(gap / gap_step) - 1)`` candidates evenly spaced
    inside it, one unit (r0) out. An isolated particle (m = 0) gets a hexagon. At most
    ``MAX_PER_PARTICLE`` candidates per particle go to ``out[i, :count[i]]``. Particles are
    independent: threaded, the same result for any thread count.
    """
    n = pos.shape[0]
    two_pi = 2.0 * np.pi
    for i in prange(n):
        m = offsets[i + 1] - offsets[i]
        count[i] = 0
        if m < min_nb or m > max_nb:
            continue
        u0, u1, u2, v0, v1, v2 = tangent_frame_xyz(nrm[i, 0], nrm[i, 1], nrm[i, 2])
        p0 = pos[i, 0]
        p1 = pos[i, 1]
        p2 = pos[i, 2]
        c = 0
        if m == 0:
            for a in range(MAX_PER_PARTICLE):
                th = a * two_pi / MAX_PER_PARTICLE
                ct = np.cos(th)
                st = np.sin(th)
                out[i, c, 0] = p0 + ct * u0 + st * v0
                out[i, c, 1] = p1 + ct * u1 + st * v1
                out[i, c, 2] = p2 + ct * u2 + st * v2
                c += 1
            count[i] = c
            continue
        ang = np.empty(m)
        for a in range(m):
            j = indices[offsets[i] + a]
            d0 = pos[j, 0] - p0
            d1 = pos[j, 1] - p1
            d2 = pos[j, 2] - p2
            ang[a] = np.arctan2(d0 * v0 + d1 * v1 + d2 * v2, d0 * u0 + d1 * u1 + d2 * u2)
        ang.sort()
        for a in range(m):
            start = ang[a]
            end = ang[a + 1] if a + 1 < m else ang[0] + two_pi
            gap = end - start
            if gap <= gap_angle:
                continue
            k = max(1, int(np.floor(gap / gap_step + 0.5)) - 1)
            for b in range(1, k + 1):
                if c >= MAX_PER_PARTICLE:
                    break
                th = start + gap * b / (k + 1)
                ct = np.cos(th)
                st = np.sin(th)
                out[i, c, 0] = p0 + ct * u0 + st * v0
                out[i, c, 1] = p1 + ct * u1 + st * v1
                out[i, c, 2] = p2 + ct * u2 + st * v2
                c += 1
        count[i] = c
