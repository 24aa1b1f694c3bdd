r"""Scatter matrices of point neighbourhoods: the first half of a PCA normal, in one sweep.

The normal estimate (:func:`recon.normals.estimate_normals`) and the crease screen
(:func:`recon.creases.detect_creases`) take, for every data point i, the scatter matrix of its
k nearest points about their mean,

.. math::  C_i = \sum_j (p_j - \bar p)(p_j - \bar p)^T,\qquad
           \bar p = \frac{1}{k}\sum_j p_j,

optionally in the point's own frame (:math:`p_j - p_i` first: keeps precision far from the
origin), and hand the (n, 3, 3) stack to ``numpy.linalg.eigh``. In numpy that is a
(n, k, 3) gather, a mean over the neighbours and an ``einsum``, three passes over 24 k bytes
per point; here it is one pass over each neighbourhood, with the same arithmetic in the same
order (neighbours summed one after the other, the mean divided by k), so the matrices, and
hence the eigenvectors, are bit-identical to numpy's (``tests/kernels/test_pca.py``).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .options import EXACT_JIT_OPTIONS


@njit(**EXACT_JIT_OPTIONS)
def scatter_matrices(points, idx, centre, local, out):  # pragma: no cover - numba
    """``out[r]`` = the scatter matrix of ``points[idx[r]]`` about their mean.

    Parameters
    ----------
    points : (n, 3) float64
    idx : (m, k) int
        Row r: the neighbourhood's points (indices into ``points``).
    centre : (m, 3) float64
        Row r's own point; subtracted from its neighbours first when ``local``.
    local : bool
        Work in each point's frame (numpy: ``nb = points[idx] - centre[:, None]``).
    out : (m, 3, 3) float64, out
        numpy's ``einsum("nki,nkj->nij", nb, nb)`` of ``nb - nb.mean(axis=1)``.
    """
    m, k = idx.shape
    nb = np.empty((k, 3))
    for r in range(m):
        for j in range(k):
            q = idx[r, j]
            for a in range(3):
                nb[j, a] = points[q, a] - centre[r, a] if local else points[q, a]
        for a in range(3):
            s = 0.0
            for j in range(k):
                s += nb[j, a]
            mean = s / k
            for j in range(k):
                nb[j, a] -= mean
        for a in range(3):
            for b in range(a, 3):
                s = 0.0
                for j in range(k):
                    s += nb[j, a] * nb[j, b]
                out[r, a, b] = s
                out[r, b, a] = s
