r"""Handles that fit in a small geodesic ball of a mesh: tunnels the sampling cannot resolve.

A closed surface of genus g has g handles; each has two short generating cycles only when the
whole handle is small. For a vertex s, the *ball* B(s, R) is the set of faces whose three
corners lie within geodesic distance R of s (shortest paths along edges). A ball on a surface
without a small handle is a disc, or an annulus where it wraps round a part thinner than R;
a ball that holds a whole handle has the Euler characteristic

.. math::

    \chi = V - E + F = 2c - b - 2h,\qquad h = (2c - b - \chi) / 2 > 0

with c its components and b its boundary loops. A handle of the true surface (a ring, a torus)
is longer than 2R round one of its cycles and never fits in a ball; a tunnel a few spacings
across (two sheets of a sparse thin part bridged by a flap) does.

References
----------
.. [WHDS04] Z. Wood, H. Hoppe, M. Desbrun, P. Schröder. "Removing excess topology from
   isosurfaces". ACM TOG 23(2), 2004: small handles as defects of reconstructed surfaces.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from .mesh_tables import find_root, union_sets
from .options import EXACT_JIT_OPTIONS

_PARALLEL_EXACT = dict(EXACT_JIT_OPTIONS, parallel=True)
#: Fewest vertices per thread's block of sources (smaller meshes use fewer threads: each block
#: allocates scratch marks for the whole mesh).
MIN_BLOCK_VERTICES = 2048
#: Most blocks of sources: each holds ~40 bytes of scratch per vertex of the mesh, so that many
#: cores do not multiply it past about the size of the mesh's own tables.
MAX_BLOCKS = 4


def source_blocks(n_vertices: int, threads: int) -> int:
    """Blocks of sources for :func:`small_handle_sources`: one per thread, at most
    ``MAX_BLOCKS``, each of at least ``MIN_BLOCK_VERTICES`` (0 or 1: one block, serial)."""
    return min(int(threads), MAX_BLOCKS, int(n_vertices) // MIN_BLOCK_VERTICES)


@njit(**EXACT_JIT_OPTIONS)
def geodesic_ball(
    source, reach, vv_offsets, vv_nbr, vv_len, mark, dist, ball, stamp
):  # pragma: no cover - numba
    """Vertices within geodesic distance ``reach`` of ``source`` along edges (Dijkstra).

    Writes them to ``ball`` (their count is returned; -1 when more than ``len(ball)``) and
    sets ``mark[v] = stamp`` and ``dist[v]`` for each; ``mark`` must not hold ``stamp``
    elsewhere. The selection of the next vertex is a linear scan of the ball: balls hold tens
    of vertices.
    """
    cap = ball.shape[0]
    ball[0] = source
    mark[source] = stamp
    dist[source] = 0.0
    k = 1
    done = 0  # ball[:done] are settled, in order of distance
    while done < k:
        best = done
        for a in range(done + 1, k):
            if dist[ball[a]] < dist[ball[best]]:
                best = a
        u = ball[best]
        ball[best] = ball[done]
        ball[done] = u
        done += 1
        for p in range(vv_offsets[u], vv_offsets[u + 1]):
            w = vv_nbr[p]
            d = dist[u] + vv_len[p]
            if d > reach:
                continue
            if mark[w] != stamp:
                if k == cap:
                    return -1
                mark[w] = stamp
                dist[w] = d
                ball[k] = w
                k += 1
            elif d < dist[w]:
                dist[w] = d
    return k


@njit(**EXACT_JIT_OPTIONS)
def ball_handles(
    faces, ball, k, stamp, mark, fmark, vf_offsets, vf_faces, he_edge, edge_faces, local
):  # pragma: no cover - numba
    """Handles ``h = (2c - b - chi) / 2`` of the faces of a geodesic ball (module docstring):
    the faces whose corners all carry ``stamp`` in ``mark``. ``fmark`` (per face) and
    ``local`` (per vertex) are scratch: faces of the ball get ``stamp`` in ``fmark``.
    Returns (handles, faces of the ball, ring); handles is -1 where an edge of the ball has
    more than two faces (not a manifold: the count means nothing there); ring is true when
    the ball is one annulus (one component, two boundary loops, no handle) whose rims are
    not the mesh's own boundary: it wraps round a part thinner than the ball (a ball round
    a small hole of the mesh is an annulus too)."""
    nf = 0
    # the ball's faces, each once; its vertices numbered for the union-finds
    nv = 0
    for a in range(k):
        u = ball[a]
        local[u] = -1
    for a in range(k):
        u = ball[a]
        for p in range(vf_offsets[u], vf_offsets[u + 1]):
            f = vf_faces[p]
            if fmark[f] == stamp:
                continue
            if mark[faces[f, 0]] != stamp or mark[faces[f, 1]] != stamp:
                continue
            if mark[faces[f, 2]] != stamp:
                continue
            fmark[f] = stamp
            nf += 1
            for c in range(3):
                v = faces[f, c]
                if local[v] < 0:
                    local[v] = nv
                    nv += 1
    if nf == 0:
        return 0, 0, False
    parent_v = np.arange(nv)  # components of the faces (through their corners)
    parent_b = np.arange(nv)  # components of the boundary edges (through their ends)
    on_rim = np.zeros(nv, dtype=np.bool_)
    n_rim = 0  # boundary half-edges
    open_mesh = False  # a rim edge on the mesh's own boundary: a hole's rim, not a stalk
    for a in range(k):
        u = ball[a]
        for p in range(vf_offsets[u], vf_offsets[u + 1]):
            f = vf_faces[p]
            if fmark[f] != stamp or faces[f, 0] != u:
                continue  # each face once: from its first corner
            for c in range(3):
                x = local[faces[f, c]]
                y = local[faces[f, (c + 1) % 3]]
                union_sets(parent_v, x, y)
                e = he_edge[3 * f + c]
                g0 = edge_faces[e, 0]
                g1 = edge_faces[e, 1]
                if edge_faces[e, 2] >= 0:
                    return -1, nf, False
                other = g1 if g0 == f else g0
                if other < 0 or fmark[other] != stamp:
                    open_mesh = open_mesh or other < 0
                    n_rim += 1
                    on_rim[x] = True
                    on_rim[y] = True
                    union_sets(parent_b, x, y)
    components = 0
    loops = 0
    for x in range(nv):
        if find_root(parent_v, x) == x:
            components += 1
        if on_rim[x] and find_root(parent_b, x) == x:
            loops += 1
    edges = (3 * nf + n_rim) // 2
    chi = nv - edges + nf
    h = (2 * components - loops - chi) // 2
    return h, nf, h == 0 and components == 1 and loops == 2 and not open_mesh


@njit(**_PARALLEL_EXACT)
def small_handle_sources(
    faces,
    n_vertices,
    reach,
    vv_offsets,
    vv_nbr,
    vv_len,
    vf_offsets,
    vf_faces,
    he_edge,
    edge_faces,
    max_ball,
    blocks,
):  # pragma: no cover - numba
    """Every vertex whose geodesic ball of radius ``reach`` holds a handle, and the number of
    faces of that ball (``(m,)`` int64 each, vertices ascending); then the same for the
    vertices whose ball is one annulus (``ring`` of :func:`ball_handles`: it wraps round a
    stalk thinner than the ball). Balls of more than ``max_ball`` vertices are skipped.

    Each source's ball is independent of the others: the vertices are split into ``blocks``
    blocks (at least 1; :func:`source_blocks`), each with its own scratch marks (stamped with
    the source, so never cleared); the result is the same for any split."""
    n_faces = faces.shape[0]
    blocks = max(1, blocks)
    size = (n_vertices + blocks - 1) // blocks
    handles = np.zeros(n_vertices, dtype=np.int64)
    ball_faces = np.zeros(n_vertices, dtype=np.int64)
    rings = np.zeros(n_vertices, dtype=np.bool_)
    for b in prange(blocks):
        mark = np.full(n_vertices, -1, dtype=np.int64)
        dist = np.zeros(n_vertices)
        local = np.full(n_vertices, -1, dtype=np.int64)
        fmark = np.full(n_faces, -1, dtype=np.int64)
        ball = np.empty(max_ball, dtype=np.int64)
        for s in range(b * size, min(n_vertices, (b + 1) * size)):
            if vf_offsets[s + 1] == vf_offsets[s]:
                continue  # not a corner of any face
            k = geodesic_ball(s, reach, vv_offsets, vv_nbr, vv_len, mark, dist, ball, s)
            if k < 0:
                continue
            h, nf, ring = ball_handles(
                faces, ball, k, s, mark, fmark, vf_offsets, vf_faces, he_edge, edge_faces, local
            )
            handles[s] = h
            ball_faces[s] = nf
            rings[s] = ring
    hits = np.flatnonzero(handles > 0).astype(np.int64)
    around = np.flatnonzero(rings).astype(np.int64)
    return hits, ball_faces[hits], around, ball_faces[around]
