"""The point-cloud type every stage receives: :class:`PointCloud` (coordinates, normals, colours).

A module of its own, with no dependency beyond numpy, so that stages can name the type without
importing the readers; :mod:`recon.io` builds the instances (from files or arrays).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["PointCloud"]


@dataclass
class PointCloud:
    """A point cloud read from a file.

    Attributes
    ----------
    points : (n, 3) float64 [length]
        Coordinates relative to ``origin``.
    origin : (3,) float64 [length]
        File coordinates are ``points + origin``.
    normals : (n, 3) float64 or None
        Unit normals from the file. Rows that were invalid in the file (non-finite or zero)
        are NaN; ``info["n_invalid_normals"]`` counts them and
        :func:`recon.normals.compute_normals` replaces them. None when the file has no normals
        or more than 5 % of them are invalid.
    colors : (n, 3) float64 in [0, 1] or None
    path : Path or None
        The file read.
    format : str
        ``'ply-binary_little_endian'``, ``'ply-binary_big_endian'``, ``'ply-ascii'``, ``'xyz'``,
        ``'pts'``, ``'pcd-ascii'``, ``'pcd-binary'`` or ``'obj'``.
    info : dict
        ``n_read`` (rows in the file), ``n_nonfinite_dropped``, ``n_duplicates_merged``,
        ``n_points`` (after cleaning), ``n_invalid_normals``, ``elements`` (name -> count),
        ``has_faces``, ``properties`` (vertex field names), ``normals_dropped`` (bool); LAS and
        E57 add ``point_format``, ``crs``, ``classes`` (class -> count in the file) and
        ``classes_kept``.
    attributes : dict of str -> (n,) array
        Per-point scalars beside the colours, row-aligned with ``points``: ``intensity``
        (float64, the file's scale, e.g. 0-65535 for LAS) and ``classification`` (uint8, LAS
        classes) when the file has them.
    """

    points: np.ndarray
    origin: np.ndarray
    normals: np.ndarray | None = None
    colors: np.ndarray | None = None
    path: Path | None = None
    format: str = ""
    info: dict[str, Any] = field(default_factory=dict)
    attributes: dict[str, np.ndarray] = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.points.shape[0])

    def absolute_points(self) -> np.ndarray:
        """File coordinates, ``points + origin``.

        Returns
        -------
        (n, 3) float64 [length]
        """
        return self.points + self.origin
