"""Per-point neighbourhood size for the PCA normals across thin parts.

Where a part is about as thick as a k-neighbourhood is wide, that neighbourhood holds both
faces and is as tall as it is wide (the smallest two eigenvalues ``l0 ~ l1``): its smallest
eigenvector can lie in the faces' plane. The thin-part split and the orientation
(:func:`recon.normals.orient_normals`) then fail with it. Measured on the held-out knife
(``bench_thin_parts.py --shapes knife --noise 0.0001``: k = 20, since the data is clean), 20-47 %
of the normals were 25 deg or more off where the blade is 1-2 r0 thick, and 12-36 % of the
signs were wrong there; at the default noise the noise rule had taken k = 80, whose flat
discs hold both faces with their normal, and no sign was wrong up to 0.92 of the half-length.

A point whose k-neighbourhood is not as thin as the noise rule asks (surface variation
``THIN_VARIATION`` or more) therefore takes, of its ``k``, ``2 k``, ``4 k`` ... nearest (up
to the noise rule's widest), the neighbourhood whose normal is best determined: the least
ratio ``l0 / l1`` (per-point scale selection, after [MNG04]). A wider one counts only where
it is thin itself or holds the two faces of a thin part (its offsets along its normal split
in two groups ``separation`` pooled deviations apart: the test of
:func:`recon.thin_split.across_neighbours` without its gap). Across a crease or a wedge's edge
the offsets along a wide normal, the bisector's, spread with the distance from the edge and
do not split, so the point keeps its own scale.

References
----------
[MNG04] N. J. Mitra, A. Nguyen, L. Guibas. "Estimating surface normals in noisy point cloud
        data". International Journal of Computational Geometry & Applications 14(4-5), 2004.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy.spatial import cKDTree

from .errors import ConfigError
from .geometry import median_variation
from .kernels.pca import scatter_matrices
from .kernels.thin_sides import split_sides_kernel

__all__ = [
    "MAX_K",
    "MAX_SCALE",
    "THIN_VARIATION",
    "best_scale_normals",
    "choose_neighborhood_size",
    "neighbourhood_scales",
    "per_point_k_max",
    "radius_counts",
    "radius_weights",
    "wider_query",
]

#: The widest neighbourhood the normals take, in multiples of ``normals.k``: the noise rule
#: (:func:`choose_neighborhood_size`) and the per-point scale (:func:`best_scale_normals`).
MAX_SCALE = 4
#: The most neighbours the noise rule raises ``normals.k`` to: the top of that key's range
#: (recon/config.py), so that a raised k is one a user could have set.
MAX_K = 500
#: Median PCA surface variation lambda_0 / (lambda_0 + lambda_1 + lambda_2) below which a
#: neighbourhood counts as thin (clean data: <= 0.016; 1 % noise at k = 20: ~0.18).
THIN_VARIATION = 0.05


def per_point_k_max(k: int, per_point_scale: bool) -> int | None:
    """The widest neighbourhood a point's normal may take: ``MAX_SCALE`` x the configured
    ``normals.k`` when ``normals.per_point_scale`` is on, else None (one k for every point)."""
    return MAX_SCALE * k if per_point_scale else None


def choose_neighborhood_size(
    points: np.ndarray,
    k: int,
    sample: int = 4000,
    tree: cKDTree | None = None,
    variations: dict[int, float] | None = None,
    limit: int = MAX_K,
) -> int:
    """Neighbourhood size for normals and local surfaces: k, doubled while the data is noisy.

    The median surface variation of k-neighbourhoods (PCA) is near 0 on clean surfaces and
    grows with noise; wider neighbourhoods average the noise. Returns the smallest of
    k, 2k, 4k whose median variation is below ``THIN_VARIATION`` (4k at most: wider
    neighbourhoods mix the two sides of thin parts; measured on the 1 %-noise bunny, sign
    consistency 99.3 % at k = 80 but 94.6 % at k = 160), each capped at ``limit`` (the top
    of ``normals.k``'s range) and at the number of points; k itself when it is already at
    a cap. ``tree``: one of ``points`` if built.
    ``variations``: a dict that receives each median variation measured, by k (the chosen k's
    among them, which :func:`recon.normal_signs.resign_thin_parts` need not measure again).
    """
    n = len(points)
    tree = cKDTree(points) if tree is None else tree
    variations = {} if variations is None else variations
    chosen = k
    cap = min(n, max(k, limit))
    for factor in (1, 2, MAX_SCALE):
        kk = min(k * factor, cap)
        chosen = kk
        variations[kk] = variation = median_variation(points, kk, sample, tree)
        if variation < THIN_VARIATION or kk >= cap:
            break
    return int(chosen)


def neighbourhood_scales(k: int, k_max: int | None, n: int) -> list[int]:
    """The neighbourhood sizes compared: ``k``, ``2 k``, ``4 k`` ... up to ``k_max`` (and
    ``n``); ``[k]`` without ``k_max``.

    >>> neighbourhood_scales(20, 80, 10_000), neighbourhood_scales(40, 80, 10_000)
    ([20, 40, 80], [40, 80])
    """
    scales = [k]
    while k_max is not None and 2 * scales[-1] <= min(k_max, n):
        scales.append(2 * scales[-1])
    return scales


def wider_query(
    pts: np.ndarray,
    neighbors: tuple[np.ndarray, np.ndarray] | None,
    tree: cKDTree | None,
    k: int,
    workers: int,
) -> Callable[[np.ndarray], np.ndarray]:
    """``at -> (len(at), k)``: the nearest ``k`` of the points ``pts[at]``, from ``neighbors``
    (a shared query of at least ``k`` columns) when given, else from ``tree``'s query."""
    if neighbors is not None:
        return lambda at: neighbors[1][at, :k]
    return lambda at: tree.query(pts[at], k=k, workers=workers)[1].reshape(len(at), k)


def best_scale_normals(
    pts: np.ndarray,
    query: np.ndarray,
    idx: np.ndarray,
    scales: list[int],
    sides_min: int,
    separation: float,
    wider: Callable[[np.ndarray], np.ndarray] | None = None,
) -> np.ndarray:
    """Unit normals of the rows ``query`` (points of ``pts``, each its own nearest), from the
    best determined of their nearest ``scales[0]``, ``scales[1]`` ... as the module docstring
    says; the first scale's on a tie. ``idx`` (m, >= ``scales[0]``): each row's nearest,
    nearest first; ``wider(rows)``: the nearest ``scales[-1]`` of those rows, asked only for
    the rows whose first neighbourhood is not thin (default: ``idx``'s own columns)."""
    centre = np.ascontiguousarray(query)

    def decompose(rows_idx: np.ndarray, centres: np.ndarray) -> tuple:
        cov = np.empty((len(centres), 3, 3))
        scatter_matrices(pts, np.ascontiguousarray(rows_idx), centres, True, cov)
        vals, vecs = np.linalg.eigh(cov)
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where(vals[:, 1] > 0.0, vals[:, 0] / vals[:, 1], np.inf)
        thin = vals[:, 0] < THIN_VARIATION * np.maximum(vals.sum(axis=1), 1e-300)
        return ratio, thin, vecs[:, :, 0]

    ratio, thin, out = decompose(idx[:, : scales[0]], centre)
    rows = np.flatnonzero(~thin)  # the first scale's normal stands where it is thin
    if len(scales) > 1 and len(rows):
        idx_w = idx[rows] if wider is None else wider(rows)
        c = np.ascontiguousarray(centre[rows])
        best, sub = ratio[rows], out[rows]
        for kk in scales[1:]:
            ratio_w, thin_w, normal_w = decompose(idx_w[:, :kk], c)
            sel = np.flatnonzero(ratio_w < best)
            offsets = np.einsum(
                "rqi,ri->rq", pts[idx_w[sel, 1:kk]] - c[sel, None, :], normal_w[sel]
            )
            two_faces = np.zeros(len(sel), dtype=bool)
            no_columns = np.zeros((len(sel), 0), dtype=bool)
            # the split alone (no gap test: radius 0), no neighbour classified (k = 0)
            split_sides_kernel(
                offsets, np.zeros(len(sel)), 0, sides_min, separation, 0.0, no_columns, two_faces
            )
            sel = sel[two_faces | thin_w[sel]]
            best[sel] = ratio_w[sel]
            sub[sel] = normal_w[sel]
        out[rows] = sub
    return out / np.linalg.norm(out, axis=1, keepdims=True)


def radius_weights(
    dist: np.ndarray, radius: float, stats: dict[str, np.ndarray] | None, rows: slice
) -> np.ndarray:
    """0/1 PCA weights of each row's nearest (``dist`` (m, k), nearest first, itself the
    first): those within ``radius``, or all of them where fewer than 3 are (a plane needs 3
    points). ``stats`` (with ``inside``, ``third_distance``, ``kth_distance`` arrays over all
    points, of which these are ``rows``): the count within the radius and the radii that hold
    the 3 and k nearest."""
    inside = dist <= radius
    count = inside.sum(axis=1)
    if stats is not None:
        stats["inside"][rows] = count
        stats["third_distance"][rows] = dist[:, min(2, dist.shape[1] - 1)]
        stats["kth_distance"][rows] = dist[:, -1]
    return np.where((count >= 3)[:, None], inside, True).astype(np.float64)


def radius_counts(where: str, radius: float, k: int, stats: dict[str, np.ndarray]) -> dict:
    """What ``normals.radius`` did, from :func:`recon.normals.estimate_normals`'s ``stats``
    (``k``: the neighbours it took): ``n_radius_trimmed``, the points that took fewer than
    their k nearest, and ``n_radius_fallback``, those with fewer than 3 within it, which
    took their k nearest. Refused (a :class:`~recon.errors.ConfigError` naming ``where``)
    when more than half the points fall back: the radius would then change little while
    seeming to work; the message gives radii that would."""
    inside = stats["inside"]
    n = len(inside)
    fallback = int(np.count_nonzero(inside < 3))
    if fallback > n / 2:
        raise ConfigError(
            f"{where}: normals.radius = {radius:g} holds fewer than 3 points (each point "
            f"itself included) for {fallback:,} of {n:,} points, which would take their {k} "
            f"nearest instead. Use a radius of at least "
            f"{float(np.quantile(stats['third_distance'], 0.9)):.3g} (3 points for 90 % of "
            f"them; {float(np.median(stats['kth_distance'])):.3g} holds the {k} nearest of "
            "half of them), or none (the k nearest alone)"
        )
    return {
        "n_radius_trimmed": int(np.count_nonzero((inside >= 3) & (inside < k))),
        "n_radius_fallback": fallback,
    }
