"""Which neighbours of a point lie on the other face of a thin part: the split of its
neighbourhood's offsets along its normal into two faces.

Where a blade tapers to its edge, its faces come closer than the gap test's ``gap`` radii long
before they meet. :func:`thin_sides` then also keeps the rows that split at the smaller
``taper_gap`` (hysteresis, as in Canny's edge linking): those joined, through two-sided rows,
to a patch of at least ``TAPER_MIN_STRONG`` rows that pass the full gap. A part thinner than
``gap`` everywhere has no such patch and keeps the signs the full gap gives it (its faces
are then meshed as one layer); the faces of a part that is thicker somewhere are told apart
down to its edge.

Shared by the orientation's graph (:func:`recon.normals.orient_normals`: edges across a thin
part ask for opposed signs) and the vote that turns a thin scan outward
(:func:`recon.normal_signs.outward_across`). The split itself runs in
:mod:`recon.kernels.thin_sides`.
"""

from __future__ import annotations

import numpy as np
from scipy import sparse
from scipy.sparse import csgraph

from .kernels.thin_sides import span_screen, split_sides_kernel

__all__ = [
    "SIDES_GAP",
    "SIDES_K",
    "SIDES_MIN",
    "SIDES_SEPARATION",
    "TAPER_GAP",
    "TAPER_MIN_STRONG",
    "across_neighbours",
    "thin_sides",
]

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
#: Rows that split only at this smaller gap (``normals.thin_gap_taper``) count where they are
#: joined to a patch of at least ``TAPER_MIN_STRONG`` rows that split at the full gap: a
#: third of a neighbourhood, a patch rather than a few rows where a curve or the noise crossed
#: the gap (a 3,000-point knife, thinner than a spacing everywhere, shows 0-3 such rows; the
#: 5,000-point one, 1.7 spacings thick in its middle, 82-120).
TAPER_GAP = 0.2
TAPER_MIN_STRONG = SIDES_K // 3


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


def thin_sides(
    points: np.ndarray,
    normals: np.ndarray,
    idx: np.ndarray,
    k: int,
    gap: float = SIDES_GAP,
    taper_gap: float = TAPER_GAP,
    chunk: int = 16384,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`across_neighbours` for every point, with the taper rule of the module
    docstring: ``idx`` (n, K) holds each point's K >= ``SIDES_K`` nearest (itself not
    among them); ``taper_gap`` (``normals.thin_gap_taper``): rows that split only at this
    smaller gap count when joined to a patch that splits at ``gap`` (0, or at least ``gap``:
    off); ``chunk``: rows split at a time (the split holds ~10 (chunk, K) arrays).

    Returns ``across`` (n, k) and ``two_sided`` (n,), as :func:`across_neighbours`."""
    across, two_sided = _blocks(points, normals, idx, k, gap, chunk)
    # the best split of a row does not depend on the gap, only its test: the rows that split
    # at the full gap split alike at the smaller one (fewer than TAPER_MIN_STRONG: no patch)
    if 0.0 < taper_gap < gap and np.count_nonzero(two_sided) >= TAPER_MIN_STRONG:
        strong = two_sided
        across, two_sided = _blocks(points, normals, idx, k, taper_gap, chunk)
        weak = _unlinked_taper(idx, two_sided, strong)
        two_sided[weak] = False
        across[weak] = False
    return across, two_sided


def _blocks(
    points: np.ndarray, normals: np.ndarray, idx: np.ndarray, k: int, gap: float, chunk: int
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`across_neighbours` of every row of ``idx``, ``chunk`` rows at a time."""
    n = len(idx)
    across = np.zeros((n, k), dtype=bool)
    two_sided = np.zeros(n, dtype=bool)
    for lo in range(0, n, chunk):
        hi = min(lo + chunk, n)
        across[lo:hi], two_sided[lo:hi] = across_neighbours(points, normals, idx[lo:hi], k, lo, gap)
    return across, two_sided


def _unlinked_taper(idx: np.ndarray, two_sided: np.ndarray, strong: np.ndarray) -> np.ndarray:
    """The two-sided rows that are not ``strong`` and not joined (neighbour to neighbour in
    ``idx``, through two-sided rows) to at least ``TAPER_MIN_STRONG`` strong rows."""
    rows = np.flatnonzero(two_sided)
    m = len(rows)
    if m == 0:
        return rows
    pos = np.full(len(two_sided), -1, dtype=np.int64)
    pos[rows] = np.arange(m)
    nb = idx[rows]
    linked = two_sided[nb]
    a = np.repeat(np.arange(m), nb.shape[1])[linked.ravel()]
    b = pos[nb[linked]]
    graph = sparse.coo_matrix((np.ones(len(a), dtype=np.int8), (a, b)), shape=(m, m))
    n_parts, part = csgraph.connected_components(graph, directed=False)
    count = np.bincount(part[strong[rows]], minlength=n_parts)
    keep = strong[rows] | (count[part] >= TAPER_MIN_STRONG)
    return rows[~keep]
