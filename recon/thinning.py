"""Points denser than the surface needs, thinned before the fit's normals and local surfaces.

Two samplings give a point a neighbourhood that does not span the surface round it:

- **Clumps**: a scan that records one place many times with a tiny jitter (repeated returns,
  merged scans whose copies did not come out exactly equal) gives that place a neighbourhood
  of copies: its local quadric is fitted on a patch 1e-6 of a spacing wide (curvatures of 1e4
  / r0 where the surface's are 0.01), and the normals of the points beside it are fitted on
  the copies. A sphere of 10,000 points with 100 of them repeated 50 times at 1e-6 jitter came
  out with bumps up to 0.23 off the sphere (8 r0). :func:`clump_rows`.
- **Scan lines** far denser along than across (airborne strips, profile scanners): a point's
  20 nearest lie on its own line, its normal is any direction across the line and its local
  surface a ribbon. r0 follows the gaps between the lines (:mod:`recon.fitting.scale`), but a
  tester's airborne strip (lines 0.8 m apart, points 0.05 m along them) still came out in 28
  pieces with 45 % of its area facing down. :func:`line_rows`.

Either way the points are thinned (greedy Poisson-disk, :func:`recon.geometry.poisson_disk_thin`)
and the fit starts again on the points kept (:func:`thinned_cloud`), saying so in a warning
(:func:`thinning_notes`). Detail finer than the thinning radius is finer than the mesh: the
radii are 0.1 and 1 point spacings, r0 is 2.5.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from .cloud import PointCloud
from .geometry import SURROUND_RATIO, poisson_disk_thin
from .kernels.options import query_workers

__all__ = [
    "CLUMP",
    "LINE_RATIO",
    "LINES_THINNED",
    "LINE_THIN",
    "NEAR_DUPLICATE",
    "clump_rows",
    "line_gap",
    "line_rows",
    "thinned_cloud",
    "thinned_rows",
    "thinning_notes",
]

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
#: Scan lines are thinned, and the fit says the spacing across them, from a point spacing of
#: this many median nearest-neighbour distances (a surround distance of 5 of them; a smaller
#: change is no news: a sphere with 1 point in 3 repeated in clumps, 1.06).
LINE_RATIO = 1.25
#: Scan lines are thinned to one point per this many point spacings (the spacing across the
#: lines over ``SURROUND_RATIO``): a line's 20 nearest then reach 10 spacings along it, past
#: the neighbouring lines 4 spacings away, and the nearest-neighbour distance is no longer
#: below the point spacing, so that the fit started again does not thin again (at 0.8, lines
#: 50 times denser along than across were thinned twice).
LINE_THIN = 1.0
#: Rows whose nearest distance the median is taken over (every n // this-th).
_MEDIAN_SAMPLE = 20_000


def clump_rows(
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
    >>> len(clump_rows(pts, cKDTree(pts)))  # the clump and the grid point under it
    16
    >>> clump_rows(grid, cKDTree(grid)) is None
    True
    """
    if len(points) <= CLUMP:
        return None
    if neighbors is None or neighbors[0].shape[1] <= CLUMP:
        neighbors = tree.query(points, CLUMP + 1)
    dist = neighbors[0]
    tol = NEAR_DUPLICATE * median_nearest(dist)
    if not np.any(dist[:, CLUMP] < tol):
        return None
    keep = np.flatnonzero(poisson_disk_thin(points, tol))
    return None if len(keep) == len(points) else keep


def median_nearest(dist: np.ndarray) -> float:
    """The median nearest-neighbour distance of a k-nearest query's ``dist`` (the point itself
    in column 0), over every n // ``_MEDIAN_SAMPLE``-th row, exact repeats (kept when
    ``io.merge_duplicates`` is off) left out unless they are most."""
    nearest = dist[:: max(1, len(dist) // _MEDIAN_SAMPLE), 1]
    apart = nearest[nearest > 0.0]
    return float(np.median(apart if 2 * len(apart) > len(nearest) else nearest))


def line_rows(points: np.ndarray, spacing: float, nearest: float) -> np.ndarray | None:
    """The rows to keep when the point spacing ``spacing`` is the one across scan lines
    (:func:`recon.fitting.scale.sampled_spacing`), at least ``LINE_RATIO`` times the
    median nearest-neighbour distance ``nearest``: the points thinned to one per ``LINE_THIN``
    x ``spacing``; None otherwise (or when nothing is that close).

    Examples
    --------
    >>> x, y = np.meshgrid(np.arange(0.0, 20.0, 0.1), np.arange(0.0, 20.0, 2.0))
    >>> lines = np.c_[x.ravel(), y.ravel(), np.zeros(x.size)]  # 0.1 along, 2 across
    >>> kept = line_rows(lines, 0.45, 0.1)  # thinned to 0.45: every fifth point
    >>> len(lines), len(kept), np.round(np.diff(lines[kept[:3], 0]), 6).tolist()
    (2000, 400, [0.5, 0.5])
    """
    if not (nearest > 0.0 and spacing >= LINE_RATIO * nearest):  # (0: repeats kept)
        return None
    keep = np.flatnonzero(poisson_disk_thin(points, LINE_THIN * float(spacing)))
    return None if len(keep) == len(points) else keep


def thinned_rows(
    points: np.ndarray,
    tree: cKDTree,
    neighbors: tuple[np.ndarray, np.ndarray] | None,
    spacing: float,
    info: dict[str, Any] | None = None,
) -> tuple[np.ndarray, dict[str, Any]] | None:
    """The rows a fit keeps of ``points`` (:func:`clump_rows`, else :func:`line_rows`) and why
    (the ``why`` of :func:`thinned_cloud`); None: all of them.

    ``neighbors``: the fit's shared k-nearest query (queried when None or narrow);
    ``spacing``: the point spacing (:func:`recon.fitting.scale.choose_spacing`); ``info``:
    the cloud's, whose lines were thinned already when it says so (once is enough: a few
    dozen points in lines, measured again, thinned again to 10).
    """
    if neighbors is None or neighbors[0].shape[1] <= CLUMP:
        neighbors = tree.query(points, CLUMP + 1, workers=query_workers())
    keep = clump_rows(points, tree, neighbors)
    if keep is not None:
        return keep, {"kind": "clumps"}
    if any(done["kind"] == "lines" for done in (info or {}).get("thinned", [])):
        return None
    nearest = median_nearest(neighbors[0])
    keep = line_rows(points, spacing, nearest)
    if keep is None:
        return None
    why = {"kind": "lines", "gap": SURROUND_RATIO * spacing, "nearest": nearest}
    return keep, {**why, "radius": LINE_THIN * spacing}


def line_gap(info: dict[str, Any]) -> tuple[float, int] | None:
    """The distance between the scan lines measured before the cloud (``info``: its) was
    thinned along them, and its point count then (None: it was not thinned so): the fit
    started again keeps both, so that r0 is the one the scan's own points give (as a tiled
    fit's, which measures them before its tiles thin) and a few dozen points left do not
    measure their own lines farther apart."""
    done = [d for d in info.get("thinned", []) if d["kind"] == "lines"]
    return (done[-1]["gap"], done[-1]["before"]) if done else None


def thinned_cloud(cloud: PointCloud, keep: np.ndarray, why: dict[str, Any]) -> PointCloud:
    """``cloud`` with only the rows ``keep`` and ``why`` they were thinned in its info
    (``thinned``: a list, one entry per thinning, with ``removed`` and the count ``before``
    added)."""
    n = len(cloud.points)
    done = [*cloud.info.get("thinned", []), {**why, "removed": n - len(keep), "before": n}]
    return replace(cloud.take(keep), info={**cloud.info, "thinned": done})


#: How a note about thinned scan lines ends (a tiled fit says it once for the scan, not per
#: tile).
LINES_THINNED = "so that each point's neighbours reach across the lines"


def thinning_notes(info: dict[str, Any], cfg: Any) -> list[str]:
    """The fit's warnings about the thinnings of its cloud (``info``: the cloud's; ``cfg``: the
    fit's configuration: the lines' note says r0 follows them when the data chose it)."""
    notes = []
    for done in info.get("thinned", []):
        n = done["removed"]
        if done["kind"] == "clumps":
            notes.append(
                f"{n:,} points lay in clumps ({CLUMP} or more others within "
                f"{NEAR_DUPLICATE:g} median point spacings: one place sampled many times) and "
                "were merged before the fit: copies make local surfaces of no width"
            )
        else:
            gap, along = done["gap"], done["nearest"]
            note = (
                f"the points lie in lines or clumps about {gap:.4g} apart, {gap / along:.0f} "
                f"times their median spacing {along:.4g}: thinned to one point per "
                f"{done['radius']:.4g} ({n:,} of {done['before']:,} went) {LINES_THINNED}"
            )
            if cfg.seeds.spacing is None and cfg.seeds.spacing_relative is None:
                note += ", and r0 follows the gaps between them (--spacing, seeds.spacing, sets it)"
            notes.append(note)
    return notes
