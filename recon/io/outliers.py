"""Statistical outlier removal on reading, and the fit's warning when a scan looks outlier-ridden.

:func:`statistical_outliers` is the removal ``io.outliers: statistical`` (``--remove-outliers``)
asks for; :func:`recon.io.clean.make_cloud` applies it once, after merging duplicates and before
normals and spacing. A point is an outlier when its mean distance to its k nearest other points
exceeds the median of that distance over all points by ``std_ratio`` robust standard deviations
(1.4826 x the median absolute deviation).

This is Open3D's ``remove_statistical_outlier(nb_neighbors, std_ratio)`` (and PCL's
``StatisticalOutlierRemoval``, ``setMeanK`` / ``setStddevMulThresh``) with robust statistics.
Open3D has no defaults (both arguments are required); its tutorial uses ``nb_neighbors=20,
std_ratio=2.0`` and the threshold mean + std_ratio x std, its neighbours counting the point
itself (the same ranking as k - 1 others). The defaults here: ``io.outlier_k`` 20 (the
tutorial's, and ``normals.k``: the neighbourhood the fit treats as local surface) and
``io.outlier_std_ratio`` 3 (the three-sigma rule, which with robust statistics removes
0.2-0.6 % of the dev set's uniformly sampled clean scans, about 1 % of a sparse one or one
with a large hole's border). Why not the mean and std: the outliers widen them. On 10,000
points on a unit sphere with 2,500 uniform outliers in [-1.5, 1.5]^3, Open3D's rule
(nb_neighbors 21, std_ratio 2) keeps 1,264 outliers, 1,031 of them farther than 0.1 from the
sphere; the robust rule at 3 keeps 173, all within 0.08 of it, and no sphere point is
removed. Like Open3D's, the rule is global: a nonuniformly sampled scan loses its sparsest
parts (bunny-nonuniform 8 %), a noisy or sparse one 3-5 %.

:func:`outlier_summary` is the check every untiled fit makes at default settings, on the
k-nearest query the fit makes anyway (:func:`recon.fitting.pipeline.shared_neighbors`): the
fraction of points whose mean distance to their k nearest exceeds ``FAR_RATIO`` times the
median one. Above ``WARN_FRACTION`` the fit's report warns and names the flag.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.spatial import cKDTree

__all__ = [
    "FAR_RATIO",
    "MAD_TO_STD",
    "WARN_FRACTION",
    "far_fraction",
    "mean_knn_distance",
    "outlier_removal",
    "outlier_summary",
    "outlier_warnings",
    "statistical_outliers",
]

#: The standard deviation of a normal distribution over its median absolute deviation.
MAD_TO_STD = 1.4826

#: A point is "far" when its mean distance to its k nearest exceeds this many times the
#: median point's. On a sampled surface that distance grows as 1 / sqrt(density): 4x is a
#: 16 times sparser neighbourhood. The dev set's 26 scans without outliers have at most 0.2 %
#: of their points that far (hemisphere-nonuniform, sampled up to 5x sparser in places; the
#: uniformly sampled ones none); uniform outliers in a sphere's box are 4-15x farther.
FAR_RATIO = 4.0
#: ... and the fit warns when more than this fraction of the points is far: 10x the dev
#: set's largest without outliers, above bunny-outliers' 0.7 % (1 % outliers, some of them
#: near the surface, which the fit absorbs), below the 3.8 % and 13.5 % of spheres with 5 %
#: and 20 % uniform outliers in their box (10,000 points; the 20 % one comes out in 23 pieces
#: with 65 crossing face pairs, the 5 % one whole but with a coarser r0).
WARN_FRACTION = 0.02


def outlier_removal(io: Any) -> tuple[int, float] | None:
    """``(k, std_ratio)`` of the removal an ``io`` configuration section
    (:class:`~recon.config.IOConfig`) asks for, None when ``io.outliers`` is ``none``: the
    ``outliers`` argument of :func:`recon.io.read_points` and
    :func:`recon.io.cloud_from_arrays`."""
    if io.outliers == "statistical":
        return int(io.outlier_k), float(io.outlier_std_ratio)
    return None


def mean_knn_distance(
    points: np.ndarray, k: int, tree: cKDTree | None = None, workers: int = 1
) -> np.ndarray:
    """Each point's mean distance to its ``k`` nearest other points.

    Parameters
    ----------
    points : (n, 3) float64 [length]
    k : int
        Neighbours, the point itself not counted (at most n - 1 are used).
    tree : cKDTree, optional
        A k-d tree of ``points`` when one is built already.
    workers : int
        Threads of the query (the distances do not depend on it).

    Returns
    -------
    (n,) float64 [length]
    """
    n = len(points)
    k = min(int(k), n - 1)
    if k < 1:
        return np.zeros(n)
    tree = cKDTree(points) if tree is None else tree
    dist, _ = tree.query(points, k + 1, workers=workers)
    return dist[:, 1:].mean(axis=1)


def statistical_outliers(
    points: np.ndarray, k: int, std_ratio: float, workers: int = 1
) -> np.ndarray:
    """The points a statistical outlier removal drops: True where a point's mean distance to
    its ``k`` nearest exceeds ``median + std_ratio * 1.4826 * MAD`` of that distance.

    Deterministic: it depends only on the set of points and their order (the k-d tree's
    distances are exact), not on ``workers``.

    Parameters
    ----------
    points : (n, 3) float64 [length]
    k : int
        Neighbours (``io.outlier_k``), the point itself not counted.
    std_ratio : float
        Robust standard deviations above the median (``io.outlier_std_ratio``).
    workers : int
        Threads of the k-nearest query.

    Returns
    -------
    (n,) bool
        True for the outliers. When more than half the points have the same mean distance (a
        regular grid) the MAD is 0 and the plain standard deviation stands in for the spread.
    """
    mean = mean_knn_distance(points, k, workers=workers)
    if len(mean) == 0:
        return np.zeros(0, dtype=bool)
    median = float(np.median(mean))
    spread = MAD_TO_STD * float(np.median(np.abs(mean - median)))
    if spread == 0.0:  # more than half the points alike (a grid): nothing stands out
        spread = float(np.std(mean))
    return mean > median + std_ratio * spread


def far_fraction(mean: np.ndarray) -> float:
    """The fraction of points whose mean k-nearest distance ``mean`` exceeds ``FAR_RATIO``
    times the median one (0 for an empty array)."""
    if len(mean) == 0:
        return 0.0
    median = float(np.median(mean))
    return float(np.count_nonzero(mean > FAR_RATIO * median)) / len(mean)


def outlier_summary(
    info: dict[str, Any],
    points: np.ndarray,
    k: int,
    neighbors: tuple[np.ndarray, np.ndarray] | None = None,
    tree: cKDTree | None = None,
) -> dict[str, Any]:
    """What the fit's report says about outliers: the points removed on reading and the
    fraction of far points among the rest (:func:`far_fraction`).

    Parameters
    ----------
    info : dict
        The cloud's ``info`` (``n_outliers_removed`` when ``io.outliers`` removed some).
    points : (n, 3) float64 [length]
        The points the fit uses.
    k : int
        ``io.outlier_k``.
    neighbors : (distances, indices), optional
        A k-nearest query of ``points`` against themselves, nearest first (the point itself
        in column 0): its first ``k`` neighbours are used when it holds them, so the check
        costs no query of its own.
    tree : cKDTree, optional
        A k-d tree of ``points`` (for the query when ``neighbors`` is too narrow).

    Returns
    -------
    dict
        ``removed`` (int), ``k`` and ``far_fraction`` (float, rounded to 1e-4): the
        fit keeps it in its ``normals_info`` (the report's ``input.normals.outliers``).
    """
    k = min(int(k), len(points) - 1)
    if neighbors is not None and neighbors[0].shape[1] > k >= 1:
        mean = neighbors[0][:, 1 : k + 1].mean(axis=1)
    else:
        mean = mean_knn_distance(points, k, tree)
    return {
        "removed": int(info.get("n_outliers_removed", 0)),
        "k": k,
        "far_fraction": round(far_fraction(mean), 4),
    }


def outlier_warnings(normals_info: dict[str, Any]) -> list[str]:
    """The fit's warning when its :func:`outlier_summary` (``normals_info["outliers"]``) has
    more than ``WARN_FRACTION`` of far points: the fraction, and the flag that removes them."""
    summary = normals_info.get("outliers")
    if not summary or summary["far_fraction"] <= WARN_FRACTION:
        return []
    return [
        f"{100 * summary['far_fraction']:.1f} % of the input points are more than "
        f"{FAR_RATIO:g}x farther from their {summary['k']} nearest than the median point: "
        "the scan looks outlier-ridden (stray points can make extra pieces, crossing faces "
        "and a coarser spacing); "
        "--remove-outliers (io.outliers: statistical) removes them before the fit"
    ]
