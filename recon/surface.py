"""The input points seen as a surface: nearest planes, support tests and coverage.

The fit stage works in *normalised* coordinates in which the rest spacing r0 is 1. This module
holds the data in those units, with one k-d tree built once per fit, and answers the questions
the particle stages ask of the data:

* where is the data's local plane near a particle (the anchor of the ``fidelity`` pull);
* is a candidate particle supported by data (inside the data, or inside a hole smaller than
  ``max_gap``) and on its tangent plane (DESIGN §4.4: without that test growth runs away);
* which fraction of the input points is covered by the particle sheet.

Local planes are fitted once per data point by PCA over its k nearest neighbours (the centroid
and the smallest principal direction, oriented like the data normal), which averages sensor
noise instead of pulling particles onto individual noisy samples.

References
----------
[ST92] Szeliski & Tonnesen 1992, §7 (fitting to data, growth bounded by data).
[H92]  Hoppe, DeRose, Duchamp, McDonald, Stuetzle. "Surface reconstruction from unorganized
       points". SIGGRAPH 1992 (tangent planes by PCA of k nearest neighbours).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba as nb
import numpy as np
from scipy.spatial import cKDTree


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
    noise : float [r0]
        Median RMS residual of the local planes (a noise-level estimate).
    """

    points: np.ndarray
    normals: np.ndarray
    plane_points: np.ndarray
    plane_normals: np.ndarray
    noise: float
    tree: cKDTree

    @classmethod
    def build(cls, points: np.ndarray, normals: np.ndarray, k: int = 20) -> DataSurface:
        """Fit local planes to ``points`` (normalised units) with oriented ``normals``."""
        points = np.ascontiguousarray(points, dtype=np.float64)
        normals = np.ascontiguousarray(normals, dtype=np.float64)
        tree = cKDTree(points)
        k = int(min(max(k, 3), len(points)))
        _, idx = tree.query(points, k=k, workers=-1)
        plane_points, plane_normals, residual = fit_local_planes(points, normals, idx)
        return cls(points, normals, plane_points, plane_normals, float(np.median(residual)), tree)

    @property
    def n_points(self) -> int:
        return len(self.points)

    def nearest(self, query: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Distance [r0] and index of the nearest data point for each query point."""
        dist, idx = self.tree.query(query, k=1, workers=-1)
        return dist, idx

    def anchors(self, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Local data plane nearest to each position: (plane point, plane normal, distance)."""
        dist, idx = self.nearest(positions)
        return self.plane_points[idx], self.plane_normals[idx], dist

    def project(self, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Project positions onto their nearest local data plane.

        Returns the projected positions, the plane normals, and the signed offset along the
        normal before projection [r0].
        """
        p, n, _ = self.anchors(positions)
        offset = np.einsum("ij,ij->i", positions - p, n)
        return positions - offset[:, None] * n, n, offset


@nb.njit(cache=True)
def _fit_planes_kernel(points, normals, idx, out_p, out_n, out_r):  # pragma: no cover - numba
    n, k = idx.shape
    for i in range(n):
        c = np.zeros(3)
        for a in range(k):
            c += points[idx[i, a]]
        c /= k
        cov = np.zeros((3, 3))
        for a in range(k):
            d = points[idx[i, a]] - c
            for u in range(3):
                for v in range(3):
                    cov[u, v] += d[u] * d[v]
        cov /= k
        w, vec = np.linalg.eigh(cov)
        nn = vec[:, 0]
        if nn[0] * normals[i, 0] + nn[1] * normals[i, 1] + nn[2] * normals[i, 2] < 0.0:
            nn = -nn
        out_p[i] = c
        out_n[i] = nn
        out_r[i] = np.sqrt(max(w[0], 0.0))


def fit_local_planes(points: np.ndarray, normals: np.ndarray,
                     neighbor_idx: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """PCA plane of each point's neighbourhood [H92].

    Parameters
    ----------
    points : (n, 3) float64
    normals : (n, 3) float64
        Orientation reference: each plane normal is flipped to agree with it.
    neighbor_idx : (n, k) int
        Indices of each point's k nearest neighbours (itself included).

    Returns
    -------
    centroids : (n, 3) float64
    plane_normals : (n, 3) float64
    residuals : (n,) float64
        RMS distance of the neighbourhood to its plane (square root of the smallest
        eigenvalue of the covariance).
    """
    n = len(points)
    out_p = np.zeros((n, 3))
    out_n = np.zeros((n, 3))
    out_r = np.zeros(n)
    _fit_planes_kernel(points, normals, np.ascontiguousarray(neighbor_idx, dtype=np.int64),
                       out_p, out_n, out_r)
    return out_p, out_n, out_r


@nb.njit(cache=True)
def _max_angular_gap_kernel(cands, normals, nbr_pts, nbr_count):  # pragma: no cover - numba
    m = cands.shape[0]
    out = np.full(m, 2.0 * np.pi)
    for i in range(m):
        cnt = nbr_count[i]
        if cnt < 3:
            continue
        nrm = normals[i]
        # tangent frame
        if abs(nrm[0]) < 0.9:
            t = np.array([1.0, 0.0, 0.0])
        else:
            t = np.array([0.0, 1.0, 0.0])
        u = t - (t[0] * nrm[0] + t[1] * nrm[1] + t[2] * nrm[2]) * nrm
        u /= np.sqrt(u[0] ** 2 + u[1] ** 2 + u[2] ** 2)
        v = np.cross(nrm, u)
        ang = np.zeros(cnt)
        for a in range(cnt):
            d = nbr_pts[i, a] - cands[i]
            ang[a] = np.arctan2(d[0] * v[0] + d[1] * v[1] + d[2] * v[2],
                                d[0] * u[0] + d[1] * u[1] + d[2] * u[2])
        ang.sort()
        gap = ang[0] + 2.0 * np.pi - ang[cnt - 1]
        for a in range(1, cnt):
            g = ang[a] - ang[a - 1]
            if g > gap:
                gap = g
        out[i] = gap
    return out


def max_angular_gap(centers: np.ndarray, normals: np.ndarray, tree: cKDTree,
                    tree_points: np.ndarray, radius: float, k: int = 48) -> np.ndarray:
    """Largest angle [rad] between successive directions to nearby points, in the tangent plane.

    A point strictly inside the data (or inside a hole of the data) sees data all around it:
    its largest gap is below pi. A point past an open boundary sees data on one side only:
    a gap of pi or more. Points up to ``radius`` away (at most ``k`` of them) count.
    """
    if len(centers) == 0:
        return np.zeros(0)
    k = int(min(k, len(tree_points)))
    dist, idx = tree.query(centers, k=k, distance_upper_bound=radius, workers=-1)
    dist = dist.reshape(len(centers), k)
    idx = idx.reshape(len(centers), k)
    valid = np.isfinite(dist)
    count = valid.sum(axis=1).astype(np.int64)
    safe = np.where(valid, idx, 0)
    nbr = tree_points[safe]
    # push valid rows first (query returns sorted by distance, invalid at the end already)
    return _max_angular_gap_kernel(np.ascontiguousarray(centers), np.ascontiguousarray(normals),
                                   np.ascontiguousarray(nbr), count)
