"""Helpers shared by the format modules: error messages, file checks, columns, text parsing.

Every problem with an input file is an :class:`~recon.errors.InputError` whose message starts
with the file name (:func:`input_error`).
"""

from __future__ import annotations

import contextlib
import os
import re
import warnings
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InputError
from ..geometry import as_points

__all__ = [
    "COLOR_NAMES",
    "LIDAR_EXTRA",
    "MAX_HEADER_BYTES",
    "NORMAL_NAMES",
    "as_input_points",
    "check_count",
    "check_readable",
    "colors_from",
    "input_error",
    "loadtxt",
    "loadtxt_message",
    "optional_module",
    "pick",
    "read_text_file",
    "triangulate_fans",
]


#: Header size limit for PLY and PCD files.
MAX_HEADER_BYTES = 1 << 20


#: Column names of normals and colours, in order of preference (PLY properties, CSV headers).
NORMAL_NAMES = (("nx", "ny", "nz"), ("normal_x", "normal_y", "normal_z"))

COLOR_NAMES = (
    ("red", "green", "blue"),
    ("r", "g", "b"),
    ("diffuse_red", "diffuse_green", "diffuse_blue"),
)


def input_error(path: Path | str | None, message: str) -> InputError:
    """An :class:`~recon.errors.InputError` ``"<path>: <message>"`` (None: ``input array``)."""
    return InputError(f"{path if path is not None else 'input array'}: {message}")


@contextlib.contextmanager
def reading(path: Path) -> Iterator[None]:
    """Read ``path`` inside: out-of-memory and OS errors become an :class:`InputError` naming it.

    Hostile values (signalling NaNs, 1e39 in a float field) are data, not warnings.
    """
    try:
        with np.errstate(invalid="ignore", over="ignore"):
            yield
    except InputError:
        raise
    except MemoryError:
        raise input_error(path, "out of memory while reading (file too large?)") from None
    except OSError as exc:
        raise input_error(path, f"cannot read: {exc.strerror or exc}") from None


def as_input_points(arr: Any, name: str, *, where: str | None = None) -> np.ndarray:
    """:func:`recon.geometry.as_points` raising :class:`~recon.errors.InputError`.

    Parameters
    ----------
    arr : array_like, (n, 3)
    name : str
        What the array is (``'points'``), named in the message.
    where : str or None
        Prefix of the message (``'<where>: <name>: ...'``), e.g. ``'input array'``.

    Returns
    -------
    (n, 3) float64, C-contiguous

    Raises
    ------
    InputError
        Wrong shape (the message gives expected and received shapes).
    """
    try:
        return as_points(arr, name)
    except ValueError as exc:
        raise InputError(str(exc) if where is None else f"{where}: {exc}") from None


def check_readable(path: Path) -> int:
    """Existence, type and size checks common to all readers; returns the file size."""
    if not path.exists():
        raise input_error(path, "no such file")
    if path.is_dir():
        raise input_error(path, "is a directory, expected a point-cloud file")
    try:
        size = path.stat().st_size
    except OSError as exc:
        raise input_error(path, f"cannot read: {exc.strerror or exc}") from None
    if size == 0:
        raise input_error(path, "file is empty")
    if not os.access(path, os.R_OK):
        raise input_error(path, "cannot read: permission denied")
    return size


def check_count(path: Path, n: int, max_points: int) -> None:
    if n > max_points:
        raise input_error(path, f"{n} points exceed the limit of {max_points} (io.max_points)")


def colors_from(arr: np.ndarray) -> np.ndarray:
    """Colour channels of any numeric type to float64 in [0, 1]."""
    if np.issubdtype(arr.dtype, np.integer):
        top = float(np.iinfo(arr.dtype).max)
        return arr.astype(np.float64) / (255.0 if top >= 255 else top)
    out = arr.astype(np.float64)
    if out.size and np.nanmax(out) > 1.0:
        out = out / 255.0
    return out


def pick(names: set[str], candidates: Sequence[tuple[str, ...]]) -> tuple[str, ...] | None:
    return next((c for c in candidates if all(n in names for n in c)), None)


def loadtxt(*args: Any, **kwargs: Any) -> np.ndarray:
    """``np.loadtxt`` without its warnings about empty input or lines (callers check rows)."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="loadtxt: input contained no data")
        warnings.filterwarnings("ignore", message=r"Input line \d+ contained no data")
        return np.loadtxt(*args, **kwargs)


#: numpy's message for a row whose number of values differs from the rows before it (numpy
#: >= 1.23), which ends with advice about a numpy argument.
_RAGGED = re.compile(r"the number of columns changed from (\d+) to (\d+) at row (\d+)")


def loadtxt_message(exc: ValueError) -> str:
    """The message of ``np.loadtxt``'s ``exc`` for a user: a ragged row is said in our words."""
    msg = str(exc).strip().rstrip(".")
    ragged = _RAGGED.search(msg)
    if ragged:
        before, got, row = ragged.groups()
        return f"row {row} has {got} columns, the rows before it have {before}"
    return msg[0].lower() + msg[1:] if msg else "malformed numeric data"


def read_text_file(path: Path) -> str:
    try:
        return path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError:
        raise input_error(
            path, "not a text file (binary content); expected x y z columns"
        ) from None


def triangulate_fans(path: Path, polys: Any) -> np.ndarray:
    """(F, m) array or list of index arrays -> (T, 3) int64 triangles (fan from vertex 0)."""
    if isinstance(polys, np.ndarray) and polys.ndim == 2:
        arr = polys
        if np.issubdtype(arr.dtype, np.floating):
            if not np.all(arr == np.round(arr)):
                raise input_error(path, "non-integer face vertex index")
        arr = arr.astype(np.int64)
        m = arr.shape[1]
        if m < 3:
            return np.zeros((0, 3), dtype=np.int64)
        tris = [np.stack([arr[:, 0], arr[:, i], arr[:, i + 1]], axis=1) for i in range(1, m - 1)]
        return tris[0] if len(tris) == 1 else np.stack(tris, axis=1).reshape(-1, 3)
    out: list[np.ndarray] = []
    for poly in polys:
        poly = np.asarray(poly)
        if poly.size < 3:
            continue
        if np.issubdtype(poly.dtype, np.floating) and not np.all(poly == np.round(poly)):
            raise input_error(path, "non-integer face vertex index")
        poly = poly.astype(np.int64)
        k = poly.size
        out.append(np.stack([np.full(k - 2, poly[0]), poly[1:-1], poly[2:]], axis=1))
    return np.concatenate(out) if out else np.zeros((0, 3), dtype=np.int64)


#: The extra that installs the LiDAR readers (named in the error when one is missing).
LIDAR_EXTRA = 'pip install "oprecon[lidar]"'


def optional_module(name: str, path: Path, what: str) -> Any:
    """Import an optional reader package, or raise :class:`~recon.errors.InputError`.

    Parameters
    ----------
    name : str
        The module (``'laspy'``, ``'lazrs'``, ``'pye57'``).
    path : Path
        The file being read (named in the message).
    what : str
        What the package is needed for, e.g. ``'LAS/LAZ files'``.
    """
    import importlib

    try:
        return importlib.import_module(name)
    except ImportError:
        raise input_error(
            path, f"reading {what} needs the package '{name}': {LIDAR_EXTRA}"
        ) from None
