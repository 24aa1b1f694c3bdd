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
def _edge_sure(positions, normals, i, j, na, margin):  # pragma: no cover - numba
    """Edge (i, j)'s reflected dot product exceeds ``margin |n_i| |n_j|`` (``na``: |n_i|)."""
    ux = positions[j, 0] - positions[i, 0]
    uy = positions[j, 1] - positions[i, 1]
    uz = positions[j, 2] - positions[i, 2]
    norm = np.sqrt(ux * ux + uy * uy + uz * uz)
    if norm < 1e-300:
        norm = 1e-300
    ux /= norm
    uy /= norm
    uz /= norm
    ax = normals[i, 0]
    ay = normals[i, 1]
    az = normals[i, 2]
    bx = normals[j, 0]
    by = normals[j, 1]
    bz = normals[j, 2]
    hi = ax * ux + ay * uy + az * uz
    hj = bx * ux + by * uy + bz * uz
    r = (ax * bx + ay * by + az * bz) - 2.0 * hi * hj
    nb = np.sqrt(bx * bx + by * by + bz * bz)
    return r > margin * na * nb


@njit(**EXACT_JIT_OPTIONS)
def surely_agree(positions, normals, idx, margin):  # pragma: no cover - numba
    """Whether every edge ``(i, idx[i, q])``, ``q >= 1`` and ``idx[i, q] != i``, has a
    reflected dot product above ``margin |n_i| |n_j|`` (so certainly >= 0 however it is
    rounded); False at the first that does not (or is NaN)."""
    n, kk = idx.shape
    for i in range(n):
        na = np.sqrt(normals[i, 0] ** 2 + normals[i, 1] ** 2 + normals[i, 2] ** 2)
        for q in range(1, kk):
            j = idx[i, q]
            if j != i and not _edge_sure(positions, normals, i, j, na, margin):
                return False
    return True


@njit(**EXACT_JIT_OPTIONS)
def surely_agree_within(positions, normals, dist, idx, k, margin):  # pragma: no cover - numba
    """:func:`surely_agree` over every edge that a ``k + 1``-nearest query could hold, read
    from a wider table: for each point i all ``idx[i, q]`` (not i) at most the (k+1)-th
    distance ``dist[i, k]`` away (slightly more: ``1e-12`` of it, for the rounding of
    another query's distances), whichever of the tied ones that query picks. False also
    when a row's ties may run past the table's last column (then ask the query itself)."""
    n, m = idx.shape
    for i in range(n):
        limit = dist[i, k] * (1.0 + 1e-12)
        if not dist[i, m - 1] > limit:  # the table may not hold every tie (or NaN)
            return False
        na = np.sqrt(normals[i, 0] ** 2 + normals[i, 1] ** 2 + normals[i, 2] ** 2)
        for q in range(m):
            if not dist[i, q] <= limit:
                break
            j = idx[i, q]
            if j != i and not _edge_sure(positions, normals, i, j, na, margin):
                return False
    return True
