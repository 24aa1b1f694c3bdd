"""Which neighbours of a point lie on the other face of a thin part: the split of its
neighbourhood's offsets along its normal into two faces.

Shared by the orientation's graph (:func:`recon.normals.orient_normals`: edges across a thin
part ask for opposed signs) and the vote that turns a thin scan outward
(:func:`recon.normal_signs.outward_across`). The split itself runs in
:mod:`recon.kernels.thin_sides`.
"""

from __future__ import annotations

import numpy as np

from .kernels.thin_sides import span_screen, split_sides_kernel

__all__ = ["SIDES_GAP", "SIDES_K", "SIDES_MIN", "SIDES_SEPARATION", "across_neighbours"]

#: A neighbourhood spans the two faces of a thin part when its offsets along the point's normal
#: split into two groups whose means are this many pooled standard deviations apart (one
#: Gaussian sheet splits at about 2.7; see ``across_neighbours``) ...
SIDES_SEPARATION = 5.0
#: ... and at least this fraction of the neighbourhood's radius apart (``normals.thin_gap``).
#: A sheet of curvature radius R spreads its offsets evenly over ``radius^2 / 2R``, whose
#: halves' means lie ``radius^2 / 4R`` apart: only R under half a radius (0.5) or 1.25 radii
#: (0.2), an undersampled surface, reaches it, and such a spread splits at 3.5 deviations ...
SIDES_GAP = 0.5
#: ... each group of at least this many points (itself included), of ``SIDES_K`` or more.
SIDES_MIN = 3
SIDES_K = 30


def across_neighbours(
    points: np.ndarray,
    normals: np.ndarray,
    idx: np.ndarray,
    k: int,
    start: int = 0,
    gap: float = SIDES_GAP,
) -> tuple[np.ndarray, np.ndarray]:
    """Which neighbours lie on the other face of a thin part.

    The offsets along n_i of i and its neighbours ``idx[i]`` (a wide neighbourhood) are split
    in two by 1-D two-means (the split of the sorted offsets with the least within-group sum
    of squares). The neighbourhood spans two faces when the groups' means lie more than
    ``SIDES_SEPARATION`` pooled standard deviations and ``gap`` neighbourhood radii
    apart, each group holding ``SIDES_MIN`` points. Noise around one sheet is one Gaussian
    group (its best split is about 2.7 deviations apart); two faces a thickness t apart with
    noise sigma split t / sigma apart.

    The rows of ``idx`` are the points ``start, start + 1, ...`` (a block of a large cloud).
    ``gap`` (``normals.thin_gap``, in (0, 1]): a smaller one finds faces closer together, where
    a blade thins towards its edge, and gathers more rows past the screen.

    Returns
    -------
    across : (n, k) bool
        Neighbour ``idx[i, j]`` (``j < k``) is in the group without i.
    two_sided : (n,) bool
        i's neighbourhood spans two faces (so its first ``k`` neighbours are classified).
    """
    if not gap > 0.0:
        raise ValueError(f"gap: expected a number > 0 (neighbourhood radii), got {gap}")
    n, k_wide = idx.shape
    if k_wide < SIDES_K:  # too few neighbours: a split would be chance
        return np.zeros((n, k), dtype=bool), np.zeros(n, dtype=bool)
    across, two_sided = np.zeros((n, k), dtype=bool), np.zeros(n, dtype=bool)
    sure = np.zeros(n, dtype=bool)  # certainly one-sided (most of a smooth scan): not gathered
    span_screen(points, normals, idx, start, float(gap), sure)
    rows = np.flatnonzero(~sure)
    if 2 * len(rows) > n:  # mostly unsure (noisy data): all rows, no sub-gathers (same rows)
        rows = np.arange(n)
    rel = points[idx[rows]] - points[start + rows, None, :]
    offsets = np.einsum("ijk,ik->ij", rel, normals[start + rows])
    radius = np.linalg.norm(rel[:, -1], axis=1)
    part, part_sided = np.zeros((len(rows), k), dtype=bool), np.zeros(len(rows), dtype=bool)
    args = (SIDES_MIN, SIDES_SEPARATION, float(gap), part, part_sided)
    split_sides_kernel(offsets, radius, k, *args)  # the split, row by row
    across[rows], two_sided[rows] = part, part_sided
    return across, two_sided
