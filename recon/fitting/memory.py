"""Predictable memory: the peak resident memory of a whole fit, estimated before it starts.

The estimate is linear in the input points and the particles the sheet will hold::

    peak = BASE_BYTES + BYTES_PER_POINT * n_points + BYTES_PER_PARTICLE * n_particles

with ``n_particles = AREA_PER_POINT * n_points * (d_nn / r0)^2 / HEX_AREA`` (the data's area
over the area of one particle of a hexagonal sheet at spacing r0; ``d_nn`` is the median
point spacing), capped by ``dynamics.max_particles``. The constants were fitted to the peak RSS
of whole ``oprecon fit`` runs, so that the estimate is never below the measured peak
(``python benchmarks/bench_memory.py --points 20000 80000 --spacing-factors 1 2.5
--scale-json scale.json --fit``: synthetic terrain + building scenes at r0 = 1 and 2.5 median
spacings, and the 100k, 1M and 4M-point tori of ``benchmarks/bench_scale.py``); measured, it
is 1 to 46 % above the peak (``ESTIMATE_FACTOR``); the README gives the table.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..config import ReconConfig, parse_size
from ..errors import InputError
from .scale import AREA_PER_POINT, HEX_AREA, choose_spacing

__all__ = [
    "BASE_BYTES",
    "BYTES_PER_PARTICLE",
    "BYTES_PER_POINT",
    "ESTIMATE_FACTOR",
    "MemoryEstimate",
    "check_memory",
    "estimate_fit_memory",
    "estimate_peak_memory",
    "format_bytes",
    "parse_size",
]

#: The process before any data: Python, numpy, scipy, numba and the JIT-compiled kernels
#: (350 MiB since the commands keep freed memory for reuse, :mod:`recon.heap`; 330 before).
BASE_BYTES = 350 * 2**20
#: Per input point: coordinates, normals, k-d trees, neighbourhoods, local surfaces.
BYTES_PER_POINT = 125
#: Per particle at the peak: state, neighbour lists, growth candidates, triangulation.
BYTES_PER_PARTICLE = 2700
#: The estimate lies within this factor of the measured peak (from 20k to 4M points: 1.01 to
#: 1.46 times it, never below; README, "Predictable memory").
ESTIMATE_FACTOR = 1.5
#: The estimate's particle count never exceeds this (an r0 many orders of magnitude below the
#: data's spacing asks for more particles than a float counts exactly).
MAX_ESTIMATED_PARTICLES = float(2**53)


@dataclass(frozen=True)
class MemoryEstimate:
    """The estimated peak of one fit.

    Attributes
    ----------
    points : int
    particles : int
        Predicted particle count at spacing r0.
    peak_bytes : int
    """

    points: int
    particles: int
    peak_bytes: int

    def to_dict(self) -> dict[str, int]:
        return {
            "points": self.points,
            "particles": self.particles,
            "peak_bytes": self.peak_bytes,
        }


def estimate_peak_memory(
    n_points: int, r0: float, median_spacing: float, max_particles: int | None = None
) -> MemoryEstimate:
    """Estimated peak resident memory of a fit of ``n_points`` at rest spacing ``r0``.

    Parameters
    ----------
    n_points : int
    r0 : float [length]
    median_spacing : float [length]
        Median nearest-neighbour distance of the points.
    max_particles : int, optional
        The particle cap (``dynamics.max_particles``): the sheet never holds more.

    Returns
    -------
    MemoryEstimate

    Examples
    --------
    A million points at the default r0 (2.5 median spacings):

    >>> e = estimate_peak_memory(1_000_000, 2.5, 1.0)
    >>> e.particles, round(e.peak_bytes / 2**30, 2)
    (739030, 2.32)
    """
    ratio = float(median_spacing) / float(r0) if r0 > 0 else 0.0
    # as floats: an r0 far below the spacing overflows to inf, which the caps bound (and no
    # points need no particles, whatever the ratio: 0 x inf would be nan)
    wanted = AREA_PER_POINT * n_points * (ratio * ratio) / HEX_AREA if n_points > 0 else 0.0
    if max_particles is not None:
        wanted = min(wanted, float(max_particles))
    particles = int(round(min(wanted, MAX_ESTIMATED_PARTICLES)))
    peak = BASE_BYTES + BYTES_PER_POINT * n_points + BYTES_PER_PARTICLE * particles
    return MemoryEstimate(int(n_points), particles, int(peak))


def format_bytes(n: float) -> str:
    """``'1.5 GiB'`` style.

    Examples
    --------
    >>> format_bytes(3 * 2**29), format_bytes(512 * 2**20)
    ('1.5 GiB', '512 MiB')
    """
    for unit, size in (("TiB", 2**40), ("GiB", 2**30), ("MiB", 2**20), ("KiB", 2**10)):
        if n >= size:
            v = n / size
            return f"{v:.1f} {unit}" if v < 10 else f"{v:.0f} {unit}"
    return f"{int(n)} B"


def check_memory(
    estimate: MemoryEstimate, limit: str | int | None, r0: float, *, key: str = "--max-memory"
) -> None:
    """Raise :class:`~recon.errors.InputError` when the estimate exceeds ``limit``.

    The message says what to do: the spacing at which the fit would fit in the limit (the
    particle term scales with 1/r0^2).
    """
    if limit is None:
        return
    cap = parse_size(limit, key) if isinstance(limit, str) else int(limit)
    if estimate.peak_bytes <= cap:
        return
    fixed = BASE_BYTES + BYTES_PER_POINT * estimate.points
    hint = "thin the input (fewer points)"
    if BASE_BYTES >= cap:
        hint = f"oprecon itself needs about {format_bytes(BASE_BYTES)}"
    elif fixed < cap and estimate.particles > 0:
        room = (cap - fixed) / BYTES_PER_PARTICLE
        factor = (estimate.particles / room) ** 0.5
        hint = f"use a larger --spacing (at least {1.05 * factor * r0:.4g}, now {r0:.4g})"
    raise InputError(
        f"the fit needs an estimated {format_bytes(estimate.peak_bytes)} at peak "
        f"({estimate.points:,} points, ~{estimate.particles:,} particles at r0 = {r0:.4g}), "
        f"more than {key} {format_bytes(cap)}; {hint}, fit in tiles (--tiles auto), or raise "
        f"{key}"
    )


def estimate_fit_memory(points: np.ndarray, cfg: ReconConfig) -> MemoryEstimate:
    """The estimate for a fit of ``points`` with ``cfg`` (r0 as the fit will choose it).

    Raises
    ------
    InputError
        The estimate exceeds ``io.max_memory`` (the message says which spacing would fit).
    """
    r0, d_nn = choose_spacing(points, cfg)
    estimate = estimate_peak_memory(len(points), r0, d_nn, cfg.dynamics.max_particles)
    check_memory(estimate, cfg.io.max_memory, r0)
    return estimate
