"""Keep the heavy parts of third-party packages that no command uses out of start-up.

``import open3d`` (0.20) also imports its plotly viewer, ``open3d.visualization.draw_plotly``,
which pulls in dash, plotly and asyncio: about 0.7 s of the 1.2 s the import takes, paid by
every fit (ball pivoting and the distance queries use Open3D). :func:`defer_open3d_plotly`
registers a stand-in for that one module before open3d is imported; its three functions load
the real module on their first call and forward to it, so a program that uses Open3D's plotly
viewer next to oprecon still can.
"""

from __future__ import annotations

import importlib
import sys
import types
from collections.abc import Callable

#: The open3d module the stand-in replaces, and the functions open3d imports from it.
PLOTLY_MODULE = "open3d.visualization.draw_plotly"
PLOTLY_FUNCTIONS = ("get_plotly_fig", "draw_plotly", "draw_plotly_server")


def _load_real() -> types.ModuleType:
    stand_in = sys.modules.get(PLOTLY_MODULE)
    if stand_in is not None and getattr(stand_in, "_oprecon_stand_in", False):
        del sys.modules[PLOTLY_MODULE]
    real = importlib.import_module(PLOTLY_MODULE)
    visualization = sys.modules.get("open3d.visualization")
    if visualization is not None:
        for name in PLOTLY_FUNCTIONS:
            setattr(visualization, name, getattr(real, name))
    return real


def _forward(name: str) -> Callable:
    def call(*args, **kwargs):
        return getattr(_load_real(), name)(*args, **kwargs)

    call.__name__ = name
    call.__doc__ = f"Loads open3d's plotly viewer on first use, then calls its ``{name}``."
    return call


def _other_name(name: str) -> object:
    if name.startswith("__"):
        raise AttributeError(name)
    return getattr(_load_real(), name)


def defer_open3d_plotly() -> None:
    """Register the stand-in for open3d's plotly viewer (no-op once open3d is imported)."""
    if "open3d" in sys.modules or PLOTLY_MODULE in sys.modules:
        return
    stand_in = types.ModuleType(PLOTLY_MODULE, "Stand-in: loads the real module on first use.")
    stand_in._oprecon_stand_in = True  # type: ignore[attr-defined]
    for name in PLOTLY_FUNCTIONS:
        setattr(stand_in, name, _forward(name))
    # Any other public name (a later open3d importing more from the module) loads the real
    # module (PEP 562), so the stand-in cannot break ``import open3d``; the import system's
    # probes of dunder names (``__path__``, ``__all__``) must not.
    stand_in.__getattr__ = _other_name  # type: ignore[attr-defined]
    sys.modules[PLOTLY_MODULE] = stand_in
