"""Small handles: find the tunnels a geodesic ball of a few spacings holds, and cut them.

Where a sparse thin part meets the body (an ear's base), a flap of faces can bridge two
sheets into a tunnel a few spacings across: a handle the true surface does not have. The
sampling cannot resolve a tunnel that small (growth closes holes narrower than ``max_gap``
for the same reason), so a handle that fits in a geodesic ball of ``reach`` is taken as a
defect: the smallest such ball is removed and its rim zipped into a disc
(:func:`recon.holes.zip_loop`), which takes the handle with it. A handle too large for the
ball can still be cut at a stalk thinner than it, when the tunnel beside the stalk is no
longer round than the largest hole that hole filling closes (:func:`_cut_stalk`: an ear
joined to the head by two thin stalks). The kernels are in
:mod:`recon.kernels.local_topology`.
"""

from __future__ import annotations

import logging
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np
from scipy import sparse
from scipy.sparse import csgraph

from .holes import zip_loop
from .intersections import self_intersections
from .kernels.local_topology import (
    ball_handles,
    geodesic_ball,
    small_handle_sources,
    source_blocks,
)
from .kernels.mesh_tables import edge_table
from .kernels.options import current_threads, thread_limit
from .mesh import boundary_loops, drop_unreferenced, handle_count

if TYPE_CHECKING:
    from .triangulate import TriangulationResult

log = logging.getLogger(__name__)

__all__ = ["SMALL_HANDLE_REACH", "cut_small_handles", "small_handles", "without_small_handles"]

#: A handle inside a geodesic ball of this radius [local spacings] is a defect. Growth takes
#: holes up to ``growth.max_gap`` across as gaps of the sampling (10 data spacings: 4 r0 on
#: the dense bunny, 12 r0 on the sparse one-eared body of the tests). A handle that fits in a
#: ball of 5 r0 has both cycles shorter than about 10 r0 (a tunnel about 3 r0 across through
#: a bridge about 1.5 r0 thick), which the particles cannot resolve, while a handle of the
#: true surface (a ring, a torus, a cup's handle) is longer round one of its cycles. (3 r0
#: until 2026-11-29: an ear's base on the held-out eared shape at 5,000 points held a tunnel
#: that fits in 5 r0 and not in 3.)
SMALL_HANDLE_REACH = 5.0
#: Balls with more vertices than this are skipped (a vertex of far more than the usual ~90
#: within the reach: a clump of tiny faces, not a sheet).
MAX_BALL_VERTICES = 512
#: The cut tries these fractions of the reach, smallest first: the smallest ball that holds
#: the handle leaves the smallest patch; a ball a little wider than the reach can have the
#: simple rim the one just holding the handle lacks (a rim that touches itself).
RADIUS_LADDER = (0.5, 0.65, 0.8, 1.0, 1.25, 1.5)
#: Vertices tried per cut, smallest ball first.
MAX_TRIES = 8
#: Cuts per mesh (each removes at least one handle).
MAX_CUTS = 8


class _Tables:
    """Vertex adjacency with edge lengths, vertex-face incidence and edge-face table."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray) -> None:
        n = len(vertices)
        f = np.ascontiguousarray(faces, dtype=np.int64)
        keys, inverse, counts = edge_table(f, n)
        lo, hi = keys // n, keys % n
        both = np.concatenate([lo, hi])
        other = np.concatenate([hi, lo])
        order = np.argsort(both, kind="stable")
        self.vv_nbr = other[order]
        self.vv_offsets = np.zeros(n + 1, dtype=np.int64)
        np.cumsum(np.bincount(both, minlength=n), out=self.vv_offsets[1:])
        length = np.linalg.norm(vertices[lo] - vertices[hi], axis=1)
        self.vv_len = np.concatenate([length, length])[order]
        corner = f.reshape(-1)
        order = np.argsort(corner, kind="stable")
        self.vf_faces = order // 3
        self.vf_offsets = np.zeros(n + 1, dtype=np.int64)
        np.cumsum(np.bincount(corner, minlength=n), out=self.vf_offsets[1:])
        # each edge's first three faces (-1: none); a third means a non-manifold edge
        self.edge_faces = np.full((len(keys), 3), -1, dtype=np.int64)
        order = np.argsort(inverse, kind="stable")
        start = np.zeros(len(keys) + 1, dtype=np.int64)
        np.cumsum(counts, out=start[1:])
        rank = np.arange(len(order)) - start[inverse[order]]
        keep = rank < 3
        self.edge_faces[inverse[order][keep], rank[keep]] = order[keep] // 3
        self.he_edge = inverse
        self.faces = f
        self.n = n


def small_handles(
    vertices: np.ndarray, faces: np.ndarray, reach: float, threads: int | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """The vertices whose geodesic ball of radius ``reach`` holds a handle, and the number of
    faces of each ball: ``(m,)`` int64 each, vertices ascending. ``threads``: blocks of
    sources scanned in parallel (default: numba's thread count); the result is the same."""
    t = _Tables(np.asarray(vertices, dtype=np.float64), faces)
    return _sources(t, reach, threads)[:2]


def _sources(
    t: _Tables, reach: float, threads: int | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Small-handle sources and their balls' face counts, then the same for the vertices
    whose ball is an annulus round a thin stalk (:func:`small_handle_sources`)."""
    blocks = source_blocks(t.n, current_threads() if threads is None else threads)
    with thread_limit(blocks > 1):  # one block: no threaded region to wake
        return small_handle_sources(
            t.faces,
            t.n,
            float(reach),
            t.vv_offsets,
            t.vv_nbr,
            t.vv_len,
            t.vf_offsets,
            t.vf_faces,
            t.he_edge,
            t.edge_faces,
            MAX_BALL_VERTICES,
            blocks,
        )


def _ball_faces(t: _Tables, source: int, radius: float) -> tuple[int, np.ndarray, bool]:
    """(handles, face mask, is an annulus) of the geodesic ball of ``radius`` round
    ``source``."""
    mark = np.full(t.n, -1, dtype=np.int64)
    dist = np.zeros(t.n)
    ball = np.empty(MAX_BALL_VERTICES, dtype=np.int64)
    k = geodesic_ball(source, radius, t.vv_offsets, t.vv_nbr, t.vv_len, mark, dist, ball, source)
    fmark = np.full(len(t.faces), -1, dtype=np.int64)
    if k < 0:
        return 0, fmark >= 0, False
    local = np.full(t.n, -1, dtype=np.int64)
    h, _, ring = ball_handles(
        t.faces,
        ball,
        k,
        source,
        mark,
        fmark,
        t.vf_offsets,
        t.vf_faces,
        t.he_edge,
        t.edge_faces,
        local,
    )
    return int(h), fmark == source, bool(ring)


def _rim_loops(faces: np.ndarray, inside: np.ndarray) -> tuple[np.ndarray, list[np.ndarray]]:
    """The faces outside a ball (face mask ``inside``) and the boundary loops of those
    faces that touch the ball."""
    kept = faces[~inside]
    rim = set(np.unique(faces[inside]).tolist())
    return kept, [loop for loop in boundary_loops(kept) if rim.intersection(loop.tolist())]


def _zipped(
    vertices: np.ndarray,
    kept: np.ndarray,
    loops: list[np.ndarray],
    counts: tuple[int, int, int],
) -> tuple[np.ndarray, tuple[int, int, int]] | None:
    """``kept`` with each of ``loops`` zipped (:func:`recon.holes.zip_loop`), and its
    :func:`recon.mesh.handle_count`, when that leaves fewer handles, no more components or
    boundary loops than ``counts`` and no face of the patches crossing another; else None."""
    he = kept[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    edges = set(map(tuple, np.sort(he, axis=1).tolist()))
    patches = []
    for loop in loops:
        patch = zip_loop(vertices, loop[::-1], edges)
        edges |= set(map(tuple, np.sort(patch[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), 1).tolist()))
        patches.append(patch)
    trial = np.concatenate([kept, *patches])
    c, b, h = handle_count(trial, len(vertices))
    c0, b0, h0 = counts
    if c > c0 or b > b0 or h >= h0:
        return None
    if len(self_intersections(vertices, trial, np.arange(len(kept), len(trial)))):
        return None
    return trial, (c, b, h)


def _rim_distance(
    vertices: np.ndarray, kept: np.ndarray, a: np.ndarray, b: np.ndarray, limit: float
) -> float:
    """Shortest path along the edges of ``kept`` from a vertex of loop ``a`` to one of loop
    ``b``; inf when longer than ``limit``. Only the edges whose ends lie within ``limit``
    (straight line) of ``a`` are searched: a path that leaves them is longer than ``limit``."""
    centre = vertices[a].mean(axis=0)
    near = np.linalg.norm(vertices - centre, axis=1)
    span = float(np.max(np.linalg.norm(vertices[a] - centre, axis=1)))
    edges = np.sort(kept[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    edges = np.unique(edges[(near[edges] <= limit + span).all(axis=1)], axis=0)  # each once
    if len(edges) == 0:
        return np.inf
    ids, local = np.unique(edges, return_inverse=True)
    i, j = local.reshape(edges.shape).T
    length = np.linalg.norm(vertices[ids[i]] - vertices[ids[j]], axis=1)
    graph = sparse.coo_matrix((length, (i, j)), shape=(len(ids), len(ids))).tocsr()
    where = np.full(len(vertices), -1, dtype=np.int64)
    where[ids] = np.arange(len(ids))
    start, end = where[a], where[b]
    if (start < 0).all() or (end < 0).all():
        return np.inf
    dist = csgraph.dijkstra(
        graph, directed=False, indices=start[start >= 0], min_only=True, limit=limit
    )
    return float(dist[end[end >= 0]].min())


def _cut_one(
    vertices: np.ndarray,
    faces: np.ndarray,
    reach: float,
    counts: tuple[int, int, int],
    tunnel_perimeter: float | None = None,
    editable: np.ndarray | None = None,
) -> tuple[np.ndarray, tuple[int, int, int], np.ndarray | None] | None:
    """``faces`` with one small handle cut out and its hole zipped, its
    :func:`recon.mesh.handle_count`, and which of its faces are ``editable`` (the patch's
    are); None when no small handle can be cut cleanly (one rim, fewer handles, no new
    crossing) within the ``editable`` faces (all when None). ``counts``: ``handle_count`` of
    ``faces``.

    With ``tunnel_perimeter``, a handle too large for the ball may still be cut at a thin
    stalk (:func:`_cut_stalk`)."""
    t = _Tables(vertices, faces)
    hits, sizes, rings, ring_sizes = _sources(t, reach)
    for s in hits[np.argsort(sizes, kind="stable")][:MAX_TRIES]:
        for fraction in RADIUS_LADDER:
            h, inside, _ = _ball_faces(t, int(s), fraction * reach)
            if h <= 0 or not _all_editable(inside, editable):
                continue
            kept, loops = _rim_loops(faces, inside)
            if len(loops) != 1:
                continue  # no simple rim (it touches itself) or more than one: a wider ball
            done = _zipped(vertices, kept, loops, counts)
            if done is not None:
                return (*done, _editable_after(editable, inside, done[0]))
    if tunnel_perimeter is None or len(rings) == 0:
        return None
    return _cut_stalk(vertices, faces, t, rings[np.argsort(ring_sizes, kind="stable")],
                      reach, counts, tunnel_perimeter, editable)  # fmt: skip


def _all_editable(inside: np.ndarray, editable: np.ndarray | None) -> bool:
    """Whether every face of a ball (face mask ``inside``) may be removed."""
    return editable is None or not bool(np.any(inside & ~editable))


def _editable_after(
    editable: np.ndarray | None, inside: np.ndarray, trial: np.ndarray
) -> np.ndarray | None:
    """The editable mask of ``trial`` (the faces outside the ball, then the patch's)."""
    if editable is None:
        return None
    kept = editable[~inside]
    return np.concatenate([kept, np.ones(len(trial) - len(kept), dtype=bool)])


def _cut_stalk(
    vertices: np.ndarray,
    faces: np.ndarray,
    t: _Tables,
    sources: np.ndarray,
    reach: float,
    counts: tuple[int, int, int],
    tunnel_perimeter: float,
    editable: np.ndarray | None = None,
) -> tuple[np.ndarray, tuple[int, int, int], np.ndarray | None] | None:
    """Cut a handle at a thin stalk: the ball round one of ``sources`` (smallest first) is an
    annulus round a stalk thinner than ``reach``; it is removed and both its rims zipped
    when the tunnel beside the stalk is short: the shortest path from one rim to the other
    round the tunnel, plus the ball's diameter it closes across, is at most
    ``tunnel_perimeter`` (the perimeter of the largest hole that hole filling closes). A true
    ring or tube is far longer round its other cycle; a stalk whose cut would split the mesh
    has no such path. Otherwise as :func:`_cut_one`."""
    tried = np.zeros(t.n, dtype=bool)
    tries = 0
    for s in sources:
        if tries == MAX_TRIES:
            break
        if tried[s]:
            continue  # inside the ball of a stalk already tried
        tries += 1
        for fraction in RADIUS_LADDER:
            radius = fraction * reach
            if radius > reach:
                break  # wider balls than the scan's need not be annuli round the same stalk
            _, inside, ring = _ball_faces(t, int(s), radius)
            if not ring or not _all_editable(inside, editable):
                continue
            kept, loops = _rim_loops(faces, inside)
            if len(loops) != 2:
                continue
            limit = tunnel_perimeter - 2.0 * radius
            if _rim_distance(vertices, kept, loops[0], loops[1], limit) > limit:
                break  # the tunnel is longer (or the stalk splits the mesh): not this stalk
            done = _zipped(vertices, kept, loops, counts)
            if done is not None:
                return (*done, _editable_after(editable, inside, done[0]))
        tried[np.unique(faces[_ball_faces(t, int(s), reach)[1]])] = True
    return None


def cut_small_handles(
    vertices: np.ndarray,
    faces: np.ndarray,
    reach: float = SMALL_HANDLE_REACH,
    tunnel_perimeter: float | None = None,
    editable: np.ndarray | None = None,
) -> tuple[np.ndarray, int]:
    """``faces`` with every handle that fits in a geodesic ball of radius ``reach`` cut out
    and its hole zipped (no new vertex; vertices inside a cut ball are left unreferenced),
    and the number of cuts. A cut is kept only when the mesh then has fewer handles, no more
    components or boundary loops, and no face of the patch crosses another. The patch's
    faces come last, after the kept faces in their order.

    ``tunnel_perimeter`` (default: none): also cut a handle at a stalk thinner than
    ``reach`` when the tunnel beside it is at most this long round (:func:`_cut_stalk`):
    an ear joined to the head by two thin stalks with a window between them.

    ``editable`` (F,) bool, optional: the faces a cut may remove; a ball that holds any
    other face is not cut (a tile of a tiled fit keeps the faces its neighbours see, the
    seam's repair keeps the faces round its zone)."""
    v = np.ascontiguousarray(vertices, dtype=np.float64)
    f = np.ascontiguousarray(faces, dtype=np.int64)
    edit = None if editable is None else np.asarray(editable, dtype=bool)
    if edit is not None and not edit.any():
        return f, 0
    cuts = 0
    counts = handle_count(f, len(v))
    while cuts < MAX_CUTS and counts[2] > 0:
        trial = _cut_one(v, f, reach, counts, tunnel_perimeter, edit)
        if trial is None:
            break
        (f, counts, edit), cuts = trial, cuts + 1
    return f, cuts


def without_small_handles(
    result: TriangulationResult,
    reach: float = SMALL_HANDLE_REACH,
    tunnel_perimeter: float | None = None,
) -> TriangulationResult:
    """``result`` with its small handles cut (:func:`cut_small_handles`; ``reach`` and
    ``tunnel_perimeter`` in the mesh's units, r0 for a fit's particle mesh), the vertices
    inside the cut balls dropped, and ``stats["small_handles_cut"]`` set (the cuts at thin
    stalks included); ``result`` itself when it has none."""
    faces, cuts = cut_small_handles(result.vertices, result.faces, reach, tunnel_perimeter)
    if cuts == 0:
        return result
    v, n, f, crease = drop_unreferenced(result.vertices, result.normals, faces, result.crease)
    log.debug("cut %d small handles", cuts)
    stats = {**result.stats, "small_handles_cut": cuts}
    return replace(result, vertices=v, faces=f, normals=n, crease=crease, stats=stats)
