"""Seed particles: Poisson-disk thinning of the data, pinned in position and frame.

S&T92 §7 starts a reconstruction from particles placed at the sample locations with their
position and orientation fixed; growth then fills between them. Dense inputs are thinned first so
that seeds sit about one rest spacing apart (otherwise the pinned seeds fight the spacing
potential). Every input point still counts for coverage and fidelity. The thinning itself
(:func:`recon.geometry.poisson_disk_thin`) is shared with the growth stage.

The seeds are then projected onto the data's local surfaces (:meth:`recon.surface.DataSurface.
project`), which can bring two of them to one place where those surfaces squash the data: on
a handful of points (a cube's 8 corners, an octahedron) every neighbourhood holds the whole
cloud, whose covariance has no thin direction, and all the points share one local plane
through the centre; two points on either side of it project to the same foot. Two particles at
one place have no defined force, and the dynamics stopped with a message blaming duplicate
points in the input. :func:`seed_particles` keeps the first of such seeds.

References
----------
[ST92] Szeliski & Tonnesen 1992, §7.
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

import numpy as np
from scipy.spatial import cKDTree

from .geometry import poisson_disk_thin

if TYPE_CHECKING:
    from .surface import DataSurface

__all__ = ["COINCIDENT", "distinct_seeds", "seed_particles", "select_seeds"]

logger = logging.getLogger(__name__)

#: Projected seeds nearer than this fraction of the thinning spacing count as one place.
COINCIDENT = 1e-3


def select_seeds(points: np.ndarray, spacing: float, rng: np.random.Generator) -> np.ndarray:
    """Indices of seed points: a Poisson-disk subset of ``points`` at ``spacing``.

    The visiting order is a permutation drawn from ``rng``, so a fixed seed gives fixed seeds.
    """
    order = rng.permutation(len(points))
    keep = poisson_disk_thin(points, spacing, order)
    return np.flatnonzero(keep)


def seed_particles(
    surface: DataSurface, spacing: float, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The seed particles: :func:`select_seeds` of the surface's points, projected onto the
    local surfaces, without those that land where an earlier one did (:func:`distinct_seeds`;
    a warning says how many).

    Parameters
    ----------
    surface : DataSurface
        The data in r0 units.
    spacing : float [r0]
        The thinning distance (``seeds.thinning``).
    rng : numpy.random.Generator
        Draws the visiting order of the thinning.

    Returns
    -------
    idx : (m,) int64
        The data points the seeds come from, ascending.
    positions : (m, 3) float64 [r0]
        Their projections onto the local surfaces, pairwise at least ``COINCIDENT`` x
        ``spacing`` apart.
    normals : (m, 3) float64
        The surface normals there.
    """
    idx = select_seeds(surface.points, spacing, rng)
    pos, nrm, offsets = surface.project(surface.points[idx], surface.normals[idx])
    keep = distinct_seeds(pos, offsets, spacing)
    if not keep.all():
        logger.warning(
            "%d of %d seed particles fell on the same place as another once projected onto "
            "the data's local surfaces, and were dropped: the local surfaces squash the data "
            "(too few points, or a symmetric cloud whose every neighbourhood spans the whole "
            "of it and has no thin direction); the mesh may not follow the input",
            int(np.count_nonzero(~keep)),
            len(keep),
        )
        idx, pos, nrm = idx[keep], pos[keep], nrm[keep]
    return idx, pos, nrm


def distinct_seeds(
    positions: np.ndarray, offsets: np.ndarray, spacing: float, tolerance: float = COINCIDENT
) -> np.ndarray:
    """Which projected seeds to keep: all but those within ``tolerance`` x ``spacing`` of an
    earlier kept one (the first of each place is kept).

    The seeds were at least ``spacing`` apart before their projection, which moved each by
    ``|offset|``; two come within ``t = tolerance x spacing`` of each other only if
    ``|o_i| + |o_j| > spacing - t``, so one of them moved at least ``(spacing - t) / 2``. Only
    the neighbourhoods of those are searched: none on ordinary data (the seeds move by the
    noise, a fraction of the spacing), and the result is then all True at no cost.

    Parameters
    ----------
    positions : (m, 3) float64 [r0]
        Projected seeds.
    offsets : (m,) float64 [r0]
        How far each moved (signed, along its normal).
    spacing : float [r0]
        The thinning distance they had before.
    tolerance : float
        Nearer than this fraction of ``spacing`` is the same place.

    Returns
    -------
    (m,) bool
    """
    keep = np.ones(len(positions), dtype=bool)
    near = tolerance * spacing
    moved = np.flatnonzero(np.abs(offsets) >= 0.5 * (spacing - near))
    if len(moved) == 0:
        return keep
    earlier: dict[int, list[int]] = {}  # seed -> the lower-numbered seeds at its place
    found = cKDTree(positions).query_ball_point(positions[moved], near)
    for i, others in zip(moved.tolist(), found, strict=True):
        for j in others:
            if j != i:
                a, b = min(i, j), max(i, j)
                earlier.setdefault(b, []).append(a)
    for b in sorted(earlier):
        if any(keep[a] for a in earlier[b]):
            keep[b] = False
    return keep
