"""One mesh from the tiles: normal signs agreed across seams (:func:`agree_signs`) and the
seam zone repaired one dual cell at a time (:func:`repair_cell`, driven by
:func:`recon.tiling.assemble.stitch_streamed`).

Normal signs. Every tile orients its normals on its own (PCA is local, so a point's normal
does not depend on the tile when its k neighbours lie within the halo, but the global sign of
each tile's orientation is chosen per tile). The fit does not depend on that sign (flipping
every data normal mirrors the particles' normals and nothing else), so the signs are agreed
*after* the fits: where two tiles meet, the particles one tile fitted in its halo are compared
with the other tile's own particles there, and a spanning tree over the strongest agreements
flips whole tiles (:func:`agree_signs`).
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from scipy.spatial import cKDTree

from ..holes import loop_width, zip_loop
from ..mesh import boundary_loops, face_components, orientation_flips
from ..small_handles import SMALL_HANDLE_REACH, cut_small_handles
from ..triangulate import remove_non_manifold_faces
from ..winding import MIN_COMPONENT_FACES, orient_consistently, twisted_faces
from .grid import TileGrid

__all__ = [
    "SEAM_BAND",
    "agree_signs",
    "face_keys",
    "repair_cell",
    "same_winding",
    "unmatched_crease_particles",
]

#: Edges and loops within this many r0 of an inner tile face count as "on a seam".
SEAM_BAND = 2.0
#: A loop is a seam's when at least this fraction of its vertices lie within SEAM_BAND of one.
SEAM_LOOP_FRACTION = 0.5
#: A seam crack is zipped when its width (4 area / perimeter) is at most this many r0 ...
CRACK_WIDTH = 2.5
#: ... and pairs closer than this many r0 compare their normal signs.
SIGN_PAIR_DISTANCE = 0.75
#: A crease particle a tile placed in its neighbour's core is matched by one of the
#: neighbour's own within this many r0 (crease particles lie about r0 apart along a line).
CREASE_PAIR_DISTANCE = 1.0


def agree_signs(
    grid: TileGrid,
    border_in: Mapping[int, tuple[np.ndarray, np.ndarray]],
    border_out: Mapping[int, tuple[np.ndarray, np.ndarray]],
    r0: float,
) -> tuple[dict[int, float], int]:
    """A sign (+1/-1) per tile so that the normals agree across seams; and the number of tile
    pairs whose normals disagreed before.

    ``border_in[t]``: (positions, normals) of tile t's own particles near its core's faces;
    ``border_out[t]``: those its fit placed in the neighbours' cores. One tile's own particles
    are searched at a time, against its neighbours' (the mappings may load each entry from
    disk when asked: :class:`recon.tiling.tasks.BorderFiles`), so the memory held is a few
    tiles' borders, whatever the tile count."""
    tiles = sorted(border_in)
    votes: dict[tuple[int, int], float] = {}
    for b in tiles:
        pb, nb = border_in[b]
        if not len(pb):
            continue
        tree = cKDTree(pb)
        for a in grid.neighbours(b):
            if a not in border_out:
                continue
            p, n = border_out[a]
            sel = grid.cell_of(p) == b if len(p) else np.zeros(0, dtype=bool)
            if not sel.any():
                continue
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


def unmatched_crease_particles(
    grid: TileGrid,
    border_in: Mapping[int, tuple[np.ndarray, np.ndarray]],
    border_out: Mapping[int, tuple[np.ndarray, np.ndarray]],
    r0: float,
    depth: float,
) -> int:
    """Crease particles a tile's fit placed in a neighbour's core that the neighbour's own fit
    has no crease particle near: a crease one tile fitted and its neighbour did not, which
    rounds it. Each tile detects the creases of its core and halo on the points within the
    crease reach (:func:`recon.tiling.run.crease_reach`), so near a seam both label them as
    the untiled detection does; a safety net for where they still differ (data much sparser
    than the scan's median, whose neighbourhoods outgrow the reach; a corner on a seam).

    ``border_in[t]``, ``border_out[t]``: (positions, crease flags) of tile t's own particles
    near its core's faces and of those its fit placed in the neighbours' cores (the sides of
    :class:`recon.tiling.tasks.BorderFiles`, :meth:`~recon.tiling.tasks.BorderFiles.creases`);
    ``depth`` [r0]: how far into its core a tile's ``border_in`` particles reach. Only the
    crease particles are compared whose whole search ball lies within that depth."""
    reach = CREASE_PAIR_DISTANCE * r0
    known = depth * r0 - reach
    unmatched = 0
    for b in sorted(border_in):
        pb, cb = border_in[b]
        tree = cKDTree(pb[cb]) if np.any(cb) else None
        for a in grid.neighbours(b):
            if a not in border_out:
                continue
            p, c = border_out[a]
            if not np.any(c):
                continue
            p = p[c]
            p = p[(grid.cell_of(p) == b) & ~grid.in_halo_box(b, p, -known)]
            if not len(p):
                continue
            if tree is None:
                unmatched += len(p)
                continue
            d, _ = tree.query(p, distance_upper_bound=reach)
            unmatched += int(np.count_nonzero(~np.isfinite(d)))
    return unmatched


def _edges_among(faces: np.ndarray, ids: np.ndarray, n_vertices: int) -> set[tuple[int, int]]:
    """The mesh edges between vertices of ``ids`` as ``(lo, hi)`` pairs (what :func:`zip_loop`
    must not add twice), without a Python set of every edge of the mesh."""
    inside = np.zeros(n_vertices, dtype=bool)
    inside[ids] = True
    e = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    e = e[inside[e[:, 0]] & inside[e[:, 1]]]
    return {(int(a), int(b)) for a, b in e}


def face_keys(faces: np.ndarray) -> np.ndarray:
    """One int64 key per face, the same for the same three vertices in any order."""
    s = np.sort(np.asarray(faces, dtype=np.int64), axis=1)
    if len(s) == 0 or s.max() >= 2**21:
        return np.unique(s, axis=0, return_inverse=True)[1].reshape(-1).astype(np.int64)
    return (s[:, 0] << 42) | (s[:, 1] << 21) | s[:, 2]  # three local ids in 63 bits


def same_winding(faces: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Whether each face runs its three vertices in the cyclic order of ``reference``."""
    if len(faces) == 0:
        return np.zeros(0, dtype=bool)
    pos0 = np.argmax(reference == faces[:, [0]], axis=1)
    nxt = reference[np.arange(len(faces)), (pos0 + 1) % 3]
    return nxt == faces[:, 1]


def _split_keeping_frame(
    vertices: np.ndarray, normals: np.ndarray, faces: np.ndarray, is_frame: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Split bow-tie vertices (:func:`split_non_manifold_vertices`) without touching the frame:
    when a frame face would move to the copy, the copy and the original swap roles; when
    frame faces are on both sides, the vertex stays a bow-tie. The last array gives the
    vertex each appended copy copies."""
    from ..triangulate import split_non_manifold_vertices

    n0 = len(vertices)
    v2, n2, f2, k = split_non_manifold_vertices(vertices, normals, faces)
    sources = np.zeros(k, dtype=np.int64)
    if k == 0:
        return vertices, normals, faces, sources
    for new in range(n0, n0 + k):
        at = f2 == new
        rows = at.any(axis=1)
        src = int(faces[at][0])
        sources[new - n0] = src
        if not (rows & is_frame).any():
            continue
        kept = (f2 == src).any(axis=1)
        if (kept & is_frame).any():
            f2[at] = src  # frame on both sides: leave the bow-tie
        else:
            src_at = f2 == src
            f2[at] = src
            f2[src_at] = new
    return v2, n2, f2, sources


def _open_vertices(faces: np.ndarray, is_frame: np.ndarray, n: int) -> np.ndarray:
    """Vertices only frame faces use: their stars are cut off by the sub-mesh."""
    ed = np.zeros(n, dtype=bool)
    ed[faces[~is_frame].ravel()] = True
    fr = np.zeros(n, dtype=bool)
    fr[faces[is_frame].ravel()] = True
    return fr & ~ed


def _debris(faces: np.ndarray, is_frame: np.ndarray, opened: np.ndarray) -> np.ndarray:
    """The editable faces of components the sub-mesh holds whole (no frame face, no vertex
    whose star it cuts off: ``opened``) with fewer than ``MIN_COMPONENT_FACES`` faces: debris
    by the untiled fit's rule (:func:`remove_small_components`; its other bound, a fraction of
    the largest component, is looser in any tile of more than 5,000 faces). Splitting a
    bow-tie can cut one loose: a lone triangle, whose three edges are no hole to fill."""
    n, labels = face_components(faces, len(opened))
    framed = np.bincount(labels[is_frame], minlength=n) > 0
    framed[labels[opened[faces].any(axis=1)]] = True
    small = np.bincount(labels, minlength=n) < MIN_COMPONENT_FACES
    return (small & ~framed)[labels]


def _orient_with_frame(
    vertices: np.ndarray,
    normals: np.ndarray,
    faces: np.ndarray,
    is_frame: np.ndarray,
    frame_ref: dict,
) -> tuple[np.ndarray, np.ndarray, int]:
    """One winding per component, chosen to agree with the frame's (unchanged) faces where
    the component reaches the frame, else by :func:`orient_consistently`'s rule. Conflicting
    editable faces are dropped: as :func:`orient_consistently` does, the editable faces where
    the surface turns over (:func:`twisted_faces`) when dropping them makes the sub-mesh
    orientable and drops no more faces than the conflicts, else the conflicting ones (which
    lie where the search's fronts met, possibly far from the cause). Returns faces, is_frame
    and the frame faces left disagreeing."""
    faces = faces.copy()
    for _ in range(3):
        flip, conflict = orientation_flips(faces)
        drop = conflict & ~is_frame
        if drop.any():
            twist = twisted_faces(vertices, normals, faces) & ~is_frame
            if 0 < twist.sum() <= drop.sum():
                cut_flip, cut_conflict = orientation_flips(faces[~twist])
                if not (cut_conflict & ~is_frame[~twist]).any():
                    faces, is_frame = faces[~twist], is_frame[~twist]
                    flip, conflict = cut_flip, cut_conflict
                    drop = conflict & ~is_frame
        faces[flip] = faces[flip][:, [0, 2, 1]]
        if not drop.any():
            break
        faces, is_frame = faces[~drop], is_frame[~drop]
    n, labels = face_components(faces, len(vertices))
    keys = face_keys(faces)
    ref = np.array([frame_ref.get(int(k), (-1, -1, -1)) for k in keys[is_frame]]).reshape(-1, 3)
    same = same_winding(faces[is_frame], ref)
    vote = np.bincount(labels[is_frame], weights=np.where(same, 1.0, -1.0), minlength=n)
    has_frame = np.bincount(labels[is_frame], minlength=n) > 0
    turn = has_frame & (vote < 0)
    bad = turn[labels]
    faces[bad] = faces[bad][:, [0, 2, 1]]
    free = ~has_frame[labels]
    if free.any():
        sub = orient_consistently(vertices, normals, faces[free])
        if len(sub) == int(free.sum()):
            faces[free] = sub
        else:  # conflicts dropped inside a free component
            faces = np.vstack([faces[~free], sub])
            is_frame = np.concatenate([is_frame[~free], np.zeros(len(sub), dtype=bool)])
    ref = np.array([frame_ref.get(int(k), (-1, -1, -1)) for k in face_keys(faces)[is_frame]])
    left = int((~same_winding(faces[is_frame], ref.reshape(-1, 3))).sum())
    return faces, is_frame, left


def repair_cell(
    grid: TileGrid,
    vertices: np.ndarray,
    normals: np.ndarray,
    faces: np.ndarray,
    n_frame: int,
    r0: float,
    max_hole: float,
    cut: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict]:
    """Repair the seam zone of one dual cell: ``faces[n_frame:]`` may change, the first
    ``n_frame`` (the frame: neighbouring cells' and tile interiors' faces around them) may not.

    The rules of the untiled fit: faces on over-shared edges dropped (the frame's kept
    first), bow-ties split (and the debris a split cuts loose dropped: :func:`_debris`), seam
    cracks (loops along a seam, small or narrow) zipped, the winding made consistent (and
    agreeing with the frame), then the small holes orienting opened closed, and last the
    small handles cut (:func:`recon.small_handles.cut_small_handles`: a handle across the
    seam, which no tile sees whole) where a cut removes only editable faces none of whose
    vertices has its star cut off. Only loops through a vertex of an editable face are
    zipped, never one through a vertex whose star the sub-mesh cuts off: ``cut`` marks those
    (one flag per vertex); without it, the vertices only the frame uses.

    Returns the vertices (with copies appended), normals, the editable faces after the repair,
    and counts (``cut_orientation_conflicts``: frame faces next to the editable ones whose
    winding disagrees with the repaired zone's; ``small_handles_cut``).
    """

    stats = {
        "faces_dropped": 0,
        "seam_loops_zipped": 0,
        "cut_orientation_conflicts": 0,
        "small_handles_cut": 0,
    }
    faces = np.asarray(faces, dtype=np.int64)
    frame_faces = faces[:n_frame]
    frame_ref = {int(k): tuple(f) for k, f in zip(face_keys(frame_faces), frame_faces, strict=True)}
    frame_keys = np.fromiter(frame_ref.keys(), dtype=np.int64, count=len(frame_ref))
    n_edit = len(faces) - n_frame

    def tag(f: np.ndarray) -> np.ndarray:
        return np.isin(face_keys(f), frame_keys)

    def near(f, fr, n_v):
        """The editable faces and the frame faces that share a vertex with them: the only
        faces the repair and the orientation look at (the rest of the frame, unrepaired
        zones of cells not yet done among it, only shows the loops whole)."""
        ed = np.zeros(n_v, dtype=bool)
        ed[f[~fr].ravel()] = True
        return ~fr | ed[f].any(axis=1)

    # the vertex of the sub-mesh each vertex is or copies (bow-tie copies are appended)
    origin = np.arange(len(vertices))

    def repair(v, n, f):
        nonlocal origin
        fr = tag(f)
        keep = near(f, fr, len(v))
        far, f = f[~keep], f[keep]  # far: frame faces only
        f = remove_non_manifold_faces(f, len(v))  # keeps the lowest indices: the frame first
        fr = tag(f)
        f = np.vstack([f[fr], f[~fr]])
        fr = np.sort(fr)[::-1]
        v, n, f, sources = _split_keeping_frame(v, n, f, fr)
        origin = np.concatenate([origin, origin[sources]])
        f, fr = np.vstack([far, f]), np.concatenate([np.ones(len(far), bool), fr])
        junk = _debris(f, fr, opened_at(f, fr, len(v)))
        return v, n, f[~junk], fr[~junk]

    def opened_at(f, fr, n_v) -> np.ndarray:
        """The vertices whose star the sub-mesh cuts off."""
        if cut is None:
            return _open_vertices(f, fr, n_v)
        # bow-tie copies (appended) are where their sources were: cut as they are
        return np.asarray(cut, dtype=bool)[origin]

    def orient(v, n, f, fr):
        keep = near(f, fr, len(v))
        g, gr, left = _orient_with_frame(v, n, f[keep], fr[keep], frame_ref)
        return (
            np.vstack([f[~keep], g]),
            np.concatenate([np.ones(int((~keep).sum()), bool), gr]),
            left,
        )

    vertices, normals, faces, is_frame = repair(vertices, normals, faces)
    stats["faces_dropped"] = int(n_edit - (~is_frame).sum())

    def close(v, f, fr, rule) -> list[np.ndarray]:
        opened = opened_at(f, fr, len(v))
        edited = np.zeros(len(v), dtype=bool)
        edited[f[~fr].ravel()] = True
        chosen = []
        for loop in boundary_loops(f):
            if len(loop) < 3 or opened[loop].any() or not edited[loop].any():
                continue
            if rule(loop):
                chosen.append(loop)
        return chosen

    def seam_rule(loop):
        if np.mean(grid.seam_distance(vertices[loop]) <= SEAM_BAND * r0) < SEAM_LOOP_FRACTION:
            return False
        ring = vertices[loop] / r0
        perim = float(np.linalg.norm(ring - np.roll(ring, -1, axis=0), axis=1).sum())
        return perim <= np.pi * max_hole or (len(loop) >= 4 and loop_width(ring) <= CRACK_WIDTH)

    def small_rule(loop):
        ring = vertices[loop] / r0
        perim = float(np.linalg.norm(ring - np.roll(ring, -1, axis=0), axis=1).sum())
        slit = len(loop) >= 4 and loop_width(ring) <= CRACK_WIDTH
        return perim <= np.pi * max_hole or (slit and perim <= 3 * np.pi * max_hole)

    for rule, rounds in ((seam_rule, 3), (small_rule, 2)):
        for _ in range(rounds):
            if rule is small_rule:
                faces, is_frame, _ = orient(vertices, normals, faces, is_frame)
                vertices, normals, faces, is_frame = repair(vertices, normals, faces)
            chosen = close(vertices, faces, is_frame, rule)
            if not chosen:
                break
            edge_set = _edges_among(faces, np.concatenate(chosen), len(vertices))
            new = [zip_loop(vertices, loop[::-1], edge_set) for loop in chosen]
            stats["seam_loops_zipped"] += len(new)
            faces = np.vstack([faces, *new])
            is_frame = np.concatenate([is_frame, np.zeros(sum(len(x) for x in new), dtype=bool)])
            vertices, normals, faces, is_frame = repair(vertices, normals, faces)
    faces, is_frame, left = orient(vertices, normals, faces, is_frame)
    vertices, normals, faces, is_frame = repair(vertices, normals, faces)
    stats["cut_orientation_conflicts"] = left
    # a small handle across the seam (the untiled fit cuts it, a tile cannot see it whole):
    # cut where every face of the ball is the zone's and no vertex's star is cut off
    editable = ~is_frame & ~opened_at(faces, is_frame, len(vertices))[faces].any(axis=1)
    faces, stats["small_handles_cut"] = cut_small_handles(
        vertices / r0, faces, SMALL_HANDLE_REACH, np.pi * max_hole, editable
    )
    if stats["small_handles_cut"]:
        is_frame = tag(faces)
    return vertices, normals, faces[~is_frame], stats
