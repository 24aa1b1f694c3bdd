"""Consistent signs for the particles' normals before ball pivoting.

Ball pivoting [B99] needs consistently oriented normals; the particles take their signs from
the data normals, whose orientation can fail where a sparse neighbourhood holds both faces of
a thin part. :func:`consistent_normals` re-signs patches of wrong sign over the evenly spaced
particle sheet (Hoppe et al. 1992 propagation over a minimum spanning tree), and turns a patch
over only where its own sheet's neighbours disagree with it.

Whether two neighbours' signs agree is read from :func:`reflected_dots`, not from
``n_i . n_j``: across a sharp edge that turns by more than 90 deg (a knife edge) or between the
two faces of a thin part, consistent normals point more than 90 deg apart, and the plain dot
product calls them inconsistent (it turned a whole face of a 30 deg wedge over).

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
from .kernels.signs import surely_agree, surely_agree_within
from .normals import path_products, tree_parents

__all__ = ["all_agree", "consistent_normals", "reflected_dots"]

#: Particle normals are re-signed (:func:`consistent_normals`) over this many nearest
#: particles: the first ring of an evenly spaced sheet.
PARTICLE_ORIENT_K = 6
#: An edge's sign counts only when its reflected dot product (:func:`reflected_dots`) is this
#: far from zero (cos 60 deg): near-perpendicular normals on one sheet say nothing.
PARTICLE_SIGN_DOT = 0.5
#: Added to every spanning-tree edge cost so that exactly consistent neighbours keep their edge.
_EDGE_EPSILON = 1e-6
#: :func:`consistent_normals` returns at once when every reflected dot product exceeds this
#: many times ``|n_i| |n_j|`` in the screen's own arithmetic (:mod:`recon.kernels.signs`):
#: far above the rounding, so numpy's values are all >= 0 too (:func:`all_agree`).
_SURE_MARGIN = 1e-9


def reflected_dots(
    positions: np.ndarray, normals: np.ndarray, rows: np.ndarray, cols: np.ndarray
) -> np.ndarray:
    """``n_i . (I - 2 u u^T) n_j`` for the pairs ``(rows, cols)``, u the unit offset i -> j.

    The mirror in the plane that bisects the segment i-j maps j onto i; on a surface that is
    symmetric about that plane (any circle through the two points, a sphere, a plane, a
    symmetric crease or the two faces of a thin part) it maps j's consistently oriented
    normal onto i's. So the value is near +1 when the two signs agree and near -1 when one
    is flipped, whatever the angle between the normals:

    - neighbours on one sheet (u in both tangent planes): ``n_i . n_j``, Hoppe's measure;
    - the two faces of a 30 deg knife edge (normals 150 deg apart, ``n_i . n_j = -0.87``),
      one particle on each face at the same distance from the edge: +1;
    - the two faces of a thin plate, one above the other (normals opposed): +1;
    - a crease of any angle, one particle on each face at the same distance from it: +1;
    - perpendicular normals on one flat sheet: 0 (no evidence either way).

    Where the pair is far from symmetric the value weakens: across a thin plate it turns
    negative once the sideways offset exceeds the thickness, and two particles within a
    fraction of a spacing of a knife edge, offset along it, read like one sheet. The
    propagation prefers the decisive edges (cost ``1 - |r|``) and the vote counts only
    those, so these weak pairs rarely decide.
    """
    u = positions[cols] - positions[rows]
    u /= np.maximum(np.linalg.norm(u, axis=1, keepdims=True), 1e-300)
    hi = np.einsum("ij,ij->i", normals[rows], u)
    hj = np.einsum("ij,ij->i", normals[cols], u)
    return np.einsum("ij,ij->i", normals[rows], normals[cols]) - 2.0 * hi * hj


def propagate_signs(
    positions: np.ndarray,
    normals: np.ndarray,
    rows: np.ndarray,
    cols: np.ndarray,
    dots: np.ndarray | None = None,
) -> np.ndarray:
    """Signs (n,) that make the normals consistent along a minimum spanning tree of the graph
    of edges ``(rows, cols)``: Hoppe's propagation [Hoppe92] with cost ``1 - |r|`` and sign
    ``sign(r)``, r the edge's :func:`reflected_dots` (``dots`` when already computed). Each
    connected part keeps its root's sign."""
    n = len(positions)
    r = reflected_dots(positions, normals, rows, cols) if dots is None else dots
    cost = np.clip(1.0 - np.abs(r), 0.0, None)
    graph = sparse.coo_matrix((cost + _EDGE_EPSILON, (rows, cols)), shape=(n, n)).tocsr()
    graph = graph.maximum(graph.T).tocsr()
    _, labels = csgraph.connected_components(graph, directed=False)
    parent = tree_parents(csgraph.minimum_spanning_tree(graph), labels)
    to_parent = reflected_dots(positions, normals, np.arange(n), parent)
    return path_products(parent, np.where(to_parent < 0.0, -1.0, 1.0))


def all_agree(dots: np.ndarray) -> bool:
    """Whether no edge of the neighbour graph reads a sign disagreement (every
    :func:`reflected_dots` value >= 0): then :func:`consistent_normals` has nothing to do.

    The screen is exact, not a heuristic: :func:`reflected_dots` is symmetric in i and j, so
    every spanning-tree edge of :func:`propagate_signs` (an edge of this graph) and every
    root (its own parent: ``n . n >= 0``) keeps its sign, all proposed signs are +1, no
    particle is proposed for flipping and the normals come back unchanged. On clean scans
    it holds everywhere (bunny-clean: all 240k data and 165k particle edges), and it skips
    the spanning tree and the component labelling (~0.25 s of the bunny's 5 s of CPU)."""
    return not bool(np.any(dots < 0.0))


def consistent_normals(
    positions: np.ndarray,
    normals: np.ndarray,
    tree: cKDTree | None = None,
    neighbors: tuple[np.ndarray, np.ndarray] | None = None,
) -> np.ndarray:
    """The particles' normals, with patches of wrong sign re-signed over the particle sheet.

    Ball pivoting needs consistently oriented normals: it does not join a patch whose normals
    point the other way, which is left as a separate one-sided sheet with a loop round it,
    and where a thin part's two faces meet it bridges particles of the wrong sign across the
    part (a 30 deg wedge's knife edge came out with a handle). The particles take their
    signs from the data normals, whose orientation can fail where a sparse neighbourhood
    holds both faces of a thin part (bunny-sparse's ear tips, the wedge's knife edge). The
    particle sheet is evenly spaced at about r0, so its neighbourhoods are narrower than the
    data's: :func:`propagate_signs` over the ``PARTICLE_ORIENT_K`` nearest particles proposes
    signs; each connected part of the neighbour graph keeps the global sign most of its
    fitted normals agree with.

    The propagation can also cross a fold of an open sheet and turn a correct patch over, so
    a proposed patch (connected particles it would flip) is flipped only where that makes
    its neighbours agree more: more of the patch's edges to the rest disagree in sign than
    agree, by :func:`reflected_dots`, counting only edges where it is decisive
    (``|r| > PARTICLE_SIGN_DOT``). Directions never change, only signs. ``tree``: a k-d
    tree of ``positions`` when one is built already (the same query, no second tree);
    ``neighbors``: (distances, indices) of each position's m > ``PARTICLE_ORIENT_K + 1``
    nearest, nearest first (the fit's shared query of the data): when every edge that the
    query could hold surely agrees (:func:`recon.kernels.signs.surely_agree_within`), the
    normals come back at once, without a query.
    """
    n = len(positions)
    k = PARTICLE_ORIENT_K
    if n <= k:
        return normals
    if neighbors is not None and neighbors[1].shape[1] > k + 1:
        pos = np.ascontiguousarray(positions, dtype=np.float64)
        nrm = np.ascontiguousarray(normals, dtype=np.float64)
        if surely_agree_within(pos, nrm, neighbors[0], neighbors[1], k, _SURE_MARGIN):
            return normals  # a superset of the query's edges all agree: all_agree holds
    tree = cKDTree(positions) if tree is None else tree
    _, idx = tree.query(positions, k + 1, workers=query_workers())
    pos = np.ascontiguousarray(positions, dtype=np.float64)
    if surely_agree(pos, np.ascontiguousarray(normals, dtype=np.float64), idx, _SURE_MARGIN):
        return normals  # all_agree below holds: a certified screen, one sweep, no gathers
    rows, cols = np.repeat(np.arange(n), k), idx[:, 1:].ravel()
    keep = rows != cols  # duplicate positions can reorder self
    rows, cols = rows[keep], cols[keep]
    dots = reflected_dots(positions, normals, rows, cols)
    if all_agree(dots):
        return normals
    signed = normals * propagate_signs(positions, normals, rows, cols, dots)[:, None]
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
    rim = flip[rows] != flip[cols]  # each such edge seen from its flipped end
    end = np.where(flip[rows], rows, cols)[rim]
    r = reflected_dots(positions, normals, rows[rim], cols[rim])
    sign = np.where(np.abs(r) > PARTICLE_SIGN_DOT, np.sign(r), 0.0)  # not decisive: no vote
    balance = np.bincount(patch[end], weights=sign, minlength=n)  # agree - disagree
    take = flip & (balance[patch] < 0)
    out = normals.copy()
    out[take] *= -1.0
    return out
