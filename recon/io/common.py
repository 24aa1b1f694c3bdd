"""Helpers shared by the format modules: error messages, file checks, columns, text parsing.

Every problem with an input file is an :class:`~recon.errors.InputError` whose message starts
with the file name (:func:`input_error`).
"""

from __future__ import annotations

import contextlib
import os
import re
import stat
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
    "check_regular_file",
    "colors_from",
    "input_error",
    "integer_color_scale",
    "loadtxt",
    "loadtxt_message",
    "optional_module",
    "SCALAR_PROPERTIES",
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
    check_regular_file(path)  # a pipe has no size: it said "file is empty"
    try:
        size = path.stat().st_size
    except OSError as exc:
        raise input_error(path, f"cannot read: {exc.strerror or exc}") from None
    if size == 0:
        raise input_error(path, "file is empty")
    if not os.access(path, os.R_OK):
        raise input_error(path, "cannot read: permission denied")
    return size


def check_regular_file(path: str | os.PathLike[str]) -> None:
    """Refuse an input that is a pipe, a socket or a device rather than a regular file.

    A pipe (``oprecon info <(cat s.xyz)``, a FIFO) has no size and can be read only once, but
    the readers check sizes claimed by headers against the file size, recognise the format of
    a file without a known extension from its first bytes before reading it again, and the
    tiled commands read an input twice: a pipe was reported as "file is empty", and would
    otherwise be read in part. Saving the stream to a file is the simple and safe answer.

    A missing file or a folder passes: the readers' own checks say so.

    Raises
    ------
    InputError
        ``path`` is a pipe, a socket or a device (the message says to save it to a file).
    """
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return
    if stat.S_ISREG(mode) or stat.S_ISDIR(mode):
        return
    if stat.S_ISFIFO(mode):
        what = "a pipe"
    elif stat.S_ISSOCK(mode):
        what = "a socket"
    else:
        what = "a device"
    raise input_error(
        path,
        f"is {what}, not a regular file: point clouds are read from files that can be measured "
        "and read more than once, which pipes cannot; save the stream to a file first",
    )


def check_count(path: Path, n: int, max_points: int) -> None:
    if n > max_points:
        raise input_error(path, f"{n} points exceed the limit of {max_points} (io.max_points)")


def colors_from(channels: np.ndarray | Sequence[np.ndarray]) -> np.ndarray:
    """Colour channels of any numeric type to float64, 1.0 being full intensity.

    Integer channels are scaled by their type (:func:`integer_color_scale`), never by their
    values. Float channels are on a 0-1 scale unless a value exceeds 1, then on 0-255; the
    decision is one for all float channels together, so that a dark blue channel of a 0-255
    file is not taken as a 0-1 one.

    Parameters
    ----------
    channels : (n, k) array, or k arrays (n,)
        The channels (red, green, blue); given separately each keeps its own type (PLY
        properties).

    Returns
    -------
    (n, k) float64
        Values outside [0, 1] are kept (the reader's cleaning clips them).
    """
    if isinstance(channels, np.ndarray):
        if channels.ndim != 2:
            raise ValueError(f"colour channels must be an (n, k) array, got {channels.shape}")
        cols = list(channels.T)
    else:
        cols = [np.asarray(c) for c in channels]
    out = np.zeros((cols[0].shape[0] if cols else 0, len(cols)), dtype=np.float64)
    floats = []
    for j, c in enumerate(cols):
        if np.issubdtype(c.dtype, np.integer):
            if c.dtype.itemsize == 1 and c.dtype.kind == "i":
                c = c.astype(np.uint8)  # a signed byte holds 0-255 colours as -128..127
            out[:, j] = c / integer_color_scale(c.dtype)
        else:
            out[:, j] = c
            floats.append(j)
    if floats:
        values = out[:, floats]
        finite = values[np.isfinite(values)]
        if finite.size and finite.max() > 1.0:
            out[:, floats] = values / 255.0
    return out


def integer_color_scale(dtype: np.dtype) -> float:
    """The value of full intensity in an integer colour channel of type ``dtype``.

    65535 for 16-bit unsigned channels (PLY ``ushort``, as in LAS), 255 for every other type:
    ``uchar`` is the usual 8-bit colour, ``char`` holds the same bytes read as signed, and the
    wider types (``short``, ``int``, ``uint``) are written by tools that use a generic integer
    type for 0-255 values; no writer uses their whole range for colours.
    """
    return 65535.0 if np.dtype(dtype) == np.uint16 else 255.0


#: Per-point scalars a file's columns or properties hold (``PointCloud.attributes``, for
#: ``--transfer``): attribute -> the names tools write it under.
SCALAR_PROPERTIES = {
    "intensity": ("intensity", "scalar_intensity"),
    "classification": ("classification", "scalar_classification"),
}


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


#: numpy's message for a value that is not a number; its row is 0-based, its column 1-based.
_NOT_A_NUMBER = re.compile(r"could not convert string (.*) to \w+ at row (\d+), column (\d+)")


def loadtxt_message(
    exc: ValueError, lines: Sequence[str] | None = None, start: int = 0, first_line: int = 1
) -> str:
    """The message of ``np.loadtxt``'s ``exc`` for a user, in our words.

    numpy counts rows without the blank lines it skips, from 0 for a value that is not a
    number and from 1 for a ragged row, and knows nothing of the comment and header lines the
    caller removed; a user looks for the line in an editor. Given the lines, the row is named
    by its line in the file (1-based, every line counted).

    Parameters
    ----------
    exc : ValueError
        Raised by ``np.loadtxt``.
    lines : sequence of str, optional
        The file's lines, of which ``lines[start:]`` were given to ``np.loadtxt``; without
        them, rows are numbered among the data rows (from 1).
    start : int
        Index in ``lines`` of the first line given to ``np.loadtxt``.
    first_line : int
        The file's line number of ``lines[0]`` (when ``lines`` are a part of the file).

    Returns
    -------
    str
        For example ``"line 6: could not convert 'y' to a number (column 2)"``.
    """
    msg = str(exc).strip().rstrip(".")
    ragged = _RAGGED.search(msg)
    if ragged:
        before, got, row = ragged.groups()
        said = f"data row {row} has {got} columns, the rows before it have {before}"
        line = _line_of_row(lines, start, int(row) - 1, first_line)
        return f"line {line}: {said}" if line else said
    bad = _NOT_A_NUMBER.search(msg)
    if bad:
        token, row, column = bad.groups()
        line = _line_of_row(lines, start, int(row), first_line)
        if line:
            return f"line {line}: could not convert {token} to a number (column {column})"
        return f"data row {int(row) + 1}, column {column}: could not convert {token} to a number"
    return msg[0].lower() + msg[1:] if msg else "malformed numeric data"


def _line_of_row(lines: Sequence[str] | None, start: int, row: int, first_line: int) -> int | None:
    """The file's line number of numpy's 0-based data ``row`` of ``lines[start:]``.

    numpy skips the lines that are empty or whitespace only, which ``str.strip`` empties too.
    Only called for an error, so a loop over the lines is fine.
    """
    if lines is None:
        return None
    seen = -1
    for i in range(start, len(lines)):
        if lines[i].strip():
            seen += 1
            if seen == row:
                return first_line + i
    return None


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
