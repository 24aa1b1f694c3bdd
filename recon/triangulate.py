"""Triangulate the final particles into a manifold, consistently oriented mesh.

Two methods:

* ``ball_pivoting`` (default): Open3D's ball-pivoting algorithm [B99] over the particles with
  radii of about 0.7-2 r0. On the near-uniform particle sheet it is manifold and fast (DESIGN
  §4.7: 0 non-manifold edges on the bunny); the small holes it leaves are filled afterwards when
  their perimeter is below ``pi * max_hole``. Larger loops are real boundaries and stay.
* ``circumsphere``: the test of S&T92 §8: a triangle (i, j, k) of mutual neighbours is kept when
  the smallest sphere through its corners contains no other particle. Kept for comparison; it
  cannot be made manifold on co-circular quads (both diagonals pass).

Lengths are in units of r0 (the particles' rest spacing).

References
----------
[ST92] Szeliski & Tonnesen 1992, §8 "Triangulating the particles".
[B99]  F. Bernardini, J. Mittleman, H. Rushmeier, C. Silva, G. Taubin. "The ball-pivoting
       algorithm for surface reconstruction". IEEE TVCG 5(4), 1999.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import open3d as o3d
from scipy.spatial import cKDTree

from .config import TriangulationConfig
from .kernels.circumsphere import circumsphere_kernel
from .mesh import boundary_loops, edge_keys, face_area_vectors, face_components, vertex_fans
from .neighbors import build_neighbor_list

log = logging.getLogger(__name__)


@dataclass
class TriangulationResult:
    vertices: np.ndarray  # (V, 3) float64 [r0]
    faces: np.ndarray  # (F, 3) int64
    normals: np.ndarray  # (V, 3) float64 unit vertex normals
    stats: dict = field(default_factory=dict)


#: Loops whose interior holds data are triangulation gaps: closed up to this many times the
#: ``max_hole`` perimeter.
COVERED_HOLE_FACTOR = 3.0
#: Debris removal: components with fewer faces than this and than ``MIN_COMPONENT_FRACTION``
#: of the largest component are dropped.
MIN_COMPONENT_FACES = 50
MIN_COMPONENT_FRACTION = 0.01
#: Hole-filling passes: a fill can meet an edge that already exists elsewhere; the repair after
#: it can open a new small loop, which the second pass closes.
FILL_PASSES = 2
#: Triangles kept per particle by the circumsphere test (a hexagonal sheet has ~6).
CIRCUMSPHERE_CAPACITY = 64
#: Rounds of dropping faces on over-shared edges (each round settles the worst edges).
NON_MANIFOLD_EDGE_ROUNDS = 10
#: Rounds of dropping extra fans at bow-tie vertices (dropping a fan can leave a new bow-tie).
NON_MANIFOLD_VERTEX_ROUNDS = 5
#: A bow-tie vertex is split into one copy per fan; each extra copy moves this fraction of the
#: way to its fan's centroid, so the copies do not coincide (coincident vertices of different
#: faces read as a self-intersection to Open3D's ``is_watertight``).
SPLIT_SHIFT = 0.1


def triangulate_particles(
    positions: np.ndarray,
    normals: np.ndarray,
    cfg: TriangulationConfig,
    max_hole: float,
    is_covered: Callable[[np.ndarray], np.ndarray] | None = None,
    project: Callable[[np.ndarray], np.ndarray] | None = None,
) -> TriangulationResult:
    """Mesh the particles (normalised units, r0 = 1).

    Parameters
    ----------
    positions : (n, 3) float64 [r0]
    normals : (n, 3) float64, unit, consistently oriented
    cfg : TriangulationConfig
    max_hole : float [r0]
        Diameter of the largest hole to fill (loops with perimeter <= pi * max_hole).
    is_covered : callable, optional
        ``centres (m, 3) -> (m,) bool``: does data lie at these hole centres? Loops over data
        are closed up to ``COVERED_HOLE_FACTOR`` times the ``max_hole`` perimeter.
    project : callable, optional
        ``points (m, 3) -> (m, 3)``: moves vertices added by hole filling onto the data.
    """
    positions = np.ascontiguousarray(positions, dtype=np.float64)
    normals = np.ascontiguousarray(normals, dtype=np.float64)
    if len(positions) < 3:
        return TriangulationResult(
            positions, np.zeros((0, 3), dtype=np.int64), normals, {"method": cfg.method}
        )
    if cfg.method == "ball_pivoting":
        faces = ball_pivoting(positions, normals, cfg.radii)
    else:
        faces = circumsphere_triangles(positions, normals, radius=max(cfg.radii))
    stats: dict = {"method": cfg.method, "faces_raw": int(len(faces))}
    faces = orient_faces(positions, normals, faces)
    faces = make_manifold(faces, len(positions))
    stats["faces_manifold"] = int(len(faces))
    vertices, vnormals = positions, normals
    stats["holes_filled"] = 0
    for _ in range(FILL_PASSES if cfg.fill_holes else 0):
        # a fill can meet an edge that already exists elsewhere; repair, then fill what opened
        n_before = len(vertices)
        vertices, vnormals, faces, n_filled = fill_small_holes(
            vertices,
            vnormals,
            faces,
            np.pi * max_hole,
            is_covered,
            COVERED_HOLE_FACTOR * np.pi * max_hole,
        )
        stats["holes_filled"] += n_filled
        if project is not None and len(vertices) > n_before:
            vertices = vertices.copy()
            vertices[n_before:] = project(vertices[n_before:])
        faces = make_manifold(faces, len(vertices))
        if n_filled == 0:
            break
    faces, n_small = remove_small_components(
        faces, len(vertices), MIN_COMPONENT_FRACTION, MIN_COMPONENT_FACES
    )
    stats["small_components_removed"] = n_small
    vertices, vnormals, faces = drop_unreferenced(vertices, vnormals, faces)
    return TriangulationResult(vertices, faces, vnormals, stats)


def ball_pivoting(positions: np.ndarray, normals: np.ndarray, radii: list[float]) -> np.ndarray:
    """Faces (F, 3) from Open3D ball pivoting with the given radii [r0] [B99]."""
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(positions))
    pcd.normals = o3d.utility.Vector3dVector(normals)
    mesh = o3d.geometry.TriangleMesh.create_from_point_cloud_ball_pivoting(
        pcd, o3d.utility.DoubleVector(sorted(float(r) for r in radii))
    )
    faces = np.asarray(mesh.triangles, dtype=np.int64).reshape(-1, 3)
    # Open3D keeps vertex order; guard against a future version that reorders
    if len(mesh.vertices) != len(positions):  # pragma: no cover - defensive
        tree = cKDTree(positions)
        _, remap = tree.query(np.asarray(mesh.vertices))
        faces = remap[faces]
    return faces


def circumsphere_triangles(
    positions: np.ndarray, normals: np.ndarray, radius: float = 2.0
) -> np.ndarray:
    """Faces from the empty-circumsphere test over neighbours within ``radius`` [r0] (S&T92 §8).

    Only neighbours of the first corner are tested for emptiness, as in the paper (the sphere of
    an accepted triangle has a radius below ``radius``).
    """
    offsets, indices = build_neighbor_list(positions, radius)
    cap = CIRCUMSPHERE_CAPACITY
    out = np.zeros((len(positions), cap, 3), dtype=np.int64)
    count = np.zeros(len(positions), dtype=np.int64)
    circumsphere_kernel(positions, offsets, indices, out, count)
    mask = np.arange(cap)[None, :] < count[:, None]
    return out[mask]


def orient_faces(vertices: np.ndarray, normals: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Flip each face whose winding disagrees with the mean of its vertex normals."""
    if len(faces) == 0:
        return faces
    fn = face_area_vectors(vertices, faces)
    vn = normals[faces].sum(axis=1)
    flip = np.einsum("ij,ij->i", fn, vn) < 0
    faces = faces.copy()
    faces[flip] = faces[flip][:, [0, 2, 1]]
    return faces


def remove_non_manifold_faces(faces: np.ndarray, n_vertices: int) -> np.ndarray:
    """Drop degenerate and duplicate faces, then faces on edges shared by more than two faces.

    For an over-shared edge, the faces with the largest index are dropped first, so the
    result is deterministic.
    """
    if len(faces) == 0:
        return faces
    ok = (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])
    faces = faces[ok]
    key = np.sort(faces, axis=1)
    _, first = np.unique(key, axis=0, return_index=True)
    faces = faces[np.sort(first)]
    for _ in range(NON_MANIFOLD_EDGE_ROUNDS):
        keys = edge_keys(faces, n_vertices)
        uniq, inv, cnt = np.unique(keys, return_inverse=True, return_counts=True)
        over = cnt[inv] > 2
        if not over.any():
            break
        face_of = np.repeat(np.arange(len(faces)), 3)
        # for each over-shared edge keep the two lowest face indices
        bad_edges = np.flatnonzero(cnt > 2)
        drop = np.zeros(len(faces), dtype=bool)
        sel = np.isin(inv, bad_edges)
        e_inv, e_face = inv[sel], face_of[sel]
        order = np.lexsort((e_face, e_inv))
        e_inv, e_face = e_inv[order], e_face[order]
        rank = np.arange(len(e_inv)) - np.searchsorted(e_inv, e_inv)
        drop[e_face[rank >= 2]] = True
        faces = faces[~drop]
    return faces


def make_manifold(faces: np.ndarray, n_vertices: int) -> np.ndarray:
    """Drop faces until no edge has more than two faces and every vertex has one fan."""
    faces = remove_non_manifold_faces(faces, n_vertices)
    for _ in range(NON_MANIFOLD_VERTEX_ROUNDS):
        bad = non_manifold_vertex_faces(faces, n_vertices)
        if not bad.any():
            break
        faces = remove_non_manifold_faces(faces[~bad], n_vertices)
    return faces


def split_non_manifold_vertices(
    vertices: np.ndarray, normals: np.ndarray, faces: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Give every extra fan of a bow-tie vertex its own copy of the vertex.

    The largest fan (ties: the lowest fan label) keeps the vertex; every other fan gets a new
    vertex moved ``SPLIT_SHIFT`` of the way towards its fan's centroid, with the same normal.
    No face is dropped, so a closed fan stays closed and an open one leaves a simple boundary
    loop that hole filling can walk. Expects no non-manifold edges.

    Returns
    -------
    vertices, normals, faces, n_new_vertices
    """
    if len(faces) == 0:
        return vertices, normals, faces, 0
    fans = vertex_fans(faces).ravel()
    corner_v = faces.ravel()
    pair, corner_pair, size = np.unique(
        np.stack([corner_v, fans], axis=1), axis=0, return_inverse=True, return_counts=True
    )
    corner_pair = corner_pair.reshape(-1)
    # rank the fans of each vertex: largest first, then by label (deterministic)
    order = np.lexsort((pair[:, 1], -size, pair[:, 0]))
    first = np.searchsorted(pair[order, 0], pair[order, 0])
    rank = np.empty(len(pair), dtype=np.int64)
    rank[order] = np.arange(len(pair)) - first
    extra = np.flatnonzero(rank > 0)
    if len(extra) == 0:
        return vertices, normals, faces, 0
    new_id = np.full(len(pair), -1, dtype=np.int64)
    new_id[extra] = len(vertices) + np.arange(len(extra))
    # centroid of each extra fan: mean of its faces' centroids
    face_centre = vertices[faces].mean(axis=1)
    corner_face = np.repeat(np.arange(len(faces)), 3)
    sel = new_id[corner_pair] >= 0
    slot = np.searchsorted(extra, corner_pair[sel])
    acc = np.zeros((len(extra), 3))
    np.add.at(acc, slot, face_centre[corner_face[sel]])
    cnt = np.bincount(slot, minlength=len(extra))[:, None]
    base = vertices[pair[extra, 0]]
    new_v = base + SPLIT_SHIFT * (acc / cnt - base)
    faces = faces.copy().reshape(-1)
    faces[sel] = new_id[corner_pair[sel]]
    vertices = np.vstack([vertices, new_v])
    normals = np.vstack([normals, normals[pair[extra, 0]]])
    return vertices, normals, faces.reshape(-1, 3), len(extra)


def repair_non_manifold(
    vertices: np.ndarray, normals: np.ndarray, faces: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A manifold mesh: faces on over-shared edges dropped, then bow-tie vertices split.

    Every edge ends up in one or two faces and every vertex with one fan
    (:func:`remove_non_manifold_faces`, :func:`split_non_manifold_vertices`).
    """
    faces = remove_non_manifold_faces(faces, len(vertices))
    vertices, normals, faces, _ = split_non_manifold_vertices(vertices, normals, faces)
    return vertices, normals, faces


def _find(parent: dict[int, int], x: int) -> int:
    """Union-find root with path halving."""
    while parent[x] != x:
        parent[x] = parent[parent[x]]
        x = parent[x]
    return x


def non_manifold_vertex_faces(faces: np.ndarray, n_vertices: int) -> np.ndarray:
    """Faces to drop so that every vertex keeps a single fan (its largest one).

    Expects no non-manifold edges. A vertex with several fans of faces (a "bow-tie") is
    found by counting: around a manifold vertex the number of distinct incident edges exceeds
    the number of incident faces by at most one. Returns a boolean mask over faces.
    """
    drop = np.zeros(len(faces), dtype=bool)
    if len(faces) == 0:
        return drop
    n_faces_at = np.bincount(faces.reshape(-1), minlength=n_vertices)
    e = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    e = np.unique(e, axis=0)
    n_edges_at = np.bincount(e.reshape(-1), minlength=n_vertices)
    suspects = np.flatnonzero(n_edges_at - n_faces_at >= 2)
    if len(suspects) == 0:
        return drop
    vf_order = np.argsort(faces.reshape(-1), kind="stable")
    vf_face = vf_order // 3
    starts = np.searchsorted(faces.reshape(-1)[vf_order], np.arange(n_vertices + 1))
    for v in suspects:
        inc = vf_face[starts[v] : starts[v + 1]]
        inc = inc[~drop[inc]]
        parent = {int(f): int(f) for f in inc}
        by_other: dict[int, int] = {}
        for f in inc:
            for w in faces[f]:
                if w == v:
                    continue
                if int(w) in by_other:
                    a, b = _find(parent, int(f)), _find(parent, by_other[int(w)])
                    if a != b:
                        parent[max(a, b)] = min(a, b)
                else:
                    by_other[int(w)] = int(f)
        roots = np.array([_find(parent, int(f)) for f in inc])
        labels, counts = np.unique(roots, return_counts=True)
        if len(labels) < 2:
            continue
        keep = labels[np.argmax(counts)]
        drop[inc[roots != keep]] = True
    return drop


def fill_small_holes(
    vertices: np.ndarray,
    normals: np.ndarray,
    faces: np.ndarray,
    max_perimeter: float,
    is_covered: Callable[[np.ndarray], np.ndarray] | None = None,
    covered_max_perimeter: float | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Close boundary loops whose perimeter is at most ``max_perimeter``.

    With ``is_covered`` (centroids (m, 3) -> bool (m,)), loops up to ``covered_max_perimeter``
    whose interior holds data are closed too: they are gaps of the triangulation, not holes of
    the surface. Triangles and quads are closed directly (a quad by its shorter diagonal);
    longer loops by a fan around a new vertex at the loop's centroid. The new faces are wound
    opposite to the boundary half-edges, so orientation stays consistent.
    """
    loops = boundary_loops(faces)
    new_faces = []
    new_vertices = []
    new_normals = []
    n_v = len(vertices)
    filled = 0
    perims = np.array(
        [np.linalg.norm(vertices[lp] - vertices[np.roll(lp, -1)], axis=1).sum() for lp in loops]
    )
    fill = perims <= max_perimeter
    if is_covered is not None and covered_max_perimeter is not None and len(loops):
        cand = np.flatnonzero(~fill & (perims <= covered_max_perimeter))
        if len(cand):
            centers = np.array([vertices[loops[i]].mean(axis=0) for i in cand])
            fill[cand[is_covered(centers)]] = True
    for loop, do_fill in zip(loops, fill, strict=True):
        ring = vertices[loop]
        if not do_fill or len(loop) < 3:
            continue
        rev = loop[::-1]
        # A patch wound this way must face the side the loop's vertex normals face; if it faces
        # away, the loop is the outer rim of an open sheet (e.g. a small flat patch), and
        # "filling" it would cap the sheet's back side into a closed double layer.
        # Only loops whose normals agree (a flat-ish rim) are judged; on a rim whose normals
        # cancel (a cylinder's open end) the test says nothing and the loop is filled.
        centre = ring.mean(axis=0)
        patch_normal = np.cross(vertices[rev] - centre, vertices[np.roll(rev, -1)] - centre).sum(0)
        rim_normal = normals[loop].sum(axis=0)
        agree = float(patch_normal @ rim_normal)
        coherent = np.linalg.norm(rim_normal) > 0.5 * len(loop)
        if coherent and agree < -0.5 * np.linalg.norm(patch_normal) * np.linalg.norm(rim_normal):
            continue
        filled += 1
        if len(loop) == 3:
            new_faces.append(rev[None, :])
        elif len(loop) == 4:
            a, b, c, d = rev
            if np.linalg.norm(vertices[a] - vertices[c]) <= np.linalg.norm(
                vertices[b] - vertices[d]
            ):
                new_faces.append(np.array([[a, b, c], [a, c, d]]))
            else:
                new_faces.append(np.array([[b, c, d], [b, d, a]]))
        else:
            center = ring.mean(axis=0)
            nrm = normals[loop].sum(axis=0)
            nrm /= max(np.linalg.norm(nrm), 1e-12)
            idx = n_v + len(new_vertices)
            new_vertices.append(center)
            new_normals.append(nrm)
            k = len(rev)
            fan = np.stack([rev, np.roll(rev, -1), np.full(k, idx)], axis=1)
            new_faces.append(fan)
    if not new_faces:
        return vertices, normals, faces, 0
    if new_vertices:
        vertices = np.vstack([vertices, np.asarray(new_vertices)])
        normals = np.vstack([normals, np.asarray(new_normals)])
    faces = np.vstack([faces] + [f.astype(np.int64) for f in new_faces])
    return vertices, normals, faces, filled


def remove_small_components(
    faces: np.ndarray,
    n_vertices: int,
    min_fraction: float = MIN_COMPONENT_FRACTION,
    min_faces: int = MIN_COMPONENT_FACES,
) -> tuple[np.ndarray, int]:
    """Drop debris: components smaller than ``min_faces`` and ``min_fraction`` of the largest."""
    n, labels = face_components(faces, n_vertices)
    if n <= 1:
        return faces, 0
    sizes = np.bincount(labels)
    small = (sizes < min_faces) & (sizes < min_fraction * sizes.max())
    if not small.any():
        return faces, 0
    return faces[~small[labels]], int(small.sum())


def drop_unreferenced(
    vertices: np.ndarray, normals: np.ndarray, faces: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Remove vertices no face uses (isolated particles) and renumber faces."""
    used = np.zeros(len(vertices), dtype=bool)
    used[faces.reshape(-1)] = True
    remap = np.cumsum(used) - 1
    return vertices[used], normals[used], remap[faces].astype(np.int64)
