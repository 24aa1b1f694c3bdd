"""Named presets: the YAML files shipped as package data of ``recon.configs``.

>>> "open_scan" in available_presets()
True
>>> preset_path("open_scan").name
'open_scan.yaml'
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from .errors import ConfigError, did_you_mean

__all__ = ["available_presets", "preset_path"]

_PACKAGE = "recon.configs"


def _preset_dir() -> Path:
    return Path(str(resources.files(_PACKAGE)))


def available_presets() -> list[str]:
    """Names of the bundled presets, sorted (``default`` is the defaults written out)."""
    return sorted(p.stem for p in _preset_dir().glob("*.yaml"))


def preset_path(name: str) -> Path:
    """The YAML file of preset ``name``; :class:`ConfigError` naming the valid ones if unknown."""
    path = _preset_dir() / f"{name}.yaml"
    if not path.is_file():
        names = available_presets()
        listed = ", ".join(names) or "none installed"
        raise ConfigError(
            f"unknown preset '{name}'{did_you_mean(name, names)} (available: {listed})"
        )
    return path
