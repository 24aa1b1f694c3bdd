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
from .particle_signs import consistent_normals

__all__ = ["CLEAN_VARIATION", "resign_thin_parts"]

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
