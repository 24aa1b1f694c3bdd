"""The fit: points in, mesh + particles + report out.

Modules
-------
- :mod:`recon.fitting.scale`: the length scales from the data (r0, neighbourhood size, max gap);
- :mod:`recon.fitting.schedule`: seeds, growth rounds and release, with the divergence retry;
- :mod:`recon.fitting.report`: the typed report and the measurements of the mesh;
- :mod:`recon.fitting.pipeline`: :func:`fit`, :func:`reconstruct` and :func:`fit_file`;
- :mod:`recon.fitting.library`: the checks before a fit that :func:`fit` and :func:`fit_file`
  share (the config's kinds, the progress callback, ``io.max_points``, ``io.max_memory``);
- :mod:`recon.fitting.results`: what a fit returns (:class:`FitResult`, :class:`Mesh`,
  :class:`Particles`, :class:`ParticleFit`);
- :mod:`recon.fitting.collector`: the garbage collector kept off the objects alive before a fit.

``recon.fit(points, config)`` (the library's main function) is :func:`fit` from here.

Examples
--------
>>> import numpy as np, recon
>>> rng = np.random.default_rng(0)
>>> p = rng.normal(size=(800, 3))
>>> result = recon.fit(p / np.linalg.norm(p, axis=1, keepdims=True))  # doctest: +SKIP
>>> result.report.topology.watertight  # doctest: +SKIP
True
"""

from __future__ import annotations

from .pipeline import FitResult, Mesh, Particles, fit, fit_file, reconstruct
from .report import (
    Fidelity,
    FitReport,
    History,
    InputSummary,
    MeshToInput,
    OutputPaths,
    StepCounts,
    Timings,
    Topology,
    TriangleQuality,
    TriangulationStats,
    report_path_for,
)
from .scale import choose_spacing
from .schedule import ProgressFn

__all__ = [
    "Fidelity",
    "FitReport",
    "FitResult",
    "History",
    "InputSummary",
    "Mesh",
    "MeshToInput",
    "OutputPaths",
    "Particles",
    "ProgressFn",
    "StepCounts",
    "Timings",
    "Topology",
    "TriangleQuality",
    "TriangulationStats",
    "choose_spacing",
    "fit",
    "fit_file",
    "reconstruct",
    "report_path_for",
]
