"""Creases in the mesh (issue 12, step 3): edges along crease lines and split normals.

* :func:`flip_straddling_edges`: ball pivoting sometimes joins a particle of one face to one of
  the other face across a crease, beside two crease particles (the quad ``u, a, w, b`` with ``a``
  and ``b`` on the crease took the diagonal ``u-w``). Such a triangle straddles the crease: its
  corners lie on both faces and none on the crease, so it cuts the edge. Flipping the diagonal
  to ``a-b`` puts a mesh edge on the crease line. The flip keeps the outer edges of the quad, so
  the mesh stays manifold, closed and consistently oriented.
* :func:`corner_normals`: per face corner normals that are not averaged across a crease: the
  area-weighted mean of the normals of the faces around the vertex whose normal is within
  ``angle_deg`` of the corner's face (at a crease vertex each side gets its own normal; on a
  smooth surface this is the usual vertex normal).
* :func:`split_crease_vertices`: the same as a vertex list for formats with one normal per
  vertex (PLY): crease vertices are duplicated, one copy per side, faces re-pointed.
"""

from __future__ import annotations

import numpy as np

from .mesh import face_area_vectors

__all__ = ["corner_normals", "flip_straddling_edges", "split_crease_vertices", "straddling"]

#: Two non-crease vertices whose normals differ by more than this lie on different faces of
#: a crease [deg].
SIDE_ANGLE_DEG = 30.0
#: Passes of :func:`flip_straddling_edges` (a face flips at most once per pass).
FLIP_PASSES = 3


def _edge_map(faces: np.ndarray) -> dict[tuple[int, int], list[int]]:
    out: dict[tuple[int, int], list[int]] = {}
    for t, (a, b, c) in enumerate(faces.tolist()):
        for u, w in ((a, b), (b, c), (c, a)):
            out.setdefault((min(u, w), max(u, w)), []).append(t)
    return out


def straddling(faces: np.ndarray, normals: np.ndarray, crease: np.ndarray) -> np.ndarray:
    """Mask of triangles with no crease corner and two corners whose normals differ by more
    than ``SIDE_ANGLE_DEG`` (corners on both faces of a crease)."""
    if len(faces) == 0:
        return np.zeros(0, dtype=bool)
    n = normals[faces]
    cos = np.cos(np.radians(SIDE_ANGLE_DEG))
    apart = (
        (np.einsum("ij,ij->i", n[:, 0], n[:, 1]) < cos)
        | (np.einsum("ij,ij->i", n[:, 1], n[:, 2]) < cos)
        | (np.einsum("ij,ij->i", n[:, 2], n[:, 0]) < cos)
    )
    return apart & ~crease[faces].any(axis=1)


def flip_straddling_edges(
    faces: np.ndarray, normals: np.ndarray, crease: np.ndarray
) -> tuple[np.ndarray, int]:
    """Flip the diagonal ``u-w`` of every quad ``(u, w, a) + (w, u, b)`` where ``a`` and ``b``
    are crease vertices, ``u`` and ``w`` are not and lie on different faces (normals more than
    ``SIDE_ANGLE_DEG`` apart), and the edge ``a-b`` does not exist yet. Returns the faces and
    the number of flips."""
    faces = np.array(faces, dtype=np.int64, copy=True)
    if len(faces) == 0 or not crease.any():
        return faces, 0
    cos = np.cos(np.radians(SIDE_ANGLE_DEG))
    flips = 0
    for _ in range(FLIP_PASSES):
        edges = _edge_map(faces)
        touched = np.zeros(len(faces), dtype=bool)
        created: set[tuple[int, int]] = set()
        done = 0
        for (u, w), owners in edges.items():
            if len(owners) != 2 or crease[u] or crease[w] or normals[u] @ normals[w] >= cos:
                continue
            t1, t2 = owners
            if touched[t1] or touched[t2]:
                continue
            f1, f2 = faces[t1].tolist(), faces[t2].tolist()
            a = next(x for x in f1 if x != u and x != w)
            b = next(x for x in f2 if x != u and x != w)
            key = (min(a, b), max(a, b))
            if a == b or not (crease[a] and crease[b]) or key in edges or key in created:
                continue
            i = f1.index(u)
            if f1[(i + 1) % 3] != w:  # name them so that t1 runs u -> w
                u, w = w, u
            # t1 = (u, w, a), t2 = (w, u, b) -> (a, u, b), (b, w, a): same outer edges
            faces[t1] = (a, u, b)
            faces[t2] = (b, w, a)
            touched[t1] = touched[t2] = True
            created.add(key)
            done += 1
        flips += done
        if done == 0:
            break
    return faces, flips


def corner_normals(
    vertices: np.ndarray,
    faces: np.ndarray,
    vertex_normals: np.ndarray,
    crease: np.ndarray,
    angle_deg: float,
) -> np.ndarray:
    """(F, 3, 3) unit normal at each face corner: ``vertex_normals`` away from creases; at a
    crease vertex the area-weighted mean of the normals of the faces around it that turn by at
    most ``angle_deg`` from this face (each side of the crease its own normal)."""
    out = np.asarray(vertex_normals, dtype=np.float64)[faces].copy()
    if len(faces) == 0 or not np.any(crease):
        return out
    area = face_area_vectors(vertices, faces)
    unit = area / np.maximum(np.linalg.norm(area, axis=1, keepdims=True), 1e-300)
    cos = np.cos(np.radians(angle_deg))
    flat = faces.reshape(-1)
    order = np.argsort(flat, kind="stable")
    starts = np.searchsorted(flat[order], np.arange(len(vertices) + 1))
    owner = order // 3
    for k in np.flatnonzero(crease[flat]):
        t, c = divmod(int(k), 3)
        v = flat[k]
        ring = owner[starts[v] : starts[v + 1]]
        keep = ring[unit[ring] @ unit[t] >= cos]
        total = area[keep].sum(axis=0)
        norm = np.linalg.norm(total)
        if norm > 0:
            out[t, c] = total / norm
    return out


def split_crease_vertices(
    vertices: np.ndarray,
    faces: np.ndarray,
    vertex_normals: np.ndarray,
    crease: np.ndarray,
    angle_deg: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One vertex per distinct face-corner normal (:func:`corner_normals`), for formats with one
    normal per vertex (PLY): a crease vertex is duplicated, one copy per side, and faces are
    re-pointed. Returns ``(faces, normals, source)``: output vertex ``i`` is input vertex
    ``source[i]`` (the first ``len(vertices)`` are the input vertices, in order). The copies
    sit at the same place, so the mesh is closed but its topology opens along the creases
    (weld by ``source`` to close it)."""
    cn = corner_normals(vertices, faces, vertex_normals, crease, angle_deg).reshape(-1, 3)
    normals = np.asarray(vertex_normals, dtype=np.float64).copy()
    flat = faces.reshape(-1).copy()
    extra_src: list[int] = []
    extra_n: list[np.ndarray] = []
    first: dict[int, np.ndarray] = {}
    copies: dict[tuple[int, tuple[float, ...]], int] = {}
    for k in np.flatnonzero(crease[flat]):
        v = int(flat[k])
        key = (v, tuple(np.round(cn[k], 5).tolist()))
        if v not in first:
            first[v] = cn[k]
            normals[v] = cn[k]
            copies[key] = v
            continue
        idx = copies.get(key)
        if idx is None:
            idx = len(vertices) + len(extra_src)
            extra_src.append(v)
            extra_n.append(cn[k])
            copies[key] = idx
        flat[k] = idx
    source = np.r_[np.arange(len(vertices)), np.asarray(extra_src, dtype=np.int64)]
    normals = np.vstack([normals, np.asarray(extra_n, dtype=np.float64).reshape(-1, 3)])
    return flat.reshape(-1, 3), normals, source
