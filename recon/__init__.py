"""oprecon: surface reconstruction from point clouds with oriented particle systems.

References
----------
[ST92] R. Szeliski, D. Tonnesen. "Surface Modeling with Oriented Particle Systems".
       SIGGRAPH '92, Computer Graphics 26(2):185-194, 1992. Equation numbers refer to this
       edition (not the DEC CRL 91/14 technical report).
[T00]  D. Tonnesen. "Dynamically Coupled Particle Systems for Geometric Modeling,
       Reconstruction, and Animation". PhD thesis, University of Toronto, 1998/2000, chapter 4.
"""

from typing import Any

from .errors import ConfigError, InputError, OpreconError
from .lazy_imports import defer_open3d_plotly
from .version import __version__

defer_open3d_plotly()  # 0.7 s of dash/plotly imports that no command uses

__all__ = ["ConfigError", "InputError", "OpreconError", "__version__", "fit", "load_config"]


def __getattr__(name: str) -> Any:  # lazy: keep `import recon` (and `oprecon --help`) light
    if name == "fit":
        from .fitting import fit

        return fit
    if name == "load_config":
        from .config import load_config

        return load_config
    raise AttributeError(f"module 'recon' has no attribute {name!r}")


def __dir__() -> list[str]:
    """The module's names and the lazy ones (``fit``, ``load_config``), for tab completion."""
    return sorted(set(globals()) | set(__all__))
