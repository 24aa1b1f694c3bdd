"""The types a fit returns: :class:`FitResult` (:class:`Mesh`, :class:`Particles` and the
report) from :func:`recon.fitting.pipeline.fit` and :func:`~recon.fitting.pipeline.reconstruct`,
and :class:`ParticleFit`, the particle sheet of one tile
(:func:`~recon.fitting.pipeline.fit_particles`). :mod:`recon.fitting.pipeline` re-exports them.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..config import ReconConfig
from .report import FitReport

__all__ = ["FitResult", "Mesh", "ParticleFit", "Particles"]


@dataclass
class Mesh:
    """A triangle mesh in absolute (file) coordinates."""

    vertices: np.ndarray  # (V, 3) float64 [length]
    faces: np.ndarray  # (F, 3) int64
    normals: np.ndarray  # (V, 3) float64 unit vertex normals
    crease: np.ndarray | None = None  # (V,) bool: on a crease line or corner (creases.fit)


@dataclass
class Particles:
    """The final oriented particles in absolute (file) coordinates."""

    positions: np.ndarray  # (n, 3) float64 [length]
    normals: np.ndarray  # (n, 3) float64


@dataclass
class FitResult:
    """What a fit returns: the mesh, the particles and the report.

    Attributes
    ----------
    mesh : Mesh
    particles : Particles
    report : FitReport
        ``report.to_dict()`` is the JSON of ``<mesh>.report.json``.
    origin : (3,) float64 [length]
        The cloud's origin (mesh and particles are already absolute).
    """

    mesh: Mesh
    particles: Particles
    report: FitReport
    origin: np.ndarray = field(default_factory=lambda: np.zeros(3))


@dataclass
class ParticleFit:
    """The particle sheet of one fit, before triangulation (:func:`fit_particles`).

    Attributes
    ----------
    positions : (n, 3) float64 [length]
        Absolute (file) coordinates.
    normals : (n, 3) float64
    rest : (n,) float64 [r0] or None
        Each particle's rest spacing with ``seeds.adaptive``; None otherwise.
    r0 : float [length]
    config : ReconConfig
        The configuration as resolved by the fit (``normals.k``, ``growth.max_gap``, ``dt``).
    n_trimmed : int
    steps : dict
    warnings : list of str
    stop_reason : str or None
    crease : (n,) bool or None
        The crease particles (unoriented, on a crease line or corner) when creases were
        fitted, else None: the triangulation pivots and flips around them
        (:func:`recon.triangulate.triangulate_particles`), as the untiled fit's does.
    """

    positions: np.ndarray
    normals: np.ndarray
    rest: np.ndarray | None
    r0: float
    config: ReconConfig
    n_trimmed: int
    steps: dict
    warnings: list
    stop_reason: str | None
    crease: np.ndarray | None = None
