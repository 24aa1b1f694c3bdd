"""Small geometric helpers shared by the stages: point validation, sizes, spacing, best-fit
planes and Poisson-disk thinning.

References
----------
[B07]     R. Bridson. "Fast Poisson disk sampling in arbitrary dimensions". SIGGRAPH sketches
          2007 (:mod:`recon.kernels.poisson_disk`).
[Hoppe92] H. Hoppe, T. DeRose, T. Duchamp, J. McDonald, W. Stuetzle. "Surface reconstruction
          from unorganized points". SIGGRAPH '92, Computer Graphics 26(2):71-78, 1992
          (tangent planes by PCA of k nearest neighbours, section 3.2).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from .kernels.options import query_workers
from .kernels.poisson_disk import poisson_disk_graded_kernel, poisson_disk_kernel

#: Seed of the subsample the median point spacing is measured on (inputs of more than 20,000
#: points): ``fit`` and ``info`` pass ``np.random.default_rng(SPACING_SAMPLE_SEED)``. Fixed, not
#: ``config.seed``: r0 is a property of the data, the same for every seed.
SPACING_SAMPLE_SEED = 0

__all__ = [
    "as_points",
    "bbox_diagonal",
    "fit_plane",
    "median_nearest_neighbor_distance",
    "median_variation",
    "SURROUND_RATIO",
    "surround_distances",
    "poisson_disk_thin",
    "poisson_disk_thin_graded",
    "snap_to_precision",
    "unit_vectors",
]


def as_points(
    points: Any,
    name: str = "points",
    *,
    rows: int | None = None,
    finite: bool = False,
    allow_single: bool = False,
    error: type[Exception] = ValueError,
) -> np.ndarray:
    """Check and convert an array of 3-D points: the one ``(n, 3)`` validator.

    Parameters
    ----------
    points : array_like, (n, 3)
    name : str
        Names the array in the error message.
    rows : int, optional
        Required number of rows.
    finite : bool
        Reject NaN and infinite coordinates (the message names the first bad row).
    allow_single : bool
        Accept one point of shape (3,) as (1, 3) (when ``rows`` is None or 1).
    error : exception class
        Raised on a bad array: ``ValueError`` for programming errors (default),
        :class:`~recon.errors.InputError` where the array comes from the user.

    Returns
    -------
    (n, 3) float64, C-contiguous

    Raises
    ------
    ValueError (or ``error``)
        Wrong shape (the message gives expected and received shapes), wrong row count, or a
        non-finite row when ``finite``.

    Examples
    --------
    >>> as_points([[0, 0, 1]]).dtype
    dtype('float64')
    """
    arr = np.ascontiguousarray(points, dtype=np.float64)
    if allow_single and arr.ndim == 1 and arr.shape[0] == 3 and rows in (None, 1):
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise error(f"{name}: expected shape (n, 3), got {arr.shape}")
    if rows is not None and arr.shape[0] != rows:
        raise error(f"{name}: expected {rows} rows, got {arr.shape[0]}")
    if finite:
        ok = np.isfinite(arr).all(axis=1)
        if not ok.all():
            first = int(np.flatnonzero(~ok)[0])
            raise error(f"{name}: row {first} is not finite ({arr[first]})")
    return arr


def bbox_diagonal(points: np.ndarray) -> float:
    """Length of the diagonal of the axis-aligned bounding box.

    Parameters
    ----------
    points : (n, 3) float64 [length]

    Returns
    -------
    float [length]
        0.0 for an empty array.

    Examples
    --------
    >>> bbox_diagonal(np.array([[0.0, 0.0, 0.0], [3.0, 4.0, 0.0]]))
    5.0
    """
    pts = as_points(points)
    if pts.shape[0] == 0:
        return 0.0
    return float(np.linalg.norm(pts.max(axis=0) - pts.min(axis=0)))


def median_nearest_neighbor_distance(
    points: np.ndarray,
    sample: int | None = 20000,
    *,
    rng: np.random.Generator,
    tree: cKDTree | None = None,
    nearest: np.ndarray | None = None,
) -> float:
    """Median distance from a point to its nearest other point (the data spacing).

    Parameters
    ----------
    points : (n, 3) float64 [length]
        At least 2 points.
    sample : int or None
        Query at most this many points (the tree always holds all of them); None = all.
    rng : numpy.random.Generator
        Chooses the sample when there are more than ``sample`` points (the fit passes
        ``np.random.default_rng(SPACING_SAMPLE_SEED)``).
    tree : scipy.spatial.cKDTree, optional
        A k-d tree of ``points`` already built (the fit shares one); built here when None.
    nearest : (n,) float64 [length], optional
        Each point's distance to its nearest other point when already known (the second
        column of the fit's shared k-nearest query: the values a k = 2 query gives, whoever
        the nearest is); the same sample is taken from it and no tree is queried.

    Returns
    -------
    float [length]
        Exactly repeated points count with distance 0.

    Examples
    --------
    >>> grid = np.stack(np.meshgrid(np.arange(4.0), np.arange(4.0), [0.0]), -1).reshape(-1, 3)
    >>> median_nearest_neighbor_distance(grid, rng=np.random.default_rng(0))
    1.0
    """
    pts = as_points(points)
    n = pts.shape[0]
    if n < 2:
        raise ValueError(f"points: need at least 2 points for a spacing, got {n}")
    rows = None
    if sample is not None and n > sample:
        rows = np.sort(rng.choice(n, size=sample, replace=False))
    if nearest is not None:
        return float(np.median(nearest if rows is None else nearest[rows]))
    tree = cKDTree(pts) if tree is None else tree
    dist, _ = tree.query(pts if rows is None else pts[rows], k=2, workers=query_workers())
    return float(np.median(dist[:, 1]))


#: Median surround distance (:func:`surround_distances`) over this many median nearest-neighbour
#: distances: the samples lie in lines (or clumps) farther apart than uniformly random samples
#: would be (3.4-3.5 for those: random points on a plane, the clean dev scans; a jittered grid
#: 1.8), and the point spacing is the surround distance over this
#: (:func:`recon.fitting.scale.sampled_spacing`). Lines D apart then get r0 = 2.5 D / 4 = D /
#: 1.6, no place more than 1.6 r0 from a sample, as random samples at the default r0 (3.4 /
#: 2.5 = 1.4).
SURROUND_RATIO = 4.0
#: Neighbours asked for by :func:`surround_distances`.
SURROUND_NEIGHBOURS = 32
#: Neighbours asked for, as a multiple of ``SURROUND_NEIGHBOURS``, where those do not surround
#: a point (scan lines over 16 times denser along than across).
SURROUND_WIDE = 8
#: A point is surrounded once its neighbours leave no angular gap wider than this [rad]
#: round it in its tangent plane (120 deg: three directions at least).
SURROUND_GAP = 2.0 * np.pi / 3.0


def surround_distances(
    points: np.ndarray,
    rows: np.ndarray,
    tree: cKDTree,
    k: int = SURROUND_NEIGHBOURS,
) -> np.ndarray:
    """For each of ``points[rows]``, how far its neighbours reach before they surround it:
    the distance of the nearest neighbour after which the neighbours so far, seen in the
    tangent plane (PCA of its ``k`` nearest [Hoppe92]), leave no angular gap wider than
    ``SURROUND_GAP`` round it.

    The nearest-neighbour distance tells how close samples are along the direction they are
    closest in; this tells how far apart they are across the direction they are farthest in.
    Uniformly random samples of a surface give about 3.4 median nearest-neighbour distances
    (2.3-3.5 on the 27 dev scans), a jittered grid about 1.8; scan lines ``D`` apart give
    ``D`` whatever the spacing along them.

    Parameters
    ----------
    points : (n, 3) float64 [length]
    rows : (m,) int
        The points to measure.
    tree : scipy.spatial.cKDTree
        A k-d tree of ``points``.
    k : int
        Neighbours asked for (fewer when there are fewer points).

    Returns
    -------
    (m,) float64 [length]
        A point the ``k`` nearest do not surround (dense scan lines) is measured again among
        its ``SURROUND_WIDE`` x ``k`` nearest; one these do not surround either (its
        neighbours all on one line, or on one side: a border, every point of a strip two
        rows wide) gets NaN: its distances say nothing of the spacing across.

    Examples
    --------
    >>> x, y = np.meshgrid(np.arange(40.0), np.arange(0.0, 40.0, 3.0))  # lines 3 apart
    >>> pts = np.c_[x.ravel(), y.ravel(), np.zeros(x.size)]
    >>> float(surround_distances(pts, np.array([7 * 40 + 20]), cKDTree(pts))[0])
    3.0
    """
    n_max = len(points) - 1
    k = min(int(k), n_max)
    if len(rows) == 0 or k < 2:
        return np.zeros(len(rows))
    out, left = _surround_within(points, rows, tree, k)
    wide = min(SURROUND_WIDE * k, n_max)
    if len(left) and wide > k:  # dense lines: their k nearest all on one line
        again, still = _surround_within(points, rows[left], tree, wide)
        out[left] = again
        left = left[still]
    out[left] = np.nan  # on one side of all its neighbours: a border, or a lone line
    return out


def _surround_within(
    points: np.ndarray, rows: np.ndarray, tree: cKDTree, k: int
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`surround_distances` among each row's ``k`` nearest, and the positions (in
    ``rows``) of those they do not surround (their distance: the ``k``-th)."""
    dist, nb = tree.query(points[rows], k + 1, workers=query_workers())
    dist, nb = dist[:, 1:], nb[:, 1:]
    offsets = points[nb] - points[rows][:, None, :]
    centred = offsets - offsets.mean(axis=1, keepdims=True)
    _, axes = np.linalg.eigh(np.matmul(centred.transpose(0, 2, 1), centred))
    plane = np.matmul(offsets, axes[:, :, 1:])  # (m, k, 2): along the two widest axes
    angle = np.arctan2(plane[:, :, 0], plane[:, :, 1])
    # the fewest nearest neighbours (j) that leave no gap: a gap only closes as j grows, so
    # bisect j between lo (not enough, or 2) and hi (enough, or k + 1: never)
    m = len(rows)
    lo, hi = np.full(m, 2), np.full(m, k + 1)
    hi[_max_gap(angle, np.full(m, k)) < SURROUND_GAP] = k
    while np.any(hi - lo > 1):
        mid = (lo + hi) // 2
        ok = _max_gap(angle, mid) < SURROUND_GAP
        hi = np.where(ok & (hi - lo > 1), mid, hi)
        lo = np.where(~ok & (hi - lo > 1), mid, lo)
    found = hi <= k
    out = dist[:, -1].copy()
    out[found] = dist[np.flatnonzero(found), hi[found] - 1]
    return out, np.flatnonzero(~found)


def _max_gap(angle: np.ndarray, count: np.ndarray) -> np.ndarray:
    """The widest angular gap [rad] round each row among its first ``count`` angles."""
    k = angle.shape[1]
    valid = np.arange(k)[None, :] < count[:, None]
    around = np.sort(np.where(valid, angle, 4.0), axis=1)  # the valid ones (<= pi) first
    steps = np.diff(around, axis=1)
    steps[~valid[:, 1:]] = 0.0  # (steps past the last valid angle)
    last = np.take_along_axis(around, (count - 1)[:, None], axis=1)[:, 0]
    return np.maximum(steps.max(axis=1), around[:, 0] + 2.0 * np.pi - last)


def fit_plane(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Least-squares plane through points (principal component analysis).

    Parameters
    ----------
    points : (n, 3) float64 [length]

    Returns
    -------
    centroid : (3,) float64 [length]
    normal : (3,) float64
        Unit direction of least variance (sign arbitrary).
    singular_values : (3,) float64 [length]
        Of the centred points, descending; ``singular_values[2]`` is 0 for planar input.
    """
    pts = as_points(points)
    centroid = pts.mean(axis=0)
    _, s, vt = np.linalg.svd(pts - centroid, full_matrices=True)
    sv = np.zeros(3)
    sv[: s.size] = s
    return centroid, vt[2], sv


def unit_vectors(vectors: np.ndarray) -> np.ndarray:
    """Rows scaled to unit length; zero rows stay zero.

    Parameters
    ----------
    vectors : (n, 3) float64

    Returns
    -------
    (n, 3) float64
    """
    v = np.asarray(vectors, dtype=np.float64)
    length = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.divide(v, length, out=np.zeros_like(v), where=length > 0)


def snap_to_precision(coordinates: np.ndarray) -> np.ndarray:
    """``coordinates`` (float64) rounded to multiples of the float64 resolution at their
    largest magnitude (one ulp of ``max |x|``, a power of two): the digits below it are
    rounding noise of the arithmetic that made them, not geometry.

    Near zero float64 resolves far finer than at the mesh's size, so a vertex on a face in the
    plane y = 0 keeps residues such as 5e-19. Snapped, they become exact zeros (never -0.0), and
    faces on the planes through 0 are exactly flat. Elsewhere a plane's coordinates keep the
    rounding they had (values in the largest's binade do not move; smaller ones move to the
    grid). Other tools' triangle tests, which are not exact, take nearly coplanar disjoint faces
    for crossing ones: Open3D's ``is_watertight()`` failed on an L-block fit for one pair on
    y = 0 (issue 11). Each coordinate moves by at most half an ulp of the largest. Scaling by
    a power of two and rounding to an integer are exact, so snapping twice is snapping once.
    An array holding NaN or inf (or only zeros) is returned as float64, unchanged.

    Examples
    --------
    >>> snap_to_precision(np.array([[1.0, 5e-19, -0.25], [-1e-20, 0.5, 0.75]]))
    array([[ 1.  ,  0.  , -0.25],
           [ 0.  ,  0.5 ,  0.75]])
    """
    x = np.asarray(coordinates, dtype=np.float64)
    if x.size == 0:
        return x
    largest = float(np.max(np.abs(x)))
    if not np.isfinite(largest) or largest == 0.0:
        return x
    quantum = float(np.spacing(np.ldexp(1.0, int(np.frexp(largest)[1]) - 1)))
    return np.round(x / quantum) * quantum + 0.0  # (+ 0.0: -0.0 becomes 0.0)


def poisson_disk_thin(
    points: np.ndarray, radius: float, order: np.ndarray | None = None, keep_first: int = 0
) -> np.ndarray:
    """Greedy Poisson-disk selection: keep a point unless a kept point lies within ``radius``.

    Parameters
    ----------
    points : (n, 3) float64 [length]
    radius : float [length]
    order : (n,) int, optional
        Visiting order (a permutation). Earlier points win. Default: index order.
    keep_first : int
        The first ``keep_first`` points of ``order`` are kept unconditionally (used to accept new
        candidates against existing particles placed first in the order).

    Returns
    -------
    keep : (n,) bool
        Kept points are pairwise at least ``radius`` apart (except among the forced ones).

    Examples
    --------
    >>> poisson_disk_thin(np.array([[0.0, 0, 0], [0.5, 0, 0], [2, 0, 0]]), 1.0).tolist()
    [True, False, True]
    """
    points = np.ascontiguousarray(points, dtype=np.float64)
    if order is None:
        order = np.arange(len(points), dtype=np.int64)
    if radius <= 0:
        raise ValueError(f"radius must be > 0, got {radius}")
    return poisson_disk_kernel(
        points, np.ascontiguousarray(order, dtype=np.int64), float(radius), int(keep_first)
    )


def poisson_disk_thin_graded(
    points: np.ndarray, radius: np.ndarray, order: np.ndarray | None = None, keep_first: int = 0
) -> np.ndarray:
    """Greedy Poisson-disk selection with a radius per point: keep point i unless a kept point
    j lies within (r_i + r_j) / 2 (the kept density goes as 1 / r²).

    Parameters
    ----------
    points : (n, 3) float64 [length]
    radius : (n,) float64 [length], > 0
    order, keep_first
        As for :func:`poisson_disk_thin`.

    Returns
    -------
    keep : (n,) bool

    Examples
    --------
    >>> pts = np.array([[0.0, 0, 0], [0.5, 0, 0], [2, 0, 0], [2.5, 0, 0]])
    >>> poisson_disk_thin_graded(pts, np.array([1.0, 1.0, 0.2, 0.2])).tolist()
    [True, False, True, True]
    """
    points = np.ascontiguousarray(points, dtype=np.float64)
    radius = np.ascontiguousarray(radius, dtype=np.float64)
    if radius.shape != (len(points),):
        raise ValueError(f"radius must have shape ({len(points)},), got {radius.shape}")
    if len(radius) and not np.all(radius > 0):
        raise ValueError("radius must be > 0")
    if order is None:
        order = np.arange(len(points), dtype=np.int64)
    return poisson_disk_graded_kernel(
        points, np.ascontiguousarray(order, dtype=np.int64), radius, int(keep_first)
    )


def median_variation(
    points: np.ndarray, k: int, sample: int = 4000, tree: cKDTree | None = None
) -> float:
    """Median PCA surface variation ``l0 / (l0 + l1 + l2)`` of the k-neighbourhoods of up to
    ``sample`` evenly picked points: near 0 on clean surfaces, growing with noise."""
    n = len(points)
    idx = np.linspace(0, n - 1, min(n, sample)).astype(np.int64)
    tree = cKDTree(points) if tree is None else tree
    _, nb = tree.query(points[idx], k=min(k, n), workers=query_workers())
    q = points[nb] - points[nb].mean(axis=1, keepdims=True)
    ev = np.linalg.eigvalsh(np.einsum("mki,mkj->mij", q, q))
    return float(np.median(ev[:, 0] / np.maximum(ev.sum(axis=1), 1e-300)))
