"""The faces' winding: per face from the vertex normals, consistent per component, outward.

:func:`orient_consistently` gives the triangulation one winding per component (the fit's,
the tiles' seams and the remesher's); :func:`twisted_faces` finds where the surface turns
over; :func:`consistently_wound` tells whether a mesh needs none of it.
"""

from __future__ import annotations

import logging

import numpy as np

from .kernels.mesh_tables import half_edge_winding
from .mesh import (
    corner_sum,
    edge_keys,
    face_area_vectors,
    face_components,
    orientation_flips,
    runs_of_equal,
    unique_edges,
)

log = logging.getLogger(__name__)

__all__ = [
    "MIN_COMPONENT_FACES",
    "ORIENTATION_ROUNDS",
    "consistently_wound",
    "orient_consistently",
    "orient_faces",
    "turn_closed_outward",
    "turned_with_faces",
    "twisted_faces",
]

#: A fold is cut when at least this many faces are wound against their component's normals
#: (:func:`orient_consistently`); the triangulation's debris limit too.
MIN_COMPONENT_FACES = 50
#: Rounds of dropping faces on orientation conflicts (a dropped face can expose another).
ORIENTATION_ROUNDS = 5


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


def consistently_wound(faces: np.ndarray, n_vertices: int) -> bool:
    """Does every directed edge lie in one face at most (every edge in at most two faces,
    wound opposite ways: a consistently oriented edge-manifold mesh)?"""
    he = faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2).astype(np.int64)
    n = max(n_vertices, int(he.max()) + 1) if len(he) else 1  # keys unique per pair
    keys = he[:, 0] * n + he[:, 1]
    return len(np.unique(keys)) == len(keys)


def twisted_faces(vertices: np.ndarray, normals: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Faces on the manifold edges where the surface turns over: each face wound to agree with
    its vertex normals (:func:`orient_faces`), the two faces of the edge run it the same way.
    A boolean mask over faces.

    On an orientable mesh with consistent vertex normals there are none; where a fold or a
    twist joins a sheet to itself one-sidedly, these are the faces that join it.
    """
    twist = np.zeros(len(faces), dtype=bool)
    if len(faces) == 0:
        return twist
    wound = orient_faces(vertices, normals, faces)
    keys = edge_keys(wound, len(vertices))
    forward = (wound < np.roll(wound, -1, axis=1)).ravel()  # edge k runs from lo to hi
    order, start, count = runs_of_equal(keys)
    pair = start[count == 2]
    a, b = order[pair], order[pair + 1]
    same = forward[a] == forward[b]
    twist[a[same] // 3] = True
    twist[b[same] // 3] = True
    return twist


def orient_consistently(vertices: np.ndarray, normals: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """One winding per component, facing the side its vertex normals face (outward).

    Flips propagate across manifold edges (:func:`recon.mesh.orientation_flips`); where they
    conflict (a one-sided, Moebius-like seam, e.g. two sheets of a thin part glued crosswise)
    faces are dropped, which opens a small hole for hole filling: the faces where the surface
    turns over (:func:`twisted_faces`) when dropping them makes the mesh orientable and drops
    no more faces than the conflicts, else the faces on the conflicting edges (which lie
    where the search's fronts met, possibly far from the cause).
    Each component then keeps the winding that agrees with its vertex normals (area-weighted),
    and a closed component whose signed volume is negative is turned inside out.

    A fold is cut too, though it meets no conflict: a part (a leg) joined to the body by a
    band of faces that each face their vertex normals' way but are wound against their
    neighbours (ball pivoting at a sparse leg's concave root; :func:`twisted_faces` marks
    them). The mesh is orientable, so the propagation winds the whole part as the body and
    turns it over against its normals: the part comes out inside out, and the seam between
    the two windings is left as a boundary loop at its root by the repairs after.
    When the consistent winding leaves at least ``MIN_COMPONENT_FACES`` faces (the
    debris limit's face count) against the side their component's normals vote for, the
    mesh without the twisted faces is oriented instead if that costs fewer faces than it
    sets right: the faces dropped plus those still against their component's side after
    the cut are fewer than those against it without. The part is then its own component,
    wound outward; in :func:`recon.triangulate.triangulate_particles` hole filling caps both
    cuts and :func:`recon.holes.join_closed_parts` joins it to the body again. Faces against the
    normals here and there (noise, the merged normals at a thin edge) are not a fold: on
    the dev cases and the held-out fits measured the twisted faces about them outnumber
    them, and the consistent winding stays. The rule reads the winding and the normals
    only, not the geometry: a large compact patch whose vertex normals are wrong on a
    surface without a fold passes it too, and is then cut off wound by those normals
    (inside out), where the consistent winding would have set it right. The particles'
    normals are re-signed over the sheet before ball pivoting (:mod:`recon.particle_signs`),
    which leaves few such patches; on the 27 dev cases and 23 held-out fits the cut fired
    only at folds (issue 11's history: docs/topology-history.md).
    """
    if len(faces) == 0:
        return faces
    out, against = _wound(vertices, normals, faces)
    if against < MIN_COMPONENT_FACES:
        return out
    twist = twisted_faces(vertices, normals, faces)
    n_twist = int(np.count_nonzero(twist))
    if n_twist == 0 or n_twist >= against:
        return out  # the cut would cost at least what it sets right (or leave no face)
    cut, against_cut = _wound(vertices, normals, faces[~twist])
    if n_twist + against_cut < against:
        log.debug(
            "cut a fold at %d twisted faces (%d faces against their normals -> %d)",
            n_twist,
            against,
            against_cut,
        )
        return cut
    return out


def _wound(vertices: np.ndarray, normals: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, int]:
    """:func:`orient_consistently` without the fold cut, and how many faces are wound against
    their vertex normals relative to the rest of their component: against the side its
    normals' area-weighted vote takes (not against the normals themselves: a closed
    component is turned by its volume, whichever way its normals face as a whole)."""
    faces = faces.copy()
    # one sort of the half-edges for the winding test, the open faces and the first round
    order, consistent, open_face = half_edge_winding(
        faces.astype(np.int64), max(len(vertices), faces.max() + 1)
    )
    known = {"order": order, "consistent": consistent}
    for _ in range(0 if consistent else ORIENTATION_ROUNDS):
        flip, conflict = orientation_flips(faces, **known)
        known = {}  # later rounds see flipped or fewer faces
        if conflict.any():
            # cut where the surface turns over, if that is a smaller cut that works: the
            # search's conflicts lie where its fronts happened to meet
            twist = twisted_faces(vertices, normals, faces)
            if 0 < twist.sum() <= conflict.sum():
                cut_flip, cut_conflict = orientation_flips(faces[~twist])
                if not cut_conflict.any():
                    faces, flip, conflict = faces[~twist], cut_flip, cut_conflict
        faces[flip] = faces[flip][:, [0, 2, 1]]
        if not conflict.any():
            break
        faces = faces[~conflict]
    n, labels = face_components(faces, len(vertices))
    fn = face_area_vectors(vertices, faces)
    agree = np.einsum("ij,ij->i", fn, normals[faces].sum(axis=1))
    vote = np.bincount(labels, weights=agree, minlength=n)
    # signed volume (x6) of each component; meaningful for closed ones
    p = vertices[faces]
    vol = np.bincount(labels, weights=np.einsum("ij,ij->i", p[:, 0], fn), minlength=n)
    if len(faces) < len(open_face):  # the loop dropped faces (flips keep the edges): again
        _, inv, cnt = unique_edges(faces, len(vertices))
        open_face = (cnt[inv.reshape(-1)] == 1).reshape(-1, 3).any(axis=1)
    closed = np.bincount(labels, weights=open_face, minlength=n) == 0
    turn = np.where(closed, vol < 0, vote < 0)
    bad = turn[labels]
    faces[bad] = faces[bad][:, [0, 2, 1]]
    return faces, int(np.count_nonzero(agree * np.sign(vote)[labels] < 0))


def turn_closed_outward(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Turn every closed component that faces inward: the last word of the fit's winding.

    :func:`orient_consistently` turns a closed component by its signed volume, but a component
    that is still open there is turned by its normals' vote, and a later step (the polish's
    hole closing) can close it: a sheet whose particle normals point inward (two misaligned
    scans of one surface, taken for a thin part's two faces) then came out as a closed mesh
    inside out. Here a component whose every edge lies in exactly two faces, wound in
    opposite directions, and whose signed volume (about its own vertex mean) is negative has
    its faces turned; open, over-shared or inconsistently wound components are left as they
    are.

    Parameters
    ----------
    vertices : (V, 3) float64 [length]
    faces : (F, 3) int

    Returns
    -------
    faces : (F, 3) int64
        A copy, with the faces of the inward closed components turned.
    turned : (V,) bool
        The vertices of the turned components (their vertex normals turn with them).

    Examples
    --------
    >>> v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    >>> f = np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]])
    >>> out, turned = turn_closed_outward(v, f[:, ::-1])
    >>> out.tolist() == f[:, [2, 0, 1]].tolist(), turned.tolist()
    (True, [True, True, True, True])
    """
    f = np.array(faces, dtype=np.int64).reshape(-1, 3)
    turned = np.zeros(len(vertices), dtype=bool)
    if len(f) == 0:
        return f, turned
    _, inverse, counts = unique_edges(f, len(vertices))
    # components through shared edges, not vertices: two bodies touching at a vertex are two
    n, labels = _edge_components(inverse, len(f), len(counts))
    # each edge of a consistently wound closed surface: two faces, one in each direction
    forward = np.where(f < np.roll(f, -1, axis=1), 1.0, -1.0).ravel()
    balance = np.bincount(inverse, weights=forward, minlength=len(counts))
    bad_edge = (counts != 2) | (balance != 0)
    bad_face = bad_edge[inverse].reshape(-1, 3).any(axis=1)
    closed = np.bincount(labels, weights=bad_face, minlength=n) == 0
    if not closed.any():
        return f, turned
    v = np.asarray(vertices, dtype=np.float64)
    corner_label = np.repeat(labels, 3)
    weight = np.bincount(corner_label, minlength=n)
    centre = (
        np.stack(
            [np.bincount(corner_label, weights=v[f.ravel(), k], minlength=n) for k in range(3)], 1
        )
        / np.maximum(weight, 1)[:, None]
    )
    p = v[f] - centre[labels][:, None, :]
    volume = np.bincount(
        labels, weights=np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2])), minlength=n
    )
    turn = closed & (volume < 0.0)
    if not turn.any():
        return f, turned
    flip = turn[labels]
    f[flip] = f[flip][:, [0, 2, 1]]
    turned[f[flip].ravel()] = True
    return f, turned


def _edge_components(inverse: np.ndarray, n_faces: int, n_edges: int) -> tuple[int, np.ndarray]:
    """Components of faces joined through shared edges: (count, label per face), from the
    edge of every face corner (``inverse`` of :func:`recon.mesh.unique_edges`)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    face = np.repeat(np.arange(n_faces), 3)
    graph = coo_matrix(
        (np.ones(len(face)), (face, n_faces + inverse)), shape=(n_faces + n_edges,) * 2
    )
    n, labels = connected_components(graph, directed=False)
    return n, labels[:n_faces]


def turned_with_faces(
    vertices: np.ndarray, faces: np.ndarray, normals: np.ndarray, which: np.ndarray
) -> np.ndarray:
    """``normals`` with those of the vertices ``which`` that point against their faces (the
    area-weighted sum of the normals of the faces round them) turned over: the vertex normals
    of components :func:`turn_closed_outward` turned. A copy."""
    acc = corner_sum(faces, face_area_vectors(vertices, faces), len(vertices))
    against = which & (np.einsum("ij,ij->i", acc, normals) < 0.0)
    return np.where(against[:, None], -normals, normals)
