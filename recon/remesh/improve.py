"""Polish the triangulated particles: angle-raising edge flips and tangential smoothing.

Neither changes the connectivity's topology: a flip keeps the outline and winding of its quad
(:mod:`recon.kernels.edge_flip`), smoothing moves vertices only. Each round flips edges until no
flip raises the smallest angle, then moves every free vertex a fraction :data:`SMOOTH_STEP` of
the way to the centroid of its neighbours, within its tangent plane, and back onto the input
surface (its closest point). Vertices on feature lines and corners do not move, and no edge
between two of them is flipped, so boundaries and creases stay where the particles put them.

References
----------
[BK04] M. Botsch, L. Kobbelt. "A remeshing approach to multiresolution modeling". SGP 2004.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy import sparse

from ..kernels.edge_flip import flip_edges_kernel
from ..mesh import corner_sum, face_area_vectors
from .surface import MeshSurface

__all__ = [
    "FLIP_MIN_NORMAL_DOT",
    "SMOOTH_STEP",
    "EdgeFlipper",
    "flip_and_smooth",
    "flip_edges",
    "improve",
    "neighbour_centroids",
    "twin_half_edges",
]

#: A flip's new triangles must face within ~37 degrees of the old pair's mean normal...
FLIP_MIN_NORMAL_DOT = 0.8
#: ... and the old pair must be flatter than ~45 degrees (no flip across a bend).
FLIP_MIN_FLAT_DOT = 0.7
#: Smallest gain in the cosine of the smallest angle for a flip.
FLIP_EPS = 1e-9
#: Passes over all edges per flip call.
FLIP_PASSES = 20
#: Valence flips (toward 6 neighbours) during the smoothing rounds, when no angle of the new
#: pair falls below this [deg]; None: angle flips only.
VALENCE_MIN_ANGLE: float | None = 30.0
#: Fraction of the way to the neighbours' centroid moved per smoothing round.
SMOOTH_STEP = 0.5


def twin_half_edges(faces: np.ndarray, n_vertices: int) -> np.ndarray:
    """``(3 F,)`` int64: the twin of half-edge ``3 f + k`` (corner k -> k+1), -1 if none."""
    a = faces.ravel()
    b = np.roll(faces, -1, axis=1).ravel()
    key = a * np.int64(n_vertices) + b
    rev = b * np.int64(n_vertices) + a
    order = np.argsort(key)
    pos = np.searchsorted(key[order], rev)
    pos = np.minimum(pos, len(key) - 1)
    found = key[order[pos]] == rev
    return np.where(found, order[pos], -1).astype(np.int64)


class EdgeFlipper:
    """Angle-raising flips on one mesh, round after round: the twin half-edges, locks and
    valence targets are built once and kept up to date by the kernel (a flip changes faces,
    twins and locks in place, never the boundary).

    ``line_edges`` (k, 2) vertex pairs (feature lines) are locked where they exist and
    recovered by a flip where one creates them.
    """

    def __init__(
        self, n_vertices: int, faces: np.ndarray, line_edges: np.ndarray | None = None
    ) -> None:
        self.faces = np.ascontiguousarray(faces, dtype=np.int64).copy()
        nv = np.int64(n_vertices)
        self.twin = twin_half_edges(self.faces, n_vertices)
        a = self.faces.ravel()
        b = np.roll(self.faces, -1, axis=1).ravel()
        if line_edges is None or len(line_edges) == 0:
            self.wanted = np.zeros(0, dtype=np.int64)
        else:
            le = np.sort(np.asarray(line_edges, dtype=np.int64), axis=1)
            self.wanted = np.unique(le[:, 0] * nv + le[:, 1])
        self.locked = np.ascontiguousarray(
            np.isin(np.minimum(a, b) * nv + np.maximum(a, b), self.wanted)
        )
        self.target = np.full(n_vertices, 6, dtype=np.int64)
        self.target[a[self.twin < 0]] = 4

    def flip(self, vertices: np.ndarray, valence_min_angle: float | None = None) -> int:
        """Flip until no flip helps (:func:`flip_edges`); returns the number of flips."""
        if len(self.faces) < 2:
            return 0
        vmin = 1.0 if valence_min_angle is None else float(np.cos(np.radians(valence_min_angle)))
        return int(
            flip_edges_kernel(
                np.ascontiguousarray(vertices, dtype=np.float64),
                self.faces,
                self.twin,
                self.locked,
                self.wanted,
                self.target,
                FLIP_MIN_NORMAL_DOT,
                FLIP_MIN_FLAT_DOT,
                FLIP_EPS,
                FLIP_PASSES,
                vmin,
            )
        )


def flip_edges(
    vertices: np.ndarray,
    faces: np.ndarray,
    line_edges: np.ndarray | None = None,
    valence_min_angle: float | None = None,
) -> tuple[np.ndarray, int]:
    """Angle-raising flips; ``line_edges`` (k, 2) vertex pairs (feature lines) are locked where
    they exist and recovered by a flip where one creates them. With ``valence_min_angle``
    [deg], a flip that brings valences closer to 6 (4 on a boundary) is made too when no angle
    of the new pair falls below it. Returns (faces, flips)."""
    flipper = EdgeFlipper(len(vertices), faces, line_edges)
    n = flipper.flip(vertices, valence_min_angle)
    return flipper.faces, n


def neighbour_centroids(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(V, 3): the mean of each vertex's neighbours, every neighbour counted once per face
    the two share (twice across an interior edge, once across a boundary edge)."""
    n = len(vertices)
    idx = faces.ravel()
    around = vertices[np.roll(faces, -1, axis=1)] + vertices[np.roll(faces, 1, axis=1)]
    around = around.reshape(-1, 3)
    total = np.stack(
        [np.bincount(idx, weights=around[:, j], minlength=n) for j in range(3)], axis=1
    )
    count = 2.0 * np.bincount(idx, minlength=n)
    return total / np.maximum(count, 1.0)[:, None]


def _vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    cross = face_area_vectors(vertices, faces)
    vn = corner_sum(faces, cross, len(vertices))
    return vn / np.maximum(np.linalg.norm(vn, axis=1), 1e-300)[:, None]


def improve(
    vertices: np.ndarray,
    faces: np.ndarray,
    fixed: np.ndarray,
    surface: MeshSurface,
    rounds: int,
    weights: np.ndarray | None = None,
    line_edges: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, dict[str, int]]:
    """``rounds`` rounds of flips and tangential smoothing (module docstring), each moved vertex
    back on ``surface`` (its closest point).

    ``fixed`` vertices do not move; ``line_edges`` (k, 2): see :func:`flip_edges`.
    ``weights`` (V,), optional: each neighbour counts with this weight in the centroid (e.g.
    1/spacing² for adaptive meshes, so that vertices drift toward the dense side less).
    """

    def closest(target: np.ndarray, _moved: np.ndarray) -> np.ndarray:
        return surface.closest(target)[0]

    return flip_and_smooth(
        vertices, faces, fixed, closest, rounds, weights=weights, line_edges=line_edges
    )


def flip_and_smooth(
    vertices: np.ndarray,
    faces: np.ndarray,
    fixed: np.ndarray,
    project: Callable[[np.ndarray, np.ndarray], np.ndarray],
    rounds: int,
    step: float = SMOOTH_STEP,
    weights: np.ndarray | None = None,
    line_edges: np.ndarray | None = None,
    flips: bool = True,
    fix_boundary: bool = False,
    final_flips: bool = True,
) -> tuple[np.ndarray, np.ndarray, dict[str, int]]:
    """``rounds`` rounds of (with ``flips``) angle-raising flips and tangential smoothing.

    Each round moves every free vertex ``step`` of the way to its neighbours' centroid, within
    its tangent plane (the area-weighted vertex normal), and then onto the surface:
    ``project(target, moved)`` returns the surface point for each target, ``moved`` being the
    moved vertices' indices. With ``flips`` and ``final_flips``, a last pass of angle flips
    follows the last round.
    ``fixed``, ``weights``, ``line_edges``: see :func:`improve`; with ``fix_boundary`` the
    vertices on the mesh's boundary are fixed too.
    """
    v = np.array(vertices, dtype=np.float64, copy=True)
    flipper = EdgeFlipper(len(v), faces, line_edges)
    held = np.array(fixed, dtype=bool)
    if fix_boundary:
        held[flipper.faces.ravel()[flipper.twin < 0]] = True
    free = np.flatnonzero(~held)
    n_flips = 0
    for _ in range(rounds):
        if flips:
            n_flips += flipper.flip(v, VALENCE_MIN_ANGLE)
        f = flipper.faces
        if weights is None:
            centroid = neighbour_centroids(v, f)
        else:
            e = f[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
            rows, cols = np.concatenate([e[:, 0], e[:, 1]]), np.concatenate([e[:, 1], e[:, 0]])
            adj = sparse.csr_matrix((weights[cols], (rows, cols)), shape=(len(v), len(v)))
            deg = np.asarray(adj.sum(axis=1)).ravel()
            centroid = (adj @ v) / np.maximum(deg, 1e-300)[:, None]
        move = centroid - v
        vn = _vertex_normals(v, f)
        move -= np.einsum("ij,ij->i", move, vn)[:, None] * vn
        v[free] = project(v[free] + step * move[free], free)
    if flips and final_flips:
        n_flips += flipper.flip(v)
    return v, flipper.faces, {"flips": n_flips, "smoothing_rounds": rounds}
