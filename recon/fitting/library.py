"""The checks before a fit, shared by :func:`~recon.fitting.pipeline.fit` (arrays, the library's
``recon.fit``) and :func:`~recon.fitting.pipeline.fit_file` (``oprecon fit``).

- :func:`resolve_config`: a config given as a :class:`~recon.config.ReconConfig`, a mapping of
  dotted overrides or the path of a YAML file, as :func:`recon.config.load_config` takes them;
- :func:`check_progress`: the progress callback is callable (checked before any work);
- :func:`cloud_from_input`: the arrays as a cloud, cleaned as a file's points are
  (``io.merge_duplicates``, ``io.outliers``) and refused past ``io.max_points``;
- :func:`checked_memory`: the peak-memory estimate, refused past ``io.max_memory``.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from typing import Any

from ..cloud import PointCloud, numeric_array
from ..config import ReconConfig, load_config
from .memory import MemoryEstimate, estimate_fit_memory
from .schedule import ProgressFn

__all__ = [
    "ConfigLike",
    "check_progress",
    "checked_memory",
    "cloud_from_input",
    "resolve_config",
]

#: What the fit functions take as ``config`` (:func:`resolve_config`).
ConfigLike = (
    ReconConfig | Mapping[str, Any] | list[str] | tuple[str, ...] | str | os.PathLike[str] | None
)


def resolve_config(config: ConfigLike) -> ReconConfig:
    """The :class:`~recon.config.ReconConfig` that ``config`` stands for.

    Parameters
    ----------
    config : ReconConfig, mapping, list of str, str, path-like or None
        A ReconConfig is used as it is; a mapping holds dotted overrides of the defaults
        (``{"seeds.spacing": 0.02}``), a list or tuple ``"key=value"`` strings as ``--set``
        takes them (both as ``recon.load_config(overrides=...)``); a str or path-like is a
        YAML file (as ``recon.load_config(path)``); None: the defaults.

    Returns
    -------
    ReconConfig

    Raises
    ------
    ConfigError
        An unknown key or an invalid value in the mapping or the file; a file that cannot
        be read.
    TypeError
        Anything else (naming ``recon.load_config``).

    Examples
    --------
    >>> resolve_config({"seed": 3}).seed
    3
    >>> resolve_config(["seed=4"]).seed
    4
    """
    if config is None:
        return ReconConfig()
    if isinstance(config, ReconConfig):
        return config
    if isinstance(config, Mapping):
        return load_config(overrides=config)
    if isinstance(config, (str, os.PathLike)):
        return load_config(config)
    if isinstance(config, (list, tuple)) and all(isinstance(c, str) for c in config):
        return load_config(overrides=config)  # "key=value" strings, as --set takes them
    raise TypeError(
        f"config: expected a ReconConfig (from recon.load_config(path, overrides)), a mapping "
        f"of dotted overrides such as {{'seeds.spacing': 0.02}}, or the path of a YAML file; "
        f"got {type(config).__name__}"
    )


def check_progress(on_progress: Any) -> ProgressFn | None:
    """``on_progress`` when it is None or callable; a :class:`TypeError` otherwise (before
    the fit, not after its normals and seeds)."""
    if on_progress is not None and not callable(on_progress):
        raise TypeError(
            "on_progress: expected a callable(phase, info) or None, got "
            f"{type(on_progress).__name__}"
        )
    return on_progress


def cloud_from_input(points: Any, normals: Any, cfg: ReconConfig) -> PointCloud:
    """The cloud of the arrays ``points`` (and ``normals``) as ``oprecon fit`` reads a file
    with ``cfg``: at most ``io.max_points`` rows, duplicates merged as ``io.merge_duplicates``
    says and statistical outliers removed as ``io.outliers`` says, then cleaned and checked
    (:func:`recon.io.cloud_from_arrays`).

    Parameters
    ----------
    points : (n, 3) array_like [length]
    normals : (n, 3) array_like or None
    cfg : ReconConfig

    Returns
    -------
    PointCloud

    Raises
    ------
    InputError
        Not an (n, 3) array of real numbers (None, text, complex values; the message names
        the array), more rows than ``io.max_points``, or input the cleaning refuses.
    """
    from ..io import cloud_from_arrays
    from ..io.common import as_input_points, check_count
    from ..io.outliers import outlier_removal

    xyz = as_input_points(numeric_array(points, "points"), "points", where="input array")
    nrm = None
    if normals is not None:
        nrm = as_input_points(numeric_array(normals, "normals"), "normals", where="input array")
    check_count(None, len(xyz), cfg.io.max_points)  # (no path: "input array: ...")
    return cloud_from_arrays(
        xyz, nrm, merge_duplicates=cfg.io.merge_duplicates, outliers=outlier_removal(cfg.io)
    )


def checked_memory(
    cloud: PointCloud, cfg: ReconConfig, *, always: bool = False
) -> MemoryEstimate | None:
    """The estimated peak memory of a fit of ``cloud``, refused past ``io.max_memory``.

    Parameters
    ----------
    cloud : PointCloud
    cfg : ReconConfig
    always : bool
        Estimate when no ``io.max_memory`` is set as well (the report of ``oprecon fit``
        carries the estimate); otherwise the estimate (a spacing choice, one k-d tree of
        the data) is made only to check a limit.

    Returns
    -------
    MemoryEstimate or None
        None when there was nothing to check and ``always`` is false.

    Raises
    ------
    InputError
        The estimate exceeds ``io.max_memory`` (:func:`recon.fitting.memory.check_memory`).
    """
    if not always and cfg.io.max_memory is None:
        return None
    return estimate_fit_memory(cloud.points, cfg)
