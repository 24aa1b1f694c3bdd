"""PLY: reading points and meshes (ascii, binary little and big endian), writing both.

Reading accepts any numeric type for x, y, z; optional nx, ny, nz and red, green, blue; other
elements (``face``, ``camera`` ...) are skipped. Faces are read from a ``vertex_indices`` (or
``vertex_index``) list and triangulated as fans. The header is validated (version 1.0, the only
PLY version; known types; sizes against the file size) before anything is allocated; comment and
obj_info lines may hold any bytes (UTF-8 text). Blank lines in ascii data are skipped. Integer
colours are scaled by their type (``ushort``: 0-65535, the others 0-255), float colours are on
0-1 unless a value exceeds 1 (then 0-255), one decision for the three channels.

Writing stores binary little-endian (or ascii) PLY 1.0: ``float`` coordinates, or ``double``
when float32 would lose more than 1e-7 of the extent; ``float`` normals; faces as
``list uchar int vertex_indices``.

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
"""

from __future__ import annotations

import itertools
import logging
import os
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from .common import (
    COLOR_NAMES,
    MAX_HEADER_BYTES,
    NORMAL_NAMES,
    SCALAR_PROPERTIES,
    check_count,
    colors_from,
    input_error,
    integer_color_scale,
    loadtxt,
    loadtxt_message,
    pick,
    triangulate_fans,
)

__all__ = ["read_mesh", "read_points", "write"]

logger = logging.getLogger("recon.io")


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

#: Relative precision (of the extent) that float32 output must keep, else double is written.
_FLOAT32_TOLERANCE = 1e-7


# --------------------------------------------------------------------------------------------
# reading


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
        raise input_error(path, f"not a PLY file: wrong magic {magic[:8]!r} (expected 'ply')")
    fmt: str | None = None
    elements: list[_PlyElement] = []
    while True:
        raw = fh.readline(MAX_HEADER_BYTES)
        if fh.tell() > MAX_HEADER_BYTES:
            raise input_error(path, "PLY header has no end_header within 1 MB")
        if not raw or not raw.endswith(b"\n"):
            raise input_error(path, "truncated PLY header (no end_header line)")
        first = raw.split(None, 1)[:1]
        if not first or first[0] in (b"comment", b"obj_info"):
            continue  # free text, in any encoding (UTF-8 names, as Open3D reads them)
        try:
            line = raw.decode("ascii").strip()
        except UnicodeDecodeError:
            raise input_error(
                path, "PLY header contains non-ASCII bytes outside comment lines"
            ) from None
        words = line.split()
        key = words[0]
        if key == "end_header":
            break
        if key == "format":
            if len(words) != 3 or words[1] not in (
                "ascii",
                "binary_little_endian",
                "binary_big_endian",
            ):
                raise input_error(path, f"PLY header: unsupported format line '{line}'")
            if words[2] != "1.0":
                raise input_error(
                    path, f"PLY version '{words[2]}' is not supported (PLY has only version 1.0)"
                )
            fmt = words[1]
        elif key == "element":
            if len(words) != 3:
                raise input_error(path, f"PLY header: malformed element line '{line}'")
            try:
                count = int(words[2])
            except ValueError:
                raise input_error(
                    path, f"PLY header: element count is not an integer: '{line}'"
                ) from None
            if count < 0:
                raise input_error(path, f"PLY header: negative element count: '{line}'")
            elements.append(_PlyElement(words[1], count, []))
        elif key == "property":
            if not elements:
                raise input_error(path, f"PLY header: property before any element: '{line}'")
            el = elements[-1]
            if len(words) == 5 and words[1] == "list":
                ct, it, name = words[2], words[3], words[4]
                if ct not in _PLY_TYPES or it not in _PLY_TYPES:
                    raise input_error(path, f"PLY header: unknown property type in '{line}'")
                if _PLY_TYPES[ct][0] == "f":
                    raise input_error(
                        path, f"PLY header: list length type must be an integer: '{line}'"
                    )
                el.properties.append(_PlyProperty(name, _PLY_TYPES[it], _PLY_TYPES[ct]))
            elif len(words) == 3:
                if words[1] not in _PLY_TYPES:
                    raise input_error(path, f"PLY header: unknown property type in '{line}'")
                el.properties.append(_PlyProperty(words[2], _PLY_TYPES[words[1]]))
            else:
                raise input_error(path, f"PLY header: malformed property line '{line}'")
            if any(p.name == words[-1] for p in el.properties[:-1]):
                raise input_error(
                    path, f"PLY header: duplicate property '{words[-1]}' in '{el.name}'"
                )
        else:
            raise input_error(path, f"PLY header: unexpected line '{line}'")
    if fmt is None:
        raise input_error(path, "PLY header has no format line")
    header = _PlyHeader(fmt, elements, fh.tell())
    # Memory-bomb guard: the data must be at least as large as the header claims.
    available = size - header.data_offset
    needed = sum(e.count * e.min_row_bytes(header.binary) for e in elements)
    if not header.binary:
        needed -= 1  # the final newline may be missing
    if needed > available:
        claims = ", ".join(f"{e.count} {e.name}" for e in elements)
        raise input_error(
            path,
            f"truncated PLY: the header declares {claims}, which needs at least {needed} bytes "
            f"of data, but only {available} bytes follow the header",
        )
    return header


def _ascii_rows(fh: BinaryIO) -> Iterator[bytes]:
    """The lines of ascii PLY data from the file's position on, blank lines skipped (they hold
    no row; some writers leave one between elements)."""
    return filter(bytes.strip, fh)  # lazy: the file stays just after the last row taken


def _skip_ply_element(path: Path, fh: BinaryIO, header: _PlyHeader, el: _PlyElement) -> None:
    if not header.binary:
        rows = _ascii_rows(fh)
        for i in range(el.count):
            if next(rows, None) is None:
                raise input_error(path, f"truncated PLY: element '{el.name}' ends at row {i}")
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
            raise input_error(
                path,
                f"truncated PLY: element '{el.name}' needs {nbytes} bytes, {len(buf)} present",
            )
        return np.frombuffer(buf, dtype=dtype, count=el.count)
    if el.count == 0:  # np.loadtxt would read the next element's rows, or say "1 values"
        return np.zeros(0, dtype=el.row_dtype("="))
    lines = (ln.decode("ascii") for ln in itertools.islice(_ascii_rows(fh), el.count))
    try:
        arr = loadtxt(lines, dtype=np.float64, ndmin=2, comments=None)
    except UnicodeDecodeError:
        raise input_error(path, f"PLY element '{el.name}': non-ASCII bytes in ascii data") from None
    except ValueError as exc:
        raise input_error(path, f"PLY element '{el.name}': {loadtxt_message(exc)}") from None
    if arr.shape[0] < el.count:
        raise input_error(
            path, f"truncated PLY: element '{el.name}' has {arr.shape[0]} of {el.count} rows"
        )
    if arr.shape[1] != len(el.properties):
        raise input_error(
            path,
            f"PLY element '{el.name}': rows have {arr.shape[1]} values, the header declares "
            f"{len(el.properties)} properties",
        )
    out = np.zeros(el.count, dtype=el.row_dtype("="))
    with np.errstate(invalid="ignore", over="ignore"):
        for j, p in enumerate(el.properties):
            out[p.name] = arr[:, j]  # through the declared type, as a binary file would be
    return out


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
                    raise input_error(path, f"truncated PLY: element '{el.name}' ends at row {i}")
                cols[j].append(np.frombuffer(raw, dtype=dt)[0])
            else:
                ct = np.dtype(order + p.count_dtype)
                raw = fh.read(ct.itemsize)
                if len(raw) < ct.itemsize:
                    raise input_error(path, f"truncated PLY: element '{el.name}' ends at row {i}")
                m = int(np.frombuffer(raw, dtype=ct)[0])
                if m < 0:
                    raise input_error(
                        path, f"PLY element '{el.name}' row {i}: negative list length"
                    )
                dt = np.dtype(order + p.dtype)
                raw = fh.read(m * dt.itemsize)
                if len(raw) < m * dt.itemsize:
                    raise input_error(path, f"truncated PLY: element '{el.name}' ends at row {i}")
                cols[j].append(np.frombuffer(raw, dtype=dt))
    return [
        np.asarray(c) if p.count_dtype is None else c
        for c, p in zip(cols, el.properties, strict=True)
    ]


def _read_ply_ascii_list_element(path: Path, fh: BinaryIO, el: _PlyElement) -> list[Any]:
    """Rows of an ascii element with list properties: one list per property (see above)."""
    cols: list[list[Any]] = [[] for _ in el.properties]
    rows = _ascii_rows(fh)
    for i in range(el.count):
        raw = next(rows, None)
        if raw is None:
            raise input_error(
                path, f"truncated PLY: element '{el.name}' has {i} of {el.count} rows"
            )
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
            raise input_error(path, f"PLY element '{el.name}' row {i}: malformed values") from None
    return [
        np.asarray(c) if p.count_dtype is None else c
        for c, p in zip(cols, el.properties, strict=True)
    ]


def _ply_vertex_element(path: Path, header: _PlyHeader) -> _PlyElement:
    vertex = header.element("vertex")
    if vertex is None:
        found = ", ".join(e.name for e in header.elements) or "none"
        raise input_error(path, f"PLY file has no 'vertex' element (elements: {found})")
    if vertex.has_lists:
        raise input_error(path, "PLY 'vertex' element with list properties is not supported")
    names = {p.name for p in vertex.properties}
    if not {"x", "y", "z"} <= names:
        raise input_error(
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
            check_count(path, vertex.count, max_points)
        for el in header.elements:
            if el is vertex:
                break
            _skip_ply_element(path, fh, header, el)
        rows = _read_ply_fixed(path, fh, header, vertex)
    except BaseException:
        fh.close()
        raise
    return header, rows, fh


def read_points(
    path: Path, size: int, max_points: int, info: dict[str, Any], all_properties: bool = False
) -> tuple[str, np.ndarray, np.ndarray | None, np.ndarray | None, dict[str, np.ndarray]]:
    """(format, xyz, normals or None, colours in [0, 1] or None, attributes).

    The attributes are the per-point scalars, in the order of the file's properties:
    ``intensity`` (float64) and ``classification`` (:func:`_classes`: uint8 for classes
    0-255, else the file's values in its type) where a vertex property holds them, and with
    ``all_properties`` every other scalar vertex property under its own name, in the file's
    type (:func:`_other_properties`).
    """
    header, rows, fh = _open_ply_vertices(path, size, max_points)
    fh.close()
    vertex = _ply_vertex_element(path, header)
    info["elements"] = {e.name: e.count for e in header.elements}
    info["has_faces"] = any(e.name == "face" and e.count > 0 for e in header.elements)
    info["properties"] = [p.name for p in vertex.properties]
    names = set(rows.dtype.names or ())
    xyz = np.stack([rows[c].astype(np.float64) for c in ("x", "y", "z")], axis=1)
    nn = pick(names, NORMAL_NAMES)
    normals = np.stack([rows[c].astype(np.float64) for c in nn], axis=1) if nn else None
    cn = pick(names, COLOR_NAMES)
    colors = _ply_colors(path, [np.asarray(rows[c]) for c in cn]) if cn else None
    scalars = {}  # property name -> attribute
    for key, candidates in SCALAR_PROPERTIES.items():
        name = next((c for c in candidates if c in names), None)
        if name is not None:
            scalars[name] = key
    used = {"x", "y", "z", *(nn or ()), *(cn or ()), *scalars}
    others = _other_properties(path, vertex, used) if all_properties else []
    attributes = {}
    for p in vertex.properties:
        if p.name in scalars:
            values = np.asarray(rows[p.name])
            key = scalars[p.name]
            attributes[key] = (
                _classes(path, values, all_properties)
                if key == "classification"
                else values.astype(np.float64)
            )
        elif p.name in others:
            attributes[p.name] = rows[p.name].astype(rows[p.name].dtype.newbyteorder("="))
    return f"ply-{header.format}", xyz, normals, colors, attributes


def _classes(path: Path, values: np.ndarray, exact: bool) -> np.ndarray:
    """A classification property as uint8 when every value is a class 0-255 (LAS classes, as
    every reader gives them), else in the file's type: classes above 255, negative or
    fractional ones keep their values (``--transfer classification`` writes them as ``int``,
    or ``float`` when they are not integers of int32: :func:`recon.attributes.class_values`).
    Only the classes neither type holds (a ``uint`` past int32, a ``double`` beyond float32)
    are rounded there, and a warning says so, unless ``exact`` (``oprecon normals`` writes
    them back as they are)."""
    if values.size == 0:
        return values.astype(np.uint8)
    with np.errstate(invalid="ignore"):
        integral = bool(np.all(values == np.round(values)))
        lo, hi = values.min().item(), values.max().item()  # (NaN when one is: not integral)
    if integral and lo >= 0 and hi <= 255:
        return values.astype(np.uint8)
    values = values.astype(values.dtype.newbyteorder("="))
    if exact or (integral and -(2**31) <= lo and hi < 2**31):
        return values
    with np.errstate(over="ignore", invalid="ignore"):
        narrow = values.astype(np.float32).astype(values.dtype)
    held = np.array_equal(narrow, values, equal_nan=values.dtype.kind == "f")
    if not held:
        finite = values[np.isfinite(values)]
        logger.warning(
            "%s: the classification holds values from %s to %s, not all integers of int32 nor "
            "values of float32: --transfer classification writes them as float, rounded",
            path,
            finite.min() if finite.size else "nan",
            finite.max() if finite.size else "nan",
        )
    return values


#: Vertex properties that the point writer takes from the normals and colours, whatever the
#: file held under those names.
_WRITTEN_NAMES = ("x", "y", "z", "nx", "ny", "nz", "red", "green", "blue")


def _other_properties(path: Path, vertex: _PlyElement, used: set[str]) -> list[str]:
    """The vertex properties not read as coordinates, normals, colours or known scalars, which
    ``all_properties`` keeps; those with a name the writer gives the normals or colours (a
    lone ``red`` without green and blue) cannot be kept beside them, and a warning names them.
    """
    rest = [p.name for p in vertex.properties if p.name not in used]
    dropped = [n for n in rest if n in _WRITTEN_NAMES]
    if dropped:
        logger.warning(
            "%s: vertex properties %s are not kept: they are not a complete set of normals "
            "(nx, ny, nz) or colours (red, green, blue), and the output's own normals and "
            "colours take those names",
            path,
            ", ".join(dropped),
        )
    return [n for n in rest if n not in dropped]


def _ply_colors(path: Path, channels: list[np.ndarray]) -> np.ndarray:
    """Colours in [0, 1] from the channels, each scaled by its type (``ushort``: 16-bit).

    An integer channel with values past full intensity for its type (an ``int`` channel
    holding 16-bit values) is clipped later: say so rather than return white in silence.
    """
    for name, c in zip(("red", "green", "blue"), channels, strict=False):
        if np.issubdtype(c.dtype, np.integer) and c.size and c.dtype.itemsize > 1:
            lo, hi, scale = int(c.min()), int(c.max()), int(integer_color_scale(c.dtype))
            if lo < 0 or hi > scale:
                logger.warning(
                    "%s: the %s (%s) channel holds colour values from %d to %d, outside 0 to "
                    "%d (full intensity for that type); they are clipped",
                    path,
                    name,
                    c.dtype.name,
                    lo,
                    hi,
                    scale,
                )
                break
    return colors_from(channels)


def read_mesh(path: Path, size: int) -> tuple[np.ndarray, np.ndarray]:
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
            raise input_error(path, "PLY 'face' element has no vertex_indices list")
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
    return vertices, triangulate_fans(path, cols[prop])


# --------------------------------------------------------------------------------------------
# writing


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


_PLY_NAMES = {
    "f4": "float",
    "f8": "double",
    "i1": "char",
    "i2": "short",
    "i4": "int",
    "u1": "uchar",
    "u2": "ushort",
    "u4": "uint",
}


#: ascii formats of float vertex properties (enough digits to read the value back exactly).
_ASCII_FORMATS = {"f4": "%.9g", "f8": "%.17g"}


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


def write(
    fh: BinaryIO,
    xyz: np.ndarray,
    normals: np.ndarray | None,
    faces: np.ndarray | None,
    ascii: bool,
    extra: list[tuple[str, np.ndarray, str]] | None = None,
) -> None:
    """Write vertices (and faces) as PLY to an open binary file.

    Parameters
    ----------
    fh : binary file
    xyz : (n, 3) float64 [length]
        Absolute coordinates.
    normals : (n, 3) float64 or None
    faces : (F, 3) int64 or None
        None writes no ``face`` element (a point cloud).
    ascii : bool
        ASCII instead of binary little-endian.
    extra : list of (name, (n,) array, type), optional
        More vertex properties after the normals, in this order; ``type`` is ``'i1'``
        (char), ``'u1'`` (uchar), ``'i2'`` (short), ``'u2'`` (ushort), ``'i4'`` (int),
        ``'u4'`` (uint), ``'f4'`` (float) or ``'f8'`` (double), e.g. ``("red", r, "u1")``.
        None or empty: the file is byte for byte as without them.
    """
    ct = _coordinate_type(xyz)
    props = [("x", ct), ("y", ct), ("z", ct)]
    if normals is not None:
        props += [("nx", "f4"), ("ny", "f4"), ("nz", "f4")]
    extra = list(extra or [])
    props += [(name, t) for name, _, t in extra]
    fh.write(_ply_header(xyz.shape[0], props, None if faces is None else faces.shape[0], ascii))
    if ascii:
        cols = [xyz] + ([normals] if normals is not None else [])
        cols += [np.asarray(a, dtype=np.float64).reshape(-1, 1) for _, a, _ in extra]
        data = np.hstack(cols) if len(cols) > 1 else xyz
        fmt = ["%.17g" if ct == "f8" else "%.9g"] * 3
        if normals is not None:
            fmt += ["%.9g"] * 3
        fmt += [_ASCII_FORMATS.get(t, "%d") for _, _, t in extra]
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
        for name, a, _ in extra:
            rows[name] = a
        fh.write(rows.tobytes())
        if faces is not None and faces.shape[0]:
            frows = np.zeros(faces.shape[0], dtype=[("n", "u1"), ("v", "<i4", (3,))])
            frows["n"] = 3
            frows["v"] = faces
            fh.write(frows.tobytes())
