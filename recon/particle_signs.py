"""Consistent signs for the particles' normals before ball pivoting.

Ball pivoting [B99] needs consistently oriented normals; the particles take their signs from
the data normals, whose orientation can fail where a sparse neighbourhood holds both faces of
a thin part. :func:`consistent_normals` re-signs patches of wrong sign over the evenly spaced
particle sheet (Hoppe et al. 1992 propagation, :func:`recon.normals.orient_normals`), and turns
a patch over only where its own sheet's neighbours disagree with it.

References
----------
[B99]     F. Bernardini et al. "The ball-pivoting algorithm for surface reconstruction".
          IEEE TVCG 5(4), 1999.
[Hoppe92] H. Hoppe et al. "Surface reconstruction from unorganized points". SIGGRAPH '92.
"""

from __future__ import annotations

import numpy as np
from scipy import sparse
from scipy.sparse import csgraph
from scipy.spatial import cKDTree

from .kernels.options import query_workers
from .normals import graph_width, orient_normals

__all__ = ["consistent_normals"]

#: Particle normals are re-signed (:func:`consistent_normals`) over this many nearest
#: particles: the first ring of an evenly spaced sheet.
PARTICLE_ORIENT_K = 6
#: ... with this extra cost on edges that cross the surface (``normals.thin_parts``' default),
#: so the two faces of a thin part are not joined across the gap.
PARTICLE_ACROSS_COST = 0.3
#: A neighbour lies in a particle's own sheet when the unit offset to it is this close to the
#: tangent plane (|u . n| below sin 30 deg) at both ends.
PARTICLE_TANGENT = 0.5
#: ... and its sign counts only when the two normals are this close to (anti)parallel
#: (|n_i . n_j| above cos 60 deg): across a crease they are near perpendicular and say nothing.
PARTICLE_SIGN_DOT = 0.5


def consistent_normals(positions: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """The particles' normals, with patches of wrong sign re-signed over the particle sheet.

    Ball pivoting needs consistently oriented normals: it does not join a patch whose normals
    point the other way, which is left as a separate one-sided sheet with a loop round it.
    The particles take their signs from the data normals, whose orientation can fail where a
    sparse neighbourhood holds both faces of a thin part (bunny-sparse's ear tips). The
    particle sheet is evenly spaced at about r0, so its neighbourhoods are narrower than the
    data's: Hoppe's propagation (:func:`recon.normals.orient_normals`) over its
    ``PARTICLE_ORIENT_K`` nearest particles, with thin-part edges asking for opposed signs
    (``PARTICLE_ACROSS_COST``), proposes signs; each connected part of the neighbour graph
    keeps the global sign most of its fitted normals agree with.

    The propagation can also cross a fold of an open sheet and turn a correct patch over, so
    a proposed patch (connected particles it would flip) is flipped only where that makes
    its *tangential* neighbours (``|u . n| < PARTICLE_TANGENT``, u the unit offset: the same
    sheet, not the opposite face of a thin part) agree more: more of the patch's tangential
    edges to the rest disagree in sign than agree, counting only edges whose normals are
    near (anti)parallel (``PARTICLE_SIGN_DOT``; across a crease they say nothing). Directions
    never change, only signs.
    """
    n = len(positions)
    k = PARTICLE_ORIENT_K
    if n <= k:
        return normals
    # one query serves the propagation's graph (its first k + 1 columns and the thin-part
    # split's wider neighbourhood) and the parts and patches below
    wide = min(graph_width(k, PARTICLE_ACROSS_COST), n)
    _, idx = cKDTree(positions).query(positions, wide, workers=query_workers())
    signed, _ = orient_normals(
        positions,
        normals,
        k=k,
        orientation="none",
        across_cost=PARTICLE_ACROSS_COST,
        neighbors=idx,
    )
    idx = idx[:, : k + 1]
    rows, cols = np.repeat(np.arange(n), k), idx[:, 1:].ravel()
    graph = sparse.coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n))
    n_parts, part = csgraph.connected_components(graph, directed=False)
    vote = np.bincount(part, weights=np.einsum("ij,ij->i", signed, normals), minlength=n_parts)
    flip = np.einsum("ij,ij->i", signed, normals) * np.where(vote[part] < 0, -1.0, 1.0) < 0
    if not flip.any():
        return normals
    # patches: connected particles proposed for flipping
    inner = flip[rows] & flip[cols]
    patch_graph = sparse.coo_matrix((np.ones(int(inner.sum())), (rows[inner], cols[inner])), (n, n))
    _, patch = csgraph.connected_components(patch_graph, directed=False)
    u = positions[cols] - positions[rows]
    u /= np.maximum(np.linalg.norm(u, axis=1, keepdims=True), 1e-300)
    tangent = (np.abs(np.einsum("ij,ij->i", u, normals[rows])) < PARTICLE_TANGENT) & (
        np.abs(np.einsum("ij,ij->i", u, normals[cols])) < PARTICLE_TANGENT
    )
    rim = tangent & (flip[rows] != flip[cols])  # each such edge seen from its flipped end
    end = np.where(flip[rows], rows, cols)[rim]
    dot = np.einsum("ij,ij->i", normals[rows[rim]], normals[cols[rim]])
    sign = np.where(np.abs(dot) > PARTICLE_SIGN_DOT, np.sign(dot), 0.0)  # across a crease: no vote
    balance = np.bincount(patch[end], weights=sign, minlength=n)  # agree - disagree
    take = flip & (balance[patch] < 0)
    out = normals.copy()
    out[take] *= -1.0
    return out
