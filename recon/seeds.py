"""Seed particles: Poisson-disk thinning of the data, pinned in position and frame.

S&T92 §7 starts a reconstruction from particles placed at the sample locations with their
position and orientation fixed; growth then fills between them. Dense inputs are thinned first so
that seeds sit about one rest spacing apart (otherwise the pinned seeds fight the spacing
potential). Every input point still counts for coverage and fidelity. The thinning itself
(:func:`recon.geometry.poisson_disk_thin`) is shared with the growth stage.

References
----------
[ST92] Szeliski & Tonnesen 1992, §7.
"""

from __future__ import annotations

import numpy as np

from .geometry import poisson_disk_thin


def select_seeds(points: np.ndarray, spacing: float, rng: np.random.Generator) -> np.ndarray:
    """Indices of seed points: a Poisson-disk subset of ``points`` at ``spacing``.

    The visiting order is a permutation drawn from ``rng``, so a fixed seed gives fixed seeds.
    """
    order = rng.permutation(len(points))
    keep = poisson_disk_thin(points, spacing, order)
    return np.flatnonzero(keep)
