"""The point-cloud type every stage receives: :class:`PointCloud` (coordinates, normals, colours).

A module of its own, with no dependency beyond numpy (and the library's error types), so that
stages can name the type without importing the readers; :mod:`recon.io` builds the instances
(from files or arrays). :func:`numeric_array` and :func:`unit_colors` check the arrays a
library user hands in (points, normals, colours) before they become a cloud.
"""

from __future__ import annotations

from collections.abc import Mapping, Set
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .errors import InputError

__all__ = ["PointCloud", "numeric_array", "spatial_order", "unit_colors"]

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
        ``classes_kept``; LAS/LAZ ``seen_from_above`` (its z is the elevation, its scanners
        above the ground: :func:`recon.normals.scanner_positions`), E57 ``scan_positions``.
    attributes : dict of str -> (n,) array
        Per-point scalars beside the colours, row-aligned with ``points``: ``intensity``
        (float64, the file's scale, e.g. 0-65535 for LAS) and ``classification`` (uint8 for
        classes 0-255, as LAS has them; a PLY's other values in their own type) when the file
        has them.
    viewpoints : (n, 3) float64 [length] or None
        Where each point was scanned from, relative to ``origin`` like the points: an E57
        file's scan positions (:mod:`recon.io.e57`). The normals are turned toward them when
        ``normals.orientation`` is ``auto`` or ``viewpoint`` and no ``normals.viewpoint`` is
        given. None when unknown.
    """

    points: np.ndarray
    origin: np.ndarray
    normals: np.ndarray | None = None
    colors: np.ndarray | None = None
    path: Path | None = None
    format: str = ""
    info: dict[str, Any] = field(default_factory=dict)
    attributes: dict[str, np.ndarray] = field(default_factory=dict)
    viewpoints: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.points.shape[0])

    def take(self, order: np.ndarray) -> PointCloud:
        """The cloud with its rows (points, normals, colours, attributes, viewpoints) in
        ``order``; the origin, path, format and info are the same."""
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
            viewpoints=None if self.viewpoints is None else self.viewpoints[order],
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


#: numpy dtype kinds of real numbers: bool, signed and unsigned integers, floats.
_REAL_KINDS = "biuf"


def _refuse(name: str, message: str) -> InputError:
    return InputError(f"input array: {name}: {message}")


def numeric_array(values: Any, name: str) -> np.ndarray:
    """``values`` as a numpy array of real numbers, or a clear :class:`~recon.errors.InputError`.

    numpy alone would turn ``None`` into a 0-d object array, drop the imaginary part of complex
    values with only a ``ComplexWarning``, and fail on text with a bare ``ValueError``. The
    shape is not checked here (:func:`recon.geometry.as_points` does).

    Parameters
    ----------
    values : array_like
        Points, normals or colours as given by the caller.
    name : str
        What the array is (``'points'``), named in the message.

    Returns
    -------
    numpy.ndarray
        ``values`` itself when it is an array of bool, integers or floats; a new array
        otherwise (float64 for an object array of numbers).

    Raises
    ------
    InputError
        ``"input array: <name>: ..."``: None, text, a mapping, complex numbers, rows of
        different lengths, or objects that are not numbers.

    Examples
    --------
    >>> numeric_array([[0, 0, 1]], "points").dtype.kind
    'i'
    """
    if values is None:
        raise _refuse(name, "expected an (n, 3) array of numbers, got None")
    if isinstance(values, (str, bytes, Mapping, Set)):
        raise _refuse(name, f"expected an (n, 3) array of numbers, got {type(values).__name__}")
    try:
        arr = np.asarray(values)
    except ValueError as exc:  # a ragged nesting of lists ("inhomogeneous shape")
        message = f"expected an (n, 3) array, got rows of different lengths ({exc})"
        raise _refuse(name, message) from None
    if arr.dtype.kind == "c":
        raise _refuse(
            name,
            f"complex numbers ({arr.dtype}) are not accepted: pass a real array (its .real "
            "part, if the imaginary part is meant to be zero)",
        )
    if arr.dtype.kind == "O":  # lists mixing numbers and other objects
        try:
            return arr.astype(np.float64)
        except (TypeError, ValueError):
            kinds = sorted({type(v).__name__ for v in arr.ravel()[:1000]})
            got = type(values).__name__ if arr.ndim == 0 else f"values of type {', '.join(kinds)}"
            raise _refuse(name, f"expected an (n, 3) array of numbers, got {got}") from None
    if arr.dtype.kind not in _REAL_KINDS:
        kind = {"U": "str", "S": "bytes"}.get(arr.dtype.kind, str(arr.dtype))
        got = kind if arr.ndim == 0 else f"an array of {kind}"
        raise _refuse(name, f"expected an (n, 3) array of numbers, got {got}")
    return arr


def _first_bad_row(bad: np.ndarray) -> int:
    return int(np.flatnonzero(bad.reshape(bad.shape[0], -1).any(axis=1))[0])


def unit_colors(colors: Any, name: str = "colors") -> np.ndarray:
    """Colours given as an array, on the 0-1 scale of :attr:`PointCloud.colors`.

    Integer channels are scaled by their type (:func:`recon.io.common.integer_color_scale`:
    0-65535 for uint16, 0-255 for every other integer type), as the readers scale a file's
    channels; float channels must already lie in [0, 1]. Nothing is clipped: a value outside
    the range of its type, or a non-finite one, is refused (clipping made uint8 200 white and
    NaN black).

    Parameters
    ----------
    colors : (n, 3) array_like
    name : str
        Named in the messages.

    Returns
    -------
    (n, 3) float64 in [0, 1]
        The same shape as given (the caller checks it against the points).

    Raises
    ------
    InputError
        Not an array of real numbers (:func:`numeric_array`), a 0-d array, or a row with a
        channel outside its range (the message names the first such row).

    Examples
    --------
    >>> unit_colors(np.array([[255, 51, 0]], dtype=np.uint8)).tolist()
    [[1.0, 0.2, 0.0]]
    """
    arr = numeric_array(colors, name)
    if arr.ndim == 0:
        raise _refuse(name, f"expected an (n, 3) array, got shape {arr.shape}")
    if arr.dtype.kind in "iu":
        from .io.common import integer_color_scale

        top = integer_color_scale(arr.dtype)
        bad = (arr < 0) | (arr > top)
        if bad.any():
            r = _first_bad_row(bad)
            raise _refuse(
                name,
                f"row {r} ({arr[r]}) is outside 0-{top:g}, the range of {arr.dtype} colour "
                "channels",
            )
        return arr / top
    out = np.asarray(arr, dtype=np.float64)
    finite = np.isfinite(out)
    if not finite.all():
        r = _first_bad_row(~finite)
        raise _refuse(name, f"row {r} ({out[r]}) is not finite")
    bad = (out < 0.0) | (out > 1.0)
    if bad.any():
        r = _first_bad_row(bad)
        scale = out.min() >= 0.0 and out.max() <= 255.0
        hint = " (on a 0-255 scale? divide by 255, or pass uint8 values)" if scale else ""
        raise _refuse(name, f"row {r} ({out[r]}) is outside [0, 1]{hint}")
    return out
