"""A certified screen of the particle sign propagation (:mod:`recon.particle_signs`).

:func:`recon.particle_signs.consistent_normals` does nothing when every edge of its neighbour
graph reads agreeing signs (every :func:`~recon.particle_signs.reflected_dots` value
``n_i . n_j - 2 (n_i . u)(n_j . u)`` is >= 0, :func:`~recon.particle_signs.all_agree`), which
holds everywhere on clean scans. numpy reads that from six (E, 3) gathers; this kernel reads
it in one sweep over the neighbour table and stops at the first doubtful edge.

Its arithmetic need not be numpy's bit for bit (numpy's dot products sum in an order that
depends on the machine's SIMD): both computations are within a few units of rounding of the
exact value, ``|error| <= c eps |n_i| |n_j|`` with c about 10, so an edge whose value here
exceeds ``margin |n_i| |n_j|`` (margin 1e-9, far above that) is >= 0 in numpy's arithmetic
too. An edge at or below it, or NaN, answers "not sure" and the caller takes numpy's path.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .options import EXACT_JIT_OPTIONS


@njit(**EXACT_JIT_OPTIONS)
def surely_agree(positions, normals, idx, margin):  # pragma: no cover - numba
    """Whether every edge ``(i, idx[i, q])``, ``q >= 1`` and ``idx[i, q] != i``, has a
    reflected dot product above ``margin |n_i| |n_j|`` (so certainly >= 0 however it is
    rounded); False at the first that does not (or is NaN)."""
    n, kk = idx.shape
    for i in range(n):
        px = positions[i, 0]
        py = positions[i, 1]
        pz = positions[i, 2]
        ax = normals[i, 0]
        ay = normals[i, 1]
        az = normals[i, 2]
        na = np.sqrt(ax * ax + ay * ay + az * az)
        for q in range(1, kk):
            j = idx[i, q]
            if j == i:
                continue
            ux = positions[j, 0] - px
            uy = positions[j, 1] - py
            uz = positions[j, 2] - pz
            norm = np.sqrt(ux * ux + uy * uy + uz * uz)
            if norm < 1e-300:
                norm = 1e-300
            ux /= norm
            uy /= norm
            uz /= norm
            bx = normals[j, 0]
            by = normals[j, 1]
            bz = normals[j, 2]
            hi = ax * ux + ay * uy + az * uz
            hj = bx * ux + by * uy + bz * uz
            r = (ax * bx + ay * by + az * bz) - 2.0 * hi * hj
            nb = np.sqrt(bx * bx + by * by + bz * bz)
            if not r > margin * na * nb:
                return False
    return True
