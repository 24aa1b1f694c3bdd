"""The preview picture of a tiled fit (``--preview``), drawn without holding the mesh.

:func:`recon.render.render_mesh_png` draws big meshes simplified by vertex clustering (about
``max_faces`` triangles). A tiled mesh is never held whole, so :func:`preview_mesh` clusters it
unit by unit (a tile's interior or a seam cell, as they are written) on one grid for the whole
mesh: the cell side is chosen from the total area as the renderer chooses it, a cluster's
vertex is the mean of the vertices it gathers, and a face survives when its three vertices
fall in three clusters (a mesh of at most ``max_faces`` is drawn as it is). What is held: the
clusters and the surviving faces (both about ``max_faces``), one unit's faces at a time. The
marked edges (boundary, non-manifold) and bow-tie vertices are the full mesh's, from the
unit-by-unit topology.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from .assemble import proper_faces

__all__ = ["preview_mesh", "write_preview"]

#: Triangles drawn (the renderer's default).
PREVIEW_FACES = 60_000


def _unit_faces(stitched: dict[str, Any]):
    store = stitched["store"]
    for faces in stitched["units"]:
        f = proper_faces(faces)
        if len(f):
            ids, local = np.unique(f, return_inverse=True)
            yield ids, store.get(ids)[0], local.reshape(-1, 3)


def preview_mesh(
    stitched: dict[str, Any], max_faces: int = PREVIEW_FACES
) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """(vertices, faces, marks) to draw a stitched mesh (see the module docstring): the
    clustered mesh, then the vertices of the marked edges; ``marks`` as
    :func:`recon.render.render_mesh_png` takes them."""
    area = 0.0
    small = stitched["n_faces"] <= max_faces  # drawn as it is: a cluster per vertex
    for _, p, f in _unit_faces(stitched) if not small else ():
        t = p[f]
        area += 0.5 * float(
            np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1).sum()
        )
    lo = np.asarray(stitched["bounds"][0], dtype=np.float64)
    if not np.all(np.isfinite(lo)):
        lo = np.zeros(3)
    cell = np.sqrt(3.0 * area / max_faces) if area > 0 else 1.0
    keys = np.zeros((0, 3), dtype=np.int64)  # clusters seen so far ...
    sums = np.zeros((0, 3))  # ... with the sum of their vertices ...
    counts = np.zeros(0, dtype=np.int64)  # ... and how many
    tris = np.zeros((0, 3, 3), dtype=np.int64)  # surviving faces as cluster keys
    for ids, p, f in _unit_faces(stitched):
        if small:
            k = np.column_stack([ids, np.zeros((len(ids), 2), dtype=np.int64)])
        else:
            k = np.floor((p - lo) / cell).astype(np.int64)
        ck, inv = np.unique(k, axis=0, return_inverse=True)
        inv = inv.reshape(-1)
        s = np.zeros((len(ck), 3))
        np.add.at(s, inv, p)
        n = np.bincount(inv, minlength=len(ck))
        keys, back = np.unique(np.vstack([keys, ck]), axis=0, return_inverse=True)
        back = back.reshape(-1)
        s2 = np.zeros((len(keys), 3))
        n2 = np.zeros(len(keys), dtype=np.int64)
        np.add.at(s2, back[: len(sums)], sums)
        np.add.at(n2, back[: len(sums)], counts)
        np.add.at(s2, back[len(sums) :], s)
        np.add.at(n2, back[len(sums) :], n)
        sums, counts = s2, n2
        cf = inv[f]
        cf = cf[(cf[:, 0] != cf[:, 1]) & (cf[:, 1] != cf[:, 2]) & (cf[:, 0] != cf[:, 2])]
        if len(cf):
            tris = np.unique(np.concatenate([tris, ck[cf]]), axis=0)
    vertices = sums / np.maximum(counts, 1)[:, None]
    faces = np.zeros((0, 3), dtype=np.int64)
    if len(tris):
        flat = tris.reshape(-1, 3)
        idx = np.searchsorted(_rows(keys), _rows(flat))
        faces = idx.reshape(-1, 3)
        # a face and its reverse (or a rotation) are one face drawn twice: keep one
        key = np.sort(faces, axis=1)
        _, first = np.unique(key, axis=0, return_index=True)
        faces = faces[np.sort(first)]
    defects = stitched["defects"]
    marked = np.unique(
        np.concatenate(
            [defects["boundary"].ravel(), defects["non_manifold"].ravel(), defects["bow_ties"]]
        )
    )
    mp = stitched["store"].get(marked)[0] if len(marked) else np.zeros((0, 3))

    def local(a: np.ndarray) -> np.ndarray:
        return len(vertices) + np.searchsorted(marked, a)

    marks = {
        "boundary": local(defects["boundary"]),
        "non_manifold": local(defects["non_manifold"]),
        "bow_ties": local(defects["bow_ties"]),
        "faces": int(stitched["n_faces"]),
    }
    return np.vstack([vertices, mp]), faces, marks


def _rows(a: np.ndarray) -> np.ndarray:
    """Integer rows as one sortable key each (a structured view)."""
    a = np.ascontiguousarray(a, dtype=np.int64)
    return a.view([("x", np.int64), ("y", np.int64), ("z", np.int64)]).reshape(-1)


def write_preview(path: Path, stitched: dict[str, Any], title: str, outputs: Any) -> None:
    """The PNG of :func:`recon.render.render_mesh_png` for a stitched mesh."""
    from ..render import render_mesh_png

    v, f, marks = preview_mesh(stitched)
    render_mesh_png(Path(path), v, f, title=title, outputs=outputs, marks=marks)
