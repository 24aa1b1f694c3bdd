"""Triangulate the relaxed particles patch by patch and close the triangulation's gaps.

A *patch* is a piece of the input between its feature lines (:func:`recon.remesh.surface
.feature_lines`): without creases, each component of the input is one. Every patch is meshed
on its own with the fit's :func:`~recon.triangulate.triangulate_particles` and the patches
are joined on their shared line particles, so a triangle never spans a crease. Ball pivoting
sees points, not the patch's outline: triangles that reach out of their patch across its
outline (a reflex corner of a patch, a bay or slit of a scan's rim) are dropped
(:func:`reaching_out`). Loops of the triangulation that are not the input's own outline are
gaps and are zipped (:func:`close_gaps`).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy.spatial import cKDTree

from ..config import TriangulationConfig
from ..holes import loft_loops, zip_loop
from ..kernels.options import query_workers
from ..mesh import boundary_loops, face_components, vertex_components
from ..triangulate import (
    remove_small_components,
    repair_non_manifold,
    triangulate_particles,
)
from ..winding import orient_consistently
from .relax import Particles
from .surface import FeatureLines, MeshSurface, edge_faces

__all__ = [
    "COVER_DISTANCE",
    "DEBRIS_SHARE",
    "GAP_BOUNDARY_SHARE",
    "GAP_PASSES",
    "MAX_HOLE",
    "OFF_SURFACE",
    "RIM_MAJORITY",
    "close_gaps",
    "on_boundary",
    "particle_of",
    "reaching_out",
    "rim_labels",
    "stray_pieces",
    "triangulate_patches",
]

#: Holes of the triangulation up to this diameter [s] are closed without asking the input.
MAX_HOLE = 1.5
#: A point counts as over the input surface within this distance [s].
COVER_DISTANCE = 0.3
#: A patch's triangle whose centroid lies farther than this from the input [s], nearest to
#: another patch or a feature line, reaches out of its patch across the outline and is
#: dropped (:func:`reaching_out`).
OFF_SURFACE = 0.15
#: ... "on" a feature line: the line is at most this much farther (relative) than the input
#: (a fitted L block's concave corner: a bridge nearest to a face 1.5e-5 spacings off the
#: crease, 0.59 spacings away; a triangle over a sharp edge that is no crease is nearest to
#: the faces it joins, and to a line only near its end, if ever).
ON_LINE_TOLERANCE = 0.01
#: Passes of gap closing (a zip can open a new small loop that the next pass closes).
GAP_PASSES = 3
#: ... and a loop is a gap only when fewer than this share of its vertices are the input's
#: boundary particles: a loop that runs mostly along the input's rim is that rim, left open
#: where the triangulation cut inside it (zipped, a fitted face scan's rim became a lid).
GAP_BOUNDARY_SHARE = 0.5
#: A closed piece left apart from a mesh that should be one, with fewer faces than this share
#: of the largest piece's, is debris (:func:`close_gaps` with ``join``, :func:`stray_pieces`).
DEBRIS_SHARE = 0.25
#: A loop of the triangulation holding more than this share of a rim's particles is that rim
#: (:func:`close_gaps`, rule "covered").
RIM_MAJORITY = 0.5


def on_boundary(lines: FeatureLines, feats: Particles) -> np.ndarray:
    """(n,) bool: the particles on a boundary line of the input (corners included)."""
    out = np.zeros(feats.n, dtype=bool)
    sliding = feats.kind == 1
    out[sliding] = lines.chain_is_boundary[feats.chain[sliding]]
    corners = feats.kind == 2
    if corners.any() and lines.chain_is_boundary.any():
        bverts = np.unique(
            np.concatenate(
                [c for c, b in zip(lines.chains, lines.chain_is_boundary, strict=True) if b]
            )
        )
        out[corners] = np.isin(lines.corners, bverts)
    return out


def triangulate_patches(
    surface: MeshSurface,
    lines: FeatureLines,
    particles: Particles,
    adaptive: bool,
    rim: np.ndarray,
):
    """Triangulate each patch (the input split along its feature lines) on its own with the
    fit's :func:`~recon.triangulate.triangulate_particles`, then join the patches on their
    shared line particles: a triangle never spans a crease, so every crease stays an edge
    chain. Line particles take the normal of the patch being meshed."""

    def is_covered(
        points: np.ndarray, scale: np.ndarray | None = None, across: bool = False
    ) -> np.ndarray:
        # the distance to the input surface: a seam's points (``across``) are judged alike
        limit = COVER_DISTANCE if scale is None else COVER_DISTANCE * np.asarray(scale)
        return surface.distance(points) <= limit

    # the fit's hole filling guesses which loops are gaps; here close_gaps knows (a loop not
    # made of the input's own boundary particles), so it runs instead
    cfg = TriangulationConfig(fill_holes=False)
    n_patches = int(lines.face_patch.max()) + 1
    if n_patches == 1:
        patch_of = np.zeros(particles.n, dtype=np.int64)
    else:
        _, face, _ = surface.closest(particles.position)
        patch_of = lines.face_patch[face]
    member = [[] for _ in range(n_patches)]
    for p, idx in zip(*_group(patch_of, particles.kind == 0), strict=True):
        member[p].append(idx)
    sliding = np.flatnonzero(particles.kind == 1)
    for c, pats in enumerate(lines.chain_patches):
        on = sliding[particles.chain[sliding] == c]
        for p in pats:
            member[p].append(on)
    corners = np.flatnonzero(particles.kind == 2)
    for i, pats in enumerate(lines.corner_patches):
        for p in pats:
            member[p].append(corners[i : i + 1])
    # the outline of a patch: its line particles, or with one patch the input's own rims
    # (``rim``, the ones a close_gaps after the joining treats alike)
    outline = (particles.kind != 0).astype(np.int64) - 1 if n_patches > 1 else rim
    vertices = [particles.position]
    normals = [particles.normal]
    faces = []
    n_total = particles.n
    stats: dict[str, int | str] = {"patches": n_patches}
    n_out = 0
    for p in range(n_patches):
        idx = np.unique(np.concatenate(member[p])) if member[p] else np.zeros(0, np.int64)
        if len(idx) < 3:
            continue
        nrm = particles.normal[idx].copy()
        feat = particles.kind[idx] != 0
        if feat.any() and n_patches > 1:
            pf = np.flatnonzero(lines.face_patch == p)
            centroid = surface.vertices[surface.faces[pf]].mean(axis=1)
            _, near = cKDTree(centroid).query(particles.position[idx[feat]])
            nrm[feat] = surface.face_normal[pf[near]]
        tri = triangulate_particles(
            particles.position[idx],
            nrm,
            cfg,
            MAX_HOLE,
            is_covered,
            local_spacing=particles.rest[idx] if adaptive else None,
            resign=False,  # the signs come from the input's oriented faces
            join_sheets=False,  # the input's components are its own
        )
        for k, v in tri.stats.items():
            if isinstance(v, int):
                stats[k] = int(stats.get(k, 0)) + v
        tv, tn, tf = tri.vertices, tri.normals, tri.faces
        tree = cKDTree(particles.position[idx])
        # ball pivoting sees points, not the patch's outline: it bridges its reflex corners,
        # and the bays and slits of an open scan's rim
        out = reaching_out(surface, lines, tv[tf].mean(axis=1), p)
        if out.any() or n_patches > 1:
            # the gaps first, while the bridges still part them from the outline (dropped
            # first, a gap beside a bay became part of the rim's loop)
            tv, tn, tf, n_closed = close_gaps(
                tv,
                tn,
                tf,
                _outline(tree, idx, tv, outline),
                "share" if n_patches > 1 else "covered",
                lambda c, p=p: ~reaching_out(surface, lines, c, p),
                join=True,
            )
            stats["patch_gaps_closed"] = int(stats.get("patch_gaps_closed", 0)) + n_closed
            out = reaching_out(surface, lines, tv[tf].mean(axis=1), p)
        if out.any():
            n_out += int(out.sum())
            # the drop can leave the rest pinched at a vertex (split, as the triangulation's
            # own) and a triangle or two cut off from the patch (debris, as its own)
            tv, tn, tf = repair_non_manifold(tv, tn, tf[~out])
            tf, _ = remove_small_components(tf, len(tv))
            if n_patches > 1:
                tv, tn, tf, n_closed = close_gaps(
                    tv, tn, tf, _outline(tree, idx, tv, outline), join=True
                )
                stats["patch_gaps_closed"] = int(stats.get("patch_gaps_closed", 0)) + n_closed
        d, j = tree.query(tv)
        same = d <= 1e-12
        glob = np.where(same, idx[j], -1)
        extra = np.flatnonzero(~same)
        glob[extra] = n_total + np.arange(len(extra))
        n_total += len(extra)
        vertices.append(tv[extra])
        normals.append(tn[extra])
        faces.append(glob[tf])
    v = np.vstack(vertices)
    n = np.vstack(normals)
    f = np.vstack(faces) if faces else np.zeros((0, 3), dtype=np.int64)
    stats["faces_reaching_out"] = n_out
    if (n_patches > 1 or n_out) and len(f):
        v, n, f = repair_non_manifold(v, n, f)
        f = orient_consistently(v, n, f)
    used = np.zeros(len(v), dtype=bool)
    used[f.ravel()] = True
    remap = np.cumsum(used) - 1
    return v[used], n[used], remap[f].astype(np.int64), stats


def reaching_out(
    surface: MeshSurface, lines: FeatureLines, centroid: np.ndarray, patch: int = 0
) -> np.ndarray:
    """Which triangles of ``patch`` (by their centroids) reach out of it across its outline.

    A triangle over a reflex corner of a patch, or across a bay or slit of a scan's rim, covers
    no surface of its patch: its centroid lies more than :data:`OFF_SURFACE` from the input,
    and what lies nearest is another patch, a crease line, or a boundary line that far out
    along the surface (the offset's part in the plane of the face there: a triangle across a
    narrow curved strip between two loops of the rim lies off the surface along its normal,
    and is kept).

    A triangle over a sharp edge that is no crease (no crease angle given) lies off the surface
    too, inside the solid, but nearest to the faces of its own patch it joins: kept (dropped,
    the sharp edges of two disjoint tetrahedra tore their patches apart, and gap closing
    capped the pieces into four closed components).
    """
    out = np.zeros(len(centroid), dtype=bool)
    if lines.empty or len(centroid) == 0:
        return out
    foot, face, normal = surface.closest(centroid)
    offset = centroid - foot
    d = np.linalg.norm(offset, axis=1)
    far = np.flatnonzero(d > OFF_SURFACE)
    if len(far) == 0:
        return out
    elsewhere = lines.face_patch[face[far]] != patch
    reach = d[far] * (1.0 + ON_LINE_TOLERANCE)
    on_crease = lines.distance(centroid[far], boundary=False) <= reach
    on_rim = lines.distance(centroid[far], boundary=True) <= reach
    off = offset[far]
    along = off - np.einsum("ij,ij->i", off, normal[far])[:, None] * normal[far]
    out[far] = elsewhere | on_crease | (on_rim & (np.linalg.norm(along, axis=1) > OFF_SURFACE))
    return out


def _outline(tree: cKDTree, idx: np.ndarray, vertices: np.ndarray, outline: np.ndarray):
    """``outline`` (per particle) at the vertices of a patch's mesh (-1 at a repair's copy)."""
    d, j = tree.query(vertices)
    return np.where(d <= 1e-12, outline[idx[j]], -1)


def stray_pieces(surface: MeshSurface, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(F,) bool: the faces of the stray pieces of a remeshed surface, to drop.

    Every piece (connected component) of the mesh lies over one component of the input (the
    one under most of its faces); where several lie over the same one, a closed piece with
    fewer than :data:`DEBRIS_SHARE` of the faces of the largest is debris: patches smaller
    than a spacing (a fitted L block's folds at its concave corner, at a crease angle of 10
    degrees) were meshed into a closed tetrahedron of four faces beside it. Open pieces stay
    (surface the rest does not cover).
    """
    n_pieces, _ = face_components(faces, len(vertices))
    if n_pieces <= 1:
        return np.zeros(len(faces), dtype=bool)
    _, comp_in = face_components(surface.faces, len(surface.vertices))
    _, face_in, _ = surface.closest(vertices[faces].mean(axis=1))
    return _small_closed_pieces(faces, len(vertices), comp_in[face_in])


def _group(labels: np.ndarray, mask: np.ndarray) -> tuple[list[int], list[np.ndarray]]:
    """(label, indices) of the masked entries, grouped by label."""
    idx = np.flatnonzero(mask)
    order = np.argsort(labels[idx], kind="stable")
    idx = idx[order]
    lab = labels[idx]
    cuts = np.flatnonzero(np.diff(lab)) + 1
    groups = np.split(idx, cuts)
    return [int(g[0]) for g in np.split(lab, cuts) if len(g)], [g for g in groups if len(g)]


def particle_of(vertices: np.ndarray, particles: Particles) -> np.ndarray:
    """The particle at each vertex, -1 for a vertex that is none (a copy made by a repair)."""
    d, i = cKDTree(particles.position).query(vertices, workers=query_workers())
    return np.where(d <= 1e-9, i, -1)


def rim_labels(surface: MeshSurface, lines: FeatureLines, particles: Particles) -> np.ndarray:
    """(n,) int64: for each particle on the input's boundary, which boundary loop of the input
    (a connected component of its boundary edges) it lies on; -1 for the others."""
    from scipy import sparse
    from scipy.sparse import csgraph

    nv = len(surface.vertices)
    edges, counts, _, _ = edge_faces(surface.faces, nv)
    b = edges[counts == 1]
    label = np.full(nv, -1, dtype=np.int64)
    out = np.full(particles.n, -1, dtype=np.int64)
    if len(b) == 0:
        return out
    graph = sparse.coo_matrix((np.ones(len(b)), (b[:, 0], b[:, 1])), shape=(nv, nv))
    _, comp = csgraph.connected_components(graph, directed=False)
    on = np.unique(b)
    label[on] = comp[on]
    sliding = np.flatnonzero(particles.kind == 1)
    first = np.array([c[0] for c in lines.chains], dtype=np.int64)
    if len(sliding):
        out[sliding] = label[first[particles.chain[sliding]]]
    corners = np.flatnonzero(particles.kind == 2)  # in the order of lines.corners
    out[corners] = label[lines.corners]
    return out


def _kept_open(loops: list[np.ndarray], rim: np.ndarray, rule: str, piece: np.ndarray) -> set[int]:
    """The loops (indices) that are outlines of the input, not gaps (:func:`close_gaps`);
    ``piece``: the component of each vertex."""
    on = [rim[lp][rim[lp] >= 0] for lp in loops]
    if rule == "share":
        return {i for i, lp in enumerate(loops) if len(on[i]) >= GAP_BOUNDARY_SHARE * len(lp)}
    # the only loop of its piece, on a rim, is the outline of that piece: zipped, the piece
    # (a strip of a scan beyond a neck narrower than a spacing) became a closed pancake
    owner = np.array([piece[lp[0]] for lp in loops], dtype=np.int64)
    alone = np.bincount(owner)[owner] == 1
    kept = {i for i in range(len(loops)) if alone[i] and len(on[i])}
    if rule == "covered":
        # a loop holding most of a rim's particles is that rim
        total = np.bincount(rim[rim >= 0]) if (rim >= 0).any() else np.zeros(0, np.int64)
        for i, o in enumerate(on):
            ids, counts = np.unique(o, return_counts=True)
            if np.any(counts > RIM_MAJORITY * total[ids]):
                kept.add(i)
        return kept
    best: dict[int, tuple[int, int, int]] = {}  # rim -> (particles on it, length, loop)
    for i, lp in enumerate(loops):
        ids, counts = np.unique(on[i], return_counts=True)
        for r, c in zip(ids.tolist(), counts.tolist(), strict=True):
            if (c, len(lp)) > best.get(r, (0, 0, -1))[:2]:
                best[r] = (c, len(lp), i)
    return kept | {i for _, _, i in best.values()}


def _join_pieces(vertices: np.ndarray, faces: np.ndarray, loops: list[np.ndarray]) -> list:
    """Strips joining the pieces of a mesh that should be one (:func:`close_gaps`'s ``join``):
    the two gap ``loops`` of different pieces nearest each other (their vertices' median
    distance to the other loop, the larger of the two) are lofted into a strip
    (:func:`recon.holes.loft_loops`), the nearest pair first, once per pair of pieces."""
    _, piece = vertex_components(faces, len(vertices))
    owner = np.array([piece[lp[0]] for lp in loops], dtype=np.int64)
    if len(np.unique(owner)) < 2:
        return []
    trees = [cKDTree(vertices[lp]) for lp in loops]
    pairs = []
    for i in range(len(loops)):
        for j in range(i + 1, len(loops)):
            if owner[i] != owner[j]:
                gap = max(
                    np.median(trees[j].query(vertices[loops[i]])[0]),
                    np.median(trees[i].query(vertices[loops[j]])[0]),
                )
                pairs.append((gap, i, j))
    strips, used, joined = [], set(), {int(p): {int(p)} for p in np.unique(piece[piece >= 0])}
    for _, i, j in sorted(pairs):
        a, b = int(owner[i]), int(owner[j])
        if i in used or j in used or b in joined[a]:
            continue
        strips.append(loft_loops(vertices, loops[i], loops[j]))
        used |= {i, j}
        merged = joined[a] | joined[b]
        for p in merged:
            joined[p] = merged
    return strips


def close_gaps(
    vertices: np.ndarray,
    normals: np.ndarray,
    faces: np.ndarray,
    rim: np.ndarray,
    rule: str = "share",
    over_surface: Callable[[np.ndarray], np.ndarray] | None = None,
    join: bool = False,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Zip every boundary loop of the triangulation that is not an outline of the input: the
    input has surface there, so the loop is a gap of the triangulation.

    ``rim`` (V,) int64: per vertex, -1 off the outline, else the outline it lies on (a
    boundary loop of the input, or any line of a patch). Which loops are outlines, by
    ``rule``:

    - ``"share"``: a loop of which at least :data:`GAP_BOUNDARY_SHARE` of the vertices lie on
      the outline;
    - ``"rim"``: for each outline, the one loop holding most of its particles; another loop
      along it is a piece the triangulation cut off it (where the rim pinches to one vertex,
      split in two by the repair) or a gap beside it;
    - ``"covered"``: a loop holding more than :data:`RIM_MAJORITY` of an outline's particles,
      and a loop on the outline whose zip would not lie over the input: ``over_surface``
      (points -> bool) holds for fewer than half of its triangles' centroids. Ball pivoting
      can bridge a small hole of a scan into pieces, none of them most of it, and a gap
      beside them holds as many of its particles.

    A loop of no outline particle is always a gap; by the rules "rim" and "covered" a loop on
    a rim that is the only loop of its piece is always that piece's outline.

    With ``join`` the mesh should be one piece (a patch, or one connected input): where the
    triangulation fell apart (ball pivoting across the sharp edges of a coarsely sampled
    tetrahedron), the gaps of different pieces are joined by strips (:func:`_join_pieces`)
    before the rest are zipped; zipped one by one, each piece became a closed surface of its
    own. Closed pieces left apart with fewer than :data:`DEBRIS_SHARE` of the largest one's
    faces are dropped then (unreferenced vertices stay).

    Returns vertices, normals, faces (manifold, consistently oriented) and the loops closed.
    """
    n_closed = 0
    for _ in range(GAP_PASSES):
        loops = [lp for lp in boundary_loops(faces) if len(lp) >= 3]
        kept = _kept_open(loops, rim, rule, vertex_components(faces, len(vertices))[1])
        if len(kept) == len(loops):
            break
        # the diagonals a zip must avoid: existing edges between vertices of the loops
        on_loop = np.zeros(len(vertices), dtype=bool)
        on_loop[np.concatenate(loops)] = True
        he = faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
        he = np.sort(he[on_loop[he].all(axis=1)], axis=1)
        edges = {(int(a), int(b)) for a, b in he}
        gaps = [lp for i, lp in enumerate(loops) if i not in kept]
        new = _join_pieces(vertices, faces, gaps) if join else []
        if new:  # the pieces joined first, zipped in the next pass
            loops, kept = [], set()
        for i, lp in enumerate(loops):
            if i in kept:
                continue
            if rule == "covered" and over_surface is not None and (rim[lp] >= 0).any():
                trial = set(edges)
                fill = zip_loop(vertices, lp[::-1], trial)
                if over_surface(vertices[fill].mean(axis=1)).mean() < 0.5:
                    continue
                edges = trial
            else:
                fill = zip_loop(vertices, lp[::-1], edges)
            new.append(fill)
        if not new:
            break
        faces = np.vstack([faces, *new])
        n_closed += len(new)
        n_before = len(vertices)
        vertices, normals, faces = repair_non_manifold(vertices, normals, faces)
        rim = np.concatenate([rim, np.full(len(vertices) - n_before, -1, dtype=np.int64)])
        faces = orient_consistently(vertices, normals, faces)
    if join:
        # a closed piece that could not be joined and is small beside the largest piece is
        # debris (two faces of a sliver beside a closed tetrahedron, zipped into a closed piece
        # of its own); an open one is kept: a strip of a scan beyond a neck narrower than a
        # spacing, cut off where the triangles across the neck reached out, is surface
        faces = faces[~_small_closed_pieces(faces, len(vertices), np.zeros(len(faces), np.int64))]
    return vertices, normals, faces, n_closed


def _small_closed_pieces(faces: np.ndarray, n_vertices: int, group: np.ndarray) -> np.ndarray:
    """(F,) bool: the faces of the closed pieces (no boundary edge) with fewer than
    :data:`DEBRIS_SHARE` of the faces of the largest piece of their ``group`` (per face; a
    piece takes the group of most of its faces)."""
    n_pieces, piece = face_components(faces, n_vertices)
    if n_pieces <= 1:
        return np.zeros(len(faces), dtype=bool)
    edges, counts, f0, _ = edge_faces(faces, n_vertices)
    open_piece = np.zeros(n_pieces, dtype=bool)
    open_piece[piece[f0[counts == 1]]] = True
    n_groups = int(group.max()) + 1
    votes = np.zeros((n_pieces, n_groups), dtype=np.int64)
    np.add.at(votes, (piece, group), 1)
    over = votes.argmax(axis=1)
    size = np.bincount(piece, minlength=n_pieces)
    largest = np.zeros(n_groups, dtype=np.int64)
    np.maximum.at(largest, over, size)
    small = ~open_piece & (size < DEBRIS_SHARE * largest[over])
    return small[piece]
