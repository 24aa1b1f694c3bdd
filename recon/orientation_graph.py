"""Edge costs of the normal-orientation graph (:func:`recon.normals.orient_normals`).

Hoppe's MST cost of an edge (i, j) is ``1 - |n_i . n_j| + eps`` [Hoppe92, section 3.3]; the
thin-part term adds ``across_cost * a^2``, a the mean of ``|u . n_i|`` and ``|u . n_j|`` with
u the unit edge direction (``normals.thin_parts``). The costs are computed in blocks of
``EDGE_BLOCK`` edges: the whole graph's gathers (``normals[rows]``, ``points[cols] -
points[rows]``, ... each 24 bytes per edge) held 1.2 GB at a million points of ten edges each;
a block's values are those of the whole (row-wise arithmetic, nothing summed across edges).

References
----------
[Hoppe92] H. Hoppe, T. DeRose, T. Duchamp, J. McDonald, W. Stuetzle. "Surface reconstruction
          from unorganized points". SIGGRAPH '92.
"""

from __future__ import annotations

import numpy as np

__all__ = ["EDGE_BLOCK", "edge_costs"]

#: Edges per block (3 MB per (block, 3) float64 gather).
EDGE_BLOCK = 1 << 17


def edge_costs(
    points: np.ndarray,
    normals: np.ndarray,
    rows: np.ndarray,
    cols: np.ndarray,
    epsilon: float,
    across_cost: float = 0.0,
    exact: np.ndarray | None = None,
) -> np.ndarray:
    """The MST cost of every edge ``(rows[e], cols[e])``: ``1 - |n_i . n_j|`` (clipped at 0)
    plus ``epsilon``, plus ``across_cost * a^2`` unless ``exact[e]`` (an edge known to join
    the two faces of a thin part, which propagates exactly: no penalty).

    Examples
    --------
    >>> p = np.array([[0.0, 0, 0], [1, 0, 0]])
    >>> n = np.array([[0.0, 0, 1], [0, 0, 1]])
    >>> edge_costs(p, n, np.array([0]), np.array([1]), 1e-6, 0.3).tolist()
    [1e-06]
    """
    out = np.empty(len(rows))
    for lo in range(0, len(rows), EDGE_BLOCK):
        r, c = rows[lo : lo + EDGE_BLOCK], cols[lo : lo + EDGE_BLOCK]
        nr, nc = normals[r], normals[c]
        dots = np.einsum("ij,ij->i", nr, nc)
        base = np.clip(1.0 - np.abs(dots), 0.0, None) + epsilon
        if across_cost > 0.0:
            u = points[c] - points[r]
            u /= np.maximum(np.linalg.norm(u, axis=1, keepdims=True), 1e-300)
            a = 0.5 * (np.abs(np.einsum("ij,ij->i", u, nr)) + np.abs(np.einsum("ij,ij->i", u, nc)))
            cost = base + across_cost * a * a
            base = cost if exact is None else np.where(exact[lo : lo + EDGE_BLOCK], base, cost)
        out[lo : lo + len(r)] = base
    return out
