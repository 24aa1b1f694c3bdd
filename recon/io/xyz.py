"""XYZ-style text: XYZ, XYZN, PTS, TXT, CSV (and ASC, PWN, XYZRGB) point files.

Space, comma or semicolon separated, ``#`` and ``//`` comments. Columns are x y z, then
optionally nx ny nz and/or r g b (told apart by unit length and by 0-255 integers), or any order
under a header line naming x, y, z (nx ny nz, red green blue). PTS: an optional first count
line, then x y z [intensity [r g b]].
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


_COMMENT_RE = re.compile(r"^\s*(#|//).*$|\s*//.*$", re.MULTILINE)


def read_points(
    path: Path, max_points: int, info: dict[str, Any]
) -> tuple[str, np.ndarray, np.ndarray | None, np.ndarray | None]:
    is_pts = path.suffix.lower() == ".pts"
    text = read_text_file(path)
    if "#" in text or "//" in text:
        text = _COMMENT_RE.sub("", text)
    text = text.replace(",", " ").replace(";", " ")
    lines = text.splitlines()
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
        lines = lines[first + 1 :]
        first = 0
        is_pts = True
    header: list[str] | None = None
    if not all(_is_number(t) for t in tokens):  # a CSV header line such as "x,y,z,nx,ny,nz"
        header = [t.strip("\"'").lower() for t in tokens]
        if not {"x", "y", "z"} <= set(header):
            raise input_error(
                path,
                f"line {first + 1}: expected numbers or a header naming x, y, z, got "
                f"'{lines[first].strip()[:80]}'",
            )
        lines = lines[first + 1 :]
    n_rows = sum(1 for ln in lines if ln.strip())
    check_count(path, n_rows, max_points)
    if n_rows == 0:
        raise input_error(path, "no data rows")
    try:
        arr = loadtxt(lines, dtype=np.float64, ndmin=2, comments=None)
    except ValueError as exc:
        raise input_error(path, loadtxt_message(exc)) from None
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
        return "xyz", xyz, normals, colors
    xyz = arr[:, :3]
    normals = colors = None
    extra = arr[:, 3:]
    names = ["x", "y", "z"]
    if is_pts:
        if ncol in (4, 7):
            names.append("intensity")
            extra = extra[:, 1:]
        if extra.shape[1] >= 3:
            colors = colors_from(extra[:, :3])
            names += ["red", "green", "blue"]
    elif ncol == 4:
        names.append("intensity")
    elif ncol >= 6:
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
    info["properties"] = names
    return ("pts" if is_pts else "xyz"), xyz, normals, colors


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
