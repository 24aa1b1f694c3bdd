"""XYZ-style text: XYZ, XYZN, PTS, TXT, CSV (and ASC, PWN, XYZRGB) point files.

Space, tab, comma or semicolon separated; ``#`` and ``//`` start a comment that runs to the end
of the line. When semicolons separate the fields, commas are decimal commas (``109,4;90,1``),
and so are they in space or tab separated rows whose every value has one (``109,4 90,1``); a
file whose numbers hold both ``,`` and ``.`` is refused, since its decimal mark is unknown.

Columns are x y z, then what the extension says: ``.xyzn`` and ``.pwn`` nx ny nz (normalised
later, zero-length ones re-estimated), ``.xyzrgb`` r g b (0-1 floats or 0-255, decided for the
whole file). Other extensions do not say, so columns 4-6 and 7-9 are guessed: normals when of
unit length, else colours when in 0-1 or 0-255 integers. A header line naming x, y, z (nx ny
nz, red green blue) gives any order. PTS: an optional first count line, then x y z [intensity
[r g b]].

Messages name rows by their line in the file (1-based, counting comment and blank lines).
"""

from __future__ import annotations

import logging
import re
from pathlib import Path
from typing import Any

import numpy as np

from .common import (
    COLOR_NAMES,
    NORMAL_NAMES,
    SCALAR_PROPERTIES,
    check_count,
    colors_from,
    input_error,
    loadtxt,
    loadtxt_message,
    pick,
    read_text_file,
)

#: One logger for the io package (its messages name the file).
logger = logging.getLogger("recon.io")

__all__ = ["TEXT_EXTENSIONS", "read_points"]

#: Extensions read as text columns.
TEXT_EXTENSIONS = {".xyz", ".xyzn", ".xyzrgb", ".txt", ".csv", ".asc", ".pts", ".pwn"}

#: Extensions whose name says what columns 4-6 hold; the others are guessed from the values.
_COLUMNS_4_6 = {".xyzn": "normals", ".pwn": "normals", ".xyzrgb": "colors"}

#: A comment: from ``#`` or ``//`` to the end of the line, whole line or trailing. ``.`` stops
#: at the newline, so every line keeps its number for messages; the spaces left before the
#: comment separate nothing (and a leading ``[ \t]*`` made the substitution 3x slower).
_COMMENT_RE = re.compile(r"(?:#|//).*")

#: A value with a decimal comma (``-109,4``, ``1,5e3``), for rows separated by spaces or tabs.
_DECIMAL_COMMA_RE = re.compile(r"[-+]?\d*,\d+(?:[eE][-+]?\d+)?")


def read_points(
    path: Path, max_points: int, info: dict[str, Any]
) -> tuple[str, np.ndarray, np.ndarray | None, np.ndarray | None, dict[str, np.ndarray]]:
    """Read a text point file: (format, xyz, normals or None, colours in [0, 1] or None,
    attributes: ``intensity`` where a column holds it (a PTS file's 4th, the 4th of four
    columns, or a header's ``intensity``))."""
    ext = path.suffix.lower()
    is_pts = ext == ".pts"
    text = read_text_file(path)
    if "#" in text or "//" in text:
        text = _COMMENT_RE.sub("", text)
    text = _separators_to_spaces(path, text)
    # "\n" only (read_text_file already turned "\r\n" and "\r" into it): line numbers in
    # messages are those of an editor, which splitlines() would shift at "\f" or "\x1c".
    lines = text.split("\n")
    first = next((i for i, ln in enumerate(lines) if ln.strip()), None)
    if first is None:
        raise input_error(path, "no data rows (only comments or blank lines)")
    tokens = lines[first].split()
    if len(tokens) == 1:  # PTS-style count line
        try:
            int(tokens[0])
        except ValueError:
            raise input_error(
                path, f"line {first + 1}: expected x y z, got '{lines[first].strip()}'"
            ) from None
        is_pts = True
        first = next((i for i in range(first + 1, len(lines)) if lines[i].strip()), len(lines))
        tokens = lines[first].split() if first < len(lines) else []
    start = first  # index in `lines` of the first data row
    header: list[str] | None = None
    if tokens and not all(_is_number(t) for t in tokens):  # a header such as "x,y,z,nx,ny,nz"
        header = [t.strip("\"'").lower() for t in tokens]
        if not {"x", "y", "z"} <= set(header):
            raise input_error(
                path,
                f"line {first + 1}: expected numbers or a header naming x, y, z, got "
                f"'{lines[first].strip()[:80]}'",
            )
        start = first + 1
    n_rows = sum(1 for i in range(start, len(lines)) if lines[i].strip())
    check_count(path, n_rows, max_points)
    if n_rows == 0:
        raise input_error(path, "no data rows")
    try:
        arr = loadtxt(_rows(lines, start), dtype=np.float64, ndmin=2, comments=None)
    except ValueError as exc:
        raise input_error(path, loadtxt_message(exc, lines, start)) from None
    ncol = arr.shape[1]
    info["elements"] = {"vertex": int(arr.shape[0])}
    if ncol < 3:
        raise input_error(path, f"rows have {ncol} column(s); expected at least x y z")
    if header is not None:
        if len(header) != ncol:
            raise input_error(path, f"the header names {len(header)} columns, rows have {ncol}")
        col = {name: j for j, name in enumerate(header)}
        xyz = arr[:, [col["x"], col["y"], col["z"]]]
        nn = pick(set(header), NORMAL_NAMES)
        cn = pick(set(header), COLOR_NAMES)
        info["properties"] = header
        normals = arr[:, [col[c] for c in nn]] if nn else None
        colors = colors_from(arr[:, [col[c] for c in cn]]) if cn else None
        return "xyz", xyz, normals, colors, _intensity(arr, header)
    xyz = arr[:, :3]
    names = ["x", "y", "z"]
    said = _COLUMNS_4_6.get(ext)
    if said is not None:
        normals, colors = _said_columns(path, said, arr, names)
    elif is_pts:
        normals, colors = _pts_columns(arr, names)
    else:
        normals, colors = _guessed_columns(path, arr, names)
    info["properties"] = names
    fmt = "pts" if is_pts and said is None else "xyz"
    return fmt, xyz, normals, colors, _intensity(arr, names)


def _intensity(arr: np.ndarray, names: list[str]) -> dict[str, np.ndarray]:
    """``{"intensity": column}`` when one of the columns ``names`` is the intensity (the
    names are the columns' in order), else empty: ``info`` lists it, so ``--transfer
    intensity`` finds it."""
    for name in SCALAR_PROPERTIES["intensity"]:
        if name in names:
            return {"intensity": np.ascontiguousarray(arr[:, names.index(name)])}
    return {}


def _rows(lines: list[str], start: int) -> Any:
    """``lines[start:]`` without copying a list of millions of lines."""
    return lines if start == 0 else (lines[i] for i in range(start, len(lines)))


def _separators_to_spaces(path: Path, text: str) -> str:
    """``text`` with fields separated by whitespace and ``.`` as the decimal mark.

    A semicolon is only ever a field separator, and files use it because the comma is their
    decimal mark; replacing both by spaces invented columns (``109,4;90,1`` read as four
    numbers). Without semicolons, commas separate fields unless every value of the first row
    of space or tab separated values has one comma inside it.
    """
    decimal_comma = ";" in text or _spaced_decimal_commas(text)
    if not decimal_comma:
        return text.replace(",", " ") if "," in text else text
    if "," in text:
        if "." in text:
            sep = "';'" if ";" in text else "spaces or tabs"
            raise input_error(
                path,
                f"fields are separated by {sep} and the numbers hold both ',' and '.', so the "
                "decimal mark is unknown; write numbers with '.' only or ',' only",
            )
        text = text.replace(",", ".")
    return text.replace(";", " ")


def _spaced_decimal_commas(text: str) -> bool:
    """Whether the first row of two or more space or tab separated values (in the first 64 KiB,
    header lines skipped) has a decimal comma in every value, as in ``109,4\t90,1\t148,1``."""
    head = text if len(text) <= 65536 else text[:65536].rsplit("\n", 1)[0]
    for line in head.split("\n"):
        tokens = line.split()
        if len(tokens) >= 2 and all(any(c.isdigit() for c in t) for t in tokens):
            return all(_DECIMAL_COMMA_RE.fullmatch(t) for t in tokens)
    return False


def _said_columns(
    path: Path, said: str, arr: np.ndarray, names: list[str]
) -> tuple[np.ndarray | None, np.ndarray | None]:
    """Normals or colours in columns 4-6 because the extension says so (then 7-9 guessed)."""
    ext = path.suffix.lower()
    ncol = arr.shape[1]
    what = "nx ny nz" if said == "normals" else "r g b"
    if ncol < 6:
        raise input_error(
            path, f"a {ext} file has x y z {what} in columns 1-6, but its rows have {ncol} columns"
        )
    g = arr[:, 3:6]
    normals = colors = None
    if said == "normals":
        # Any length: the normals are normalised and zero or non-finite ones re-estimated
        # when the cloud is made (recon.io.clean), like those of every other format.
        normals = g
        names += ["nx", "ny", "nz"]
    else:
        finite = g[np.isfinite(g)]
        if finite.size and (finite.min() < 0 or finite.max() > 255):
            raise input_error(
                path,
                f"columns 4-6 of a {ext} file are colours (0-1 or 0-255), but they hold values "
                f"from {finite.min():g} to {finite.max():g}",
            )
        colors = colors_from(g)  # 0-1 or 0-255 decided for the whole file
        names += ["red", "green", "blue"]
    if ncol >= 9:
        g = arr[:, 6:9]
        if normals is None and _looks_like_normals(g):
            normals = g
            names += ["nx", "ny", "nz"]
        elif colors is None and _looks_like_colors(g):
            colors = colors_from(g)
            names += ["red", "green", "blue"]
    if len(names) < ncol:
        logger.warning(
            "%s: columns %d-%d are neither normals nor colours; ignored", path, len(names) + 1, ncol
        )
    return normals, colors


def _pts_columns(arr: np.ndarray, names: list[str]) -> tuple[None, np.ndarray | None]:
    """PTS: x y z [intensity [r g b]] (the intensity is taken by :func:`_intensity`, colours
    0-255)."""
    ncol = arr.shape[1]
    extra = arr[:, 3:]
    colors = None
    if ncol in (4, 7):
        names.append("intensity")
        extra = extra[:, 1:]
    if extra.shape[1] >= 3:
        colors = colors_from(extra[:, :3])
        names += ["red", "green", "blue"]
    return None, colors


def _guessed_columns(
    path: Path, arr: np.ndarray, names: list[str]
) -> tuple[np.ndarray | None, np.ndarray | None]:
    """Columns 4-6 and 7-9 of a file whose extension does not say what they hold."""
    ncol = arr.shape[1]
    normals = colors = None
    if ncol == 4:
        names.append("intensity")
    elif ncol >= 6:
        extra = arr[:, 3:]
        groups = [extra[:, i : i + 3] for i in range(0, extra.shape[1] - 2, 3)]
        for g in groups[:2]:
            if normals is None and _looks_like_normals(g):
                normals = g
                names += ["nx", "ny", "nz"]
            elif colors is None and _looks_like_colors(g):
                colors = colors_from(g)
                names += ["red", "green", "blue"]
        if normals is None and colors is None:
            logger.warning(
                "%s: columns 4-%d are neither unit normals nor colours; ignored", path, ncol
            )
    return normals, colors


def _is_number(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


def _looks_like_normals(g: np.ndarray) -> bool:
    length = np.linalg.norm(g, axis=1)
    ok = np.isfinite(length)
    return bool(ok.any() and np.median(np.abs(length[ok] - 1.0)) < 1e-2)


def _looks_like_colors(g: np.ndarray) -> bool:
    ok = np.isfinite(g).all(axis=1)
    v = g[ok]
    if v.size == 0 or v.min() < 0:
        return False
    return bool(v.max() <= 1.0 or (v.max() <= 255.0 and np.all(v == np.round(v))))
