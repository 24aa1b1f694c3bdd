"""The point-cloud type every stage receives: :class:`PointCloud` (coordinates, normals, colours).

A module of its own, with no dependency beyond numpy, so that stages can name the type without
importing the readers; :mod:`recon.io` builds the instances (from files or arrays).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["PointCloud", "spatial_order"]

#: Bits per axis of the Morton code: a grid of 1024^3 cells over the bounding cube (a few
#: points per occupied cell at 10^6-10^7 points on a surface). Finer grids order no better and
#: let rounding (a scaled or shifted copy of the input) move more points across cells.
MORTON_BITS = 10


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

    def take(self, order: np.ndarray) -> PointCloud:
        """The cloud with its rows (points, normals, colours, attributes) in ``order``; the
        origin, path, format and info are the same."""
        order = np.asarray(order)
        return PointCloud(
            points=self.points[order],
            origin=self.origin,
            normals=None if self.normals is None else self.normals[order],
            colors=None if self.colors is None else self.colors[order],
            path=self.path,
            format=self.format,
            info=self.info,
            attributes={k: np.asarray(v)[order] for k, v in self.attributes.items()},
        )

    def absolute_points(self) -> np.ndarray:
        """File coordinates, ``points + origin``.

        Returns
        -------
        (n, 3) float64 [length]
        """
        return self.points + self.origin


def _spread_bits(x: np.ndarray) -> np.ndarray:
    """The low :data:`MORTON_BITS` bits of ``x`` (uint32) moved to every third bit."""
    x = x & np.uint32(0x3FF)
    for shift, mask in ((16, 0x030000FF), (8, 0x0300F00F), (4, 0x030C30C3), (2, 0x09249249)):
        x = (x | (x << np.uint32(shift))) & np.uint32(mask)
    return x


def spatial_order(points: np.ndarray) -> np.ndarray:
    """Indices that put ``points`` in Morton (Z-curve) order: points close in space end up
    close in memory, so that neighbour queries and the per-point passes that follow touch
    nearby memory (a scan in random order makes each of them a cache miss at millions of
    points).

    Parameters
    ----------
    points : (n, 3) float64 [length]

    Returns
    -------
    (n,) int64
        A permutation; ties (points in the same cell of the :data:`MORTON_BITS` grid over
        the bounding cube) keep their input order.

    References
    ----------
    [Morton66] G. M. Morton, "A computer oriented geodetic data base and a new technique in
    file sequencing", IBM, 1966.
    """
    p = np.asarray(points, dtype=np.float64)
    if len(p) == 0:
        return np.zeros(0, dtype=np.int64)
    lo = p.min(axis=0)
    extent = float((p.max(axis=0) - lo).max())
    top = 2**MORTON_BITS - 1
    scale = top / extent if extent > 0 else 0.0
    cell = np.clip((p - lo) * scale, 0, top).astype(np.uint32)
    code = _spread_bits(cell[:, 0])
    code |= _spread_bits(cell[:, 1]) << np.uint32(1)
    code |= _spread_bits(cell[:, 2]) << np.uint32(2)
    return np.argsort(code, kind="stable")
