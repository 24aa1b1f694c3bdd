"""Self-intersections of a triangle mesh: find them, and untangle the ones a fit leaves.

A mesh that is watertight by its edges can still cross itself: where the two sheets of a thin
part (an ear, a blade) come closer than a particle spacing, or where a zipped seam folds over
its neighbours. Open3D's ``is_watertight()`` and mesh booleans, slicers and CGAL reject such a
mesh, so the fit removes them: :func:`untangle` moves only the vertices around crossing faces,
pass by pass, until none is left or the pass budget is spent.

Each pass smooths the vertices of the crossing faces and their one-ring halfway toward the
mean of their neighbours (a damped step of the umbrella operator; Taubin 1995, "A signal
processing approach to fair surface design", with lambda = 1/2): a flap
folded over its neighbour unfolds, and where two sheets cross, the dent that crosses flattens
back to its side. Only those vertices move; the rest of the mesh is untouched.

Smoothing cannot part two smooth sheets that cross at a shallow angle (the two sides of a part
that thins to an edge, a wide gentle dent): their vertices already sit at their neighbours'
mean. When the umbrella passes leave crossings, the faces of each crossing pair whose normals
are opposed (the two sides of a thin part, which face away from each other) are pushed apart,
each side along its own outward normal, a small step per pass, until they no longer cross
(:func:`separate_opposed`). Two sides of a part keep their order along their normals, so this
is the direction that parts them, whichever of the two had crossed over.

Neither moves a vertex farther than :data:`UNTANGLE_REACH` median edge lengths from where it
was before :func:`untangle` began: beside a long sliver (a face hanging off a stray particle)
the umbrella passes would otherwise walk a vertex toward the far corner without bound. A
crossing that cannot be cleared within that reach is left, and counted.

Candidate pairs come from a cell grid over face centroids (bounding spheres that overlap,
:func:`recon.kernels.sphere_pairs.sphere_pairs`; a k-d tree when no grid fits); the exact test
is :func:`recon.kernels.tri_intersect.pairs_intersect`. Pairs sharing a vertex are not tested,
as in Open3D's ``get_self_intersecting_triangles``.

Whether two faces cross depends on their six corners alone, so over the passes of
:func:`untangle` and :func:`separate_opposed` every crossing pair is kept (:class:`_Crossings`)
and only the pairs of the faces a pass moved are searched again, not those of every face moved
so far: the same pairs as a search of the faces each pass asks about, where the test answers
every pair the same whichever of its faces it is tested from (:func:`_order_free`; else they
search as before)."""

from __future__ import annotations

import numpy as np
from scipy import sparse
from scipy.spatial import cKDTree

from .kernels.grid_query import coordinate_extent
from .kernels.mesh_tables import bounding_spheres
from .kernels.options import query_workers, thread_limit
from .kernels.sphere_pairs import sphere_pairs
from .kernels.tri_intersect import order_free, pairs_intersect
from .mesh import face_normals
from .neighbors import PARALLEL_MIN_PARTICLES

__all__ = [
    "UNTANGLE_PASSES",
    "UNTANGLE_STEP",
    "SEPARATE_PASSES",
    "SEPARATE_STEP",
    "UNTANGLE_REACH",
    "ROUNDING_PAD",
    "median_edge",
    "within_reach",
    "face_spheres",
    "faces_near_balls",
    "self_intersections",
    "separate_opposed",
    "untangle",
]

#: Passes of :func:`untangle` (each smooths around the crossing faces once).
UNTANGLE_PASSES = 30
#: Weight of the neighbours' mean in one umbrella step (1/2: halfway).
UNTANGLE_STEP = 0.5
#: Passes of :func:`separate_opposed` after the umbrella passes (each pushes once).
SEPARATE_PASSES = 20
#: How far one :func:`separate_opposed` pass moves a vertex along its crossing faces' normal,
#: in median edge lengths of the mesh (20 passes: at most one edge length in all).
SEPARATE_STEP = 0.05
#: How far :func:`untangle` (its umbrella passes and :func:`separate_opposed` together) may move
#: a vertex from where it was, in median edge lengths. A crossing it can clear lies between
#: sheets closer than a spacing; an umbrella step stays within a vertex's one ring and the
#: pushes add at most one edge length (``SEPARATE_PASSES * SEPARATE_STEP``): over the 27 dev
#: cases no vertex moved more than 2.0 edge lengths (bunny-noise1; the median edge is shorter
#: than the spacing where the density varies), so 4 leaves room. Without a bound, a vertex
#: beside a long sliver (a face hanging off a stray particle) walks toward its far corner pass
#: after pass (a sphere with 5 % outliers: 295 edge lengths); what the bound leaves crossing is
#: counted as left.
UNTANGLE_REACH = 4.0
#: Faces larger than this many times the median bounding radius are paired one by one rather
#: than through the common search radius (which would then hold too many pairs).
LARGE_FACE = 3.0
#: A crossing search for a subset of the faces runs on the faces near the subset alone when
#: they are at most this share of the mesh (:func:`_near_marked`).
LOCAL_SHARE = 0.5
#: Relative widening of a box that must hold every sphere an exact floating-point test could
#: find overlapping (many times the rounding of a sum or a square root, 2.2e-16).
ROUNDING_PAD = 1e-9


def candidate_pairs(
    vertices: np.ndarray, faces: np.ndarray, subset: np.ndarray | None = None
) -> np.ndarray:
    """Face pairs ``(m, 2)``, ``i < j``, whose bounding spheres (centroid, farthest corner)
    overlap: a superset of the intersecting pairs (with ``subset``: of those pairs, the ones
    with a face in ``subset``).

    Pairs of ordinary faces come from one search radius (twice the largest ordinary bounding
    radius); the few faces larger than ``LARGE_FACE`` times the median search with their own
    radius, so that one large face does not widen every search, and are paired among
    themselves the same way, one level up (:func:`_overlapping`).
    """
    return _face_pairs(vertices, faces, subset, crossing=False)


def _face_pairs(
    vertices: np.ndarray, faces: np.ndarray, subset: np.ndarray | None, crossing: bool
) -> np.ndarray:
    """:func:`candidate_pairs`, or with ``crossing`` only those that cross (tested on the
    grid as they are found: the candidates are never held)."""
    n = len(faces)
    if n < 2:
        return np.zeros((0, 2), dtype=np.int64)
    centroid, radius = face_spheres(vertices, faces)
    mark = np.ones(n, dtype=np.bool_)
    if subset is not None:
        mark[:] = False
        mark[np.asarray(subset, dtype=np.int64)] = True
        near = _near_marked(centroid, radius, mark)
        if near is not None:  # the search on the faces that can meet the subset's only
            test = (vertices, faces[near]) if crossing else None
            key = _overlapping(centroid[near], radius[near], mark[near], test)
            m = len(near)  # near ascending: local key order is the global (i, j) order
            return np.stack([near[key // m], near[key % m]], axis=1)
    test = (vertices, faces) if crossing else None
    key = _overlapping(centroid, radius, mark, test)
    return np.stack([key // n, key % n], axis=1)


def _near_marked(centroid: np.ndarray, radius: np.ndarray, mark: np.ndarray) -> np.ndarray | None:
    """Indices (ascending) of the spheres that reach into the bounding box of the marked
    spheres, the marked ones included: every sphere that can overlap a marked one, since two
    overlapping spheres each reach into the other's box. None when that is more than
    ``LOCAL_SHARE`` of them (a search over all costs about the same then), or when a sphere
    is not finite (the search of the whole mesh decides what that means).

    A subset is usually a few faces being tried (a tube, a patch, a thickened sheet) in a big
    mesh: the grid search then runs on the faces round them, not on the whole mesh. The box
    is widened by ``ROUNDING_PAD`` times the mesh's largest coordinate or radius, so that
    the rounding of the exact test (``|c_i - c_j| <= r_i + r_j`` in floating point, whose
    sum rounds to the larger radius) never keeps a pair the box left out."""
    marked = np.flatnonzero(mark)
    if len(marked) == 0 or len(marked) > LOCAL_SHARE * len(mark):
        return None
    if not (np.isfinite(centroid).all() and np.isfinite(radius).all()):
        return None
    r = radius[marked, None]
    scale = float(np.abs(centroid).max()) + float(radius.max()) + 1.0
    lo = (centroid[marked] - r).min(axis=0) - ROUNDING_PAD * scale
    hi = (centroid[marked] + r).max(axis=0) + ROUNDING_PAD * scale
    reach = radius[:, None]
    inside = np.all((centroid + reach >= lo) & (centroid - reach <= hi), axis=1)
    inside |= mark
    if np.count_nonzero(inside) > LOCAL_SHARE * len(mark):
        return None
    return np.flatnonzero(inside)


def face_spheres(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each face's bounding sphere: its centroid and the distance to its farthest corner."""
    v, f = np.asarray(vertices), np.asarray(faces)
    if v.dtype == np.float64 and v.ndim == 2 and f.ndim == 2 and f.dtype.kind in "iu":
        # a kernel with the bits of the NumPy expression below, without its (F, 3, 3) arrays
        return bounding_spheres(np.ascontiguousarray(v), np.ascontiguousarray(f, dtype=np.int64))
    corners = vertices[faces]
    centroid = corners.mean(axis=1)
    return centroid, np.linalg.norm(corners - centroid[:, None, :], axis=2).max(axis=1)


def faces_near_balls(
    vertices: np.ndarray, faces: np.ndarray, centres: np.ndarray, radii: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Faces whose bounding sphere (centroid, farthest corner) overlaps one of the balls
    ``(centres[k], radii[k])``: one grid search for all balls (:func:`_overlapping`), so that a
    search around many small regions of a big mesh costs one pass, not one per region.

    Returns
    -------
    face_idx, ball_idx : (m,) int64
        The overlapping pairs, sorted by face, then ball.
    """
    n = len(faces)
    centroid, radius = face_spheres(vertices, faces)
    mark = np.zeros(n + len(centres), dtype=np.bool_)
    mark[n:] = True
    key = _overlapping(
        np.vstack([centroid, np.asarray(centres, dtype=np.float64).reshape(-1, 3)]),
        np.concatenate([radius, np.asarray(radii, dtype=np.float64)]),
        mark,
    )
    total = n + len(centres)
    face, ball = key // total, key % total
    keep = face < n  # not a pair of two balls
    return face[keep], ball[keep] - n


def _overlapping(
    centroid: np.ndarray,
    radius: np.ndarray,
    mark: np.ndarray,
    test: tuple[np.ndarray, np.ndarray] | None = None,
) -> np.ndarray:
    """Sorted keys ``i n + j`` (``i < j``) of the overlapping bounding spheres with a marked
    sphere. On the cell grid (:func:`recon.kernels.sphere_pairs.sphere_pairs`) the large
    spheres find their ordinary partners; pairs of two large ones come from the same search
    over the large ones alone (fewer than half at each level: above 3x the median), so no
    sphere is ever compared with all of a big mesh. With ``test`` (vertices, faces: one face
    per sphere), only the pairs of faces that cross."""
    n = len(centroid)
    if n < 2:
        return np.zeros(0, dtype=np.int64)
    large = radius > LARGE_FACE * max(float(np.median(radius)), 1e-300)
    r_small = float(radius[~large].max()) if np.any(~large) else 0.0
    extent = coordinate_extent(np.ascontiguousarray(centroid, dtype=np.float64))
    if not (r_small > 0.0 and np.prod(np.floor(3.0 * extent / (2.0 * r_small)) + 1.0) < 2.0**62):
        key = _tree_overlapping(centroid, radius, mark, large, r_small)
        if test is None or not len(key):
            return key
        pairs = np.stack([key // n, key % n], axis=1)
        hit = np.zeros(len(pairs), dtype=np.bool_)
        pairs_intersect(test[0], test[1], pairs, hit)
        return key[hit]
    vertices, faces = test if test is not None else (np.zeros((0, 3)), np.zeros((0, 3), np.int64))
    with thread_limit(n >= PARALLEL_MIN_PARTICLES):
        key = sphere_pairs(centroid, radius, mark, large, r_small, vertices, faces)
    big = np.flatnonzero(large)
    if len(big) < 2:
        return key
    among = _overlapping(
        centroid[big], radius[big], mark[big], None if test is None else (vertices, faces[big])
    )
    key = np.concatenate([key, big[among // len(big)] * n + big[among % len(big)]])
    key.sort()  # the two sets are disjoint (a pair of two large spheres, or not)
    return key


def _tree_overlapping(
    centroid: np.ndarray, radius: np.ndarray, mark: np.ndarray, large: np.ndarray, r_small: float
) -> np.ndarray:
    """:func:`_overlapping` on a k-d tree, where no cell grid fits (degenerate radii, or more
    cells than int64 keys)."""
    n = len(centroid)
    everything = bool(mark.all())
    tree = cKDTree(centroid)
    found = [np.zeros((0, 2), dtype=np.int64)]
    if everything:
        found.append(tree.query_pairs(2.0 * r_small, output_type="ndarray").astype(np.int64))
    else:
        queries = np.flatnonzero(mark & ~large)
        found.append(_around(tree, centroid, queries, radius[queries] + r_small))
    big = np.flatnonzero(large)
    if len(big):
        found.append(_around(tree, centroid, big, radius[big] + radius.max()))
    pairs = np.vstack(found)
    gap = np.linalg.norm(centroid[pairs[:, 0]] - centroid[pairs[:, 1]], axis=1)
    pairs = pairs[gap <= radius[pairs[:, 0]] + radius[pairs[:, 1]]]
    if not everything:
        pairs = pairs[mark[pairs[:, 0]] | mark[pairs[:, 1]]]
    key = pairs[:, 0] * n + pairs[:, 1]
    # a pair may have been found twice (by both its faces, or also as a large face's);
    # query_pairs alone finds each pair once, and then sorting is all np.unique would do
    return np.sort(key) if everything and len(big) == 0 else np.unique(key)


def _around(tree: cKDTree, centroid: np.ndarray, faces: np.ndarray, reach: np.ndarray):
    """Pairs ``(i, j)``, ``i < j``, of each face i of ``faces`` with every face whose centroid
    lies within ``reach`` of i's (one vectorised query)."""
    if len(faces) == 0:
        return np.zeros((0, 2), dtype=np.int64)
    near = tree.query_ball_point(centroid[faces], reach, workers=query_workers())
    counts = np.fromiter((len(x) for x in near), dtype=np.int64, count=len(near))
    other = (
        np.concatenate([np.asarray(x, dtype=np.int64) for x in near])
        if counts.sum()
        else np.zeros(0, dtype=np.int64)
    )
    own = np.repeat(faces, counts)
    keep = other != own
    own, other = own[keep], other[keep]
    return np.stack([np.minimum(own, other), np.maximum(own, other)], axis=1)


def self_intersections(
    vertices: np.ndarray, faces: np.ndarray, subset: np.ndarray | None = None
) -> np.ndarray:
    """Pairs of faces ``(m, 2)`` that cross each other (sharing no vertex); with ``subset``
    (face indices), only the pairs with a face in it.

    Examples
    --------
    >>> v = np.array([[0, 0, 0], [2, 0, 0], [0, 2, 0], [.5, .5, -1], [.5, .5, 1], [1.5, 1.5, 0]])
    >>> self_intersections(v.astype(float), np.array([[0, 1, 2], [3, 4, 5]])).tolist()
    [[0, 1]]
    """
    vertices = np.ascontiguousarray(vertices, dtype=np.float64)
    faces = np.ascontiguousarray(faces, dtype=np.int64)
    return _face_pairs(vertices, faces, subset, crossing=True)


def median_edge(vertices: np.ndarray, faces: np.ndarray) -> float:
    """The median edge length of a mesh (0 with no faces)."""
    if len(faces) == 0:
        return 0.0
    edges = vertices[faces[:, [1, 2, 0]]] - vertices[faces]
    return float(np.median(np.linalg.norm(edges, axis=2)))


def within_reach(
    points: np.ndarray, origin: np.ndarray, reach: float, rows: np.ndarray | None = None
) -> np.ndarray:
    """Pull each of ``points[rows]`` (all rows when None) that lies farther than ``reach``
    from its ``origin`` back onto the sphere of radius ``reach`` round it, in place; the rows
    within reach are not touched (not a bit). Returns ``points``.

    >>> within_reach(np.array([[3.0, 4.0, 0.0], [0.5, 0.0, 0.0]]), np.zeros((2, 3)), 1.0)
    array([[0.6, 0.8, 0. ],
           [0.5, 0. , 0. ]])
    """
    rows = np.arange(len(points)) if rows is None else np.asarray(rows)
    if len(rows) == 0:
        return points
    offset = points[rows] - origin[rows]
    length = np.linalg.norm(offset, axis=1)
    far = length > reach
    if far.any():
        r = rows[far]
        points[r] = origin[r] + offset[far] * (reach / length[far])[:, None]
    return points


def _umbrella(faces: np.ndarray, n_vertices: int) -> sparse.csr_matrix:
    """Row-normalised vertex adjacency: ``A @ x`` is the mean of each vertex's neighbours."""
    e = faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    a = sparse.coo_matrix(
        (np.ones(2 * len(e)), (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])),
        shape=(n_vertices, n_vertices),
    ).tocsr()
    a.data[:] = 1.0
    deg = np.asarray(a.sum(axis=1)).ravel()
    return sparse.diags(1.0 / np.maximum(deg, 1.0)) @ a


#: Two faces' squared cross products closer than this (relative) may be equal as the crossing
#: test computes them (:func:`_order_free`): far above the rounding of any sum of three squares.
TIE_MARGIN = 1e-12
#: More faces than this in one run of possible ties: not worth sorting out (a flat grid).
TIE_RUN = 16


def _order_free(vertices: np.ndarray, faces: np.ndarray) -> bool:
    """Whether the crossing test gives every pair of ``faces`` the same answer either way round
    (:func:`recon.kernels.tri_intersect.order_free`): then which face of a pair the grid search
    tests it from (which depends on the subset searched) does not matter."""
    return bool(order_free(vertices, faces, TIE_MARGIN, TIE_RUN))


class _Crossings:
    """Every crossing pair of a mesh whose vertices move, kept by searching again only around
    the faces that moved (:meth:`moved`): whether two faces cross depends on their six corners
    alone, so a pair of faces neither of which moved crosses as it did.

    That holds when the test gives each pair the same answer whichever face it is tested from
    (:func:`_order_free`, checked at every state searched); where it might not, ``exact``
    turns False and the caller searches as before. ``pairs`` must hold every crossing pair of
    the start, or at least those that the caller will ask for before their faces move."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, pairs: np.ndarray) -> None:
        self.faces = faces
        self.n = len(faces)
        self.exact = _order_free(vertices, faces)
        keys = pairs[:, 0] * self.n + pairs[:, 1] if len(pairs) else np.zeros(0, np.int64)
        self.keys = np.unique(keys.astype(np.int64))

    def moved(self, vertices: np.ndarray, faces_moved: np.ndarray) -> bool:
        """Account for the new ``vertices``, of which only ``faces_moved`` have moved corners.
        False (and from then on) when the pairs can no longer be kept exactly."""
        if self.exact and len(faces_moved) == 0:
            return True  # no face has moved: every pair crosses as it did
        if not self.exact or not _order_free(vertices, self.faces):
            self.exact = False
            return False
        mask = np.zeros(self.n, dtype=bool)
        mask[faces_moved] = True
        keep = self.keys[~(mask[self.keys // self.n] | mask[self.keys % self.n])]
        new = self_intersections(vertices, self.faces, faces_moved)
        self.keys = np.sort(np.concatenate([keep, new[:, 0] * self.n + new[:, 1]]))
        return True

    def touching(self, mask: np.ndarray) -> np.ndarray:
        """The crossing pairs ``(m, 2)`` with a face in ``mask`` (F,), sorted: what
        :func:`self_intersections` returns for that subset."""
        i, j = self.keys // self.n, self.keys % self.n
        hit = mask[i] | mask[j]
        return np.stack([i[hit], j[hit]], axis=1)


def untangle(
    vertices: np.ndarray,
    faces: np.ndarray,
    passes: int = UNTANGLE_PASSES,
    step: float = UNTANGLE_STEP,
    fixed: np.ndarray | None = None,
    separate_passes: int = SEPARATE_PASSES,
    reach: float = UNTANGLE_REACH,
) -> tuple[np.ndarray, int, int]:
    """Smooth around crossing faces until the mesh no longer crosses itself; then part the
    opposed sheets that still cross (:func:`separate_opposed`).

    Parameters
    ----------
    vertices : (V, 3) float64
    faces : (F, 3) int64
    passes, step
        Pass budget, and the weight of the neighbours' mean in each umbrella step.
    fixed : (V,) bool, optional
        Vertices that never move (e.g. on a crease line: smoothing would round it).
    separate_passes : int
        Pass budget of :func:`separate_opposed` (0: smoothing only).
    reach : float
        How far a vertex may move in all [median edge lengths]; a vertex the passes would
        take farther stops at that distance from where it was (:data:`UNTANGLE_REACH`).

    Returns
    -------
    vertices, found, left
        The new vertices (a copy), the number of crossing face pairs found at the start and
        the number left (0 when the mesh is free of self-intersections). When the passes do
        not clear them, the state with the fewest crossings is returned.
    """
    vertices = np.array(vertices, dtype=np.float64)
    faces = np.ascontiguousarray(faces, dtype=np.int64)
    pairs = self_intersections(vertices, faces)
    found = len(pairs)
    if found == 0:
        return vertices, 0, 0
    mean_of_neighbours = _umbrella(faces, len(vertices))
    vertex_faces = _vertex_faces(faces, len(vertices))
    origin = vertices.copy()
    limit = reach * median_edge(vertices, faces)
    touched = np.zeros(len(faces), dtype=bool)  # the faces with a vertex moved so far
    first = pairs
    best, best_left = vertices.copy(), found
    start = best
    every = _Crossings(vertices, faces, pairs)
    best_every = every.keys if every.exact else None
    for _ in range(passes):
        crossing = np.unique(faces[pairs].ravel())
        ring = np.unique(faces[vertex_faces[crossing].indices].ravel())
        if fixed is not None:
            ring = ring[~fixed[ring]]
        target = mean_of_neighbours[ring] @ vertices
        vertices[ring] += step * (target - vertices[ring])
        within_reach(vertices, origin, limit, ring)
        # only faces with a vertex that has moved can have started or stopped crossing
        now = np.unique(vertex_faces[ring].indices)
        touched[now] = True
        # the pairs with a face touched so far: from every crossing pair, which only the faces
        # moved in this pass change (or, where that is not exact, a search of those faces)
        if every.moved(vertices, now):
            pairs = every.touching(touched)
        else:
            pairs = self_intersections(vertices, faces, np.flatnonzero(touched))
        if len(pairs) < best_left:
            best, best_left = vertices.copy(), len(pairs)
            best_every = every.keys if every.exact else None
        if len(pairs) == 0:
            break
    # the passes re-test only pairs with a face that moved: count what is left over all faces
    # (a crossing between fixed vertices, for one, never moves). A pair of faces that ``best``
    # did not move crosses as it did at the start; the others are searched again.
    left_pairs = _pairs_after_moving(start, best, faces, vertex_faces, first, best_every)
    if len(left_pairs):
        # smooth sheets crossing at a shallow angle: part the opposed ones
        parted, parted_left = separate_opposed(
            best, faces, separate_passes, fixed=fixed, pairs=left_pairs, origin=origin, reach=limit
        )
        if parted_left < len(left_pairs):
            return parted, found, parted_left
    return best, found, len(left_pairs)


def _vertex_faces(faces: np.ndarray, n_vertices: int) -> sparse.csr_matrix:
    """Vertex-face incidence: row v holds the faces with corner v."""
    return sparse.csr_matrix(
        (np.ones(faces.size), (faces.ravel(), np.repeat(np.arange(len(faces)), 3))),
        shape=(n_vertices, len(faces)),
    )


def _pairs_after_moving(
    start: np.ndarray,
    vertices: np.ndarray,
    faces: np.ndarray,
    vertex_faces: sparse.csr_matrix,
    first: np.ndarray,
    every: np.ndarray | None = None,
) -> np.ndarray:
    """Crossing pairs of ``vertices`` over all faces, given the pairs ``first`` of ``start``:
    a pair of faces that did not move crosses as it did; around the moved ones, a search (or,
    given ``every``, the sorted keys ``i F + j`` of every crossing pair of ``vertices``
    (:class:`_Crossings`), those pairs)."""
    shifted = np.flatnonzero(np.any(vertices != start, axis=1))
    touched = np.unique(vertex_faces[shifted].indices)
    was_moved = np.zeros(len(faces), dtype=bool)
    was_moved[touched] = True
    if every is None:
        around = self_intersections(vertices, faces, touched)
    else:
        i, j = every // len(faces), every % len(faces)
        hit = was_moved[i] | was_moved[j]
        around = np.stack([i[hit], j[hit]], axis=1)
    return np.vstack([first[~was_moved[first].any(axis=1)], around])


def separate_opposed(
    vertices: np.ndarray,
    faces: np.ndarray,
    passes: int = SEPARATE_PASSES,
    step: float = SEPARATE_STEP,
    fixed: np.ndarray | None = None,
    pairs: np.ndarray | None = None,
    origin: np.ndarray | None = None,
    reach: float | None = None,
) -> tuple[np.ndarray, int]:
    """Push crossing faces with opposed normals apart, each along its own normal.

    Each pass finds the crossing pairs, keeps those whose unit face normals point away from
    each other (n_a · n_b < 0: the two sides of a thin part) and moves every corner of their
    faces by ``step`` median edge lengths along the mean normal of its crossing faces there.
    Pairs with agreeing normals (a folded flap) are left to the umbrella passes of
    :func:`untangle`.

    Parameters
    ----------
    vertices : (V, 3) float64
    faces : (F, 3) int64, consistently oriented
    passes, step
        Pass budget, and the push of one pass [median edge lengths].
    fixed : (V,) bool, optional
        Vertices that never move.
    pairs : (m, 2) int, optional
        The crossing pairs of ``vertices`` over all faces, when the caller has them
        (:func:`self_intersections`; searched here when None).
    origin, reach
        No vertex moves farther than ``reach`` (a length) from its ``origin`` (V, 3) (default:
        ``vertices``, and :data:`UNTANGLE_REACH` median edge lengths).

    Returns
    -------
    vertices, left
        The state with the fewest crossing pairs over all faces (a copy) and that count.

    Examples
    --------
    Two sides of a thin part (top facing +z, bottom facing -z) whose dent crosses over:

    >>> v = np.array([[0, 0, 0], [2, 0, 0], [0, 2, 0],
    ...               [.5, .5, .1], [.5, 1.5, .1], [1.5, .5, -.3]], dtype=float)
    >>> f = np.array([[0, 1, 2], [3, 4, 5]])
    >>> len(self_intersections(v, f)), separate_opposed(v, f)[1]
    (1, 0)
    """
    vertices = np.array(vertices, dtype=np.float64)
    faces = np.ascontiguousarray(faces, dtype=np.int64)
    if pairs is None:
        pairs = self_intersections(vertices, faces)
    first = pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    start = vertices.copy()
    best, best_left = start, len(pairs)
    if best_left == 0:
        return best, best_left
    vertex_faces = _vertex_faces(faces, len(vertices))
    every = _Crossings(vertices, faces, first)  # only the pairs of moved faces are asked for
    edge = median_edge(vertices, faces)
    push = step * edge
    origin = start if origin is None else np.asarray(origin, dtype=np.float64)
    reach = UNTANGLE_REACH * edge if reach is None else reach
    for _ in range(passes):
        normals = face_normals(vertices, faces)
        opposed = np.einsum("ij,ij->i", normals[pairs[:, 0]], normals[pairs[:, 1]]) < 0.0
        if not opposed.any():
            break
        crossing = pairs[opposed].ravel()
        corners = faces[crossing].ravel()
        direction = np.zeros_like(vertices)
        np.add.at(direction, corners, np.repeat(normals[crossing], 3, axis=0))
        count = np.bincount(corners, minlength=len(vertices))
        move = count > 0
        if fixed is not None:
            move &= ~fixed
        if not move.any():
            break
        vertices[move] += push * direction[move] / count[move, None]
        within_reach(vertices, origin, reach, np.flatnonzero(move))
        followed = every.moved(vertices, np.unique(vertex_faces[np.flatnonzero(move)].indices))
        pairs = _pairs_after_moving(
            start, vertices, faces, vertex_faces, first, every.keys if followed else None
        )
        if len(pairs) < best_left:
            best, best_left = vertices.copy(), len(pairs)
        if best_left == 0:
            break
    return best, best_left
