"""Reading and writing point clouds and meshes: the only module that knows file formats.

Readers return a :class:`PointCloud` whose coordinates are float64 and *relative* to an
``origin`` (the rounded bounding-box centre when the coordinates are large compared with the
extent, e.g. georeferenced scans at x ~ 5e6 with mm detail; zero otherwise), so that nothing
downstream loses precision. Writers add the origin back and store float64 (``double``) vertex
coordinates whenever float32 would lose more than ``1e-7`` of the extent.

Supported inputs

======================  ==============================================================
PLY (``.ply``)          ascii, binary little and big endian; any numeric type for x, y, z;
                        optional nx, ny, nz and red, green, blue; other elements
                        (``face``, ``camera`` ...) are skipped (``info["has_faces"]``)
XYZ text                ``.xyz .xyzn .txt .csv .asc .pts``: space or comma separated,
                        ``#`` and ``//`` comments; columns x y z [nx ny nz | r g b]
                        (told apart by unit length / 0-255 integers), or any order under
                        a header line naming x, y, z (nx ny nz, red green blue);
                        PTS: optional first count line, x y z [intensity [r g b]]
PCD (``.pcd``)          ascii and binary (``binary_compressed`` is not supported)
OBJ (``.obj``)          ``v`` (and ``vn`` when there is one per ``v``); faces are ignored
======================  ==============================================================

Every problem with an input file raises :class:`~recon.errors.InputError` with a message of the
form ``"<path>: <what is wrong>"``; sizes claimed by headers are checked against the file size
before anything is allocated. Files of an unknown extension are recognised by their content.

Notes
-----
PLY is parsed here with numpy rather than with plyfile: the header must be validated against the
file size before any allocation (a header may claim 10^12 vertices), and faces are read as one
structured array when every face has the same number of corners (plyfile walks list elements
row by row). The tests use plyfile as the independent reference reader and writer.

References
----------
[PLY] G. Turk. "The PLY polygon file format", 1994.
      http://paulbourke.net/dataformats/ply/
[PCD] Point Cloud Library. "The PCD (Point Cloud Data) file format".
      https://pointclouds.org/documentation/tutorials/pcd_file_format.html
[OBJ] Wavefront Technologies. "Object files (.obj)", Advanced Visualizer manual, appendix B1.
"""

from __future__ import annotations

import contextlib
import io as _io
import itertools
import logging
import os
import re
import secrets
import warnings
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from .errors import InputError

logger = logging.getLogger(__name__)

__all__ = [
    "SUPPORTED_POINT_FORMATS",
    "PointCloud",
    "atomic_output",
    "check_output_path",
    "cloud_from_arrays",
    "read_mesh",
    "read_points",
    "write_mesh",
    "write_points",
]

SUPPORTED_POINT_FORMATS = "PLY (.ply), XYZ/XYZN/PTS/TXT/CSV text, PCD (.pcd), OBJ (.obj)"

#: A normal is invalid when it is non-finite or shorter than this.
_MIN_NORMAL_LENGTH = 1e-12
#: More invalid input normals than this fraction: drop the file's normals altogether.
_MAX_INVALID_NORMAL_FRACTION = 0.05
#: Relative precision (of the extent) that float32 output must keep, else double is written.
_FLOAT32_TOLERANCE = 1e-7
#: Largest coordinate magnitude accepted: squares and products of lengths stay finite.
_MAX_COORDINATE = 1e100
#: Smallest extent accepted: squared spacings stay normal floating-point numbers.
_MIN_EXTENT = 1e-100
#: Header size limit for PLY and PCD files.
_MAX_HEADER_BYTES = 1 << 20

#: Largest element COUNT of a PCD field (descriptor arrays such as FPFH have 33 or 308).
_MAX_PCD_COUNT = 1 << 16

_TEXT_EXTENSIONS = {".xyz", ".xyzn", ".xyzrgb", ".txt", ".csv", ".asc", ".pts", ".pwn"}


# --------------------------------------------------------------------------------------------
# the point cloud


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
        ``has_faces``, ``properties`` (vertex field names), ``normals_dropped`` (bool).
    """

    points: np.ndarray
    origin: np.ndarray
    normals: np.ndarray | None = None
    colors: np.ndarray | None = None
    path: Path | None = None
    format: str = ""
    info: dict[str, Any] = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.points.shape[0])

    def absolute_points(self) -> np.ndarray:
        """File coordinates, ``points + origin``.

        Returns
        -------
        (n, 3) float64 [length]
        """
        return self.points + self.origin


# --------------------------------------------------------------------------------------------
# helpers shared by the readers


def _err(path: Path | str | None, message: str) -> InputError:
    return InputError(f"{path if path is not None else 'input array'}: {message}")


def _check_readable(path: Path) -> int:
    """Existence, type and size checks common to all readers; returns the file size."""
    if not path.exists():
        raise _err(path, "no such file")
    if path.is_dir():
        raise _err(path, "is a directory, expected a point-cloud file")
    try:
        size = path.stat().st_size
    except OSError as exc:
        raise _err(path, f"cannot read: {exc.strerror or exc}") from None
    if size == 0:
        raise _err(path, "file is empty")
    if not os.access(path, os.R_OK):
        raise _err(path, "cannot read: permission denied")
    return size


def choose_origin(points: np.ndarray) -> np.ndarray:
    """A round origin near the bounding-box centre when coordinates are large, else zero.

    The origin is non-zero when the centre is farther from zero than 100 x the largest extent
    (so relative coordinates keep about 2 more significant digits in float32 than absolute
    ones). It is the centre rounded to a power of ten at or above the extent, which keeps file
    values and relative values exactly convertible (Sterbenz: ``x - o`` is exact for
    ``o / 2 <= x <= 2 o``).

    Parameters
    ----------
    points : (n, 3) float64 [length]

    Returns
    -------
    (3,) float64 [length]
    """
    if points.shape[0] == 0:
        return np.zeros(3)
    lo = points.min(axis=0)
    hi = points.max(axis=0)
    centre = 0.5 * (lo + hi)
    extent = float(np.max(hi - lo))
    scale = float(np.max(np.abs(centre)))
    if scale == 0.0 or scale <= 100.0 * extent:
        return np.zeros(3)
    step = 10.0 ** np.ceil(np.log10(extent)) if extent > 0 else 10.0 ** np.floor(np.log10(scale))
    return np.round(centre / step) * step


def _clean_points(
    path: Path | None,
    xyz: np.ndarray,
    normals: np.ndarray | None,
    colors: np.ndarray | None,
    merge_duplicates: bool,
    info: dict[str, Any],
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]:
    """Drop non-finite rows, merge duplicates, validate normals; returns relative points."""
    n_read = int(xyz.shape[0])
    info["n_read"] = n_read
    finite = np.isfinite(xyz).all(axis=1)
    n_bad = int(n_read - np.count_nonzero(finite))
    info["n_nonfinite_dropped"] = n_bad
    if n_bad:
        logger.info("%s: dropped %d point(s) with non-finite coordinates", path, n_bad)
        xyz = xyz[finite]
        normals = normals[finite] if normals is not None else None
        colors = colors[finite] if colors is not None else None
    n_dup = 0
    if merge_duplicates and xyz.shape[0] > 1:
        keep = _first_occurrences(xyz)
        n_dup = int(xyz.shape[0] - keep.size)
        if n_dup:
            xyz = xyz[keep]
            normals = normals[keep] if normals is not None else None
            colors = colors[keep] if colors is not None else None
            logger.info("%s: merged %d exactly repeated point(s)", path, n_dup)
    info["n_duplicates_merged"] = n_dup
    info["n_points"] = int(xyz.shape[0])
    _check_spans_plane(path, xyz)

    info["n_invalid_normals"] = 0
    info["normals_dropped"] = False
    if normals is not None:
        normals = np.asarray(normals, dtype=np.float64)
        length = np.linalg.norm(normals, axis=1)
        valid = np.isfinite(length) & (length > _MIN_NORMAL_LENGTH)
        n_invalid = int(valid.size - np.count_nonzero(valid))
        info["n_invalid_normals"] = n_invalid
        if n_invalid > _MAX_INVALID_NORMAL_FRACTION * valid.size:
            logger.warning(
                "%s: %d of %d normals are invalid (non-finite or zero); ignoring the file's "
                "normals",
                path,
                n_invalid,
                valid.size,
            )
            normals = None
            info["normals_dropped"] = True
        else:
            with np.errstate(invalid="ignore", divide="ignore"):
                normals = normals / length[:, None]
            normals[~valid] = np.nan
            if n_invalid:
                logger.info("%s: %d invalid normal(s) will be re-estimated", path, n_invalid)
    if colors is not None:
        colors = np.clip(np.nan_to_num(np.asarray(colors, dtype=np.float64)), 0.0, 1.0)

    origin = choose_origin(xyz)
    points = xyz - origin if np.any(origin) else xyz
    return points, origin, normals, colors


def _first_occurrences(xyz: np.ndarray) -> np.ndarray:
    """Sorted indices of the first occurrence of every distinct row (exact comparison).

    Rows are hashed to one uint64 and sorted by hash (much faster than ``np.unique(axis=0)``);
    rows with equal hashes are compared exactly, so a hash collision can at worst leave a
    duplicate unmerged, never merge distinct points.
    """
    bits = np.ascontiguousarray(xyz + 0.0).view(np.uint64).reshape(-1, 3)  # + 0.0: -0 -> +0
    h = bits[:, 0] * np.uint64(0x9E3779B97F4A7C15)
    h ^= bits[:, 1] * np.uint64(0xC2B2AE3D27D4EB4F)
    h ^= bits[:, 2] * np.uint64(0x165667B19E3779F9)
    h ^= h >> np.uint64(29)
    order = np.argsort(h, kind="stable")
    hs = h[order]
    dup = np.zeros(xyz.shape[0], dtype=bool)
    cand = np.flatnonzero(hs[1:] == hs[:-1]) + 1
    if cand.size:
        rows = bits[order]
        equal = np.all(rows[cand] == rows[cand - 1], axis=1)
        dup[order[cand[equal]]] = True
    return np.flatnonzero(~dup)


def _check_spans_plane(path: Path | None, xyz: np.ndarray) -> None:
    """Enough points, coordinates in a usable range, not all identical, not all on one line.

    The line test ignores a few far outliers (the 1 % extremes on each axis, when there are at
    least 100 points): one stray point 1e12 away must not make a sphere look like a line.
    """
    n = xyz.shape[0]
    if n < 4:
        raise _err(path, f"only {n} distinct finite point(s); at least 4 are needed")
    biggest = float(np.max(np.abs(xyz)))
    if biggest > _MAX_COORDINATE:
        raise _err(
            path,
            f"coordinates up to {biggest:.3g} are too large (their magnitude must stay below "
            f"{_MAX_COORDINATE:g}); rescale the data",
        )
    extent = float(np.max(xyz.max(axis=0) - xyz.min(axis=0)))
    if extent == 0.0:
        raise _err(path, "all points are identical; the points must span at least a plane")
    if extent < _MIN_EXTENT:
        raise _err(
            path,
            f"the points span only {extent:.3g} units, too small to compute with (at least "
            f"{_MIN_EXTENT:g}); rescale the data",
        )
    sample = xyz if n <= 200_000 else xyz[:: n // 200_000 + 1]
    if _is_collinear(sample) and (len(sample) < 100 or _is_collinear(_core(sample))):
        raise _err(path, "all points lie on one line; the points must span at least a plane")


def _is_collinear(xyz: np.ndarray) -> bool:
    s = np.linalg.svd(xyz - xyz.mean(axis=0), compute_uv=False)
    return bool(s[0] == 0.0 or s[1] <= 1e-9 * s[0])


def _core(xyz: np.ndarray) -> np.ndarray:
    """Rows inside the 1st-99th percentile box of every axis."""
    lo, hi = np.percentile(xyz, [1.0, 99.0], axis=0)
    inside = np.all((xyz >= lo) & (xyz <= hi), axis=1)
    return xyz[inside] if np.count_nonzero(inside) >= 4 else xyz


def _colors_from(arr: np.ndarray) -> np.ndarray:
    """Colour channels of any numeric type to float64 in [0, 1]."""
    if np.issubdtype(arr.dtype, np.integer):
        top = float(np.iinfo(arr.dtype).max)
        return arr.astype(np.float64) / (255.0 if top >= 255 else top)
    out = arr.astype(np.float64)
    if out.size and np.nanmax(out) > 1.0:
        out = out / 255.0
    return out


def _finish(
    path: Path | None,
    fmt: str,
    xyz: np.ndarray,
    normals: np.ndarray | None,
    colors: np.ndarray | None,
    merge_duplicates: bool,
    info: dict[str, Any],
) -> PointCloud:
    xyz = np.ascontiguousarray(xyz, dtype=np.float64)
    points, origin, normals, colors = _clean_points(
        path, xyz, normals, colors, merge_duplicates, info
    )
    return PointCloud(points, origin, normals, colors, path, fmt, info)


def _check_count(path: Path, n: int, max_points: int) -> None:
    if n > max_points:
        raise _err(path, f"{n} points exceed the limit of {max_points} (io.max_points)")


# --------------------------------------------------------------------------------------------
# format detection


def _sniff(path: Path) -> str:
    """Format family from the extension, else from the first bytes."""
    ext = path.suffix.lower()
    if ext == ".ply":
        return "ply"
    if ext == ".pcd":
        return "pcd"
    if ext == ".obj":
        return "obj"
    if ext in _TEXT_EXTENSIONS:
        return "text"
    with open(path, "rb") as fh:
        head = fh.read(4096)
    if head.startswith(b"ply"):
        return "ply"
    if re.search(rb"^(# \.PCD|VERSION|FIELDS)", head, re.MULTILINE) and b"FIELDS" in head:
        return "pcd"
    try:
        text = head.decode("ascii")
    except UnicodeDecodeError:
        text = None
    if text is not None:
        if re.search(r"^\s*v\s+[-+.\d]", text, re.MULTILINE):
            return "obj"
        for line in text.splitlines():
            line = line.strip()
            if not line or line.startswith(("#", "//")):
                continue
            tokens = re.split(r"[\s,;]+", line)
            if {"x", "y", "z"} <= {t.strip("\"'").lower() for t in tokens}:
                return "text"  # a CSV header line
            try:
                [float(t) for t in tokens if t]
            except ValueError:
                break
            return "text"
    raise _err(
        path,
        f"unknown file format (extension '{path.suffix}'); supported: {SUPPORTED_POINT_FORMATS}",
    )


# --------------------------------------------------------------------------------------------
# public readers


def read_points(
    path: str | os.PathLike[str],
    *,
    max_points: int = 50_000_000,
    merge_duplicates: bool = True,
) -> PointCloud:
    """Read a point cloud (PLY, XYZ text, PCD or OBJ) into float64 relative coordinates.

    Parameters
    ----------
    path : path-like
        The file. The format comes from the extension, or from the content when the extension
        is not a known one.
    max_points : int
        Refuse files with more points than this (checked from headers before reading).
    merge_duplicates : bool
        Merge exactly repeated points (the first occurrence is kept).

    Returns
    -------
    PointCloud
        Non-finite rows dropped, duplicates merged, ``origin`` chosen by :func:`choose_origin`.

    Raises
    ------
    InputError
        Missing, empty, truncated or malformed file; fewer than 4 distinct points; points on
        one line.
    """
    p = Path(path)
    size = _check_readable(p)
    kind = _sniff(p)
    info: dict[str, Any] = {"has_faces": False, "elements": {}, "properties": []}
    try:
        # hostile values (signalling NaNs, 1e39 in a float field) are data, not warnings
        with np.errstate(invalid="ignore", over="ignore"):
            if kind == "ply":
                fmt, xyz, nrm, col = _read_ply_points(p, size, max_points, info)
            elif kind == "pcd":
                fmt, xyz, nrm, col = _read_pcd(p, size, max_points, info)
            elif kind == "obj":
                fmt, xyz, nrm, col = _read_obj_points(p, max_points, info)
            else:
                fmt, xyz, nrm, col = _read_text(p, max_points, info)
    except InputError:
        raise
    except MemoryError:
        raise _err(p, "out of memory while reading (file too large?)") from None
    except OSError as exc:
        raise _err(p, f"cannot read: {exc.strerror or exc}") from None
    return _finish(p, fmt, xyz, nrm, col, merge_duplicates, info)


def cloud_from_arrays(
    points: np.ndarray,
    normals: np.ndarray | None = None,
    *,
    colors: np.ndarray | None = None,
    merge_duplicates: bool = True,
) -> PointCloud:
    """A :class:`PointCloud` from arrays, cleaned and checked exactly like a file.

    Parameters
    ----------
    points : (n, 3) array_like [length]
        Absolute coordinates.
    normals : (n, 3) array_like, optional
    colors : (n, 3) array_like in [0, 1], optional
    merge_duplicates : bool

    Returns
    -------
    PointCloud
        ``path`` None, ``format`` ``'array'``.

    Raises
    ------
    InputError
        Wrong shapes, fewer than 4 distinct finite points, collinear points.
    """
    xyz = np.asarray(points, dtype=np.float64)
    if xyz.ndim != 2 or xyz.shape[1] != 3:
        raise _err(None, f"points: expected shape (n, 3), got {xyz.shape}")
    nrm = None if normals is None else np.asarray(normals, dtype=np.float64)
    col = None if colors is None else np.asarray(colors, dtype=np.float64)
    for name, arr in (("normals", nrm), ("colors", col)):
        if arr is not None and arr.shape != xyz.shape:
            raise _err(None, f"{name}: expected shape {xyz.shape}, got {arr.shape}")
    info: dict[str, Any] = {
        "has_faces": False,
        "elements": {"vertex": int(xyz.shape[0])},
        "properties": ["x", "y", "z"] + (["nx", "ny", "nz"] if nrm is not None else []),
    }
    return _finish(None, "array", xyz, nrm, col, merge_duplicates, info)


def read_mesh(path: str | os.PathLike[str]) -> tuple[np.ndarray, np.ndarray]:
    """Read a triangle mesh from PLY or OBJ; polygons are triangulated as fans.

    Parameters
    ----------
    path : path-like
        ``.ply`` (any encoding; face list ``vertex_indices`` or ``vertex_index``) or ``.obj``.

    Returns
    -------
    vertices : (V, 3) float64 [length]
        Absolute (file) coordinates.
    faces : (F, 3) int64
        Vertex indices; ``(0, 3)`` when the file has no faces (a point cloud).

    Raises
    ------
    InputError
        Unreadable or malformed file, non-finite vertices, face indices out of range.
    """
    p = Path(path)
    size = _check_readable(p)
    kind = _sniff(p)
    try:
        with np.errstate(invalid="ignore", over="ignore"):
            if kind == "ply":
                vertices, faces = _read_ply_mesh(p, size)
            elif kind == "obj":
                vertices, faces = _read_obj_mesh(p)
            else:
                raise _err(p, "meshes can be read from .ply and .obj files only")
    except InputError:
        raise
    except MemoryError:
        raise _err(p, "out of memory while reading (file too large?)") from None
    except OSError as exc:
        raise _err(p, f"cannot read: {exc.strerror or exc}") from None
    vertices = np.ascontiguousarray(vertices, dtype=np.float64)
    faces = np.ascontiguousarray(faces, dtype=np.int64).reshape(-1, 3)
    if faces.size and (faces.min() < 0 or faces.max() >= vertices.shape[0]):
        raise _err(p, f"face vertex index out of range [0, {vertices.shape[0]})")
    used = vertices[np.unique(faces)] if faces.size else vertices
    if not np.isfinite(used).all():
        raise _err(p, "non-finite vertex coordinates")
    return vertices, faces


# --------------------------------------------------------------------------------------------
# PLY

_PLY_TYPES = {
    "char": "i1",
    "int8": "i1",
    "uchar": "u1",
    "uint8": "u1",
    "short": "i2",
    "int16": "i2",
    "ushort": "u2",
    "uint16": "u2",
    "int": "i4",
    "int32": "i4",
    "uint": "u4",
    "uint32": "u4",
    "float": "f4",
    "float32": "f4",
    "double": "f8",
    "float64": "f8",
}

_NORMAL_NAMES = (("nx", "ny", "nz"), ("normal_x", "normal_y", "normal_z"))
_COLOR_NAMES = (
    ("red", "green", "blue"),
    ("r", "g", "b"),
    ("diffuse_red", "diffuse_green", "diffuse_blue"),
)


@dataclass
class _PlyProperty:
    name: str
    dtype: str  # numpy kind+size without byte order, e.g. 'f4'
    count_dtype: str | None = None  # list properties: type of the length prefix


@dataclass
class _PlyElement:
    name: str
    count: int
    properties: list[_PlyProperty]

    @property
    def has_lists(self) -> bool:
        return any(p.count_dtype is not None for p in self.properties)

    def row_dtype(self, order: str) -> np.dtype:
        return np.dtype([(p.name, order + p.dtype) for p in self.properties])

    def min_row_bytes(self, binary: bool) -> int:
        if binary:
            return sum(np.dtype(p.count_dtype or p.dtype).itemsize for p in self.properties)
        return 2 * len(self.properties)  # one character and one separator per value


@dataclass
class _PlyHeader:
    format: str  # 'ascii', 'binary_little_endian', 'binary_big_endian'
    elements: list[_PlyElement]
    data_offset: int

    @property
    def order(self) -> str:
        return ">" if self.format == "binary_big_endian" else "<"

    @property
    def binary(self) -> bool:
        return self.format != "ascii"

    def element(self, name: str) -> _PlyElement | None:
        return next((e for e in self.elements if e.name == name), None)


def _parse_ply_header(path: Path, fh: BinaryIO, size: int) -> _PlyHeader:
    magic = fh.readline(16)
    if magic.rstrip(b"\r\n") != b"ply":
        raise _err(path, f"not a PLY file: wrong magic {magic[:8]!r} (expected 'ply')")
    fmt: str | None = None
    elements: list[_PlyElement] = []
    while True:
        raw = fh.readline(_MAX_HEADER_BYTES)
        if fh.tell() > _MAX_HEADER_BYTES:
            raise _err(path, "PLY header has no end_header within 1 MB")
        if not raw or not raw.endswith(b"\n"):
            raise _err(path, "truncated PLY header (no end_header line)")
        try:
            line = raw.decode("ascii").strip()
        except UnicodeDecodeError:
            raise _err(path, "PLY header contains non-ASCII bytes") from None
        words = line.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        key = words[0]
        if key == "end_header":
            break
        if key == "format":
            if len(words) != 3 or words[1] not in (
                "ascii",
                "binary_little_endian",
                "binary_big_endian",
            ):
                raise _err(path, f"PLY header: unsupported format line '{line}'")
            if words[2] != "1.0":
                raise _err(
                    path, f"PLY version '{words[2]}' is not supported (PLY has only version 1.0)"
                )
            fmt = words[1]
        elif key == "element":
            if len(words) != 3:
                raise _err(path, f"PLY header: malformed element line '{line}'")
            try:
                count = int(words[2])
            except ValueError:
                raise _err(path, f"PLY header: element count is not an integer: '{line}'") from None
            if count < 0:
                raise _err(path, f"PLY header: negative element count: '{line}'")
            elements.append(_PlyElement(words[1], count, []))
        elif key == "property":
            if not elements:
                raise _err(path, f"PLY header: property before any element: '{line}'")
            el = elements[-1]
            if len(words) == 5 and words[1] == "list":
                ct, it, name = words[2], words[3], words[4]
                if ct not in _PLY_TYPES or it not in _PLY_TYPES:
                    raise _err(path, f"PLY header: unknown property type in '{line}'")
                if _PLY_TYPES[ct][0] == "f":
                    raise _err(path, f"PLY header: list length type must be an integer: '{line}'")
                el.properties.append(_PlyProperty(name, _PLY_TYPES[it], _PLY_TYPES[ct]))
            elif len(words) == 3:
                if words[1] not in _PLY_TYPES:
                    raise _err(path, f"PLY header: unknown property type in '{line}'")
                el.properties.append(_PlyProperty(words[2], _PLY_TYPES[words[1]]))
            else:
                raise _err(path, f"PLY header: malformed property line '{line}'")
            if any(p.name == words[-1] for p in el.properties[:-1]):
                raise _err(path, f"PLY header: duplicate property '{words[-1]}' in '{el.name}'")
        else:
            raise _err(path, f"PLY header: unexpected line '{line}'")
    if fmt is None:
        raise _err(path, "PLY header has no format line")
    header = _PlyHeader(fmt, elements, fh.tell())
    # Memory-bomb guard: the data must be at least as large as the header claims.
    available = size - header.data_offset
    needed = sum(e.count * e.min_row_bytes(header.binary) for e in elements)
    if not header.binary:
        needed -= 1  # the final newline may be missing
    if needed > available:
        claims = ", ".join(f"{e.count} {e.name}" for e in elements)
        raise _err(
            path,
            f"truncated PLY: the header declares {claims}, which needs at least {needed} bytes "
            f"of data, but only {available} bytes follow the header",
        )
    return header


def _skip_ply_element(path: Path, fh: BinaryIO, header: _PlyHeader, el: _PlyElement) -> None:
    if not header.binary:
        for i in range(el.count):
            if not fh.readline():
                raise _err(path, f"truncated PLY: element '{el.name}' ends at row {i}")
        return
    if not el.has_lists:
        fh.seek(el.count * el.row_dtype(header.order).itemsize, os.SEEK_CUR)
        return
    _read_ply_list_element(path, fh, header, el)


def _read_ply_fixed(path: Path, fh: BinaryIO, header: _PlyHeader, el: _PlyElement) -> np.ndarray:
    """Rows of an element with scalar properties only, as a structured array."""
    dtype = el.row_dtype(header.order)
    if header.binary:
        nbytes = el.count * dtype.itemsize
        buf = fh.read(nbytes)
        if len(buf) < nbytes:
            raise _err(
                path,
                f"truncated PLY: element '{el.name}' needs {nbytes} bytes, {len(buf)} present",
            )
        return np.frombuffer(buf, dtype=dtype, count=el.count)
    lines = (ln.decode("ascii") for ln in itertools.islice(fh, el.count))
    try:
        arr = _loadtxt(lines, dtype=np.float64, ndmin=2, comments=None)
    except UnicodeDecodeError:
        raise _err(path, f"PLY element '{el.name}': non-ASCII bytes in ascii data") from None
    except ValueError as exc:
        raise _err(path, f"PLY element '{el.name}': {_loadtxt_message(exc)}") from None
    if arr.shape[0] < el.count:
        raise _err(
            path, f"truncated PLY: element '{el.name}' has {arr.shape[0]} of {el.count} rows"
        )
    if arr.shape[1] != len(el.properties):
        raise _err(
            path,
            f"PLY element '{el.name}': rows have {arr.shape[1]} values, the header declares "
            f"{len(el.properties)} properties",
        )
    out = np.zeros(el.count, dtype=el.row_dtype("="))
    with np.errstate(invalid="ignore", over="ignore"):
        for j, p in enumerate(el.properties):
            out[p.name] = arr[:, j]  # through the declared type, as a binary file would be
    return out


def _loadtxt(*args: Any, **kwargs: Any) -> np.ndarray:
    """``np.loadtxt`` without its warnings about empty input or lines (callers check rows)."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="loadtxt: input contained no data")
        warnings.filterwarnings("ignore", message=r"Input line \d+ contained no data")
        return np.loadtxt(*args, **kwargs)


def _loadtxt_message(exc: ValueError) -> str:
    msg = str(exc).strip().rstrip(".")
    return msg[0].lower() + msg[1:] if msg else "malformed numeric data"


def _read_ply_list_element(
    path: Path, fh: BinaryIO, header: _PlyHeader, el: _PlyElement
) -> list[list[np.ndarray]]:
    """Rows of an element with list properties (binary); fast path for constant lengths.

    Returns one list per property: for scalars a (count,) array; for lists a (count, m) array
    when every row has the same length m, else a list of per-row arrays.
    """
    order = header.order
    start = fh.tell()
    # Fast path: read the first row's list lengths and assume they are constant.
    lengths = []
    head = fh.read(4096)
    fh.seek(start)
    pos = 0
    ok = True
    for p in el.properties:
        if p.count_dtype is None:
            pos += np.dtype(p.dtype).itemsize
            continue
        ct = np.dtype(order + p.count_dtype)
        if pos + ct.itemsize > len(head):
            ok = False
            break
        m = int(np.frombuffer(head, dtype=ct, count=1, offset=pos)[0])
        lengths.append(m)
        pos += ct.itemsize + m * np.dtype(p.dtype).itemsize
    if ok and el.count > 0:
        fields = []
        li = 0
        for p in el.properties:
            if p.count_dtype is None:
                fields.append((p.name, order + p.dtype))
            else:
                fields.append((p.name + "__n", order + p.count_dtype))
                fields.append((p.name, order + p.dtype, (lengths[li],)))
                li += 1
        dtype = np.dtype(fields)
        nbytes = el.count * dtype.itemsize
        buf = fh.read(nbytes)
        if len(buf) == nbytes:
            rows = np.frombuffer(buf, dtype=dtype)
            li = 0
            consistent = True
            for p in el.properties:
                if p.count_dtype is not None:
                    if not np.all(rows[p.name + "__n"] == lengths[li]):
                        consistent = False
                        break
                    li += 1
            if consistent:
                return [
                    rows[p.name].reshape(el.count, -1)
                    if p.count_dtype is not None
                    else rows[p.name]
                    for p in el.properties
                ]
        fh.seek(start)
    # Slow path: variable list lengths, row by row.
    cols: list[list[Any]] = [[] for _ in el.properties]
    for i in range(el.count):
        for j, p in enumerate(el.properties):
            if p.count_dtype is None:
                dt = np.dtype(order + p.dtype)
                raw = fh.read(dt.itemsize)
                if len(raw) < dt.itemsize:
                    raise _err(path, f"truncated PLY: element '{el.name}' ends at row {i}")
                cols[j].append(np.frombuffer(raw, dtype=dt)[0])
            else:
                ct = np.dtype(order + p.count_dtype)
                raw = fh.read(ct.itemsize)
                if len(raw) < ct.itemsize:
                    raise _err(path, f"truncated PLY: element '{el.name}' ends at row {i}")
                m = int(np.frombuffer(raw, dtype=ct)[0])
                if m < 0:
                    raise _err(path, f"PLY element '{el.name}' row {i}: negative list length")
                dt = np.dtype(order + p.dtype)
                raw = fh.read(m * dt.itemsize)
                if len(raw) < m * dt.itemsize:
                    raise _err(path, f"truncated PLY: element '{el.name}' ends at row {i}")
                cols[j].append(np.frombuffer(raw, dtype=dt))
    return [
        np.asarray(c) if p.count_dtype is None else c
        for c, p in zip(cols, el.properties, strict=True)
    ]


def _read_ply_ascii_list_element(path: Path, fh: BinaryIO, el: _PlyElement) -> list[Any]:
    """Rows of an ascii element with list properties: one list per property (see above)."""
    cols: list[list[Any]] = [[] for _ in el.properties]
    for i in range(el.count):
        raw = fh.readline()
        if not raw:
            raise _err(path, f"truncated PLY: element '{el.name}' has {i} of {el.count} rows")
        tokens = raw.split()
        pos = 0
        try:
            for j, p in enumerate(el.properties):
                if p.count_dtype is None:
                    cols[j].append(float(tokens[pos]))
                    pos += 1
                else:
                    m = int(tokens[pos])
                    cols[j].append(np.array([float(t) for t in tokens[pos + 1 : pos + 1 + m]]))
                    if len(cols[j][-1]) != m:
                        raise IndexError
                    pos += 1 + m
        except (ValueError, IndexError):
            raise _err(path, f"PLY element '{el.name}' row {i}: malformed values") from None
    return [
        np.asarray(c) if p.count_dtype is None else c
        for c, p in zip(cols, el.properties, strict=True)
    ]


def _pick(names: set[str], candidates: Sequence[tuple[str, ...]]) -> tuple[str, ...] | None:
    return next((c for c in candidates if all(n in names for n in c)), None)


def _ply_vertex_element(path: Path, header: _PlyHeader) -> _PlyElement:
    vertex = header.element("vertex")
    if vertex is None:
        found = ", ".join(e.name for e in header.elements) or "none"
        raise _err(path, f"PLY file has no 'vertex' element (elements: {found})")
    if vertex.has_lists:
        raise _err(path, "PLY 'vertex' element with list properties is not supported")
    names = {p.name for p in vertex.properties}
    if not {"x", "y", "z"} <= names:
        raise _err(
            path,
            "PLY 'vertex' element lacks x, y, z properties (has: "
            f"{', '.join(p.name for p in vertex.properties)})",
        )
    return vertex


def _open_ply_vertices(
    path: Path, size: int, max_points: int | None = None
) -> tuple[_PlyHeader, np.ndarray, BinaryIO]:
    """Parse the header, read the vertex rows; the open file is positioned after them."""
    fh = open(path, "rb")  # noqa: SIM115 - returned to the caller, closed there
    try:
        header = _parse_ply_header(path, fh, size)
        vertex = _ply_vertex_element(path, header)
        if max_points is not None:
            _check_count(path, vertex.count, max_points)
        for el in header.elements:
            if el is vertex:
                break
            _skip_ply_element(path, fh, header, el)
        rows = _read_ply_fixed(path, fh, header, vertex)
    except BaseException:
        fh.close()
        raise
    return header, rows, fh


def _read_ply_points(
    path: Path, size: int, max_points: int, info: dict[str, Any]
) -> tuple[str, np.ndarray, np.ndarray | None, np.ndarray | None]:
    header, rows, fh = _open_ply_vertices(path, size, max_points)
    fh.close()
    vertex = _ply_vertex_element(path, header)
    info["elements"] = {e.name: e.count for e in header.elements}
    info["has_faces"] = any(e.name == "face" and e.count > 0 for e in header.elements)
    info["properties"] = [p.name for p in vertex.properties]
    names = set(rows.dtype.names or ())
    xyz = np.stack([rows[c].astype(np.float64) for c in ("x", "y", "z")], axis=1)
    nn = _pick(names, _NORMAL_NAMES)
    normals = np.stack([rows[c].astype(np.float64) for c in nn], axis=1) if nn else None
    cn = _pick(names, _COLOR_NAMES)
    colors = np.stack([_colors_from(np.asarray(rows[c])) for c in cn], axis=1) if cn else None
    return f"ply-{header.format}", xyz, normals, colors


def _read_ply_mesh(path: Path, size: int) -> tuple[np.ndarray, np.ndarray]:
    header, rows, fh = _open_ply_vertices(path, size)
    with fh:
        vertices = np.stack([rows[c].astype(np.float64) for c in ("x", "y", "z")], axis=1)
        vertex = header.element("vertex")
        idx = header.elements.index(vertex)  # type: ignore[arg-type]
        faces_el = header.element("face")
        if faces_el is None or faces_el.count == 0:
            return vertices, np.zeros((0, 3), dtype=np.int64)
        prop = next(
            (
                j
                for j, p in enumerate(faces_el.properties)
                if p.count_dtype is not None and p.name in ("vertex_indices", "vertex_index")
            ),
            None,
        )
        if prop is None:
            raise _err(path, "PLY 'face' element has no vertex_indices list")
        for el in header.elements[idx + 1 :]:
            if el is faces_el:
                break
            _skip_ply_element(path, fh, header, el)
        if header.elements.index(faces_el) < idx:
            fh.seek(header.data_offset)
            for el in header.elements:
                if el is faces_el:
                    break
                _skip_ply_element(path, fh, header, el)
        if header.binary:
            cols = _read_ply_list_element(path, fh, header, faces_el)
        else:
            cols = _read_ply_ascii_list_element(path, fh, faces_el)
    return vertices, _triangulate_fans(path, cols[prop])


def _triangulate_fans(path: Path, polys: Any) -> np.ndarray:
    """(F, m) array or list of index arrays -> (T, 3) int64 triangles (fan from vertex 0)."""
    if isinstance(polys, np.ndarray) and polys.ndim == 2:
        arr = polys
        if np.issubdtype(arr.dtype, np.floating):
            if not np.all(arr == np.round(arr)):
                raise _err(path, "non-integer face vertex index")
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
            raise _err(path, "non-integer face vertex index")
        poly = poly.astype(np.int64)
        k = poly.size
        out.append(np.stack([np.full(k - 2, poly[0]), poly[1:-1], poly[2:]], axis=1))
    return np.concatenate(out) if out else np.zeros((0, 3), dtype=np.int64)


# --------------------------------------------------------------------------------------------
# XYZ / PTS text


def _read_text_file(path: Path) -> str:
    try:
        return path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError:
        raise _err(path, "not a text file (binary content); expected x y z columns") from None


_COMMENT_RE = re.compile(r"^\s*(#|//).*$|\s*//.*$", re.MULTILINE)


def _read_text(
    path: Path, max_points: int, info: dict[str, Any]
) -> tuple[str, np.ndarray, np.ndarray | None, np.ndarray | None]:
    is_pts = path.suffix.lower() == ".pts"
    text = _read_text_file(path)
    if "#" in text or "//" in text:
        text = _COMMENT_RE.sub("", text)
    text = text.replace(",", " ").replace(";", " ")
    lines = text.splitlines()
    first = next((i for i, ln in enumerate(lines) if ln.strip()), None)
    if first is None:
        raise _err(path, "no data rows (only comments or blank lines)")
    tokens = lines[first].split()
    if len(tokens) == 1:  # PTS-style count line
        try:
            int(tokens[0])
        except ValueError:
            raise _err(
                path, f"line {first + 1}: expected x y z, got '{lines[first].strip()}'"
            ) from None
        lines = lines[first + 1 :]
        first = 0
        is_pts = True
    header: list[str] | None = None
    if not all(_is_number(t) for t in tokens):  # a CSV header line such as "x,y,z,nx,ny,nz"
        header = [t.strip("\"'").lower() for t in tokens]
        if not {"x", "y", "z"} <= set(header):
            raise _err(
                path,
                f"line {first + 1}: expected numbers or a header naming x, y, z, got "
                f"'{lines[first].strip()[:80]}'",
            )
        lines = lines[first + 1 :]
    n_rows = sum(1 for ln in lines if ln.strip())
    _check_count(path, n_rows, max_points)
    if n_rows == 0:
        raise _err(path, "no data rows")
    try:
        arr = _loadtxt(lines, dtype=np.float64, ndmin=2, comments=None)
    except ValueError as exc:
        raise _err(path, _loadtxt_message(exc)) from None
    ncol = arr.shape[1]
    info["elements"] = {"vertex": int(arr.shape[0])}
    if ncol < 3:
        raise _err(path, f"rows have {ncol} column(s); expected at least x y z")
    if header is not None:
        if len(header) != ncol:
            raise _err(path, f"the header names {len(header)} columns, rows have {ncol}")
        col = {name: j for j, name in enumerate(header)}
        xyz = arr[:, [col["x"], col["y"], col["z"]]]
        nn = _pick(set(header), _NORMAL_NAMES)
        cn = _pick(set(header), _COLOR_NAMES)
        info["properties"] = header
        normals = arr[:, [col[c] for c in nn]] if nn else None
        colors = _colors_from(arr[:, [col[c] for c in cn]]) if cn else None
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
            colors = _colors_from(extra[:, :3])
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
                colors = _colors_from(g)
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


# --------------------------------------------------------------------------------------------
# PCD

_PCD_KINDS = {"F": "f", "I": "i", "U": "u"}


def _read_pcd(
    path: Path, size: int, max_points: int, info: dict[str, Any]
) -> tuple[str, np.ndarray, np.ndarray | None, np.ndarray | None]:
    with open(path, "rb") as fh:
        meta: dict[str, list[str]] = {}
        while True:
            raw = fh.readline(_MAX_HEADER_BYTES)
            if fh.tell() > _MAX_HEADER_BYTES:
                raise _err(path, "PCD header has no DATA line within 1 MB")
            if not raw:
                raise _err(path, "truncated PCD header (no DATA line)")
            try:
                line = raw.decode("ascii").strip()
            except UnicodeDecodeError:
                raise _err(path, "not a PCD file (non-ASCII header)") from None
            if not line or line.startswith("#"):
                continue
            words = line.split()
            meta[words[0].upper()] = words[1:]
            if words[0].upper() == "DATA":
                break
        offset = fh.tell()
        for key in ("FIELDS", "SIZE", "TYPE"):
            if key not in meta:
                raise _err(path, f"PCD header has no {key} line")
        names = meta["FIELDS"]
        counts = meta.get("COUNT", ["1"] * len(names))
        if not (len(meta["SIZE"]) == len(meta["TYPE"]) == len(counts) == len(names)):
            raise _err(path, "PCD header: FIELDS, SIZE, TYPE and COUNT differ in length")
        try:
            sizes = [int(s) for s in meta["SIZE"]]
            counts_i = [int(c) for c in counts]
            n = (
                int(meta["POINTS"][0])
                if "POINTS" in meta
                else (int(meta["WIDTH"][0]) * int(meta.get("HEIGHT", ["1"])[0]))
            )
        except (ValueError, IndexError, KeyError):
            raise _err(path, "PCD header: SIZE, COUNT, WIDTH or POINTS is not an integer") from None
        if n < 0:
            raise _err(path, "PCD header: negative point count")
        if any(c < 1 or c > _MAX_PCD_COUNT for c in counts_i):
            raise _err(
                path, f"PCD header: COUNT values must be 1 to {_MAX_PCD_COUNT}, got {counts_i}"
            )
        used = {"x", "y", "z", "normal_x", "normal_y", "normal_z", "nx", "ny", "nz", "rgb"}
        used.add("rgba")
        for name, c in zip(names, counts_i, strict=True):
            if name in used and c != 1:
                raise _err(path, f"PCD header: field '{name}' has COUNT {c}, expected 1")
        fields_dt = []
        seen: dict[str, int] = {}
        for name, sz, tp, c in zip(names, sizes, meta["TYPE"], counts_i, strict=True):
            if tp.upper() not in _PCD_KINDS or sz not in (
                (4, 8) if tp.upper() == "F" else (1, 2, 4, 8)
            ):
                raise _err(path, f"PCD header: unsupported field type {tp}{sz} for '{name}'")
            key = name if name not in seen else f"{name}__{seen[name]}"
            seen[name] = seen.get(name, 0) + 1
            base = "<" + _PCD_KINDS[tp.upper()] + str(sz)
            fields_dt.append((key, base, (c,)) if c != 1 else (key, base))
        dtype = np.dtype(fields_dt)
        data_kind = meta["DATA"][0].lower() if meta["DATA"] else ""
        if data_kind == "binary_compressed":
            raise _err(
                path,
                "PCD 'binary_compressed' data is not supported; convert it to binary or ascii "
                "(e.g. pcl_convert_pcd_ascii_binary in.pcd out.pcd 1)",
            )
        if not {"x", "y", "z"} <= set(names):
            raise _err(path, f"PCD file lacks x, y, z fields (has: {', '.join(names)})")
        _check_count(path, n, max_points)
        info["elements"] = {"vertex": n}
        info["properties"] = list(names)
        if data_kind == "binary":
            nbytes = n * dtype.itemsize
            if size - offset < nbytes:
                raise _err(
                    path,
                    f"truncated PCD: {n} points need {nbytes} bytes, only {size - offset} "
                    "bytes follow the header",
                )
            rows = np.frombuffer(fh.read(nbytes), dtype=dtype, count=n)
            fmt = "pcd-binary"
        elif data_kind == "ascii":
            ncols = sum(counts_i)
            if size - offset < 2 * ncols * n - 1:
                raise _err(path, f"truncated PCD: the header declares {n} points")
            text = _io.TextIOWrapper(fh, encoding="ascii", newline=None)
            try:
                arr = _loadtxt(text, dtype=np.float64, ndmin=2, max_rows=n, comments=None)
            except UnicodeDecodeError:
                raise _err(path, "PCD data: non-ASCII bytes in ascii data") from None
            except ValueError as exc:
                raise _err(path, f"PCD data: {_loadtxt_message(exc)}") from None
            finally:
                text.detach()
            if arr.shape[0] < n or arr.shape[1] != ncols:
                raise _err(
                    path,
                    f"PCD data: expected {n} rows of {ncols} values, got {arr.shape[0]} rows of "
                    f"{arr.shape[1]}",
                )
            rows = np.zeros(n, dtype=dtype)
            col = 0
            for name, c in zip(dtype.names or (), counts_i, strict=True):
                vals = arr[:, col : col + c] if c != 1 else arr[:, col]
                if name.startswith(("rgb", "rgba")) and dtype[name].kind == "f":
                    # packed colour written as the decimal value of the float or as an integer
                    as_int = np.all(np.isfinite(vals)) and np.all(vals == np.round(vals))
                    if as_int and np.nanmax(np.abs(vals), initial=0) > 1e6:
                        rows[name] = vals.astype(np.uint32).view(np.float32)
                        col += c
                        continue
                rows[name] = vals
                col += c
            fmt = "pcd-ascii"
        else:
            raise _err(path, f"PCD header: unknown DATA kind '{data_kind}'")
    xyz = np.stack([rows[c].astype(np.float64) for c in ("x", "y", "z")], axis=1)
    nn = _pick(set(names), (("normal_x", "normal_y", "normal_z"), ("nx", "ny", "nz")))
    normals = np.stack([rows[c].astype(np.float64) for c in nn], axis=1) if nn else None
    colors = None
    cname = "rgb" if "rgb" in names else ("rgba" if "rgba" in names else None)
    if cname is not None:
        packed = np.ascontiguousarray(rows[cname])
        packed = packed.view(np.uint32) if packed.dtype.itemsize == 4 else packed.astype(np.uint32)
        colors = np.stack([(packed >> s) & 255 for s in (16, 8, 0)], axis=1) / 255.0
    return fmt, xyz, normals, colors


# --------------------------------------------------------------------------------------------
# OBJ


def _obj_lines(path: Path) -> list[str]:
    return _read_text_file(path).splitlines()


def _parse_rows(path: Path, rows: list[list[str]], what: str, lines: list[int]) -> np.ndarray:
    try:
        return np.array(rows, dtype=np.float64).reshape(len(rows), 3)
    except ValueError:
        for r, ln in zip(rows, lines, strict=True):
            try:
                [float(t) for t in r]
            except ValueError:
                raise _err(path, f"line {ln + 1}: non-numeric {what} '{' '.join(r)}'") from None
            if len(r) != 3:
                raise _err(path, f"line {ln + 1}: {what} needs 3 numbers") from None
        raise _err(path, f"malformed {what} lines") from None


def _obj_vertices(
    path: Path, lines: list[str]
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    v_rows: list[list[str]] = []
    v_lines: list[int] = []
    vn_rows: list[list[str]] = []
    vn_lines: list[int] = []
    rgb: list[list[str]] = []
    for i, line in enumerate(lines):
        if line.startswith("v "):
            t = line.split()
            v_rows.append(t[1:4])
            v_lines.append(i)
            rgb.append(t[4:7] if len(t) == 7 else [])
        elif line.startswith("vn "):
            vn_rows.append(line.split()[1:4])
            vn_lines.append(i)
    verts = _parse_rows(path, v_rows, "vertex", v_lines) if v_rows else np.zeros((0, 3))
    normals = None
    if vn_rows and len(vn_rows) == len(v_rows):
        normals = _parse_rows(path, vn_rows, "normal", vn_lines)
    colors = None
    if rgb and all(len(c) == 3 for c in rgb):
        try:
            colors = _colors_from(np.array(rgb, dtype=np.float64))
        except ValueError:
            colors = None
    return verts, normals, colors


def _read_obj_points(
    path: Path, max_points: int, info: dict[str, Any]
) -> tuple[str, np.ndarray, np.ndarray | None, np.ndarray | None]:
    lines = _obj_lines(path)
    n_v = sum(1 for ln in lines if ln.startswith("v "))
    _check_count(path, n_v, max_points)
    if n_v == 0:
        raise _err(path, "OBJ file has no 'v' vertex lines")
    verts, normals, colors = _obj_vertices(path, lines)
    n_f = sum(1 for ln in lines if ln.startswith("f "))
    info["elements"] = {"vertex": n_v, "face": n_f}
    info["has_faces"] = n_f > 0
    info["properties"] = ["x", "y", "z"] + (["nx", "ny", "nz"] if normals is not None else [])
    return "obj", verts, normals, colors


def _read_obj_mesh(path: Path) -> tuple[np.ndarray, np.ndarray]:
    lines = _obj_lines(path)
    verts, _, _ = _obj_vertices(path, lines)
    flat: list[int] = []
    sizes: list[int] = []
    n_before: list[int] = []  # vertices defined before each face (negative indices)
    n_seen = 0
    for i, line in enumerate(lines):
        if line.startswith("v "):
            n_seen += 1
        elif line.startswith("f "):
            tokens = line.split()[1:]
            if len(tokens) < 3:  # not a polygon (as in PLY, skipped)
                continue
            try:
                flat.extend(int(t.split("/", 1)[0]) for t in tokens)
            except ValueError:
                raise _err(path, f"line {i + 1}: malformed face '{line.strip()}'") from None
            sizes.append(len(tokens))
            n_before.append(n_seen)
    if not sizes:
        return verts, np.zeros((0, 3), dtype=np.int64)
    idx = np.asarray(flat, dtype=np.int64)
    size_arr = np.asarray(sizes, dtype=np.int64)
    if np.any(idx == 0):
        raise _err(path, "face index 0 (OBJ indices start at 1)")
    base = np.repeat(np.asarray(n_before, dtype=np.int64), size_arr)
    idx = np.where(idx > 0, idx - 1, base + idx)
    if np.all(size_arr == size_arr[0]):
        return verts, _triangulate_fans(path, idx.reshape(-1, int(size_arr[0])))
    starts = np.concatenate([[0], np.cumsum(size_arr)[:-1]])
    polys = [idx[a : a + m] for a, m in zip(starts.tolist(), sizes, strict=True)]
    return verts, _triangulate_fans(path, polys)


# --------------------------------------------------------------------------------------------
# output paths and atomic writes


def check_output_path(
    path: str | os.PathLike[str],
    inputs: Sequence[str | os.PathLike[str]] = (),
    mkdir: bool = False,
    *,
    mkdir_option: str | None = "--mkdir",
) -> Path:
    """Validate an output path before any work is done.

    Parameters
    ----------
    path : path-like
        The file to be written.
    inputs : sequence of path-like
        Input files of the run; writing onto one of them is refused.
    mkdir : bool
        Create a missing parent folder instead of failing.
    mkdir_option : str or None
        The caller's option that creates the folder, named in the error; None when it has none.

    Returns
    -------
    Path

    Raises
    ------
    InputError
        ``path`` is an input, a directory, or its folder is missing (without ``mkdir``).
    """
    out = Path(path)
    if str(out) in ("", "."):
        raise _err(out, "empty output path")
    if out.is_dir():
        raise _err(out, "is a directory; give an output file name")
    resolved = out.resolve()
    for inp in inputs:
        ip = Path(inp)
        same = resolved == ip.resolve()
        if not same and out.exists() and ip.exists():
            with contextlib.suppress(OSError):
                same = os.path.samefile(out, ip)
        if same:
            raise _err(out, "refusing to overwrite an input file; choose another output name")
    parent = resolved.parent
    if not parent.exists():
        if not mkdir:
            hint = f"create it or use {mkdir_option}" if mkdir_option else "create it first"
            raise _err(out, f"folder '{out.parent}' does not exist ({hint})")
        try:
            parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise _err(out, f"cannot create folder '{out.parent}': {exc.strerror or exc}") from None
    elif not parent.is_dir():
        raise _err(out, f"'{out.parent}' is not a folder")
    return out


@contextlib.contextmanager
def atomic_output(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Write to a temporary file beside ``path`` and move it into place on success.

    The temporary file keeps the suffix of ``path`` (so writers that choose the format from the
    extension work). On any exception, including ``KeyboardInterrupt``, it is removed and
    ``path`` is left untouched; an ``OSError`` (disk full, permission denied) becomes an
    :class:`~recon.errors.InputError` naming ``path``.

    Parameters
    ----------
    path : path-like
        Final destination.

    Yields
    ------
    Path
        The temporary file to write.
    """
    dest = Path(path)
    folder = dest.parent
    tmp = folder / f".{dest.name}.{os.getpid()}-{secrets.token_hex(4)}.tmp{dest.suffix}"
    try:
        open(tmp, "xb").close()  # noqa: SIM115 - reserve the name (respects the umask)
    except OSError as exc:
        raise _err(_final_name(dest), f"cannot write: {exc.strerror or exc}") from None
    try:
        yield tmp
        os.replace(tmp, dest)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            tmp.unlink()
        if isinstance(exc, OSError):
            raise _err(_final_name(dest), f"cannot write: {exc.strerror or exc}") from None
        raise


_TMP_NAME = re.compile(r"^\.(?P<name>.+)\.\d+-[0-9a-f]{8}\.tmp")


def _final_name(path: Path) -> Path:
    """The destination a (possibly nested) :func:`atomic_output` temporary stands for."""
    while (m := _TMP_NAME.match(path.name)) is not None:
        path = path.with_name(m.group("name"))
    return path


# --------------------------------------------------------------------------------------------
# writers


def _as_points(name: str, arr: Any) -> np.ndarray:
    a = np.asarray(arr, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] != 3:
        raise InputError(f"{name}: expected an (n, 3) array, got shape {a.shape}")
    return a


def _absolute(points: Any, origin: Any) -> np.ndarray:
    pts = _as_points("points", points)
    if origin is None:
        return pts
    o = np.asarray(origin, dtype=np.float64).reshape(-1)
    if o.shape != (3,):
        raise InputError(f"origin: expected 3 numbers, got shape {np.shape(origin)}")
    return pts + o if np.any(o) else pts


def _coordinate_type(xyz: np.ndarray) -> str:
    """'f4' when float32 keeps ``_FLOAT32_TOLERANCE`` of the extent, else 'f8'."""
    if xyz.shape[0] == 0:
        return "f4"
    if not np.isfinite(xyz).all():
        return "f8"
    with np.errstate(over="ignore"):
        err = float(np.max(np.abs(xyz.astype(np.float32).astype(np.float64) - xyz)))
    extent = float(np.max(xyz.max(axis=0) - xyz.min(axis=0)))
    if not np.isfinite(err):
        return "f8"
    return "f4" if err <= _FLOAT32_TOLERANCE * extent else "f8"


_PLY_NAMES = {"f4": "float", "f8": "double", "i4": "int", "u1": "uchar"}


def _ply_header(
    n_vertices: int,
    vertex_props: list[tuple[str, str]],
    n_faces: int | None,
    ascii: bool,
) -> bytes:
    fmt = "ascii" if ascii else "binary_little_endian"
    lines = ["ply", f"format {fmt} 1.0", "comment written by oprecon"]
    lines.append(f"element vertex {n_vertices}")
    lines += [f"property {_PLY_NAMES[t]} {n}" for n, t in vertex_props]
    if n_faces is not None:
        lines.append(f"element face {n_faces}")
        lines.append("property list uchar int vertex_indices")
    lines.append("end_header")
    return ("\n".join(lines) + "\n").encode("ascii")


def _write_ply(
    path: Path,
    xyz: np.ndarray,
    normals: np.ndarray | None,
    faces: np.ndarray | None,
    ascii: bool,
) -> None:
    ct = _coordinate_type(xyz)
    props = [("x", ct), ("y", ct), ("z", ct)]
    if normals is not None:
        props += [("nx", "f4"), ("ny", "f4"), ("nz", "f4")]
    header = _ply_header(xyz.shape[0], props, None if faces is None else faces.shape[0], ascii)
    with atomic_output(path) as tmp, open(tmp, "wb") as fh:
        fh.write(header)
        if ascii:
            cols = [xyz] + ([normals] if normals is not None else [])
            data = np.hstack(cols) if len(cols) > 1 else xyz
            fmt = ["%.17g" if ct == "f8" else "%.9g"] * 3
            if normals is not None:
                fmt += ["%.9g"] * 3
            np.savetxt(fh, data, fmt=fmt, delimiter=" ")
            if faces is not None and faces.shape[0]:
                np.savetxt(fh, np.hstack([np.full((faces.shape[0], 1), 3), faces]), fmt="%d")
        else:
            rows = np.zeros(xyz.shape[0], dtype=[(n, "<" + t) for n, t in props])
            for j, c in enumerate("xyz"):
                rows[c] = xyz[:, j]
            if normals is not None:
                for j, c in enumerate(("nx", "ny", "nz")):
                    rows[c] = normals[:, j]
            fh.write(rows.tobytes())
            if faces is not None and faces.shape[0]:
                frows = np.zeros(faces.shape[0], dtype=[("n", "u1"), ("v", "<i4", (3,))])
                frows["n"] = 3
                frows["v"] = faces
                fh.write(frows.tobytes())


def _check_normals(normals: Any, n: int) -> np.ndarray | None:
    if normals is None:
        return None
    nrm = np.asarray(normals, dtype=np.float64)
    if nrm.shape != (n, 3):
        raise InputError(f"normals: expected shape ({n}, 3), got {nrm.shape}")
    return nrm


def write_points(
    path: str | os.PathLike[str],
    points: np.ndarray,
    normals: np.ndarray | None = None,
    *,
    origin: np.ndarray | None = None,
    ascii: bool = False,
) -> None:
    """Write an (oriented) point cloud as PLY, atomically.

    Parameters
    ----------
    path : path-like
        Output file (PLY whatever the extension).
    points : (n, 3) float64 [length]
        Coordinates relative to ``origin``.
    normals : (n, 3) float64, optional
        Stored as float32 ``nx, ny, nz``.
    origin : (3,) float64 [length], optional
        Added to ``points`` before writing (file coordinates are absolute).
    ascii : bool
        ASCII PLY instead of binary little-endian.

    Notes
    -----
    Coordinates are stored as ``double`` when float32 would lose more than 1e-7 of the extent
    (large offsets), else as ``float``; ascii output prints enough digits to round-trip.
    """
    xyz = _absolute(points, origin)
    nrm = _check_normals(normals, xyz.shape[0])
    _write_ply(Path(path), xyz, nrm, None, ascii)


def write_mesh(
    path: str | os.PathLike[str],
    vertices: np.ndarray,
    faces: np.ndarray,
    normals: np.ndarray | None = None,
    *,
    origin: np.ndarray | None = None,
    ascii: bool = False,
) -> None:
    """Write a triangle mesh as PLY or OBJ (chosen by the extension), atomically.

    Parameters
    ----------
    path : path-like
        ``.ply`` or ``.obj``.
    vertices : (V, 3) float64 [length]
        Relative to ``origin``.
    faces : (F, 3) integer
        Vertex indices (0-based).
    normals : (V, 3) float64, optional
        Per-vertex normals.
    origin : (3,) float64 [length], optional
    ascii : bool
        ASCII PLY (OBJ is always text, with 17 significant digits: vertices read back exactly).

    Raises
    ------
    InputError
        Unsupported extension, bad shapes, face indices out of range.
    """
    p = Path(path)
    xyz = _absolute(vertices, origin)
    f = np.asarray(faces)
    if f.size == 0:
        f = np.zeros((0, 3), dtype=np.int64)
    if f.ndim != 2 or f.shape[1] != 3 or not np.issubdtype(f.dtype, np.integer):
        raise InputError(f"faces: expected an (F, 3) integer array, got {f.dtype} {f.shape}")
    if f.size and (f.min() < 0 or f.max() >= xyz.shape[0]):
        raise InputError(f"faces: vertex index out of range [0, {xyz.shape[0]})")
    if xyz.shape[0] >= 2**31:
        raise InputError("vertices: too many for 32-bit face indices")
    nrm = _check_normals(normals, xyz.shape[0])
    ext = p.suffix.lower()
    if ext == ".ply":
        _write_ply(p, xyz, nrm, f.astype(np.int64), ascii)
    elif ext == ".obj":
        _write_obj(p, xyz, nrm, f.astype(np.int64))
    else:
        raise _err(p, f"cannot write meshes as '{p.suffix}'; use .ply or .obj")


def _write_obj(path: Path, xyz: np.ndarray, normals: np.ndarray | None, faces: np.ndarray) -> None:
    # OBJ has no number type: a reader parses float64, so 17 digits are needed for the values
    # to come back exactly (9 would round-trip only through float32)
    vfmt = "v %.17g %.17g %.17g"
    with atomic_output(path) as tmp, open(tmp, "w", encoding="ascii", newline="\n") as fh:
        fh.write("# written by oprecon\n")
        np.savetxt(fh, xyz, fmt=vfmt)
        if normals is not None:
            np.savetxt(fh, normals, fmt="vn %.9g %.9g %.9g")
        if faces.shape[0]:
            f1 = faces + 1
            if normals is not None:
                np.savetxt(fh, np.repeat(f1, 2, axis=1), fmt="f %d//%d %d//%d %d//%d")
            else:
                np.savetxt(fh, f1, fmt="f %d %d %d")
