"""One mesh from the tiles: normal signs agreed across seams, faces merged by global particle
id, the seams repaired, and the seam statistics of the report.

Normal signs. Every tile orients its normals on its own (PCA is local, so a point's normal
does not depend on the tile when its k neighbours lie within the halo, but the global sign of
each tile's orientation is chosen per tile). The fit does not depend on that sign (flipping
every data normal mirrors the particles' normals and nothing else), so the signs are agreed
*after* the fits: where two tiles meet, the particles one tile fitted in its halo are compared
with the other tile's own particles there, and a spanning tree over the strongest agreements
flips whole tiles (:func:`agree_signs`).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ..mesh import boundary_loops, count_edge_faces
from ..triangulate import (
    drop_unreferenced,
    loop_width,
    orient_consistently,
    remove_non_manifold_faces,
    repair_non_manifold,
    zip_loop,
)
from .grid import TileGrid

__all__ = ["SEAM_BAND", "agree_signs", "repair_seams", "seam_statistics"]

#: Edges and loops within this many r0 of an inner tile face count as "on a seam".
SEAM_BAND = 2.0
#: A loop is a seam's when at least this fraction of its vertices lie within SEAM_BAND of one.
SEAM_LOOP_FRACTION = 0.5
#: A seam crack is zipped when its width (4 area / perimeter) is at most this many r0 ...
CRACK_WIDTH = 2.5
#: ... and pairs closer than this many r0 compare their normal signs.
SIGN_PAIR_DISTANCE = 0.75


def agree_signs(
    grid: TileGrid,
    border_in: dict[int, tuple[np.ndarray, np.ndarray]],
    border_out: dict[int, tuple[np.ndarray, np.ndarray]],
    r0: float,
) -> tuple[dict[int, float], int]:
    """A sign (+1/-1) per tile so that the normals agree across seams; and the number of tile
    pairs whose normals disagreed before."""
    tiles = sorted(border_in)
    owner_tree = {}
    for t in tiles:
        p, n = border_in[t]
        if len(p):
            owner_tree[t] = (cKDTree(p), n)
    votes: dict[tuple[int, int], float] = {}
    for a in tiles:
        p, n = border_out.get(a, (np.zeros((0, 3)), np.zeros((0, 3))))
        if not len(p):
            continue
        cell = grid.cell_of(p)
        for b in np.unique(cell):
            b = int(b)
            if b == a or b not in owner_tree:
                continue
            sel = cell == b
            tree, nb = owner_tree[b]
            d, j = tree.query(p[sel])
            close = d < SIGN_PAIR_DISTANCE * r0
            if not close.any():
                continue
            dots = np.einsum("ij,ij->i", n[sel][close], nb[j[close]])
            key = (min(a, b), max(a, b))
            votes[key] = votes.get(key, 0.0) + float(dots.sum())
    # Kruskal over |vote|: the strongest agreements decide first
    parent = {t: t for t in tiles}
    rel = dict.fromkeys(tiles, 1.0)  # sign relative to the root

    def find(t: int) -> tuple[int, float]:
        s = 1.0
        while parent[t] != t:
            s *= rel[t]
            t = parent[t]
        return t, s

    disagreeing = sum(1 for v in votes.values() if v < 0)
    for (a, b), v in sorted(votes.items(), key=lambda kv: -abs(kv[1])):
        ra, sa = find(a)
        rb, sb = find(b)
        if ra == rb:
            continue
        want = 1.0 if v >= 0 else -1.0  # sign(a) * sign(b) must equal want
        parent[rb] = ra
        rel[rb] = sa * sb * want
    flips = {}
    for t in tiles:
        _, s = find(t)
        flips[t] = s
    return flips, disagreeing


def _edges_among(faces: np.ndarray, ids: np.ndarray, n_vertices: int) -> set[tuple[int, int]]:
    """The mesh edges between vertices of ``ids`` as ``(lo, hi)`` pairs (what :func:`zip_loop`
    must not add twice), without a Python set of every edge of the mesh."""
    inside = np.zeros(n_vertices, dtype=bool)
    inside[ids] = True
    e = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    e = e[inside[e[:, 0]] & inside[e[:, 1]]]
    return {(int(a), int(b)) for a, b in e}


def _seam_vertices(grid: TileGrid, vertices: np.ndarray, r0: float) -> np.ndarray:
    return grid.seam_distance(vertices) <= SEAM_BAND * r0


def repair_seams(
    grid: TileGrid,
    vertices: np.ndarray,
    normals: np.ndarray,
    faces: np.ndarray,
    r0: float,
    max_hole: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict]:
    """Make the merged mesh manifold and close the cracks the tiles left along the seams.

    Faces the tiles disagree on overlap (over-shared edges, duplicates) or leave gaps; the
    repair of :mod:`recon.triangulate` drops the extra faces and splits bow-tie vertices;
    boundary loops that lie along a seam (``SEAM_LOOP_FRACTION`` of their vertices within
    ``SEAM_BAND`` r0 of an inner tile face) and are small (perimeter <= pi ``max_hole`` [r0]) or
    narrow (a crack: width <= ``CRACK_WIDTH`` r0) are zipped. Loops away from the seams are
    left as the tiles made them.
    """
    stats = {"faces_merged": int(len(faces))}
    n0 = len(faces)
    faces = remove_non_manifold_faces(faces, len(vertices))
    stats["faces_dropped"] = int(n0 - len(faces))
    vertices, normals, faces = repair_non_manifold(vertices, normals, faces)
    zipped = 0
    for _ in range(3):
        seam = _seam_vertices(grid, vertices, r0)
        chosen = []
        for loop in boundary_loops(faces):
            if len(loop) < 3 or np.mean(seam[loop]) < SEAM_LOOP_FRACTION:
                continue
            ring = vertices[loop] / r0
            perim = float(np.linalg.norm(ring - np.roll(ring, -1, axis=0), axis=1).sum())
            if perim <= np.pi * max_hole or (len(loop) >= 4 and loop_width(ring) <= CRACK_WIDTH):
                chosen.append(loop)
        if not chosen:
            break
        edge_set = _edges_among(faces, np.concatenate(chosen), len(vertices))
        new = [zip_loop(vertices, loop[::-1], edge_set) for loop in chosen]
        if not new:
            break
        zipped += len(new)
        faces = np.vstack([faces, *new])
        vertices, normals, faces = repair_non_manifold(vertices, normals, faces)
    faces = orient_consistently(vertices, normals, faces)
    # orienting drops the faces of one-sided conflicts: repair what that leaves, close the
    # small holes it opens (the rule of the untiled fit: perimeter <= pi max_hole, or a slit
    # no wider than CRACK_WIDTH), orient again
    for _ in range(2):
        vertices, normals, faces = repair_non_manifold(vertices, normals, faces)
        small = []
        for loop in boundary_loops(faces):
            if len(loop) < 3:
                continue
            ring = vertices[loop] / r0
            perim = float(np.linalg.norm(ring - np.roll(ring, -1, axis=0), axis=1).sum())
            slit = len(loop) >= 4 and loop_width(ring) <= CRACK_WIDTH
            if perim <= np.pi * max_hole or (slit and perim <= 3 * np.pi * max_hole):
                small.append(loop)
        if small:
            edge_set = _edges_among(faces, np.concatenate(small), len(vertices))
            faces = np.vstack([faces, *[zip_loop(vertices, lp[::-1], edge_set) for lp in small]])
            zipped += len(small)
            vertices, normals, faces = repair_non_manifold(vertices, normals, faces)
        faces = orient_consistently(vertices, normals, faces)
        if not small:
            break
    vertices, normals, faces = repair_non_manifold(vertices, normals, faces)
    vertices, normals, faces = drop_unreferenced(vertices, normals, faces)
    stats["seam_loops_zipped"] = zipped
    return vertices, normals, faces, stats


def seam_statistics(
    grid: TileGrid, vertices: np.ndarray, faces: np.ndarray, owner: np.ndarray, r0: float
) -> dict:
    """Edges across tiles (``seam_edges``: their two ends owned by different tiles), the
    boundary edges among them and within ``SEAM_BAND`` r0 of an inner tile face, and the
    non-manifold edges of the whole mesh."""
    edges, counts = count_edge_faces(faces)
    cross = owner[edges[:, 0]] != owner[edges[:, 1]]
    mid = vertices[edges].mean(axis=1)
    near = grid.seam_distance(mid) <= SEAM_BAND * r0
    boundary = counts == 1
    return {
        "seam_edges": int(cross.sum()),
        "seam_boundary_edges": int((cross & boundary).sum()),
        "boundary_edges_near_seams": int((near & boundary).sum()),
        "non_manifold_edges": int((counts > 2).sum()),
    }
