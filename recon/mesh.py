"""Shared triangle-mesh helpers: edges, boundaries, components and face normals.

Used by mesh repair (:mod:`recon.triangulate`) and by the report (:mod:`recon.topology`,
:mod:`recon.metrics`), so both see the same edges and the same components. Faces are
``(F, 3)`` integer vertex indices; everything is vectorised NumPy and ``scipy.sparse.csgraph``
(except the loop walk), and the connectivity tables (edges, fans, components, the overlap
prefilter) come from the counting-sort kernels of :mod:`recon.kernels.mesh_tables`.

Definitions:

- An *edge* is an unordered vertex pair used by a face; its *face count* is 1 on the boundary,
  2 inside a manifold and more on a non-manifold edge.
- *Boundary loops* (:func:`boundary_loops`) are the *simple* closed walks along boundary
  half-edges, as vertex sequences in face winding order: what hole filling can close. A loop
  through a vertex with two outgoing boundary half-edges is not simple and is skipped.
- *Boundary components* (:func:`boundary_components`) are the connected components of the graph
  of boundary edges: what the report counts as ``boundary_loops``. On a manifold mesh both
  agree; where boundaries touch at a vertex (a figure of eight) the walk finds no simple loop
  while the component count is one.
- A vertex's *fans* (:func:`vertex_fans`) are its incident faces grouped by connection through
  edges that contain the vertex; a manifold vertex has one fan, a bow-tie (non-manifold)
  vertex more. Faces joined by an over-shared edge count as connected.
- Two faces at a vertex *overlap* (:func:`overlapping_faces`) when their corners' angular
  sectors around the vertex, in the plane of their mean normal, overlap: the surface covers
  that wedge twice (a manifold mesh can still do so without a crossing the exact test sees,
  since faces that share a vertex are not tested; it makes a tiny handle).
- A face is *opposed* (:func:`opposed_faces`) when the normals at two of its corners point
  more than 90 deg apart: it joins two opposed sheets (e.g. the two faces of a thin part).
- A *bridge* is a connected set of opposed faces; one that carries a handle
  (:func:`handle_bridges`) is a tunnel between the two faces of a thin part.
- *Components* (:func:`vertex_components`, :func:`face_components`) are the connected
  components of the referenced vertices, two vertices being connected when a face uses both
  (so a bow-tie is one component).

References
----------
[Bot10] M. Botsch, L. Kobbelt, M. Pauly, P. Alliez, B. Levy. "Polygon Mesh Processing".
        AK Peters, 2010, ch. 1.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy import sparse
from scipy.sparse import csgraph

from .kernels.mesh_tables import (
    area_vectors,
    edge_table,
    fan_labels,
    half_edge_order,
    half_edge_winding,
    overlap_candidates,
    vertex_component_labels,
)

__all__ = [
    "FACE_KEY_LIMIT",
    "boundary_components",
    "boundary_loop_perimeters",
    "boundary_loops",
    "capped_volume",
    "corner_sum",
    "count_edge_faces",
    "drop_unreferenced",
    "edge_keys",
    "face_keys",
    "face_area_vectors",
    "face_components",
    "face_normals",
    "first_faces",
    "handle_bridges",
    "handle_count",
    "opposed_faces",
    "orientation_flips",
    "overlapping_faces",
    "ranked_fans",
    "runs_of_equal",
    "unique_edges",
    "vertex_components",
    "vertex_fans",
]


def edge_keys(faces: np.ndarray, n_vertices: int) -> np.ndarray:
    """One integer key per face edge, ``(3 F,)``: ``lo * n_vertices + hi`` of its vertex pair.

    Edge k of face i (corner k to k + 1) is entry ``3 i + k``; equal keys are the same edge.
    """
    e = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    return e[:, 0] * n_vertices + e[:, 1]


#: Below this many vertices a face's sorted vertex triple fits one int64 key (n^3 < 2^63).
FACE_KEY_LIMIT = 2_000_000


def face_keys(faces: np.ndarray, n_vertices: int) -> np.ndarray:
    """One key per face, equal for two faces with the same vertices in any order: below
    ``FACE_KEY_LIMIT`` vertices an int64 ``(F,)`` of the sorted triple (``np.unique`` of rows
    is ~7x slower), else the sorted triples ``(F, 3)`` themselves."""
    key = np.sort(faces, axis=1).astype(np.int64, copy=False)  # int32 faces would wrap
    if n_vertices < FACE_KEY_LIMIT:
        return (key[:, 0] * n_vertices + key[:, 1]) * n_vertices + key[:, 2]
    return key


def first_faces(faces: np.ndarray, n_vertices: int) -> np.ndarray:
    """Ascending indices of the first of each set of ``faces`` with the same vertices in any
    order (:func:`face_keys`).

    Above ``FACE_KEY_LIMIT`` vertices the sorted triples are ordered by two int64 keys (the
    first two vertices as one, then the third) in a stable sort. ``np.unique`` of the rows
    sorts them as opaque bytes: on 5.3M faces it took 10.7 of the 13.9 s of
    :func:`recon.triangulate.remove_non_manifold_faces`, which takes 3.8 s with these keys.

    Examples
    --------
    >>> first_faces(np.array([[0, 1, 2], [1, 2, 3], [2, 0, 1]]), 4).tolist()
    [0, 1]
    """
    key = face_keys(faces, n_vertices)
    if key.ndim == 1:
        _, first = np.unique(key, return_index=True)
        return np.sort(first)
    hi = key[:, 0] * n_vertices + key[:, 1]  # below n^2 < 2^63 for n up to 3e9
    order = np.lexsort((key[:, 2], hi))
    hi, lo = hi[order], key[order, 2]
    start = np.ones(len(order), dtype=bool)
    start[1:] = (hi[1:] != hi[:-1]) | (lo[1:] != lo[:-1])
    return np.sort(order[start])


def unique_edges(faces: np.ndarray, n_vertices: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``np.unique(edge_keys(faces, n_vertices), return_inverse=True, return_counts=True)``:
    the sorted distinct edge keys, the edge of every face edge ``(3 F,)`` and the number of
    faces on each edge, by counting sorts (:func:`recon.kernels.mesh_tables.edge_table`).

    Examples
    --------
    >>> keys, inverse, counts = unique_edges(np.array([[0, 1, 2], [2, 1, 3]]), 4)
    >>> keys.tolist(), inverse.tolist(), counts.tolist()
    ([1, 2, 6, 7, 11], [0, 2, 1, 2, 3, 4], [1, 1, 2, 1, 1])
    """
    f = np.ascontiguousarray(faces, dtype=np.int64).reshape(-1, 3)
    if len(f) == 0:
        empty = np.zeros(0, dtype=np.int64)
        return empty, empty, empty
    if int(f.min()) < 0 or int(f.max()) >= n_vertices:  # keys as edge_keys makes them
        keys = edge_keys(f, n_vertices)
        return np.unique(keys, return_inverse=True, return_counts=True)
    return edge_table(f, int(n_vertices))


def runs_of_equal(keys: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``keys`` sorted (stably) into runs of equal keys: the sort ``order``, where each run
    starts in it, and each run's length.

    Examples
    --------
    >>> order, start, count = runs_of_equal(np.array([7, 3, 7, 5, 3]))
    >>> order.tolist(), start.tolist(), count.tolist()
    ([1, 4, 3, 0, 2], [0, 2, 3], [2, 1, 2])
    """
    order = np.argsort(keys, kind="stable")
    k = keys[order]
    first = np.ones(len(k), dtype=bool)
    first[1:] = k[1:] != k[:-1]
    start = np.flatnonzero(first)
    return order, start, np.diff(np.append(start, len(k)))


def count_edge_faces(faces: Any) -> tuple[np.ndarray, np.ndarray]:
    """Distinct edges of a triangle mesh and how many faces use each.

    Faces with a repeated vertex index are skipped (as in :func:`recon.topology.mesh_topology`).

    Parameters
    ----------
    faces : (F, 3) array_like of int
        Triangles as vertex indices.

    Returns
    -------
    edges : (E, 2) int64
        Vertex pairs, smaller index first, sorted.
    counts : (E,) int64
        Faces per edge: 1 on the boundary, 2 inside, more on non-manifold edges.

    Examples
    --------
    >>> edges, counts = count_edge_faces([[0, 1, 2], [2, 1, 3]])
    >>> edges[counts == 2].tolist(), int(counts.sum())
    ([[1, 2]], 6)
    """
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 2] != f[:, 0])]
    if len(f) == 0 or int(f.min()) < 0:
        a, b = f.ravel(), np.roll(f, -1, axis=1).ravel()
        pairs = np.stack([np.minimum(a, b), np.maximum(a, b)], axis=1)
        edges, counts = np.unique(pairs, axis=0, return_counts=True)
        return edges.reshape(-1, 2), counts.astype(np.int64)
    n = int(f.max()) + 1  # counting sorts: ~10x faster than np.unique of rows
    keys, _, counts = unique_edges(f, n)
    return np.stack([keys // n, keys % n], axis=1), counts


def boundary_loops(faces: np.ndarray) -> list[np.ndarray]:
    """Simple boundary loops as vertex sequences in face winding order (for hole filling).

    A boundary half-edge (a, b) is one whose edge belongs to a single face. Loops through a
    vertex with more than one outgoing boundary half-edge are not simple and are skipped.

    Examples
    --------
    >>> [loop.tolist() for loop in boundary_loops(np.array([[0, 1, 2], [0, 2, 3]]))]
    [[0, 1, 2, 3]]
    """
    if len(faces) == 0:
        return []
    he = faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    n_v = int(faces.max()) + 1
    _, inv, cnt = unique_edges(faces, n_v)
    bnd = he[cnt[inv] == 1]
    if len(bnd) == 0:
        return []
    out_deg = np.bincount(bnd[:, 0], minlength=n_v)
    nxt = np.full(n_v, -1, dtype=np.int64)
    nxt[bnd[:, 0]] = bnd[:, 1]
    visited = np.zeros(n_v, dtype=bool)
    loops = []
    for start in bnd[:, 0]:
        if visited[start]:
            continue
        loop = [start]
        visited[start] = True
        simple = out_deg[start] == 1
        v = nxt[start]
        while v != start and v >= 0 and not visited[v]:
            simple &= out_deg[v] == 1
            visited[v] = True
            loop.append(v)
            v = nxt[v]
        if v == start and simple:
            loops.append(np.asarray(loop, dtype=np.int64))
    return loops


def capped_volume(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Signed volume of the surface with each simple boundary loop (:func:`boundary_loops`)
    capped by a fan from its centroid, wound as the faces are: positive when the faces point
    out of the region they enclose, also for a closed surface left open in places.

    Examples
    --------
    >>> v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    >>> round(capped_volume(v, np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3]])), 4)
    0.1667
    """
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    p = vertices[f]
    six = float(np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2])).sum())
    for loop in boundary_loops(f):
        c = vertices[loop].mean(axis=0)
        a, b = vertices[np.roll(loop, -1)] - c, vertices[loop] - c  # cap (c, next, this)
        six += float(np.einsum("ij,ij->i", np.broadcast_to(c, a.shape), np.cross(a, b)).sum())
    return six / 6.0


def boundary_components(edges: np.ndarray, counts: np.ndarray, n_vertices: int) -> int:
    """Number of connected components of the boundary-edge graph (the report's loop count).

    Parameters
    ----------
    edges : (E, 2) int
        Distinct edges (:func:`count_edge_faces`).
    counts : (E,) int
        Faces per edge; edges with one face are the boundary.
    n_vertices : int

    Examples
    --------
    >>> boundary_components(*count_edge_faces([[0, 1, 2], [0, 2, 3]]), 4)
    1
    """
    boundary = counts == 1
    n_boundary = int(boundary.sum())
    if not n_boundary:
        return 0
    bl, bh = edges[boundary, 0], edges[boundary, 1]
    graph = sparse.coo_matrix((np.ones(n_boundary, np.int8), (bl, bh)), (n_vertices,) * 2)
    _, label = csgraph.connected_components(graph, directed=False)
    return len(np.unique(label[np.concatenate([bl, bh])]))


def vertex_components(faces: np.ndarray, n_vertices: int) -> tuple[int, np.ndarray]:
    """Connected components of the referenced vertices (faces link their three vertices).

    Returns
    -------
    count : int
    labels : (n_vertices,) int64
        Component of each vertex, ``0 .. count - 1`` in order of the components' lowest vertex;
        -1 for vertices no face uses.
    """
    if len(faces) == 0:
        return 0, np.full(n_vertices, -1, dtype=np.int64)
    f = np.ascontiguousarray(faces, dtype=np.int64).reshape(-1, 3)
    if int(f.min()) < 0 or int(f.max()) >= n_vertices:
        raise ValueError(f"face indices must lie in [0, {n_vertices})")
    count, labels = vertex_component_labels(f, int(n_vertices))
    return int(count), labels


def face_components(faces: np.ndarray, n_vertices: int) -> tuple[int, np.ndarray]:
    """Connected components of faces through shared vertices: (count, label per face).

    The same components as :func:`vertex_components`, labelled per face.
    """
    if len(faces) == 0:
        return 0, np.zeros(0, dtype=np.int64)
    count, labels = vertex_components(faces, n_vertices)
    return count, labels[faces[:, 0]]


def face_area_vectors(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted face normals ``(F, 3)``: ``(b - a) x (c - a)``, twice the area vector.

    For sign tests (their direction is the winding's) and area weights.
    """
    v = np.asarray(vertices)
    f = np.asarray(faces)
    if v.dtype != np.float64 or v.ndim != 2 or f.ndim != 2 or f.dtype.kind not in "iu":
        p = v[f]
        return np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    return area_vectors(np.ascontiguousarray(v), np.ascontiguousarray(f, dtype=np.int64))


def corner_sum(faces: np.ndarray, values: np.ndarray, n_vertices: int) -> np.ndarray:
    """(V, 3): the sum over its faces of a per-face (F, 3) value at every vertex."""
    idx = faces.ravel()
    rep = np.repeat(values, 3, axis=0)
    return np.stack(
        [np.bincount(idx, weights=rep[:, j], minlength=n_vertices) for j in range(3)], axis=1
    )


def face_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Unit face normals ``(F, 3)`` oriented by the winding; degenerate faces give zero rows.

    Examples
    --------
    >>> face_normals(np.eye(3), np.array([[0, 1, 2]])).round(6).tolist()
    [[0.57735, 0.57735, 0.57735]]
    """
    n = face_area_vectors(vertices, faces)
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return np.divide(n, length, out=np.zeros_like(n), where=length > 0)


def vertex_fans(faces: np.ndarray) -> np.ndarray:
    """Fan label of every face corner, ``(F, 3)`` int64.

    Two corners at the same vertex get the same label when their faces are joined, around that
    vertex, through a chain of faces sharing an edge that contains the vertex. The number of
    distinct labels among a vertex's corners is its number of fans (1 on a manifold vertex).
    Faces with a repeated vertex index should be removed first.

    Examples
    --------
    >>> fans = vertex_fans(np.array([[0, 1, 2], [0, 2, 3], [0, 4, 5]]))
    >>> len(set(fans[:, 0].tolist()))  # vertex 0: the fan {0, 1} and the lone face 2
    2
    """
    nf = len(faces)
    if nf == 0:
        return np.zeros((0, 3), dtype=np.int64)
    f = np.ascontiguousarray(faces, dtype=np.int64)
    n_v = int(f.max()) + 1
    return fan_labels(f, half_edge_order(f, n_v)).reshape(nf, 3)


def ranked_fans(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every vertex's fans (:func:`vertex_fans`), ranked at their vertex: the largest (most
    corners) first, ties by the lowest fan label, so the ranking is deterministic.

    Returns
    -------
    fan_vertex : (P,) int64
        The vertex of each of the ``P`` fans; fans are ordered by vertex, then by label (the
        rows of ``np.unique`` over the (vertex, label) pairs).
    corner_fan : (3 F,) int64
        The fan (index into ``fan_vertex``) of every face corner, corner ``3 i + k``.
    rank : (P,) int64
        0 for the fan that keeps its vertex, 1, 2, ... for a bow-tie vertex's extra fans.

    Examples
    --------
    >>> fan_vertex, corner_fan, rank = ranked_fans(np.array([[0, 1, 2], [0, 2, 3], [0, 4, 5]]))
    >>> rank[corner_fan].reshape(-1, 3).tolist()  # vertex 0's lone face is its extra fan
    [[0, 0, 0], [0, 0, 0], [1, 0, 0]]
    """
    if len(faces) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64)
    fans = vertex_fans(faces).ravel()
    corner_v = faces.ravel()
    n_fans = int(fans.max()) + 1  # labels 0 .. n_fans - 1, each at one vertex
    at = np.empty(n_fans, dtype=np.int64)
    at[fans] = corner_v
    by_vertex = np.argsort(at, kind="stable")  # the (vertex, label) pairs in np.unique's order
    fan_vertex = at[by_vertex]
    corner_fan = np.empty(n_fans, dtype=np.int64)
    corner_fan[by_vertex] = np.arange(n_fans)
    corner_fan = corner_fan[fans]
    rank = np.zeros(n_fans, dtype=np.int64)
    if n_fans == np.count_nonzero(np.bincount(corner_v)):
        return fan_vertex, corner_fan, rank  # one fan per used vertex: no bow-tie
    size = np.bincount(fans, minlength=n_fans)[by_vertex]
    order = np.lexsort((by_vertex, -size, fan_vertex))
    first = np.searchsorted(fan_vertex[order], fan_vertex[order])
    rank[order] = np.arange(n_fans) - first
    return fan_vertex, corner_fan, rank


def boundary_loop_perimeters(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Perimeter of every boundary component (:func:`boundary_components`), largest first.

    Returns
    -------
    (L,) float64 [length of ``vertices``]
        The summed length of each component's boundary edges; empty for a closed mesh.

    Examples
    --------
    >>> v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    >>> boundary_loop_perimeters(v, np.array([[0, 1, 2], [0, 2, 3]])).tolist()
    [4.0]
    """
    edges, counts = count_edge_faces(faces)
    boundary = counts == 1
    if not boundary.any():
        return np.zeros(0)
    bl, bh = edges[boundary, 0], edges[boundary, 1]
    n_v = len(vertices)
    graph = sparse.coo_matrix((np.ones(len(bl), np.int8), (bl, bh)), (n_v,) * 2)
    _, label = csgraph.connected_components(graph, directed=False)
    length = np.linalg.norm(vertices[bl] - vertices[bh], axis=1)
    _, comp = np.unique(label[bl], return_inverse=True)
    return np.sort(np.bincount(comp, weights=length))[::-1]


def orientation_flips(
    faces: np.ndarray, *, order: np.ndarray | None = None, consistent: bool | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Per-face flips that make the winding consistent across every manifold edge.

    The face graph through edges with exactly two faces is spanned by a breadth-first forest
    (each component rooted at its lowest face, which keeps its winding); pointer jumping sums
    the pair parities up to the root in ``O(F log depth)``.

    A caller that has sorted the half-edges of ``faces`` already passes what it found: their
    ``order`` (:func:`recon.kernels.mesh_tables.half_edge_order`) and whether the winding is
    ``consistent`` (:func:`recon.kernels.mesh_tables.winding_consistent`); without them both
    come from one sort (:func:`recon.kernels.mesh_tables.half_edge_winding`).

    Returns
    -------
    flip : (F,) bool
        Reverse these faces.
    conflict : (F,) bool
        Faces on a manifold edge that both faces still run in the same direction after the
        flips: none when the mesh is orientable (a Moebius strip has some; the flips are then
        the forest's best guess).

    Examples
    --------
    >>> flip, conflict = orientation_flips(np.array([[0, 1, 2], [1, 2, 3]]))
    >>> flip.tolist(), bool(conflict.any())
    ([False, True], False)
    """
    n_faces = len(faces)
    if n_faces == 0:
        return np.zeros(0, dtype=bool), np.zeros(0, dtype=bool)
    f = np.ascontiguousarray(faces, dtype=np.int64)
    if consistent is None:
        order, consistent, _ = half_edge_winding(f, int(f.max()) + 1)
    if consistent:  # the forest would flip nothing
        return np.zeros(n_faces, dtype=bool), np.zeros(n_faces, dtype=bool)
    he_from = f.ravel()
    he_to = np.roll(f, -1, axis=1).ravel()
    he_face = np.repeat(np.arange(n_faces), 3)
    lo = np.minimum(he_from, he_to)
    hi = np.maximum(he_from, he_to)
    forward = he_from < he_to
    if order is None:
        order = half_edge_order(f, int(f.max()) + 1)  # = np.lexsort((he_face, hi, lo))
    lo_s, hi_s = lo[order], hi[order]
    is_new = np.ones(len(order), dtype=bool)
    is_new[1:] = (lo_s[1:] != lo_s[:-1]) | (hi_s[1:] != hi_s[:-1])
    edge_id = np.cumsum(is_new) - 1
    count = np.bincount(edge_id)
    same = ~is_new[1:] & (count[edge_id[1:]] == 2)
    a, b = order[:-1][same], order[1:][same]
    fa, fb = he_face[a], he_face[b]
    parity = forward[a] == forward[b]  # True: the pair disagrees, one of them must flip
    root = n_faces
    face_graph = sparse.coo_matrix((np.ones(len(fa), np.int8), (fa, fb)), (n_faces,) * 2)
    _, labels = csgraph.connected_components(face_graph, directed=False)
    first = np.unique(labels, return_index=True)[1]
    rows = np.concatenate([fa, fb, np.full(len(first), root)])
    cols = np.concatenate([fb, fa, first])
    graph = sparse.csr_matrix((np.ones(len(rows), np.int8), (rows, cols)), (n_faces + 1,) * 2)
    _, pred = csgraph.breadth_first_order(graph, root, directed=True, return_predecessors=True)
    pred = pred.astype(np.int64)
    pred[root] = root
    to_parent = np.zeros(n_faces + 1, dtype=bool)
    tree_ab = pred[fb] == fa
    tree_ba = pred[fa] == fb
    to_parent[fb[tree_ab]] = parity[tree_ab]
    to_parent[fa[tree_ba]] = parity[tree_ba]
    flip = to_parent.copy()
    ptr = pred.copy()
    while np.any(ptr != root):
        flip ^= np.where(ptr != root, flip[ptr], False)
        ptr = ptr[ptr]
    flip = flip[:n_faces]
    bad = (flip[fa] ^ flip[fb]) != parity
    conflict = np.zeros(n_faces, dtype=bool)
    conflict[fa[bad]] = True
    conflict[fb[bad]] = True
    return flip, conflict


#: Two faces at a vertex are compared by :func:`overlapping_faces` when their normals agree this
#: well (cos 60 deg): faces of one sheet, not the two faces of a fold or a thin part's two sides.
OVERLAP_NORMAL_AGREEMENT = 0.5
#: ... and overlap when their sectors there share more than this angle [rad] (about 6 deg).
OVERLAP_ANGLE = 0.1
#: Corner pairs per block in :func:`overlapping_faces` (its per-pair arrays held ~0.7 GB
#: at once on a million-particle sheet).
OVERLAP_BLOCK = 1 << 18


def overlapping_faces(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Face pairs ``(m, 2)``, ``i < j``, that cover the same wedge around a shared vertex.

    At a vertex ``v`` each face ``(v, a, b)`` (in winding order) spans the angular sector from
    ``a - v`` to ``b - v``. For two faces at ``v`` whose unit normals agree
    (``OVERLAP_NORMAL_AGREEMENT``), both sectors are measured counter-clockwise in the plane
    of their mean normal; in a mesh that covers its surface once the sectors only touch,
    so an overlap wider than ``OVERLAP_ANGLE`` means the faces lie over each other (e.g. ball
    pivoting took both diagonals of a nearly co-circular quad). Faces sharing a vertex are
    not checked by :func:`recon.intersections.self_intersections`; this is that case.

    Examples
    --------
    >>> v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    >>> overlapping_faces(v, np.array([[0, 1, 2], [0, 2, 3]])).tolist()  # a quad, one diagonal
    []
    >>> overlapping_faces(v, np.array([[0, 1, 2], [0, 2, 3], [0, 1, 3]])).tolist()  # both
    [[0, 2], [1, 2]]
    """
    f = np.ascontiguousarray(faces, dtype=np.int64)
    if len(f) < 2:
        return np.zeros((0, 2), dtype=np.int64)
    corner_v = f.ravel()
    corner_f = np.repeat(np.arange(len(f)), 3)
    ahead = np.roll(f, -1, axis=1).ravel()
    behind = np.roll(f, -2, axis=1).ravel()
    fn = face_normals(vertices, f)
    # every pair of corners at one vertex: a kernel passes over the pairs that miss the test
    # by a margin (most of them) and hands on the rest, which the test below decides
    candidates = overlap_candidates(
        np.ascontiguousarray(vertices, dtype=np.float64),
        f,
        fn,
        OVERLAP_NORMAL_AGREEMENT,
        OVERLAP_ANGLE,
    )
    found = [np.zeros((0, 2), dtype=np.int64)]
    pa, pb = candidates[:, 0], candidates[:, 1]
    for lo in range(0, len(pa), OVERLAP_BLOCK):  # ~20 (block, 3) arrays per block
        a, b = pa[lo : lo + OVERLAP_BLOCK], pb[lo : lo + OVERLAP_BLOCK]
        fa, fb = corner_f[a], corner_f[b]
        m = fn[fa] + fn[fb]
        agree = np.einsum("ij,ij->i", fn[fa], fn[fb]) > OVERLAP_NORMAL_AGREEMENT
        a, b, fa, fb, m = a[agree], b[agree], fa[agree], fb[agree], m[agree]
        m /= np.linalg.norm(m, axis=1, keepdims=True)
        helper = np.where(np.abs(m[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
        e1 = np.cross(m, helper)
        e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
        e2 = np.cross(m, e1)
        here = vertices[corner_v[a]]

        def angle(w: np.ndarray, here=here, e1=e1, e2=e2) -> np.ndarray:
            d = vertices[w] - here
            return np.arctan2(np.einsum("ij,ij->i", d, e2), np.einsum("ij,ij->i", d, e1))

        start_a, start_b = angle(ahead[a]), angle(ahead[b])
        width_a = (angle(behind[a]) - start_a) % (2 * np.pi)
        width_b = (angle(behind[b]) - start_b) % (2 * np.pi)
        rel = (start_b - start_a) % (2 * np.pi)  # b's sector starts this far into a's turn
        shared = np.maximum(0.0, np.minimum(width_a - rel, width_b)) + np.maximum(
            0.0, np.minimum(width_a, rel + width_b - 2 * np.pi)
        )
        hit = shared > OVERLAP_ANGLE
        found.append(np.stack([np.minimum(fa, fb)[hit], np.maximum(fa, fb)[hit]], axis=1))
    return np.unique(np.vstack(found), axis=0)


def opposed_faces(normals: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Faces ``(F,)`` bool whose corners' unit normals point more than 90 deg apart
    (``n_a . n_b < 0`` for some pair of corners): faces that join two opposed sheets.

    Examples
    --------
    >>> n = np.array([[0, 0, 1], [0, 0, 1], [0, 0, 1], [0, 0, -1]], float)
    >>> opposed_faces(n, np.array([[0, 1, 2], [0, 1, 3]])).tolist()
    [False, True]
    """
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    a, b, c = normals[f[:, 0]], normals[f[:, 1]], normals[f[:, 2]]
    ab, bc, ca = (np.einsum("ij,ij->i", x, y) for x, y in ((a, b), (b, c), (c, a)))
    return np.minimum(np.minimum(ab, bc), ca) < 0.0


def handle_count(faces: np.ndarray, n_vertices: int) -> tuple[int, int, int]:
    """Components ``c``, boundary loops ``b`` (:func:`boundary_components`) and handles of a
    manifold mesh: ``(2 c - b - chi) / 2`` with ``chi = V - E + F`` over the used vertices.

    Examples
    --------
    >>> handle_count(np.array([[0, 1, 2], [0, 2, 3]]), 4)
    (1, 1, 0)
    """
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    if len(f) == 0:
        return 0, 0, 0
    keys, _, counts = unique_edges(f, n_vertices)
    edges = np.stack([keys // n_vertices, keys % n_vertices], axis=1)
    c, _ = vertex_components(f, n_vertices)
    b = boundary_components(edges, counts, n_vertices)
    chi = int(np.count_nonzero(np.bincount(f.ravel()))) - len(keys) + len(f)
    return c, b, (2 * c - b - chi) // 2


def handle_bridges(normals: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Faces ``(F,)`` bool of the opposed bridges that carry a handle: tunnels between the two
    faces of a thin part.

    The opposed faces (:func:`opposed_faces`) fall into connected bridges. The rim of a thin
    part is one (it closes the part's edge); a bridge across the part away from its rim makes
    a tunnel between its faces, a handle the true surface does not have. Bridges are taken
    smallest first, and one is marked when the mesh without it and the bridges marked before
    has fewer handles (:func:`handle_count`). On a thin slab with one tunnel both the tunnel
    and the rim carry the handle (either cut opens it); the tunnel is the smaller and goes
    first, after which the rim carries none. Without a handle, nothing is marked.
    """
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    marked = np.zeros(len(f), dtype=bool)
    if len(f) == 0:
        return marked
    n_v = int(f.max()) + 1
    handles = handle_count(f, n_v)[2]
    opposed = np.flatnonzero(opposed_faces(normals, f))
    if handles <= 0 or len(opposed) == 0:
        return marked
    n, label = face_components(f[opposed], n_v)
    sizes = np.bincount(label, minlength=n)
    for k in np.argsort(sizes, kind="stable"):
        trial = marked.copy()
        trial[opposed[label == k]] = True
        left = handle_count(f[~trial], n_v)[2]
        if left < handles:
            marked, handles = trial, left
            if handles == 0:
                break
    return marked


def drop_unreferenced(
    vertices: np.ndarray,
    normals: np.ndarray,
    faces: np.ndarray,
    crease: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """Remove vertices no face uses (isolated particles) and renumber faces; ``crease``
    (per-vertex flags, optional) keeps the flags of the vertices kept (None stays None)."""
    used = np.zeros(len(vertices), dtype=bool)
    used[faces.reshape(-1)] = True
    remap = np.cumsum(used) - 1
    flags = None if crease is None else np.asarray(crease, dtype=bool)[used]
    return vertices[used], normals[used], remap[faces].astype(np.int64), flags
