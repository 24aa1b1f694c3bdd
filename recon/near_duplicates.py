"""Points that sample one place many times: merged before the fit's local surfaces.

A scan that records one place many times with a tiny jitter (repeated returns, merged scans
whose copies did not come out exactly equal, points rounded and re-perturbed) gives that
place a neighbourhood of copies: its local quadric is fitted on a patch 1e-6 of a spacing
wide (curvatures of 1e4 / r0 where the surface's are 0.01), and the normals of the points
beside it are fitted on the copies. A sphere of 10,000 points with 100 of them repeated 50
times at 1e-6 jitter came out watertight but with bumps up to 0.23 off the sphere (8 r0),
245 vertices more than a third of r0 off it.

:func:`near_duplicate_rows` finds the points with ``CLUMP`` others within ``NEAR_DUPLICATE``
median nearest-neighbour distances and, when there are any, thins the points to one per that
distance, as exact duplicates are merged on reading (``io.merge_duplicates``); the fit then
starts again on the points kept.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from .cloud import PointCloud
from .geometry import poisson_disk_thin

__all__ = ["CLUMP", "NEAR_DUPLICATE", "merged_cloud", "near_duplicate_notes", "near_duplicate_rows"]

#: A point with ``CLUMP`` others within this many median nearest-neighbour distances lies in a
#: clump: one place sampled many times. No point of the 27 dev scans, nor of the held-out
#: thin-part shapes at 40,000 points, has even its third neighbour that close (the closest:
#: 0.23, torus-missing and the held-out gradient).
NEAR_DUPLICATE = 0.1
#: Others within ``NEAR_DUPLICATE`` that make a clump: a close pair or triple is chance, and
#: only where copies crowd a neighbourhood (20 points for a local surface) do they make it
#: one of no width. Chance gives a point 5 others that close once in about 1e12 uniformly
#: random samples of a surface, and once in about 1e8 random samples along scan lines (the
#: nearest-neighbour distance there is the one along the lines).
CLUMP = 5
#: Rows whose nearest distance the median is taken over (every n // this-th).
_MEDIAN_SAMPLE = 20_000


def near_duplicate_rows(
    points: np.ndarray,
    tree: cKDTree,
    neighbors: tuple[np.ndarray, np.ndarray] | None = None,
) -> np.ndarray | None:
    """The rows to keep when some ``points`` lie in clumps (``CLUMP`` others within
    ``NEAR_DUPLICATE`` median nearest-neighbour distances): the points thinned so that no two
    kept are closer than that (greedy, in row order: :func:`recon.geometry.poisson_disk_thin`;
    outside the clumps only a rare close pair goes, a tenth of a spacing from its partner);
    None when there is no clump (or nothing to thin: the fit need not start again).

    Parameters
    ----------
    points : (n, 3) float64 [length]
    tree : scipy.spatial.cKDTree
        A k-d tree of ``points``.
    neighbors : (distances, indices), optional
        Each point's nearest points, the point itself first (the fit's shared k-nearest
        query), when it holds ``CLUMP`` others (else queried).

    Returns
    -------
    (m,) int, increasing, or None

    Examples
    --------
    >>> grid = np.stack(np.meshgrid(np.arange(4.0), np.arange(4.0), [0.0]), -1).reshape(-1, 3)
    >>> clump = np.array([1.0, 1.0, 0.0]) + 1e-9 * np.arange(18).reshape(6, 3)
    >>> pts = np.vstack([grid, clump])
    >>> len(near_duplicate_rows(pts, cKDTree(pts)))  # the clump and the grid point under it
    16
    >>> near_duplicate_rows(grid, cKDTree(grid)) is None
    True
    """
    if len(points) <= CLUMP:
        return None
    if neighbors is None or neighbors[0].shape[1] <= CLUMP:
        neighbors = tree.query(points, CLUMP + 1)
    dist = neighbors[0]
    nearest = dist[:: max(1, len(points) // _MEDIAN_SAMPLE), 1]
    tol = NEAR_DUPLICATE * float(np.median(nearest))
    if not np.any(dist[:, CLUMP] < tol):
        return None
    keep = np.flatnonzero(poisson_disk_thin(points, tol))
    return None if len(keep) == len(points) else keep


def merged_cloud(cloud: PointCloud, keep: np.ndarray) -> PointCloud:
    """``cloud`` with only the rows ``keep`` (:func:`near_duplicate_rows`), the count of the
    merged ones in its info (``n_near_duplicates_merged``, added to any before)."""
    merged = cloud.take(keep)
    n = len(cloud.points) - len(keep) + int(cloud.info.get("n_near_duplicates_merged", 0))
    return replace(merged, info={**cloud.info, "n_near_duplicates_merged": n})


def near_duplicate_notes(info: dict[str, Any]) -> list[str]:
    """The fit's warning when near-duplicates were merged (``info``: the cloud's)."""
    n = int(info.get("n_near_duplicates_merged", 0))
    if not n:
        return []
    return [
        f"{n:,} points lay in clumps ({CLUMP} or more others within {NEAR_DUPLICATE:g} median "
        "point spacings: one place sampled many times) and were merged before the fit: copies "
        "make local surfaces of no width"
    ]
