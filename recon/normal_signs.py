"""Re-signing estimated data normals where both faces of a thin part share a neighbourhood.

Hoppe's propagation (:func:`recon.normals.orient_normals`) compares neighbours' normals by
``n_i . n_j``; where a sparse neighbourhood holds both faces of a thin part (bunny-sparse's
ear tips: 78 of 2,000 data normals of the wrong sign) or both faces of a knife edge, consistent
normals point more than 90 deg apart and it carries the wrong sign across. On clean data the
points' offsets along the normals are geometry, so the reflected dot products of
:func:`recon.particle_signs.reflected_dots` read the signs there;
:func:`recon.particle_signs.consistent_normals` re-signs the patches whose neighbours
disagree with them. On noisy data the offsets are mostly noise and the plain propagation is
kept.
"""

from __future__ import annotations

import logging

import numpy as np
from scipy.spatial import cKDTree

from .geometry import median_variation
from .kernels.options import query_workers
from .particle_signs import consistent_normals
from .thin_split import SIDES_GAP, SIDES_K, TAPER_GAP, thin_sides

__all__ = [
    "CLEAN_VARIATION",
    "THIN_SCAN_AGREE",
    "THIN_SCAN_SHARE",
    "outward_across",
    "resign_thin_parts",
]

log = logging.getLogger(__name__)

#: Data whose median PCA surface variation (:func:`recon.geometry.median_variation`, at the
#: normals' k) is below this counts as clean. Dev set: clean and sparse inputs 0.001-0.014,
#: 0.25 % noise 0.025-0.044, 1 % noise 0.18-0.20.
CLEAN_VARIATION = 0.02


def resign_thin_parts(
    points: np.ndarray,
    normals: np.ndarray,
    k: int,
    tree: cKDTree | None = None,
    variation: float | None = None,
    neighbors: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, int]:
    """Estimated normals with wrongly signed patches re-signed (clean data only), and how
    many normals were turned over (``tree``: a k-d tree of ``points`` if one is built;
    ``variation``: ``median_variation(points, k)`` when already measured, e.g. by
    :func:`recon.normals.choose_neighborhood_size`; ``neighbors``: the shared k-nearest
    query of ``points``, see :func:`recon.particle_signs.consistent_normals`). Directions
    never change."""
    if len(points) <= k:
        return normals, 0
    if variation is None:
        variation = median_variation(points, k, tree=tree)
    if variation >= CLEAN_VARIATION:
        return normals, 0
    out = consistent_normals(points, normals, tree=tree, neighbors=neighbors)
    n_flipped = int(np.count_nonzero(np.einsum("ij,ij->i", out, normals) < 0))
    log.debug("data normals re-signed across thin parts: %d", n_flipped)
    return out, n_flipped


#: A scan whose points' neighbourhoods span two faces (:func:`across_neighbours`) at least
#: this often has thin parts enough for :func:`outward_across` to sign it (a plate 1.2
#: spacings thick: 13 %; the test asks the faces half a neighbourhood radius apart) ...
THIN_SCAN_SHARE = 0.05
#: ... when its inward votes exceed the outward ones by at least this share of the votes
#: (0.5: three in four inward).
THIN_SCAN_AGREE = 0.5
#: Points per block of the vote (bounds its (block, SIDES_K) temporaries).
THIN_SCAN_CHUNK = 16384


def outward_across(
    points: np.ndarray,
    normals: np.ndarray,
    neighbors: np.ndarray | None = None,
    gap: float = SIDES_GAP,
    taper_gap: float = TAPER_GAP,
) -> tuple[np.ndarray, bool]:
    """Consistently signed normals of a scan with thin closed parts, turned outward as a
    whole: the other face of a thin part lies *behind* each face (the space
    between is inside). Returns the normals and whether they were turned over.

    The outward vote of :func:`orient_normals` reads the normals of the extreme points,
    which on a plate about a point spacing thick are mostly its rim's, whose PCA normals
    span both faces: 0.22 of their weight (the 0.5 a closed scan needs), so such a scan takes
    the open-scan rule (its least-variance axis up) and its sign is a guess. Here each point
    whose neighbourhood spans two faces (:func:`recon.thin_split.across_neighbours` over the
    ``SIDES_K`` nearest; ``neighbors``: each point's nearest, itself first, when already
    queried; ``gap``: ``normals.thin_gap``) votes with the mean offset of its
    neighbours on the other face along its normal: negative when they lie behind. When at
    least ``THIN_SCAN_SHARE`` of the points vote and the inward votes outnumber the outward
    ones by ``THIN_SCAN_AGREE`` of them (three in four inward), every sign is turned over;
    otherwise nothing changes (a scan without thin parts, or votes split). The fit asks this
    only of a scan that is one connected part signed by the open-scan rule. A scan whose
    two-sided neighbourhoods mostly span narrow gaps between outward faces (slots), not thin
    material, sees the other face in front and would be turned inside out.
    """
    n = len(points)
    if n <= SIDES_K:  # too few points for a wide neighbourhood
        return normals, False
    if neighbors is not None and neighbors.shape[1] >= SIDES_K + 1:
        wide = np.asarray(neighbors[:, : SIDES_K + 1])
    else:
        _, wide = cKDTree(points).query(points, k=SIDES_K + 1, workers=query_workers())
    behind = np.zeros(n)  # per two-sided point: -1 other face behind, +1 in front
    across, two_sided = thin_sides(
        points, normals, wide[:, 1:], SIDES_K, gap, taper_gap, THIN_SCAN_CHUNK
    )
    rows = np.flatnonzero(two_sided)
    for lo in range(0, len(rows), THIN_SCAN_CHUNK):
        r = rows[lo : lo + THIN_SCAN_CHUNK]
        offset = np.einsum("ijk,ik->ij", points[wide[r, 1:]] - points[r, None, :], normals[r])
        mean = np.sum(offset * across[r], axis=1) / np.maximum(across[r].sum(axis=1), 1)
        behind[r] = np.sign(mean)
    voters = int(np.count_nonzero(behind))
    inward = float(behind.sum())  # in front minus behind
    log.debug("thin-part sides: %d of %d points vote, %+d in front", voters, n, inward)
    if voters < THIN_SCAN_SHARE * n or inward < THIN_SCAN_AGREE * voters:
        return normals, False
    log.info("normal orientation: a thin part's faces turned outward (%d votes)", voters)
    return -normals, True
