"""Growing rule of the particle sheet: candidate positions in angular gaps (S&T92 §6).

References
----------
.. [ST92] R. Szeliski, D. Tonnesen. "Surface Modeling with Oriented Particle Systems".
   SIGGRAPH '92, §6 "Adding and deleting particles".
.. [T00] D. Tonnesen. PhD thesis, §4.7.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .local_surface import tangent_frame
from .options import EXACT_JIT_OPTIONS

MAX_PER_PARTICLE = 6
"""Candidates per particle and round: an isolated particle grows a hexagon of six."""


@njit(**EXACT_JIT_OPTIONS)
def grow_kernel(
    pos, nrm, offsets, indices, min_nb, max_nb, gap_angle, gap_step, out, count
):  # pragma: no cover - numba
    """Growing rule (S&T92 §6): candidates in the angular gaps of sparse particles.

    A particle i with ``min_nb <= m <= max_nb`` neighbours (CSR ``offsets``, ``indices``)
    sorts the polar angles of its neighbours in its tangent frame; every gap wider than
    ``gap_angle`` [rad] gets ``max(1, round(gap / gap_step) - 1)`` candidates evenly spaced
    inside it, one unit (r0) out. An isolated particle (m = 0) gets a hexagon. At most
    ``MAX_PER_PARTICLE`` candidates per particle go to ``out[i, :count[i]]``.
    """
    n = pos.shape[0]
    two_pi = 2.0 * np.pi
    for i in range(n):
        m = offsets[i + 1] - offsets[i]
        count[i] = 0
        if m < min_nb or m > max_nb:
            continue
        u, v = tangent_frame(nrm[i])
        c = 0
        if m == 0:
            for a in range(MAX_PER_PARTICLE):
                th = a * two_pi / MAX_PER_PARTICLE
                out[i, c] = pos[i] + np.cos(th) * u + np.sin(th) * v
                c += 1
            count[i] = c
            continue
        ang = np.empty(m)
        for a in range(m):
            d = pos[indices[offsets[i] + a]] - pos[i]
            ang[a] = np.arctan2(
                d[0] * v[0] + d[1] * v[1] + d[2] * v[2], d[0] * u[0] + d[1] * u[1] + d[2] * u[2]
            )
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
                out[i, c] = pos[i] + np.cos(th) * u + np.sin(th) * v
                c += 1
        count[i] = c
