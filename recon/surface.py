"""The input points seen as a surface: nearest planes, support tests and coverage.

The fit stage works in *normalised* coordinates in which the rest spacing r0 is 1. This module
holds the data in those units, with one k-d tree built once per fit, and answers the questions
the particle stages ask of the data:

* where is the data's local plane near a particle (the anchor of the ``fidelity`` pull);
* is a candidate particle supported by data (inside the data, or inside a hole smaller than
  ``max_gap``) and on its tangent plane (DESIGN §4.4: without that test growth runs away);
* which fraction of the input points is covered by the particle sheet.

Local surfaces are fitted once per data point: a PCA frame over its k nearest neighbours
(centroid, smallest principal direction oriented like the data normal) and a quadric height
field over that frame, in the manner of moving least squares [L98]. The quadric removes the
inward bias a plane through the centroid has on curved surfaces, and the fit averages sensor
noise instead of pulling particles onto individual noisy samples.

References
----------
[ST92] Szeliski & Tonnesen 1992, §7 (fitting to data, growth bounded by data).
[H92]  Hoppe, DeRose, Duchamp, McDonald, Stuetzle. "Surface reconstruction from unorganized
       points". SIGGRAPH 1992 (tangent planes by PCA of k nearest neighbours).
[L98]  D. Levin. "The approximation power of moving least-squares". Math. Comp. 67, 1998
       (local polynomial fits over a reference plane, the basis of MLS surfaces).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from scipy.spatial import cKDTree

from .kernels.grid_query import anchor_feet_kernel
from .kernels.local_surface import fit_quadrics_kernel, max_angular_gap_kernel, select_agreeing
from .kernels.options import ThreadChooser, query_workers, thread_limit, timed_threads
from .neighbors import GRID_MAX_RING, PARALLEL_MIN_PARTICLES, PointGrid

if TYPE_CHECKING:
    from .crease_surface import CreaseField

#: Nearest data points searched for one whose normal agrees with a particle's
#: (:meth:`DataSurface.nearest_agreeing`).
AGREE_K = 8
#: Threaded or serial anchor queries, whichever was faster lately (the feet do not depend on it).
_ANCHOR_THREADS = ThreadChooser()
#: The data's query grid (:attr:`DataSurface.grid`) has cells of this many times the median
#: distance from a data point to its ``AGREE_K``-th neighbour, so that most ``AGREE_K``-nearest
#: queries end after the first shell of cells.
GRID_CELL_FACTOR = 1.5
#: Data points sampled (evenly by index) to estimate that distance.
GRID_CELL_SAMPLE = 2000
#: Entries per data point of the anchor walk's neighbour table (:attr:`DataSurface.
#: walk_neighbors`, int32: 48 bytes per point). The walk proves its result when the particle
#: is nearer to its nearest data point than half the distance to that point's 12th nearest
#: (about 0.9 data spacings): nearly always for a particle on the sheet.
WALK_K = 16
#: Empty walk table (no hints given).
_NO_WALK = (np.zeros((0, 1), dtype=np.int32), np.zeros(0))


@dataclass
class DataSurface:
    """Input points in normalised units (r0 = 1) with per-point local planes.

    Attributes
    ----------
    points : (n, 3) float64 [r0]
    normals : (n, 3) float64, unit, consistently oriented
    plane_points : (n, 3) float64 [r0]
        Centroid of each point's k nearest neighbours (a point on the local plane).
    plane_normals : (n, 3) float64
        Unit normal of the local PCA plane, oriented like ``normals``.
    tangents : (n, 3) float64
        First tangent direction of the local frame (the second is ``normal x tangent``).
    quadrics : (n, 6) float64
        Height field h(x, y) = c0 + c1 x + c2 y + c3 x^2 + c4 x y + c5 y^2 over the local
        frame, least-squares fitted to the neighbourhood: the curved local surface.
    noise : float [r0]
        Median RMS residual of the local quadrics (a noise-level estimate).
    """

    points: np.ndarray
    normals: np.ndarray
    plane_points: np.ndarray
    plane_normals: np.ndarray
    tangents: np.ndarray
    quadrics: np.ndarray
    noise: float
    tree: cKDTree
    #: Crease lines in the data (issue 12; set by the pipeline when creases are on): anchors
    #: near a crease use its per-side planes (:meth:`recon.crease_surface.CreaseField.adjust`).
    creases: CreaseField | None = None
    #: Each point's ``WALK_K`` nearest data points (itself among them) by distance, and the
    #: distance of the last: the table the anchor refresh walks on from a previous anchor
    #: (:func:`recon.kernels.grid_query.anchor_feet_kernel`); None: the grid answers alone.
    walk_neighbors: np.ndarray | None = field(default=None, repr=False, compare=False)
    walk_reach: np.ndarray | None = field(default=None, repr=False, compare=False)
    _grid: PointGrid | None = field(default=None, repr=False, compare=False)

    @classmethod
    def build(
        cls,
        points: np.ndarray,
        normals: np.ndarray,
        k: int = 20,
        neighbors: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> DataSurface:
        """Fit local planes to ``points`` (normalised units) with oriented ``normals``.

        ``neighbors``: each point's m nearest points, nearest first, as (distances [r0],
        indices) (a shared k-d tree query); used when m >= 2 k, else queried here.
        """
        points = np.ascontiguousarray(points, dtype=np.float64)
        normals = np.ascontiguousarray(normals, dtype=np.float64)
        tree = cKDTree(points)
        k = int(min(max(k, 3), len(points)))
        # twice the neighbours, of which the first k on the same sheet (normals agreeing) fit
        k_query = int(min(2 * k, len(points)))
        if neighbors is not None and neighbors[1].shape[1] >= k_query:
            dist, idx = neighbors[0][:, :k_query], neighbors[1][:, :k_query]
        else:
            dist, idx = tree.query(points, k=k_query, workers=query_workers())
        dist = dist.reshape(len(points), -1)
        idx = idx.reshape(len(points), -1)  # a view of a shared query: not copied
        walk = min(WALK_K, idx.shape[1])
        walk_neighbors = np.ascontiguousarray(idx[:, :walk], dtype=np.int32)
        walk_reach = np.ascontiguousarray(dist[:, walk - 1])
        idx = select_agreeing(normals, idx, k)
        pp, pn, tangents, quadrics, residual = fit_local_quadrics(points, normals, idx)
        return cls(
            points,
            normals,
            pp,
            pn,
            tangents,
            quadrics,
            float(np.median(residual)),
            tree,
            walk_neighbors=walk_neighbors,
            walk_reach=walk_reach,
        )

    @property
    def n_points(self) -> int:
        return len(self.points)

    @property
    def grid(self) -> PointGrid:
        """The data binned into a cell grid once (built on first use): the queries of the fit
        (:meth:`nearest`, :meth:`anchors`) run on it instead of the k-d tree."""
        if self._grid is None:
            n = self.n_points
            k = int(min(AGREE_K, n))
            sample = self.points[:: max(1, n // GRID_CELL_SAMPLE)]
            d, _ = self.tree.query(sample, k=k, workers=query_workers())
            d = np.reshape(d, (len(sample), k))[:, -1]
            cell = GRID_CELL_FACTOR * float(np.median(d)) if len(d) else 1.0
            if not (np.isfinite(cell) and cell > 0.0):
                cell = 1.0
            self._grid = PointGrid(self.points, cell)
        return self._grid

    def nearest(self, query: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Distance [r0] and index of the nearest data point for each query point."""
        return self.grid.query(query, k=1)

    def nearest_agreeing(
        self, query: np.ndarray, normals: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Distance [r0] and index of the nearest data point whose normal agrees with
        ``normals`` (n_q . n > 0: the same sheet of a thin part); the nearest point when none of
        the ``AGREE_K`` nearest agrees or ``normals`` is None."""
        if normals is None or len(query) == 0:
            return self.nearest(query)
        k = int(min(AGREE_K, self.n_points))
        dist, idx = self.tree.query(query, k=k, workers=query_workers())
        dist = dist.reshape(len(query), k)
        idx = idx.reshape(len(query), k)
        agree = np.einsum("ijk,ik->ij", self.normals[idx], normals) > 0.0
        first = np.where(agree.any(axis=1), np.argmax(agree, axis=1), 0)
        rows = np.arange(len(query))
        return dist[rows, first], idx[rows, first]

    def anchors(
        self,
        positions: np.ndarray,
        normals: np.ndarray | None = None,
        hint: np.ndarray | None = None,
        with_index: bool = False,
    ) -> tuple[np.ndarray, ...]:
        """Foot point and normal on the local surface nearest to each position, and the
        distance to the nearest data point [r0] (and, ``with_index``, the index of the data
        point whose quadric was used).

        ``hint`` (m,) int: a data point near each position (-1: none), e.g. the index of its
        previous anchor: the nearest data point is then found by a short walk on
        :attr:`walk_neighbors` (the grid answers where the walk cannot prove its result, so
        the answers do not depend on the hints).

        The local surface is the quadric height field of the nearest data point (with
        ``normals``: the nearest whose normal agrees, so that a particle on one side of a thin
        part is never pulled onto the other side); the foot point is the vertical projection in
        its frame, and the normal is the quadric's normal there (so a point-to-plane pull
        toward (foot, normal) pulls onto the curved surface).
        """
        q = np.ascontiguousarray(positions, dtype=np.float64).reshape(-1, 3)
        m = len(q)
        grid = self.grid
        foot = np.zeros((m, 3))
        nrm = np.zeros((m, 3))
        dist = np.zeros(m)
        idx = np.zeros(m, dtype=np.int64)
        ok = np.zeros(m, dtype=np.bool_)
        if m and grid.grid is not None:
            qn = q if normals is None else np.ascontiguousarray(normals, dtype=np.float64)
            frames = (self.plane_points, self.plane_normals, self.tangents, self.quadrics)
            if hint is None or self.walk_neighbors is None:
                hint = np.full(m, -1, dtype=np.int64)
                walk_nbr, walk_reach = _NO_WALK
            else:
                hint = np.ascontiguousarray(hint, dtype=np.int64).reshape(m)
                walk_nbr, walk_reach = self.walk_neighbors, self.walk_reach
            with timed_threads(_ANCHOR_THREADS, m):
                anchor_feet_kernel(
                    q,
                    qn,
                    normals is not None,
                    self.normals,
                    frames,
                    grid.grid,
                    grid.cell_size,
                    int(min(AGREE_K, self.n_points)),
                    GRID_MAX_RING,
                    foot,
                    nrm,
                    dist,
                    idx,
                    ok,
                    hint,
                    self.points,
                    walk_nbr,
                    walk_reach,
                )
        rest = np.flatnonzero(~ok)
        if len(rest):  # far from the data: the k-d tree answers
            f, n_, d, i = self._anchors_tree(q[rest], None if normals is None else normals[rest])
            foot[rest], nrm[rest], dist[rest], idx[rest] = f, n_, d, i
        if self.creases is not None:  # crease hook: per-side planes near creases
            foot, nrm = self.creases.adjust(q, normals, foot, nrm)
        if with_index:
            return foot, nrm, dist, idx
        return foot, nrm, dist

    def _anchors_tree(
        self, positions: np.ndarray, normals: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`anchors` through the k-d tree (foot, normal, distance, data index)."""
        dist, idx = self.nearest_agreeing(positions, normals)
        foot, nrm = _quadric_foot(
            positions,
            self.plane_points[idx],
            self.plane_normals[idx],
            self.tangents[idx],
            self.quadrics[idx],
        )
        return foot, nrm, dist, idx

    def project(
        self, positions: np.ndarray, normals: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Project positions onto the local data surface (of the sheet ``normals`` agree with).

        Returns the projected positions, the surface normals, and the signed offset along the
        normal before projection [r0].
        """
        p, n, _ = self.anchors(positions, normals)
        offset = np.einsum("ij,ij->i", positions - p, n)
        return positions - offset[:, None] * n, n, offset


def _quadric_foot(
    q: np.ndarray, c: np.ndarray, n: np.ndarray, u: np.ndarray, a: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Foot points and normals of query points ``q`` on local quadric height fields."""
    v = np.cross(n, u)
    d = q - c
    x = np.einsum("ij,ij->i", d, u)
    y = np.einsum("ij,ij->i", d, v)
    h = a[:, 0] + a[:, 1] * x + a[:, 2] * y + a[:, 3] * x * x + a[:, 4] * x * y + a[:, 5] * y * y
    hx = a[:, 1] + 2 * a[:, 3] * x + a[:, 4] * y
    hy = a[:, 2] + a[:, 4] * x + 2 * a[:, 5] * y
    foot = c + x[:, None] * u + y[:, None] * v + h[:, None] * n
    nrm = n - hx[:, None] * u - hy[:, None] * v
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    return foot, nrm


def fit_local_quadrics(
    points: np.ndarray, normals: np.ndarray, neighbor_idx: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """PCA frame and quadric height field of each point's neighbourhood [H92, L98].

    Parameters
    ----------
    points : (n, 3) float64
    normals : (n, 3) float64
        Orientation reference: each frame normal is flipped to agree with it.
    neighbor_idx : (n, k) int
        Indices of each point's k nearest neighbours (itself included).

    Returns
    -------
    centroids : (n, 3) float64
    plane_normals : (n, 3) float64
    tangents : (n, 3) float64
    quadrics : (n, 6) float64
        Coefficients of h(x, y) = c0 + c1 x + c2 y + c3 x^2 + c4 x y + c5 y^2.
    residuals : (n,) float64
        RMS distance of the neighbourhood to its quadric: a noise level.
    """
    n = len(points)
    out = (np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((n, 6)), np.zeros(n))
    idx = np.ascontiguousarray(neighbor_idx, dtype=np.int64)
    with thread_limit(n >= PARALLEL_MIN_PARTICLES):
        fit_quadrics_kernel(points, normals, idx, *out)
    return out


#: Centres per k-NN query in max_angular_gap (memory per call ~ _GAP_CHUNK x 0.8 kB).
_GAP_CHUNK = 32_768


def max_angular_gap(
    centers: np.ndarray,
    normals: np.ndarray,
    tree: cKDTree,
    tree_points: np.ndarray,
    radius: float | np.ndarray,
    k: int = 48,
) -> np.ndarray:
    """Largest angle [rad] between successive directions to nearby points, in the tangent plane.

    A point strictly inside the data (or inside a hole of the data) sees data all around it:
    its largest gap is below pi. A point past an open boundary sees data on one side only:
    a gap of pi or more. Points up to ``radius`` away (at most ``k`` of them) count;
    ``radius`` is one distance for every centre or one per centre.
    """
    if len(centers) == 0:
        return np.zeros(0)
    radius = np.broadcast_to(np.asarray(radius, dtype=np.float64), (len(centers),))
    if len(centers) > _GAP_CHUNK:  # bound the (m, k) temporaries: ~0.8 kB per centre
        parts = [
            max_angular_gap(
                centers[i : i + _GAP_CHUNK],
                normals[i : i + _GAP_CHUNK],
                tree,
                tree_points,
                radius[i : i + _GAP_CHUNK],
                k,
            )
            for i in range(0, len(centers), _GAP_CHUNK)
        ]
        return np.concatenate(parts)
    k = int(min(k, len(tree_points)))
    bound = float(np.max(radius))
    dist, idx = tree.query(centers, k=k, distance_upper_bound=bound, workers=query_workers())
    dist = dist.reshape(len(centers), k)
    idx = idx.reshape(len(centers), k)
    # each row sorted by distance: its points within its radius come first (the bound is
    # strict, inf past it, so with one radius for all this counts the finite distances)
    count = (dist < radius[:, None]).sum(axis=1).astype(np.int64)
    return max_angular_gap_kernel(
        np.ascontiguousarray(centers),
        np.ascontiguousarray(normals),
        np.ascontiguousarray(tree_points, dtype=np.float64),
        np.ascontiguousarray(idx, dtype=np.int64),
        count,
    )


def feature_spacing(
    surface: DataSurface,
    spacing_min: float,
    spacing_max: float,
    epsilon: float = 0.5,
    k: int = 16,
) -> np.ndarray:
    """Target rest spacing [r0] at each data point from the local feature size (DESIGN §8).

    LFS = min(1/kappa_max of the local quadric, t/2) with t the thickness to the opposite sheet
    (data behind the point with opposed normals, n_q . n < -0.5); the spacing is epsilon x LFS
    (Amenta & Bern's epsilon-sampling), not below the local data spacing (a sheet cannot be
    finer than the samples that support it: sparse regions get larger particles), clamped
    to [spacing_min, spacing_max] and smoothed by the median over the k nearest points.
    """
    pts, nrm = surface.points, surface.normals
    k = int(min(k, len(pts)))
    dist, idx = surface.tree.query(pts, k=k, workers=query_workers())
    dist = dist.reshape(len(pts), k)
    idx = idx.reshape(len(pts), k)
    # the local data spacing [r0]: the median nearest-neighbour distance scaled by the local
    # reach of the k nearest points relative to its median (robust to single close pairs)
    reach = dist[:, -1]
    density = reach / max(float(np.median(reach)), 1e-300) * float(np.median(dist[:, 1]))
    a = surface.quadrics
    # principal curvatures of h(x, y) at the frame origin: eigenvalues of [[2a3, a4], [a4, 2a5]]
    half_trace = a[:, 3] + a[:, 5]
    root = np.sqrt((a[:, 3] - a[:, 5]) ** 2 + a[:, 4] ** 2)
    kappa = np.abs(half_trace) + root
    lfs = 1.0 / np.maximum(kappa, 1e-12)
    # thickness: nearest opposed data behind the point, within 4 spacing_max
    k_far = int(min(3 * k, len(pts)))
    far, fidx = surface.tree.query(
        pts, k=k_far, distance_upper_bound=4.0 * spacing_max, workers=query_workers()
    )
    far = far.reshape(len(pts), k_far)
    fidx = np.where(np.isfinite(far), fidx.reshape(len(pts), k_far), 0)
    offset = np.einsum("ijk,ik->ij", pts[fidx] - pts[:, None, :], nrm)
    opposed = (np.einsum("ijk,ik->ij", nrm[fidx], nrm) < -0.5) & (offset < 0) & np.isfinite(far)
    thick = np.where(opposed, -offset, np.inf).min(axis=1)
    lfs = np.minimum(lfs, 0.5 * thick)
    target = np.clip(epsilon * lfs, np.maximum(spacing_min, density), spacing_max)
    target = np.clip(target, spacing_min, spacing_max)
    return np.median(target[idx], axis=1)
