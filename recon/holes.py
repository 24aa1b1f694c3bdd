"""Closing the gaps ball pivoting leaves: which boundary loops are holes, and the zipper.

:func:`fill_small_holes` closes a loop that is small, that has data inside, or that is a
narrow seam between two growth fronts supported by data all round; real boundaries (the rim
of an open sheet, holes wider than ``max_hole``) stay. :func:`zip_loop` closes a loop without
new vertices, cutting off the corner with the shortest diagonal; a loop that wraps round a
thin part is zipped fold-free (:func:`rezip_crossing_loops`). Used by
:func:`recon.triangulate.triangulate_particles` and by the tiles' seam repair.
"""

from __future__ import annotations

import logging
from collections.abc import Callable

import numpy as np
from scipy.spatial import cKDTree

from .intersections import (
    ROUNDING_PAD,
    face_spheres,
    faces_near_balls,
    self_intersections,
    untangle,
)
from .kernels.loft import loft_path_kernel
from .mesh import (
    boundary_loops,
    count_edge_faces,
    face_area_vectors,
    face_components,
    face_normals,
)

log = logging.getLogger(__name__)

__all__ = [
    "FailedTrials",
    "across_points",
    "fill_small_holes",
    "first_clear_neck",
    "join_closed_parts",
    "loft_loops",
    "loft_nearest_loops",
    "loop_width",
    "neck_between",
    "neck_candidates",
    "rezip_crossing_loops",
    "thicken_sheet",
    "zip_loop",
    "zip_supported_loops",
]

#: A loop whose rim faces point against its patch is kept open when its component's area is
#: below this many times the patch's area (the outer rim of a small open sheet).
SHEET_AREA_FACTOR = 4.0
#: A seam is closed when data lies at this fraction of the points across it.
SEAM_SUPPORT = 0.9
#: A re-zip is judged by untangling the faces within this distance [r0] of the patch's extent
#: (:func:`_left_after_untangle`).
UNTANGLE_MARGIN = 3.0


def fill_small_holes(
    vertices: np.ndarray,
    normals: np.ndarray,
    faces: np.ndarray,
    max_perimeter: float,
    is_covered: Callable[..., np.ndarray] | None = None,
    covered_max_perimeter: float | None = None,
    scale: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Close the boundary loops that are gaps of the triangulation rather than real boundaries.

    A simple loop (:func:`recon.mesh.boundary_loops`) is closed when

    * its perimeter is at most ``max_perimeter`` (a small hole), or
    * with ``is_covered`` (points (m, 3) -> bool (m,): does data lie there?): its perimeter is
      at most ``covered_max_perimeter`` and data lies at its centroid, or
    * it is a *seam*: narrower than ``max_perimeter / pi`` (:func:`loop_width`, however long)
      and data lies at ``SEAM_SUPPORT`` of the points across it (:func:`across_points`): the
      rim is supported by data all round. ``is_covered`` is called with ``across=True`` for
      those points (judged together, they may be judged at the reach of the local sampling:
      :func:`recon.fitting.pipeline.covered`).

    A loop whose rim faces point against the patch that would close it is the outer rim of an
    open sheet and stays open. Loops are closed by :func:`zip_loop` (no new vertex), wound
    opposite to the boundary half-edges so that orientation stays consistent. A loop whose
    zip crosses the mesh and whose rim normals disagree (it wraps round a thin part) is zipped
    again fold-free (:func:`rezip_crossing_loops`).

    ``scale`` (per vertex, default 1) is the local rest spacing: every length limit above is
    multiplied by the mean scale of the loop's rim, and ``is_covered`` is then called as
    ``is_covered(points, scale_per_point)``.

    Returns
    -------
    vertices, normals, faces, n_filled
        Vertices and normals are returned unchanged (kept for the callers' symmetry).
    """
    loops = boundary_loops(faces)
    if not loops:
        return vertices, normals, faces, 0
    # Only half-edges between rim vertices are ever looked up (the rim's faces; the diagonals
    # zip_loop tests and adds join rim vertices), so the dict and the set hold only those:
    # same entries, in the same order (a later duplicate still wins), without a Python loop
    # over every half-edge.
    on_rim = np.zeros(len(vertices), dtype=bool)
    for loop in loops:
        on_rim[loop] = True
    he = faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    sel = np.flatnonzero(on_rim[he[:, 0]] & on_rim[he[:, 1]])
    rim_face = dict(zip(map(tuple, he[sel].tolist()), (sel // 3).tolist(), strict=True))
    edge_set = set(map(tuple, np.sort(he[sel], axis=1).tolist()))
    _, comp = face_components(faces, len(vertices))
    comp_area = np.bincount(
        comp, weights=0.5 * np.linalg.norm(face_area_vectors(vertices, faces), axis=1)
    )

    def covered(points: np.ndarray, s: float, across: bool = False) -> np.ndarray:
        return _covered_at(is_covered, points, None if scale is None else s, across)

    new_faces, zipped = [], []
    for loop in loops:
        if len(loop) < 3:
            continue
        ring = vertices[loop]
        s = float(scale[loop].mean()) if scale is not None else 1.0
        perim = float(np.linalg.norm(ring - np.roll(ring, -1, axis=0), axis=1).sum())
        fill = perim <= max_perimeter * s
        support = None  # share of the points across a seam over data, when tested
        if not fill and is_covered is not None and covered_max_perimeter is not None:
            if perim <= covered_max_perimeter * s:
                fill = bool(covered(ring.mean(axis=0)[None], s)[0])
            if not fill and len(loop) >= 5 and loop_width(ring) <= max_perimeter / np.pi * s:
                support = float(np.mean(covered(across_points(ring), s, across=True)))
                fill = support >= SEAM_SUPPORT
        if not fill:
            if log.isEnabledFor(logging.DEBUG):  # which rule keeps it open [local spacings]
                log.debug(
                    "loop of %d edges left open: perimeter %.1f, width %.2f, seam support %s",
                    len(loop),
                    perim / s,
                    loop_width(ring) / s,
                    "untested" if support is None else f"{support:.2f}",
                )
            continue
        rev = loop[::-1]
        # A patch wound this way must face the side the rim faces face; if it faces away and
        # the sheet is not much larger than the patch, the loop is the outer rim of an open
        # sheet (e.g. a small flat patch), and "filling" it would cap the sheet's back side
        # into a closed double layer. Only rims whose faces agree (a flat-ish rim) are judged;
        # on a rim whose normals cancel (a cylinder's open end) the test says nothing.
        centre = ring.mean(axis=0)
        patch_normal = np.cross(vertices[rev] - centre, vertices[np.roll(rev, -1)] - centre).sum(0)
        rim = [rim_face[(int(a), int(b))] for a, b in zip(loop, np.roll(loop, -1), strict=True)]
        rim_normal = face_normals(vertices, faces[rim]).sum(axis=0)
        agree = float(patch_normal @ rim_normal)
        coherent = np.linalg.norm(rim_normal) > 0.5 * len(loop)
        against = agree < -0.5 * np.linalg.norm(patch_normal) * np.linalg.norm(rim_normal)
        # ... unless the sheet is much larger than the patch: then the loop is a fold in it
        small_sheet = comp_area[comp[rim[0]]] < SHEET_AREA_FACTOR * 0.5 * np.linalg.norm(
            patch_normal
        )
        if coherent and against and small_sheet:
            log.debug("loop of %d edges left open: the outer rim of a small open sheet", len(loop))
            continue
        new_faces.append(zip_loop(vertices, rev, edge_set))
        zipped.append(rev)
    if not new_faces:
        return vertices, normals, faces, 0
    new_faces = rezip_crossing_loops(vertices, normals, faces, zipped, new_faces, edge_set)
    return vertices, normals, np.vstack([faces, *new_faces]), len(new_faces)


def zip_supported_loops(
    vertices: np.ndarray,
    faces: np.ndarray,
    loops: list[np.ndarray],
    is_covered: Callable[..., np.ndarray],
    scale: np.ndarray | None = None,
) -> np.ndarray:
    """``faces`` with each of ``loops`` (boundary loops of ``faces``) zipped (:func:`zip_loop`)
    when data lies at ``SEAM_SUPPORT`` of the points across it (:func:`across_points`) and
    untangling the mesh round the patch leaves no crossing (:func:`_left_after_untangle`),
    whatever its width and perimeter.

    For a loop already known to be a gap of a closed surface, not a real boundary: the rest
    of a thin part's edge left open beside the one-sided sheets that continue it
    (:func:`recon.triangulate.triangulate_particles`). Folded round the part's merged tip,
    such a loop is wider than any seam, so :func:`fill_small_holes` keeps it. ``scale`` (per
    vertex) is the local spacing, passed to ``is_covered`` as in :func:`fill_small_holes`.
    """
    he = faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    edges = set(map(tuple, np.sort(he, axis=1).tolist()))
    patches = []
    for loop in loops:
        s = None if scale is None else float(scale[loop].mean())
        support = np.mean(_covered_at(is_covered, across_points(vertices[loop]), s, True))
        if support < SEAM_SUPPORT:
            continue
        patch = zip_loop(vertices, loop[::-1], set(edges))
        if _left_after_untangle(vertices, np.concatenate([faces, *patches]), patch) == 0:
            edges |= set(
                map(tuple, np.sort(patch[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), 1).tolist())
            )
            patches.append(patch)
    return np.concatenate([faces, *patches]) if patches else faces


def _covered_at(
    is_covered: Callable[..., np.ndarray],
    points: np.ndarray,
    s: float | None,
    across: bool = False,
) -> np.ndarray:
    """``is_covered`` of ``points``, at the local spacing ``s`` when one is given; ``across``:
    they are the points across a seam (:func:`across_points`), judged together."""
    extra = {"across": True} if across else {}
    if s is None:
        return np.asarray(is_covered(points, **extra))
    return np.asarray(is_covered(points, np.full(len(points), s), **extra))


def loop_width(ring: np.ndarray) -> float:
    """Width of a hole: its hydraulic diameter ``4 A / P`` [units of ``ring``].

    ``A`` is the norm of the loop's vector area, ``P`` its perimeter. A round hole's width is
    its diameter; a slit of width ``w`` (a seam between two growth fronts) has width ``~2 w``
    however long it is.
    """
    nxt = np.roll(ring, -1, axis=0)
    perimeter = float(np.linalg.norm(nxt - ring, axis=1).sum())
    area = 0.5 * float(np.linalg.norm(np.cross(ring - ring[0], nxt - ring[0]).sum(axis=0)))
    return 4.0 * area / perimeter if perimeter > 0 else 0.0


def across_points(ring: np.ndarray, min_steps: int = 3) -> np.ndarray:
    """Points inside a hole: the midpoint from every rim vertex to the nearest rim vertex at
    least ``min_steps`` along the loop away, and the loop's centroid. If data lies at all of
    them, the rim is supported by data all round and the hole is a gap of the triangulation.
    Two rim vertices that are each other's nearest give their midpoint once: the support is
    a share of distinct points (counted twice, the gradient's seam at 5,000 points, seed 19,
    had 13 of 15 covered, 0.87, where 11 of its 12 distinct points are, 0.92).
    """
    k = len(ring)
    d = np.linalg.norm(ring[:, None, :] - ring[None, :, :], axis=2)
    idx = np.arange(k)
    steps = np.abs(idx[:, None] - idx[None, :])
    steps = np.minimum(steps, k - steps)
    d[steps < min_steps] = np.inf
    j = np.argmin(d, axis=1)
    pairs = np.unique(np.sort(np.stack([idx, j], axis=1), axis=1), axis=0)
    mids = 0.5 * (ring[pairs[:, 0]] + ring[pairs[:, 1]])
    return np.vstack([mids, ring.mean(axis=0)[None]])


def zip_loop(
    vertices: np.ndarray,
    loop: np.ndarray,
    edges: set[tuple[int, int]] | None = None,
    normals: np.ndarray | None = None,
) -> np.ndarray:
    """Close a loop (in the winding of the new faces) by repeatedly cutting off the corner
    with the shortest diagonal: a zipper along a narrow seam, no new vertices. Diagonals that
    are already ``edges`` (``(lo, hi)`` pairs) of the mesh are avoided. Returns faces.

    With ``normals`` (unit, per vertex), a corner whose triangle faces against the normal at
    any of its three corners is cut only when every corner does: such a triangle folds the
    patch back on itself. :func:`fill_small_holes` zips this way a loop whose plain zip
    crosses the mesh: on a hole that wraps round the rim of a thin part (both faces of an
    ear on one loop) the shortest diagonals cross the part's thickness and build a membrane
    through the part that crosses its other face.
    """
    ring = [int(x) for x in loop]
    edges = edges if edges is not None else set()
    out = []
    while len(ring) > 3:
        p = vertices[ring]
        prev, nxt = np.roll(p, 1, axis=0), np.roll(p, -1, axis=0)
        diag = np.linalg.norm(prev - nxt, axis=1)
        k = len(ring)
        for i in range(k):
            a, b = ring[(i - 1) % k], ring[(i + 1) % k]
            if (min(a, b), max(a, b)) in edges:
                diag[i] = np.inf
        if normals is not None:
            # corner i's triangle (i - 1, i, i + 1) against the normals at its corners
            tri_n = np.cross(p - prev, nxt - prev)
            n = normals[ring]
            folds = (
                (np.einsum("ij,ij->i", tri_n, n) < 0)
                | (np.einsum("ij,ij->i", tri_n, np.roll(n, 1, axis=0)) < 0)
                | (np.einsum("ij,ij->i", tri_n, np.roll(n, -1, axis=0)) < 0)
            )
            if not np.all(folds | ~np.isfinite(diag)):
                diag[folds] = np.inf
        i = int(np.argmin(diag))
        a, b = ring[(i - 1) % k], ring[(i + 1) % k]
        edges.add((min(a, b), max(a, b)))
        out.append([ring[(i - 1) % k], ring[i], ring[(i + 1) % k]])
        del ring[i]
    out.append(ring)
    return np.asarray(out, dtype=np.int64)


def rezip_crossing_loops(
    vertices: np.ndarray,
    normals: np.ndarray,
    faces: np.ndarray,
    loops: list[np.ndarray],
    patches: list[np.ndarray],
    edges: set[tuple[int, int]],
) -> list[np.ndarray]:
    """Zip again, fold-free (:func:`zip_loop` with ``normals``), each loop whose patch crosses
    the mesh or another patch and whose rim normals disagree (the loop wraps round a thin
    part); the new patch is kept when fewer crossings are left after untangling around it
    (shallow crossings untangle; a patch through a thin part's other face cannot). ``loops``
    are in the winding of the patches; ``edges`` holds the mesh's and the patches' edges.

    Only the faces near the loops take part: a patch lies inside its loop's bounding ball
    (centre ``m``, radius ``R``; it has no vertex off the loop), so a face that crosses it
    overlaps that ball, and the faces :func:`_left_after_untangle` untangles lie within
    ``3 R + UNTANGLE_MARGIN`` of ``m``. One grid search (:func:`faces_near_balls`) finds
    them for all loops at once; the result is the same as over the whole mesh.
    """
    if not patches:
        return patches
    centre = np.array([vertices[loop].mean(axis=0) for loop in loops])
    extent = np.array(
        [
            np.linalg.norm(vertices[loop] - c, axis=1).max()
            for loop, c in zip(loops, centre, strict=True)
        ]
    )
    # the untangling reach, padded against rounding: a superset is all that is needed
    reach = (3.0 * extent + UNTANGLE_MARGIN) * (1.0 + 1e-9) + 1e-9
    near, ball = faces_near_balls(vertices, faces, centre, reach)
    mid, size = face_spheres(vertices, faces[near])
    touches = np.linalg.norm(mid - centre[ball], axis=1) <= (extent[ball] + size) * (1.0 + 1e-9)
    local = faces[np.unique(near[touches])]
    owner = np.repeat(np.arange(len(patches)), [len(p) for p in patches])
    every = np.vstack([local, *patches])
    pairs = self_intersections(vertices, every, np.arange(len(local), len(every)))
    if not len(pairs):
        return patches
    hit = pairs[pairs >= len(local)] - len(local)
    crossings = np.bincount(owner[hit], minlength=len(patches))
    order = np.argsort(ball, kind="stable")  # each loop's faces, in face order
    bounds = np.searchsorted(ball[order], np.arange(len(patches) + 1))
    patches = list(patches)
    for k in np.flatnonzero(crossings):
        rim = normals[loops[k]]
        if np.min(rim @ rim.sum(axis=0)) >= 0:
            continue  # one sheet: the loop does not wrap round a thin part
        ring = set(int(x) for x in loops[k])
        where = {int(v): i for i, v in enumerate(loops[k])}
        own = {
            (min(a, b), max(a, b))
            for a, b in patches[k][:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
            if not ({int(a), int(b)} <= ring and abs(_ring_step(loops[k], a, b, where)) == 1)
        }
        alt = zip_loop(vertices, loops[k], edges - own, normals)
        # the mesh faces and the other patches within the untangling reach, in their order
        close = np.linalg.norm(centre - centre[k], axis=1) <= extent + reach[k]
        others = np.vstack(
            [
                faces[near[order[bounds[k] : bounds[k + 1]]]],
                *(patches[j] for j in np.flatnonzero(close) if j != k),
            ]
        )
        if _left_after_untangle(vertices, others, alt) < _left_after_untangle(
            vertices, others, patches[k]
        ):
            edges -= own
            edges |= {(min(a, b), max(a, b)) for a, b in alt[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)}
            patches[k] = alt
    return patches


def _left_after_untangle(vertices: np.ndarray, faces: np.ndarray, patch: np.ndarray) -> int:
    """Crossings a patch leaves once the mesh around it is untangled (the fit's repair):
    :func:`recon.intersections.untangle` on the faces near the patch, their rim held."""
    every = np.vstack([faces, patch])
    centre = vertices[patch.reshape(-1)]
    reach = float(np.linalg.norm(centre - centre.mean(axis=0), axis=1).max()) + UNTANGLE_MARGIN
    near = np.linalg.norm(vertices[every].mean(axis=1) - centre.mean(axis=0), axis=1) <= reach
    local = every[near]
    used, inv = np.unique(local, return_inverse=True)
    sub = inv.reshape(-1, 3)
    e, c = count_edge_faces(sub)
    fixed = np.zeros(len(used), dtype=bool)
    fixed[e[c == 1].reshape(-1)] = True
    return untangle(vertices[used], sub, fixed=fixed)[2]


def _ring_step(loop: np.ndarray, a: int, b: int, where: dict[int, int] | None = None) -> int:
    """Steps along the loop from vertex ``a`` to ``b`` (+-1 for a rim edge). ``where``: each
    vertex's position on the loop, when the caller has it (built here when None)."""
    if where is None:
        where = {int(v): i for i, v in enumerate(loop)}
    d = (where[int(b)] - where[int(a)]) % len(loop)
    return 1 if d == 1 else -1 if d == len(loop) - 1 else d


def _closest_pair(pa: np.ndarray, pb: np.ndarray) -> tuple[int, int]:
    """``(i, j)`` of the closest ``pa[i]``, ``pb[j]``, the first in row-major order on a tie
    (as the argmin of their whole distance matrix, without the ``m x n`` matrix: each row's
    nearest from a k-d tree, then the rows within rounding of the least measured exactly;
    loops small enough for one block are measured whole)."""
    if len(pa) == 0 or len(pb) == 0:
        raise ValueError("the closest pair of an empty loop")
    if len(pa) * len(pb) <= PAIR_BLOCK * 64:
        rows = np.arange(len(pa))
    else:
        near, _ = cKDTree(pb).query(pa)
        rows = np.flatnonzero(near <= near.min() * (1.0 + 1e-9))
    best = (np.inf, 0, 0)
    step = max(1, PAIR_BLOCK * 64 // len(pb))  # rows per block: ~64k distances
    for start in range(0, len(rows), step):  # many rows tie on symmetric loops
        block = rows[start : start + step]
        dist = np.linalg.norm(pa[block][:, None, :] - pb[None, :, :], axis=2)
        r, j = np.unravel_index(np.argmin(dist), dist.shape)
        if dist[r, j] < best[0]:
            best = (float(dist[r, j]), int(block[r]), int(j))
    return best[1], best[2]


def loft_loops(
    vertices: np.ndarray, a: np.ndarray, b: np.ndarray, directed: bool = False
) -> np.ndarray:
    """Faces ``(len(a) + len(b), 3)`` of a strip (an annulus) joining two closed loops.

    The loops are walked side by side from their closest pair of vertices along the strip
    whose new edges are shortest in total (Fuchs, Kedem & Uselton 1977:
    :func:`recon.kernels.loft.loft_path_kernel`), in the direction of ``b`` that gives the
    shorter one. No vertex is added. Winding is left to the caller; the faces run ``a``'s
    edges in its order and ``b``'s against its order. ``directed``: ``b`` is walked in its
    given direction only, so that this winding is the one the caller's loops ask for (a tube
    between two oriented surfaces, :func:`first_clear_neck`).

    Examples
    --------
    >>> t = np.linspace(0, 2 * np.pi, 6, endpoint=False)
    >>> ring = np.stack([np.cos(t), np.sin(t), np.zeros(6)], axis=1)
    >>> v = np.concatenate([ring, ring + [0, 0, 1]])
    >>> loft_loops(v, np.arange(6), np.arange(6, 12)[::-1]).shape
    (12, 3)
    """
    a, b = np.asarray(a, dtype=np.int64), np.asarray(b, dtype=np.int64)
    m, n = len(a), len(b)
    i0, j0 = _closest_pair(vertices[a], vertices[b])
    a = np.roll(a, -int(i0))
    b_fwd = np.roll(b, -int(j0))
    best = None
    for bb in (b_fwd,) if directed else (b_fwd, np.roll(b_fwd[::-1], 1)):
        steps = np.empty(m + n - 2, dtype=np.int8)
        pa = np.ascontiguousarray(vertices[a], dtype=np.float64)
        pb = np.ascontiguousarray(vertices[bb], dtype=np.float64)
        total = loft_path_kernel(pa, pb, steps)
        if best is None or total < best[0]:
            best = (total, bb, steps)
    _, b, steps = best
    # close from (m - 1, n - 1) to (m, n) = (0, 0) through the edge (a_0, b_n-1) unless the
    # path already used it (it ran up the whole of b first): then through (a_m-1, b_0)
    last = np.array([1, 0] if steps[: n - 1].all() else [0, 1], dtype=np.int8)
    steps = np.concatenate([steps, last])
    i = np.concatenate([[0], np.cumsum(steps == 0)[:-1]])
    j = np.concatenate([[0], np.cumsum(steps == 1)[:-1]])
    step_a = steps == 0
    return np.stack([a[i % m], np.where(step_a, a[(i + 1) % m], b[(j + 1) % n]), b[j % n]], axis=1)


def loft_nearest_loops(
    vertices: np.ndarray,
    faces: np.ndarray,
    max_gap: float,
    spacing: np.ndarray | None = None,
    normals: np.ndarray | None = None,
) -> np.ndarray:
    """``faces`` with each pair of mutually nearest boundary loops joined by a strip
    (:func:`loft_loops`), when each loop's vertices lie within ``max_gap`` of the other's in
    median (times the median ``spacing`` (per vertex) at the two loops' vertices). With
    ``normals`` (per vertex), only the rims of a thin part's two faces are paired: loops
    that face opposite ways, each behind the other, seen from either (:func:`_two_faces`).

    This closes the edge of a part thinner than a spacing again where the faces across it
    were dropped (:func:`recon.triangulate.triangulate_particles`): the rims of its two faces
    are two loops side by side.

    Examples
    --------
    Two discs (fans round a centre) half a unit apart become one closed surface:

    >>> t = np.linspace(0, 2 * np.pi, 8, endpoint=False)
    >>> ring = np.stack([np.cos(t), np.sin(t), np.zeros(8)], axis=1)
    >>> v = np.concatenate([ring, ring + [0, 0, 0.5], [[0, 0, 0], [0, 0, 0.5]]])
    >>> k = np.arange(8)
    >>> fans = [np.stack([np.full(8, c), o + (k + 1) % 8, o + k], 1) for c, o in ((16, 0), (17, 8))]
    >>> loft_nearest_loops(v, np.concatenate(fans), 2.0).shape
    (32, 3)
    """
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    loops = [loop for loop in boundary_loops(faces) if len(loop) >= 3]
    if len(loops) < 2:
        return faces
    trees = [cKDTree(vertices[loop]) for loop in loops]
    # A pair's median gap is at least its loops' closest approach, and a strip needs it
    # within max_gap x (the pair's median spacing): only pairs whose vertices come that close
    # (at the largest spacing) are measured. Each loop's nearest loop, where a strip could
    # join them, is the one a measure of every pair finds (a shattered mesh has thousands of
    # loops: every pair took 106 s on one, and their matrix grows as the loops squared).
    reach = max_gap * (1.0 if spacing is None else float(np.max(spacing[np.concatenate(loops)])))
    owner = np.repeat(np.arange(len(loops)), [len(loop) for loop in loops])
    pairs = _close_owner_pairs(vertices[np.concatenate(loops)], owner, reach)
    if normals is not None:  # only the two faces of a thin part are candidates
        faces_of_part = [
            _two_faces(vertices, normals, loops[i], loops[j], (trees[i], trees[j]))
            for i, j in pairs
        ]
        pairs = pairs[np.array(faces_of_part, dtype=bool).reshape(-1)]
    gap = np.array(
        [
            max(
                np.median(trees[j].query(vertices[loops[i]])[0]),
                np.median(trees[i].query(vertices[loops[j]])[0]),
            )
            for i, j in pairs
        ]
    )
    # each loop's nearest measured loop (the lower index on a tie, as argmin), or -1
    rows = np.concatenate([pairs[:, 0], pairs[:, 1]])
    cols = np.concatenate([pairs[:, 1], pairs[:, 0]])
    both = np.concatenate([gap, gap])
    order = np.lexsort((cols, both, rows))
    first = order[np.r_[True, rows[order][1:] != rows[order][:-1]]] if len(order) else order
    nearest = np.full(len(loops), -1, dtype=np.int64)
    nearest[rows[first]] = cols[first]
    best = np.full(len(loops), np.inf)
    best[rows[first]] = both[first]
    strips = []
    for i, j in enumerate(nearest):
        if j < 0 or i >= j or nearest[j] != i:
            continue
        here = 1.0 if spacing is None else float(np.median(spacing[np.append(loops[i], loops[j])]))
        if best[i] <= max_gap * here:
            strips.append(loft_loops(vertices, loops[i], loops[j]))
    return np.concatenate([faces, *strips]) if strips else faces


#: Points per block of :func:`_close_owner_pairs`' search: a block's point pairs are
#: reduced to owner pairs before the next block, so memory stays bounded however many pairs.
PAIR_BLOCK = 1024


def _close_owner_pairs(points: np.ndarray, owner: np.ndarray, reach: float) -> np.ndarray:
    """``(m, 2)`` int64: the pairs of owners ``(a, b)``, ``a < b`` ascending, that own two
    ``points`` at most ``reach`` apart.

    Block by block: the point pairs themselves can be far too many to hold (a sheet that
    stopped at the particle cap has rims of tens of thousands of vertices, 75 million pairs
    within the reach: a 24 GB peak), while the owner pairs are few."""
    if len(points) < 2:
        return np.zeros((0, 2), dtype=np.int64)
    tree = cKDTree(points)
    n = int(owner.max()) + 1
    keys = []
    for start in range(0, len(points), PAIR_BLOCK):
        block = cKDTree(points[start : start + PAIR_BLOCK])
        near = block.sparse_distance_matrix(tree, reach, output_type="ndarray")
        a, b = owner[near["i"] + start], owner[near["j"]]
        keep = a < b  # each unordered pair once (the block meets both of its orders)
        keys.append(np.unique(a[keep].astype(np.int64) * n + b[keep]))
    key = np.unique(np.concatenate(keys))
    return np.stack([key // n, key % n], axis=1)


def _two_faces(
    vertices: np.ndarray, normals: np.ndarray, a: np.ndarray, b: np.ndarray, trees: tuple
) -> bool:
    """Are loops ``a`` and ``b`` the rims of a thin part's two faces? From either loop, over
    its vertices v with w the other loop's nearest vertex (``trees``: k-d trees of a's and
    b's vertices), the medians of n_v · n_w (they face opposite ways) and of
    n_v · (x_w − x_v) (the other lies behind, not in front as a wall facing it across a slot)
    are negative. Symmetric: the answer does not depend on which loop is ``a``."""

    def seen_from(p: np.ndarray, q: np.ndarray, tree_q: cKDTree) -> bool:
        nearest = q[tree_q.query(vertices[p])[1]]
        opposite = np.einsum("ij,ij->i", normals[p], normals[nearest])
        behind = np.einsum("ij,ij->i", normals[p], vertices[nearest] - vertices[p])
        return bool(np.median(opposite) < 0.0 and np.median(behind) < 0.0)

    return seen_from(a, b, trees[1]) and seen_from(b, a, trees[0])


def thicken_sheet(
    vertices: np.ndarray, faces: np.ndarray, half: float | np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """A one-sided open sheet as a thin closed body: two copies ``half`` off it along its
    (area-weighted) vertex normals (``half``: a number, or one per vertex of ``vertices``),
    the lower one turned over, joined round each of its simple boundary loops by a strip
    (one loop for a disc, one more per hole in it). Returns the new vertices (the upper
    copy, then the lower one, in the order of ``np.unique(faces)``) and faces indexing them.

    Examples
    --------
    >>> v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)
    >>> nv, nf = thicken_sheet(v, np.array([[0, 1, 2]]), 0.1)
    >>> nv[:, 2].tolist(), len(nf)
    ([0.1, 0.1, 0.1, -0.1, -0.1, -0.1], 8)
    """
    used, local = np.unique(np.asarray(faces, dtype=np.int64), return_inverse=True)
    local = local.reshape(-1, 3)
    k = len(used)
    normal = np.zeros((k, 3))
    area = face_area_vectors(vertices[used], local)
    for c in range(3):
        np.add.at(normal, local[:, c], area)
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
    p = vertices[used]
    strips = []
    for rim in boundary_loops(local):
        a, b = rim, np.roll(rim, -1)
        strips += [np.stack([a, a + k, b], 1), np.stack([b, a + k, b + k], 1)]
    new_faces = np.concatenate([local, local[:, ::-1] + k, *strips])
    h = np.asarray(half, dtype=np.float64)
    if h.ndim:  # one per vertex of ``vertices``
        h = h[used][:, None]
    return np.concatenate([p + h * normal, p - h * normal]), new_faces


def neck_between(
    vertices: np.ndarray, faces: np.ndarray, a: np.ndarray, b: np.ndarray, candidates: int = 8
) -> np.ndarray | None:
    """Join two closed components by a short tube (a connected sum): ``faces`` without one
    face of each (``a``, ``b``: face indices) plus the strip between their corners
    (:func:`loft_loops`), at the closest of the ``candidates`` nearest pairs of faces whose
    tube crosses no face; None when every one crosses."""
    return first_clear_neck(vertices, faces, neck_candidates(vertices, faces, a, b, candidates)[0])


def first_clear_neck(
    vertices: np.ndarray, faces: np.ndarray, pairs: np.ndarray
) -> np.ndarray | None:
    """``faces`` joined by the tube between the first face pair of ``pairs`` ((m, 2), as
    :func:`neck_candidates` orders them) whose tube crosses no face: ``faces`` without the
    pair's two faces, the other faces in their order, then the tube's faces last; None when
    every tube crosses.

    The tube runs each removed face's edges the way that face ran them, as the faces beside
    it expect: with both parts wound outward it is wound outward too (a connected sum of
    oriented surfaces). A tube lofted the other way round (the shorter strip where the two faces lie
    side by side rather than face to face) joins the windings crosswise, and orienting the
    whole consistently turns one part inside out."""
    for fa, fb in np.asarray(pairs, dtype=np.int64).tolist():
        tube = loft_loops(vertices, faces[fa], faces[fb][::-1], directed=True)
        joined = np.concatenate([np.delete(faces, [fa, fb], axis=0), tube])
        subset = np.arange(len(joined) - len(tube), len(joined))
        if len(self_intersections(vertices, joined, subset)) == 0:
            return joined
    return None


class FailedTrials:
    """The parts whose last trial to join the body failed, each with the box [lo, hi] of the
    space its trial read: a join that adds or removes no face reaching into that box leaves
    its outcome as it was, so the part need not be tried again until one does
    (:func:`join_closed_parts`, :func:`recon.thin_sheets.thicken_sheets`)."""

    def __init__(self) -> None:
        self.boxes: dict[int, np.ndarray] = {}

    def add(self, k: int, points: np.ndarray, margin: float) -> None:
        pad = margin + ROUNDING_PAD * (float(np.abs(points).max()) + margin + 1.0)
        self.boxes[k] = np.stack([points.min(axis=0) - pad, points.max(axis=0) + pad])

    def __contains__(self, k: int) -> bool:
        return k in self.boxes

    def forget_near(self, points: np.ndarray) -> None:
        """A join changed the faces spanned by ``points``: retry the parts that read there."""
        lo, hi = points.min(axis=0), points.max(axis=0)
        for k in [k for k, box in self.boxes.items() if _boxes_meet(box, lo, hi)]:
            del self.boxes[k]

    def neck(
        self,
        k: int,
        vertices: np.ndarray,
        faces: np.ndarray,
        body: np.ndarray,
        part: np.ndarray,
        part_points: np.ndarray,
        largest_face: float,
    ) -> np.ndarray | None:
        """:func:`neck_between` the ``body`` and ``part`` faces of part ``k`` (its vertices:
        ``part_points``), kept in the memo: on success the parts that read near the part or
        its tube are forgotten (the body now holds both; the tube's ends were the two faces
        removed); on failure part ``k`` keeps the space its tubes read (they join faces up to
        the farthest candidate pair apart, and what they cross lies by them; ``largest_face``:
        the largest bounding radius of a face that can be removed later)."""
        pairs, gaps = neck_candidates(vertices, faces, body, part)
        joined = first_clear_neck(vertices, faces, pairs)
        if joined is None:
            self.add(k, part_points, float(gaps.max()) + 3.0 * largest_face)
            return None
        tube = joined[len(faces) - 2 :]  # last (first_clear_neck)
        self.forget_near(np.concatenate([part_points, vertices[tube.ravel()]]))
        return joined


def _boxes_meet(box: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> bool:
    return bool(np.all(box[0] <= hi) and np.all(lo <= box[1]))


def neck_candidates(
    vertices: np.ndarray, faces: np.ndarray, a: np.ndarray, b: np.ndarray, candidates: int = 8
) -> tuple[np.ndarray, np.ndarray]:
    """The face pairs :func:`neck_between` tries, in its order: each face of ``a`` with the
    face of ``b`` whose centroid is nearest, the ``candidates`` closest such pairs first
    (ties in the order of ``a``; (m, 2) face indices), and their centroid distances ((m,),
    ascending)."""
    ca, cb = vertices[faces[a]].mean(axis=1), vertices[faces[b]].mean(axis=1)
    dist, nearest = cKDTree(cb).query(ca)
    # stable: an exact tie goes to the face listed first, whatever else the array holds (a
    # join far away must not change which pairs a part is tried at: FailedTrials)
    order = np.argsort(dist, kind="stable")[:candidates]
    pairs = np.stack([np.asarray(a)[order], np.asarray(b)[nearest[order]]], axis=1)
    return pairs.astype(np.int64), dist[order]


def join_closed_parts(vertices: np.ndarray, faces: np.ndarray, reach: float) -> np.ndarray | None:
    """``faces`` with each closed component that comes within ``reach`` of the main body (the
    largest component) joined to it by a short tube (:func:`neck_between`, where the tube
    crosses no face); None when none is.

    A sparse thin part (a leg or an ear 2-5 point spacings thick) whose particles did not
    grow into the concave corner at its root is meshed as a closed part of its own, capped
    within a spacing of the body, which closed over the root. A closed part that near the
    body is the same surface: the data runs on from one to the other. An open part (the
    patches of an open scan) is left as it is. A joined part is part of the body for the
    next.
    """
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    n_v, joined_any, out = len(vertices), False, faces
    failed = FailedTrials()  # by the part's first vertex (parts share no vertex)
    open_parts: set[int] = set()
    while True:
        n, label = face_components(out, n_v)
        if n < 2:
            break
        body = int(np.argmax(np.bincount(label)))
        body_faces = np.flatnonzero(label == body)
        tree = cKDTree(vertices[np.unique(out[body_faces])])
        largest_face = float(face_spheres(vertices, out)[1].max())  # bounding radius
        joined = None
        for k in range(n):
            part = np.flatnonzero(label == k)
            if k == body:
                continue
            used = np.unique(out[part])
            key = int(used[0])
            if key in failed or key in open_parts:
                continue
            if boundary_loops(out[part]):
                open_parts.add(key)  # an open part is never joined
                continue
            if tree.query(vertices[used])[0].min() > reach:
                failed.add(key, vertices[used], reach)  # no body vertex within reach of it
                continue
            joined = failed.neck(key, vertices, out, body_faces, part, vertices[used], largest_face)
            if joined is not None:
                break
        if joined is None:
            break
        out, joined_any = joined, True
    return out if joined_any else None
