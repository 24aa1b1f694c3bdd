"""Small handles: find the tunnels a geodesic ball of a few spacings holds, and cut them.

Where a sparse thin part meets the body (an ear's base), a flap of faces can bridge two
sheets into a tunnel a few spacings across: a handle the true surface does not have. The
sampling cannot resolve a tunnel that small (growth closes holes narrower than ``max_gap``
for the same reason), so a handle that fits in a geodesic ball of ``reach`` is taken as a
defect: the smallest such ball is removed and its rim zipped into a disc
(:func:`recon.holes.zip_loop`), which takes the handle with it. The kernels are in
:mod:`recon.kernels.local_topology`.
"""

from __future__ import annotations

import logging
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

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
    return _sources(_Tables(np.asarray(vertices, dtype=np.float64), faces), reach, threads)


def _sources(t: _Tables, reach: float, threads: int | None = None) -> tuple[np.ndarray, np.ndarray]:
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


def _ball_faces(t: _Tables, source: int, radius: float) -> tuple[int, np.ndarray]:
    """(handles, face mask) of the geodesic ball of ``radius`` round ``source``."""
    mark = np.full(t.n, -1, dtype=np.int64)
    dist = np.zeros(t.n)
    ball = np.empty(MAX_BALL_VERTICES, dtype=np.int64)
    k = geodesic_ball(source, radius, t.vv_offsets, t.vv_nbr, t.vv_len, mark, dist, ball, source)
    fmark = np.full(len(t.faces), -1, dtype=np.int64)
    if k < 0:
        return 0, fmark >= 0
    local = np.full(t.n, -1, dtype=np.int64)
    h, _ = ball_handles(
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
    return int(h), fmark == source


def _cut_one(
    vertices: np.ndarray, faces: np.ndarray, reach: float, counts: tuple[int, int, int]
) -> tuple[np.ndarray, tuple[int, int, int]] | None:
    """``faces`` with one small handle cut out and its hole zipped, and its
    :func:`recon.mesh.handle_count`; None when no small handle can be cut cleanly (one rim,
    fewer handles, no new crossing). ``counts``: ``handle_count`` of ``faces``."""
    t = _Tables(vertices, faces)
    hits, sizes = _sources(t, reach)
    if len(hits) == 0:
        return None
    c0, b0, h0 = counts
    for s in hits[np.argsort(sizes, kind="stable")][:MAX_TRIES]:
        for fraction in RADIUS_LADDER:
            h, inside = _ball_faces(t, int(s), fraction * reach)
            if h <= 0:
                continue
            kept = faces[~inside]
            rim = set(np.unique(faces[inside]).tolist())
            loops = [loop for loop in boundary_loops(kept) if rim.intersection(loop.tolist())]
            if len(loops) != 1:
                continue  # no simple rim (it touches itself) or more than one: a wider ball
            he = kept[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
            edges = set(map(tuple, np.sort(he, axis=1).tolist()))
            patch = zip_loop(vertices, loops[0][::-1], edges)
            trial = np.concatenate([kept, patch])
            c, b, h1 = handle_count(trial, len(vertices))
            if c > c0 or b > b0 or h1 >= h0:
                continue
            new = np.arange(len(kept), len(trial))
            if len(self_intersections(vertices, trial, new)):
                continue
            return trial, (c, b, h1)
    return None


def cut_small_handles(
    vertices: np.ndarray, faces: np.ndarray, reach: float = SMALL_HANDLE_REACH
) -> tuple[np.ndarray, int]:
    """``faces`` with every handle that fits in a geodesic ball of radius ``reach`` cut out
    and its hole zipped (no new vertex; vertices inside a cut ball are left unreferenced),
    and the number of cuts. A cut is kept only when the mesh then has fewer handles, no more
    components or boundary loops, and no face of the patch crosses another."""
    v = np.ascontiguousarray(vertices, dtype=np.float64)
    f = np.ascontiguousarray(faces, dtype=np.int64)
    cuts = 0
    counts = handle_count(f, len(v))
    while cuts < MAX_CUTS and counts[2] > 0:
        trial = _cut_one(v, f, reach, counts)
        if trial is None:
            break
        (f, counts), cuts = trial, cuts + 1
    return f, cuts


def without_small_handles(
    result: TriangulationResult, reach: float = SMALL_HANDLE_REACH
) -> TriangulationResult:
    """``result`` with its small handles cut (:func:`cut_small_handles`; ``reach`` in the
    mesh's units, r0 for a fit's particle mesh), the vertices inside the cut balls dropped,
    and ``stats["small_handles_cut"]`` set; ``result`` itself when it has none."""
    faces, cuts = cut_small_handles(result.vertices, result.faces, reach)
    if cuts == 0:
        return result
    v, n, f, crease = drop_unreferenced(result.vertices, result.normals, faces, result.crease)
    log.debug("cut %d small handles", cuts)
    stats = {**result.stats, "small_handles_cut": cuts}
    return replace(result, vertices=v, faces=f, normals=n, crease=crease, stats=stats)
