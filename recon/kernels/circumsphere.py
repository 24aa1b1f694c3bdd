"""The empty-circumsphere triangle test of S&T92 §8 (``triangulation.method: circumsphere``).

References
----------
.. [ST92] R. Szeliski, D. Tonnesen. "Surface Modeling with Oriented Particle Systems".
   SIGGRAPH '92, §8 "Triangulating the particles".
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .options import EXACT_JIT_OPTIONS


@njit(**EXACT_JIT_OPTIONS)
def circumsphere_kernel(pos, offsets, indices, out, count):  # pragma: no cover - numba
    """Empty-circumsphere triangles (S&T92 §8) from full CSR neighbour lists.

    For i < j < k with j, k neighbours of i and of each other, the smallest sphere through the
    three points (centre in their plane) must hold no other neighbour of i; kept triangles go
    to ``out[i, :count[i]]`` (at most ``out.shape[1]`` per particle).
    """
    n = pos.shape[0]
    cap = out.shape[1]
    for i in range(n):
        c = 0
        lo, hi = offsets[i], offsets[i + 1]
        for a in range(lo, hi):
            j = indices[a]
            if j <= i:
                continue
            for b in range(a + 1, hi):
                k = indices[b]
                if k <= i:
                    continue
                # j and k must be neighbours of each other
                found = False
                for t in range(offsets[j], offsets[j + 1]):
                    if indices[t] == k:
                        found = True
                        break
                if not found:
                    continue
                pa = pos[j] - pos[i]
                pb = pos[k] - pos[i]
                axb = np.cross(pa, pb)
                den = 2.0 * (axb[0] ** 2 + axb[1] ** 2 + axb[2] ** 2)
                if den < 1e-12:
                    continue
                na = pa[0] ** 2 + pa[1] ** 2 + pa[2] ** 2
                nb_ = pb[0] ** 2 + pb[1] ** 2 + pb[2] ** 2
                cc = (na * np.cross(pb, axb) + nb_ * np.cross(axb, pa)) / den
                r2 = cc[0] ** 2 + cc[1] ** 2 + cc[2] ** 2
                center = pos[i] + cc
                empty = True
                for t in range(lo, hi):
                    m = indices[t]
                    if m == j or m == k:
                        continue
                    d = pos[m] - center
                    if d[0] ** 2 + d[1] ** 2 + d[2] ** 2 < r2 * (1.0 - 1e-9):
                        empty = False
                        break
                if empty and c < cap:
                    out[i, c, 0] = i
                    out[i, c, 1] = j
                    out[i, c, 2] = k
                    c += 1
        count[i] = c
