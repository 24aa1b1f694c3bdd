"""Check and repair the input of a remesh.

What can be repaired is repaired and listed (:attr:`CheckedMesh.repairs`): exactly repeated
vertices are merged, faces with a repeated corner or of zero area and duplicate faces are
dropped, unreferenced vertices removed, bow-tie (non-manifold) vertices split into one copy per
fan, and the winding made consistent per component. What cannot is refused with an
:class:`~recon.errors.InputError` naming the defect: no faces, edges shared by more than two
faces, a non-orientable surface, and self-intersections (faces sharing no vertex that cross:
:func:`recon.intersections.self_intersections`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError
from ..kernels.tri_intersect import pairs_intersect
from ..mesh import face_area_vectors, orientation_flips, vertex_fans
from ..topology import power_of_two_near
from .surface import edge_faces

__all__ = ["CheckedMesh", "check_mesh", "crossing_pairs"]

#: A face is degenerate when its doubled area is below this times its longest edge squared.
DEGENERATE_AREA = 1e-12
#: The edge segments cast by :func:`crossing_pairs` stop this fraction of their length short
#: of both ends (the faces at the ends touch them there).
RAY_TRIM = 1e-4


@dataclass
class CheckedMesh:
    """A manifold, consistently oriented triangle mesh and what was repaired to get it."""

    vertices: np.ndarray
    faces: np.ndarray
    repairs: list[str] = field(default_factory=list)


def _merge_duplicate_vertices(
    vertices: np.ndarray, faces: np.ndarray
) -> tuple[np.ndarray, np.ndarray, int]:
    uniq, inverse = np.unique(vertices, axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    if len(uniq) == len(vertices):
        return vertices, faces, 0
    # keep the first occurrence's order so the output does not depend on sorting
    first = np.full(len(uniq), len(vertices), dtype=np.int64)
    np.minimum.at(first, inverse, np.arange(len(vertices)))
    rank = np.argsort(np.argsort(first))
    new_v = vertices[np.sort(first)]
    return new_v, rank[inverse][faces], len(vertices) - len(uniq)


def check_mesh(
    vertices: np.ndarray, faces: np.ndarray, name: str, *, intersections: bool = True
) -> CheckedMesh:
    """Repair what can be repaired, refuse the rest (module docstring).

    Parameters
    ----------
    vertices : (V, 3) float64
    faces : (F, 3) int64
    name : str
        The file name used in messages.
    intersections : bool
        Also refuse self-intersecting meshes.
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    if len(v) == 0:
        raise InputError(f"{name}: the file holds no vertices (empty mesh)")
    if len(f) == 0:
        raise InputError(
            f"{name}: the file has {len(v):,} vertices but no faces (a point cloud); "
            "remesh needs a triangle mesh (use `oprecon fit` for points)"
        )
    repairs: list[str] = []
    v, f, merged = _merge_duplicate_vertices(v, f)
    if merged:
        repairs.append(f"merged {merged:,} duplicate vertices")
    repeated = (f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 2] == f[:, 0])
    cross = face_area_vectors(v, f)
    longest = np.max(np.linalg.norm(v[f] - v[np.roll(f, -1, axis=1)], axis=2), axis=1)
    flat = np.linalg.norm(cross, axis=1) <= DEGENERATE_AREA * longest**2
    drop = repeated | flat
    if drop.any():
        repairs.append(f"dropped {int(drop.sum()):,} degenerate faces (zero area)")
        f = f[~drop]
    key = np.sort(f, axis=1)
    # first face of each distinct vertex triple (a stable lexsort: np.unique(axis=0) was a
    # quarter of this check's time)
    order = np.lexsort((key[:, 2], key[:, 1], key[:, 0]))
    ks = key[order]
    new = np.ones(len(ks), dtype=bool)
    new[1:] = np.any(ks[1:] != ks[:-1], axis=1)
    first = order[new]
    if len(first) < len(f):
        repairs.append(f"dropped {len(f) - len(first):,} duplicate faces")
        f = f[np.sort(first)]
    if len(f) == 0:
        raise InputError(f"{name}: every face is degenerate (zero area); nothing to remesh")
    edges, counts, f0, f1 = edge_faces(f, len(v))
    over = int((counts > 2).sum())
    if over:
        raise InputError(
            f"{name}: non-manifold mesh: {over:,} edge(s) shared by more than two faces; "
            "remesh needs a manifold surface (repair it first, e.g. split the sheets)"
        )
    # before the bow-ties are split: their copies coincide, and faces meeting at a split vertex
    # would then touch without sharing it (which counts as crossing)
    if intersections:
        bad = crossing_pairs(v, f, edges, f0, f1)
        if len(bad):
            p = v[f[bad[0, 0]]].mean(axis=0)
            raise InputError(
                f"{name}: self-intersecting mesh: {len(bad):,} pair(s) of faces cross "
                f"(first near {p[0]:.6g}, {p[1]:.6g}, {p[2]:.6g}); repair it first"
            )
    # bow-tie vertices: one copy per extra fan
    fan = vertex_fans(f)
    keys = np.unique(f.ravel() * np.int64(3 * len(f)) + fan.ravel())
    per_vertex = np.bincount(keys // (3 * len(f)), minlength=len(v))
    if np.any(per_vertex > 1):
        n_bad = int((per_vertex > 1).sum())
        v, f = _split_fans(v, f, fan)
        repairs.append(f"split {n_bad:,} non-manifold (bow-tie) vertices, one copy per fan")
    used = np.zeros(len(v), dtype=bool)
    used[f.ravel()] = True
    if not used.all():
        remap = np.cumsum(used) - 1
        repairs.append(f"removed {int((~used).sum()):,} unreferenced vertices")
        v, f = v[used], remap[f]
    flip, conflict = orientation_flips(f)
    if conflict.any():
        raise InputError(
            f"{name}: the surface is not orientable (a Moebius-like twist across "
            f"{int(conflict.sum()):,} face(s)); remesh needs an orientable surface"
        )
    if flip.any():
        f = f.copy()
        f[flip] = f[flip][:, [0, 2, 1]]
        repairs.append(f"re-wound {int(flip.sum()):,} faces to a consistent orientation")
    return CheckedMesh(np.ascontiguousarray(v), np.ascontiguousarray(f), repairs)


def _split_fans(
    vertices: np.ndarray, faces: np.ndarray, fan: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Give every (vertex, fan) pair beyond the first its own copy of the vertex."""
    nf = len(faces)
    key = faces.ravel() * np.int64(3 * nf) + fan.ravel()
    uniq, inverse = np.unique(key, return_inverse=True)
    vert = uniq // (3 * nf)
    first = np.ones(len(uniq), dtype=bool)
    first[1:] = vert[1:] != vert[:-1]
    new_index = np.where(first, vert, len(vertices) + np.cumsum(~first) - 1)
    extra = vert[~first]
    return np.vstack([vertices, vertices[extra]]), new_index[inverse.reshape(-1)].reshape(-1, 3)


def crossing_pairs(
    vertices: np.ndarray,
    faces: np.ndarray,
    edges: np.ndarray,
    face0: np.ndarray,
    face1: np.ndarray,
) -> np.ndarray:
    """Pairs of faces ``(m, 2)`` sharing no vertex that cross, as
    :func:`recon.intersections.self_intersections` finds them, but from the edges.

    Where two triangles cross (not in one plane), each end of the segment they share lies on
    an edge of one of them, so some edge of one pierces the other. Every edge ``(a, b)`` (with
    its faces ``face0``, ``face1``, -1 for none: :func:`~recon.remesh.surface.edge_faces`) is
    cast as a segment against the mesh (Embree, float32, the mesh centred at the power of two
    nearest its size; trimmed by :data:`RAY_TRIM` at both
    ends); the few edges that hit a face are listed with all their hits, and each hit face
    that has neither a nor b is tested against the edge's faces exactly, in float64
    (:func:`recon.kernels.tri_intersect.pairs_intersect`). Faces that overlap in one plane are
    not found (no edge pierces the other).
    """
    import open3d as o3d

    v = np.ascontiguousarray(vertices, dtype=np.float64)
    f = np.ascontiguousarray(faces, dtype=np.int64)
    if len(f) < 2 or len(edges) == 0:
        return np.zeros((0, 2), dtype=np.int64)
    lo, hi = v.min(axis=0), v.max(axis=0)
    centre = 0.5 * (lo + hi)
    # centred, at the power of two nearest the mesh's size (as every Embree query here: a mesh
    # 1e-16 or 1e16 across had none of its crossings found)
    unit = power_of_two_near(float(np.max(hi - lo)))
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(
        o3d.core.Tensor(np.ascontiguousarray((v - centre) / unit, dtype=np.float32)),
        o3d.core.Tensor(np.ascontiguousarray(f, dtype=np.uint32)),
    )
    a, b = edges[:, 0], edges[:, 1]
    d = (v[b] - v[a]) / unit
    # direction (1 - 2 trim) d: the segment is t in [0, 1] (Embree's t is in units of |dir|)
    rays = np.hstack([(v[a] - centre) / unit + RAY_TRIM * d, (1.0 - 2.0 * RAY_TRIM) * d])
    rays = o3d.core.Tensor(np.ascontiguousarray(rays, dtype=np.float32))
    # an edge lies in its own faces' planes, so float32 may report those: listed, then dropped
    hit = np.flatnonzero(scene.test_occlusions(rays, tnear=0.0, tfar=1.0).numpy())
    if len(hit) == 0:
        return np.zeros((0, 2), dtype=np.int64)
    ans = scene.list_intersections(rays[o3d.core.Tensor(hit.astype(np.int64))])
    t = ans["t_hit"].numpy()
    edge = hit[ans["ray_ids"].numpy().astype(np.int64)]
    other = ans["primitive_ids"].numpy().astype(np.int64)
    keep = (t >= -RAY_TRIM) & (t <= 1.0 + RAY_TRIM)
    edge, other = edge[keep], other[keep]
    fo = f[other]
    apart = ~((fo == a[edge, None]) | (fo == b[edge, None])).any(axis=1)
    edge, other = edge[apart], other[apart]
    own = np.concatenate([face0[edge], face1[edge]])
    other = np.concatenate([other, other])
    ok = own >= 0
    own, other = own[ok], other[ok]
    n = np.int64(len(f))
    key = np.unique(np.minimum(own, other) * n + np.maximum(own, other))
    pairs = np.stack([key // n, key % n], axis=1)
    crossing = np.zeros(len(pairs), dtype=np.bool_)
    if len(pairs):
        pairs_intersect(v, f, pairs, crossing)
    return pairs[crossing]
