"""Polish the triangulated particles of a fit: flips and tangential smoothing on the data.

The particles are already evenly spaced when they are triangulated; two rounds of
:func:`recon.remesh.improve.flip_and_smooth` take out what is left of their irregularity
(ball pivoting's odd diagonal, a particle a little off its neighbours' centre, most of all on
noisy scans), and each moved vertex goes back onto the local data surface the dynamics pulled
it toward (:meth:`recon.surface.DataSurface.anchors`).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .intersections import median_edge, self_intersections, untangle, within_reach
from .remesh.improve import flip_and_smooth
from .small_handles import without_small_handles
from .surface import DataSurface
from .triangulate import TriangulationResult

__all__ = ["HOLD_RINGS", "POLISH_REACH", "POLISH_STEP", "polish", "polish_and_untangle"]

#: Fraction of the way to its neighbours' centroid a vertex moves per polishing round: the
#: particles are already evenly spaced (about 0.1 r0 off the ideal), so the step can be larger
#: than the remesher's, which starts from arbitrary triangles.
POLISH_STEP = 0.8
#: How far the polish may move a vertex from its particle, in median edge lengths. The
#: particles already lie on the data, about evenly spaced, so the polish's rounds move a vertex
#: within its one ring: over the 27 dev cases at most 3.2 median edge lengths (face-sparse,
#: where the spacing varies and the median edge is short of it), on the held-out knife at
#: 5,000 points (seed 0) between 4 and 6 (its tapering edge, projected onto the data); at 8
#: the six held-out shapes at 3,000 and 5,000 points (seed 0) keep their meshes. A vertex
#: that would go farther follows a sliver's far corner (a face hanging off a stray particle:
#: 427 edge lengths on a sphere with 5 % outliers) or a degenerate local quadric (a point
#: repeated 50 times with 1e-6 jitter: 2.7e9), and stops at this distance.
POLISH_REACH = 8.0
#: Rings of vertices round the faces a polished mesh still crosses that the retry holds.
HOLD_RINGS = 2


def polish(
    result: TriangulationResult,
    surface: DataSurface | None,
    rounds: int,
    flips: bool = True,
    fixed: np.ndarray | None = None,
) -> TriangulationResult:
    """``rounds`` rounds of flips (with ``flips``) and tangential smoothing of the triangulated
    particles (:func:`recon.remesh.improve.flip_and_smooth`), each moved vertex put back on
    the local data surface (:meth:`DataSurface.anchors`, on the quadric of a data point whose
    normal agrees with the vertex's) and given that surface's normal; with no ``surface``
    (a tile's meshing) the moves stay in the tangent planes. Crease and boundary vertices stay,
    and so do ``fixed`` (V,) ones; no vertex goes farther than :data:`POLISH_REACH` median edge
    lengths from where it was. Neither flips nor moves change the topology; crossings they
    might make are left to :func:`recon.intersections.untangle`, which runs after.
    """
    if rounds <= 0 or len(result.faces) < 2:
        return result
    faces = np.ascontiguousarray(result.faces, dtype=np.int64)
    n = len(result.vertices)
    held = np.zeros(n, dtype=bool) if fixed is None else np.array(fixed, dtype=bool)
    if result.crease is not None:
        held |= np.asarray(result.crease, dtype=bool)
    normals = np.array(result.normals, dtype=np.float64, copy=True)
    origin = np.asarray(result.vertices, dtype=np.float64)
    reach = POLISH_REACH * median_edge(origin, faces)

    def onto_data(target: np.ndarray, moved: np.ndarray) -> np.ndarray:
        if surface is None:
            return within_reach(target, origin[moved], reach)
        foot, nrm = surface.anchors(target, normals[moved])[:2]
        side = np.where(np.einsum("ij,ij->i", nrm, normals[moved]) < 0.0, -1.0, 1.0)
        normals[moved] = nrm * side[:, None]
        return within_reach(np.array(foot, dtype=np.float64), origin[moved], reach)

    # no last pass of angle flips: on the evenly spaced particles it changed nothing measurable
    # (bunny-clean: the same mean minimum angle) and cost more than the rounds' flips
    vertices, faces, stats = flip_and_smooth(
        result.vertices,
        faces,
        held,
        onto_data,
        rounds,
        step=POLISH_STEP,
        flips=flips,
        fix_boundary=True,
        final_flips=False,
    )
    return replace(
        result,
        vertices=vertices,
        faces=faces,
        normals=normals,
        stats={**result.stats, "polish_flips": stats["flips"]},
    )


def polish_and_untangle(
    result: TriangulationResult,
    surface: DataSurface | None,
    rounds: int,
    flips: bool = True,
    fixed: np.ndarray | None = None,
    cut_handles: bool = True,
    tunnel_perimeter: float | None = None,
) -> tuple[TriangulationResult, int, int]:
    """:func:`polish`, then :func:`recon.intersections.untangle`; returns the mesh and
    untangle's crossing pairs found and left. ``fixed`` (V,): vertices neither step moves
    (default: the crease vertices, which :func:`polish` holds anyway).

    The polish must not leave a crossing that the unpolished mesh would not: on a blade whose
    edge thins to nothing its moves can put a face through the opposite layer, beyond what
    untangling clears (the held-out knife, 4 pairs). When crossings are left, the polish runs
    again with the vertices within ``HOLD_RINGS`` rings of the crossing faces held, and the
    mesh with the fewest crossings left is kept, preferring the polished ones on a tie:
    polished, polished with those vertices held, unpolished. The mesh's stats say which
    (``polish_kept``: "polished", "held" or "unpolished") and how many vertices were held
    (``polish_held``). Last, with ``cut_handles``, a handle that fits in a geodesic ball of
    a few spacings is cut out and its hole zipped
    (:func:`recon.small_handles.without_small_handles`; vertices inside the cut are dropped),
    and with ``tunnel_perimeter`` also a handle at a thin stalk beside a tunnel at most that
    long round.
    Without it the mesh keeps the faces and vertices it came with, moved only: what a tile
    of a tiled fit needs, whose mesh is a part of the whole and must stay one with its
    neighbours'.
    """
    untangle_fixed = result.crease if fixed is None else fixed

    def finish(mesh: TriangulationResult, kept: str, held: int) -> tuple:
        vertices, found, left = untangle(mesh.vertices, mesh.faces, fixed=untangle_fixed)
        stats = {**mesh.stats, "polish_kept": kept, "polish_held": held}
        return replace(mesh, vertices=vertices, stats=stats), found, left

    def cut(best: tuple) -> tuple:
        # a tunnel a few spacings across is cut once the mesh has its final shape (the
        # polish smooths the particles' jagged rings: before it the same handle can span a
        # wider ball)
        if not cut_handles:
            return best
        return (without_small_handles(best[0], tunnel_perimeter=tunnel_perimeter), *best[1:])

    best = finish(polish(result, surface, rounds, flips, fixed=fixed), "polished", 0)
    if best[2] == 0 or rounds <= 0:
        return cut(best)
    crossing = self_intersections(best[0].vertices, best[0].faces)
    held = np.zeros(len(result.vertices), dtype=bool)
    held[best[0].faces[np.unique(crossing)].ravel()] = True
    for _ in range(HOLD_RINGS):
        held[best[0].faces[held[best[0].faces].any(axis=1)].ravel()] = True
    n_held = int(np.count_nonzero(held))
    if fixed is not None:
        held |= np.asarray(fixed, dtype=bool)
    for candidate in (
        finish(polish(result, surface, rounds, flips, fixed=held), "held", n_held),
        finish(result, "unpolished", 0),
    ):
        if candidate[2] < best[2]:
            best = candidate
    return cut(best)
