"""The fit: points in, mesh + particles + report out.

Modules
-------
- :mod:`recon.fit.scale`: the length scales from the data (r0, neighbourhood size, max gap);
- :mod:`recon.fit.schedule`: seeds, growth rounds and release, with the divergence retry;
- :mod:`recon.fit.report`: the typed report and the measurements of the mesh;
- :mod:`recon.fit.pipeline`: :func:`fit`, :func:`reconstruct` and :func:`fit_file`.

The package itself is callable: ``recon.fit(points, config)`` is :func:`fit` (``recon.fit`` is
both this package and the library's main function, so the module calls :func:`fit`).

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

import sys
import types
from typing import Any

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


class _CallableModule(types.ModuleType):
    """This package's module type: calling it calls :func:`fit`."""

    def __call__(self, *args: Any, **kwargs: Any) -> FitResult:
        return fit(*args, **kwargs)


sys.modules[__name__].__class__ = _CallableModule
