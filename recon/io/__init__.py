"""Reading and writing point clouds and meshes: the only package that knows file formats.

Readers return a :class:`~recon.cloud.PointCloud` whose coordinates are float64 and *relative*
to an ``origin`` (the rounded bounding-box centre when the coordinates are large compared with
the extent, e.g. georeferenced scans at x ~ 5e6 with mm detail; zero otherwise), so that nothing
downstream loses precision. Writers add the origin back and store float64 (``double``) vertex
coordinates whenever float32 would lose more than ``1e-7`` of the extent.

This module dispatches by extension (or content) to one module per format and holds the public
API; the layers below it are:

==================  =========================================================================
:mod:`.ply`         PLY (``.ply``): ascii, binary little and big endian; points, meshes, writer
:mod:`.xyz`         XYZ text (``.xyz .xyzn .txt .csv .asc .pts``): columns, CSV header, PTS
:mod:`.pcd`         PCD (``.pcd``): ascii and binary (``binary_compressed`` is not supported)
:mod:`.obj`         OBJ (``.obj``): ``v`` (and ``vn``), faces; writer
:mod:`.las`         LAS/LAZ (``.las .laz``, laspy + lazrs): chunked, colour, intensity, classes
:mod:`.e57`         E57 (``.e57``, pye57): every scan, poses applied, colour, intensity
:mod:`.clean`       non-finite rows, duplicates, normals, origin, degenerate inputs
:mod:`.files`       output-path checks and the one layer of atomic writes
:mod:`.common`      helpers shared by the format modules (errors, columns, fans)
==================  =========================================================================

Every problem with an input file raises :class:`~recon.errors.InputError` with a message of the
form ``"<path>: <what is wrong>"``; sizes claimed by headers are checked against the file size
before anything is allocated. Files of an unknown extension are recognised by their content.
Every written file appears complete or not at all (:mod:`recon.io.files`).
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Any

import numpy as np

from ..cloud import PointCloud, numeric_array, unit_colors
from ..errors import InputError
from . import e57, las, obj, pcd, ply, xyz
from .clean import check_coordinate_range, choose_origin, make_cloud
from .common import as_input_points, check_readable, input_error, reading
from .files import AtomicOutputs, atomic_output, atomic_outputs, check_output_path

__all__ = [
    "SUPPORTED_POINT_FORMATS",
    "AtomicOutputs",
    "PointCloud",
    "atomic_output",
    "atomic_outputs",
    "check_output_path",
    "check_png_output",
    "check_points_output",
    "choose_origin",
    "cloud_from_arrays",
    "read_mesh",
    "read_points",
    "write_mesh",
    "write_points",
]

SUPPORTED_POINT_FORMATS = (
    "PLY (.ply), XYZ/XYZN/PTS/TXT/CSV text, PCD (.pcd), OBJ (.obj), LAS/LAZ (.las .laz), E57 (.e57)"
)


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
    if ext in (".las", ".laz"):
        return "las"
    if ext == ".e57":
        return "e57"
    if ext in xyz.TEXT_EXTENSIONS:
        return "text"
    with open(path, "rb") as fh:
        head = fh.read(4096)
    if head.startswith(b"ply"):
        return "ply"
    if head.startswith(b"LASF"):
        return "las"
    if head.startswith(b"ASTM-E57"):
        return "e57"
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
    raise input_error(
        path,
        f"unknown file format (extension '{path.suffix}'); supported: {SUPPORTED_POINT_FORMATS}",
    )


# --------------------------------------------------------------------------------------------
# readers


def read_points(
    path: str | os.PathLike[str],
    *,
    max_points: int = 50_000_000,
    merge_duplicates: bool = True,
    classes: list[int] | tuple[int, ...] | None = None,
    all_properties: bool = False,
    outliers: tuple[int, float] | None = None,
) -> PointCloud:
    """Read a point cloud (PLY, XYZ text, PCD, OBJ, LAS/LAZ, E57) into relative coordinates.

    Parameters
    ----------
    path : path-like
        The file. The format comes from the extension, or from the content when the extension
        is not a known one.
    max_points : int
        Refuse files with more points than this (checked from headers before reading).
    merge_duplicates : bool
        Merge exactly repeated points (the first occurrence is kept).
    classes : sequence of int, optional
        Keep only the points of these LAS classes (e.g. ``[2, 6]``, ground and buildings);
        None or empty keeps every point. Only LAS/LAZ files have classes.
    all_properties : bool
        PLY: also keep every other scalar vertex property (``quality``, ``alpha``, a scalar
        field ...) in ``attributes``, under its own name and in the file's type, and a
        ``classification`` beyond the LAS classes 0-255 in its own type, so that
        :func:`write_points` writes them back (``oprecon normals``); the fit has no use for
        them. Properties named like the normals or colours but not a complete set of them (a
        lone ``red``) are not kept, and a warning names them. Other formats: no effect.
    outliers : (k, std_ratio), optional
        Remove statistical outliers after merging duplicates, their rows of normals, colours
        and attributes with them (:func:`recon.io.outliers.statistical_outliers`;
        ``recon.io.outliers.outlier_removal(cfg.io)``); ``info["n_outliers_removed"]`` counts them.
        None keeps every point.

    Returns
    -------
    PointCloud
        Non-finite rows dropped, duplicates merged, ``origin`` chosen by :func:`choose_origin`;
        LAS/LAZ and E57 also fill ``attributes`` (intensity, classification), text files
        with an intensity column (PTS) the intensity, PLY files their ``intensity`` and
        ``classification`` vertex properties. ``intensity`` is float64, ``classification``
        uint8 when every class is 0-255 (LAS), else the file's values in the file's type.

    Raises
    ------
    InputError
        Missing, empty, truncated or malformed file; fewer than 4 distinct points; points on
        one line; ``classes`` for a file without classification, or no point of those
        classes; a LAS/LAZ/E57 file without the optional packages (``oprecon[lidar]``).
    """
    p = Path(path)
    size = check_readable(p)
    kind = _sniff(p)
    info: dict[str, Any] = {"has_faces": False, "elements": {}, "properties": []}
    attributes: dict[str, np.ndarray] = {}
    if classes and kind != "las":
        raise input_error(
            p,
            "the file has no point classification (only LAS/LAZ files have classes); "
            "drop --classes (io.classes)",
        )
    with reading(p):
        if kind == "las":
            fmt, pts, nrm, col, attributes = las.read_points(p, max_points, info, classes)
        elif kind == "e57":
            fmt, pts, nrm, col, attributes = e57.read_points(p, max_points, info)
        elif kind == "ply":
            fmt, pts, nrm, col, attributes = ply.read_points(
                p, size, max_points, info, all_properties
            )
        elif kind == "pcd":
            fmt, pts, nrm, col = pcd.read_points(p, size, max_points, info)
        elif kind == "obj":
            fmt, pts, nrm, col = obj.read_points(p, max_points, info)
        else:
            fmt, pts, nrm, col, attributes = xyz.read_points(p, max_points, info)
    return make_cloud(p, fmt, pts, nrm, col, merge_duplicates, info, attributes, outliers)


def cloud_from_arrays(
    points: np.ndarray,
    normals: np.ndarray | None = None,
    *,
    colors: np.ndarray | None = None,
    attributes: dict[str, np.ndarray] | None = None,
    merge_duplicates: bool = True,
    outliers: tuple[int, float] | None = None,
    viewpoints: np.ndarray | None = None,
) -> PointCloud:
    """A :class:`PointCloud` from arrays, cleaned and checked exactly like a file.

    Parameters
    ----------
    points : (n, 3) array_like [length]
        Absolute coordinates.
    normals : (n, 3) array_like, optional
    colors : (n, 3) array_like, optional
        Floats in [0, 1], or integers scaled by their type (0-255; uint16: 0-65535).
    attributes : dict of str -> (n,) array_like, optional
        Per-point scalars (``intensity``, ``classification`` ...).
    merge_duplicates : bool
    outliers : (k, std_ratio), optional
        Remove statistical outliers, as :func:`read_points`.
    viewpoints : (n, 3) array_like [length], optional
        Where each point was scanned from, absolute (``PointCloud.viewpoints``).

    Returns
    -------
    PointCloud
        ``path`` None, ``format`` ``'array'``.

    Raises
    ------
    InputError
        Wrong shapes, arrays that are not real numbers (None, text, complex), colours
        outside their range or not finite, fewer than 4 distinct finite points, collinear
        points.
    """
    xyz = as_input_points(numeric_array(points, "points"), "points", where="input array")
    nrm = None if normals is None else np.asarray(numeric_array(normals, "normals"), np.float64)
    col = None if colors is None else unit_colors(colors)
    view = None if viewpoints is None else np.asarray(numeric_array(viewpoints, "viewpoints"))
    for name, arr in (("normals", nrm), ("colors", col), ("viewpoints", view)):
        if arr is not None and arr.shape != xyz.shape:
            raise input_error(None, f"{name}: expected shape {xyz.shape}, got {arr.shape}")
    if view is not None and not np.isfinite(view).all():
        raise input_error(None, "viewpoints: not every row is finite")
    attrs = {str(k): np.asarray(v) for k, v in (attributes or {}).items()}
    for name, arr in attrs.items():
        if arr.shape != (xyz.shape[0],):
            raise input_error(None, f"{name}: expected shape ({xyz.shape[0]},), got {arr.shape}")
    info: dict[str, Any] = {
        "has_faces": False,
        "elements": {"vertex": int(xyz.shape[0])},
        "properties": ["x", "y", "z"] + (["nx", "ny", "nz"] if nrm is not None else []),
    }
    return make_cloud(None, "array", xyz, nrm, col, merge_duplicates, info, attrs, outliers, view)


def read_mesh(
    path: str | os.PathLike[str], *, all_finite: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """Read a triangle mesh from PLY or OBJ; polygons are triangulated as fans.

    Parameters
    ----------
    path : path-like
        ``.ply`` (any encoding; face list ``vertex_indices`` or ``vertex_index``) or ``.obj``.
    all_finite : bool
        Also refuse non-finite coordinates in vertices that no face uses. By default those
        are kept (``oprecon remesh`` removes unreferenced vertices); the measures of every
        vertex (``oprecon report``, ``compare``) need them finite.

    Returns
    -------
    vertices : (V, 3) float64 [length]
        Absolute (file) coordinates.
    faces : (F, 3) int64
        Vertex indices; ``(0, 3)`` when the file has no faces (a point cloud).

    Raises
    ------
    InputError
        Unreadable or malformed file, non-finite vertices (used by a face, or any with
        ``all_finite``), face indices out of range.
    """
    p = Path(path)
    size = check_readable(p)
    kind = _sniff(p)
    with reading(p):
        if kind == "ply":
            vertices, faces = ply.read_mesh(p, size)
        elif kind == "obj":
            vertices, faces = obj.read_mesh(p)
        else:
            raise input_error(p, "meshes can be read from .ply and .obj files only")
    vertices = np.ascontiguousarray(vertices, dtype=np.float64)
    faces = np.ascontiguousarray(faces, dtype=np.int64).reshape(-1, 3)
    if faces.size and (faces.min() < 0 or faces.max() >= vertices.shape[0]):
        raise input_error(p, f"face vertex index out of range [0, {vertices.shape[0]})")
    used = vertices[np.unique(faces)] if faces.size else vertices
    if not np.isfinite(used).all():
        raise input_error(p, "non-finite vertex coordinates")
    if all_finite:
        bad = np.flatnonzero(~np.isfinite(vertices).all(axis=1))
        if len(bad):  # (not used by a face: those were refused above)
            raise input_error(
                p,
                f"non-finite coordinates in {_vertices_named(bad)}, used by no face; "
                "remove the vertex (every vertex is measured)",
            )
    check_coordinate_range(p, used)
    return vertices, faces


def _vertices_named(indices: np.ndarray) -> str:
    """``vertex 4`` or ``3 vertices (the first: vertex 4)`` (0-based indices)."""
    if len(indices) == 1:
        return f"vertex {int(indices[0])}"
    return f"{len(indices):,} vertices (the first: vertex {int(indices[0])})"


# --------------------------------------------------------------------------------------------
# writers


def check_points_output(path: str | os.PathLike[str]) -> None:
    """Raise :class:`~recon.errors.InputError` unless ``path`` names a PLY file: the commands
    write point clouds as PLY only, and check the name before the work that produces them
    (a PLY named ``.xyz`` is read by no other tool)."""
    p = Path(path)
    if p.suffix.lower() != ".ply":
        what = f"'{p.suffix}'" if p.suffix else "a file without an extension"
        raise input_error(p, f"cannot write point clouds as {what}; use .ply")


def check_png_output(path: str | os.PathLike[str], what: str = "the picture") -> None:
    """Raise :class:`~recon.errors.InputError` unless ``path`` ends in ``.png`` (any case): the
    pictures (``fit --preview``, ``report --png``) are PNG only, and the commands check the
    name before the work that produces them (PNG bytes named ``.jpg`` mislead every viewer).
    ``what`` names the picture in the message (``"the preview"``)."""
    p = Path(path)
    if p.suffix.lower() != ".png":
        as_ = f"'{p.suffix}'" if p.suffix else "a file without an extension"
        raise input_error(p, f"{what} is a PNG image and cannot be written as {as_}; use .png")


def write_points(
    path: str | os.PathLike[str],
    points: np.ndarray,
    normals: np.ndarray | None = None,
    *,
    origin: np.ndarray | None = None,
    ascii: bool = False,
    outputs: AtomicOutputs | None = None,
    colors: np.ndarray | None = None,
    vertex_properties: dict[str, np.ndarray] | None = None,
) -> None:
    """Write an (oriented) point cloud as PLY, atomically.

    Parameters
    ----------
    path : path-like
        Output file (PLY whatever the extension; the commands ask for ``.ply``:
        :func:`check_points_output`).
    points : (n, 3) float64 [length]
        Coordinates relative to ``origin``.
    normals : (n, 3) float64, optional
        Stored as float32 ``nx, ny, nz``.
    origin : (3,) float64 [length], optional
        Added to ``points`` before writing (file coordinates are absolute).
    ascii : bool
        ASCII PLY instead of binary little-endian.
    outputs : AtomicOutputs, optional
        Write as part of this set of outputs (moved into place together when its
        :func:`~recon.io.files.atomic_outputs` block ends) instead of on its own.
    colors : (n, 3) uint8, optional
        PLY ``red green blue`` (uchar).
    vertex_properties : dict of name -> (n,) array, optional
        More vertex properties (``intensity``, ``classification`` ...), each in the PLY type
        of its array's: ``char``, ``uchar``, ``short``, ``ushort``, ``int``, ``uint``,
        ``float``, ``double`` (bool as ``uchar``); float64 as ``float`` when float32 holds
        every value exactly, else ``double``; 64-bit integers as ``int`` or ``uint`` when
        they fit, else ``double``. No value is rounded or clipped.

    Notes
    -----
    Coordinates are stored as ``double`` when float32 would lose more than 1e-7 of the extent
    (large offsets), else as ``float``; ascii output prints enough digits to round-trip.
    """
    xyz = _absolute(points, origin)
    nrm = _check_normals(normals, xyz.shape[0])
    rgb = _check_colors(colors, xyz.shape[0])
    extra = _with_rgb(rgb, _vertex_properties(vertex_properties, xyz.shape[0], exact=True))
    with atomic_output(path, outputs) as tmp, open(tmp, "wb") as fh:
        ply.write(fh, xyz, nrm, None, ascii, extra or None)


def write_mesh(
    path: str | os.PathLike[str],
    vertices: np.ndarray,
    faces: np.ndarray,
    normals: np.ndarray | None = None,
    *,
    origin: np.ndarray | None = None,
    ascii: bool = False,
    outputs: AtomicOutputs | None = None,
    colors: np.ndarray | None = None,
    vertex_properties: dict[str, np.ndarray] | None = None,
    corner_normals: np.ndarray | None = None,
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
    outputs : AtomicOutputs, optional
        Write as part of this set of outputs (moved into place together when its
        :func:`~recon.io.files.atomic_outputs` block ends) instead of on its own.
    colors : (V, 3) uint8, optional
        Vertex colours: PLY ``red green blue`` (uchar); OBJ ``v x y z r g b`` (floats in
        [0, 1]).
    vertex_properties : dict of name -> (V,) array, optional
        More PLY vertex properties, in this order: uint8 arrays as ``uchar``, uint16 as
        ``ushort``, other integers as ``int``, floats as ``float``. PLY only.
    corner_normals : (F, 3, 3) float64, optional
        OBJ only: one normal per face corner (``f v//vn``), split across creases; replaces
        ``normals`` in the file. Ignored for PLY (one normal per vertex: split the vertices
        with :func:`recon.crease_mesh.split_crease_vertices` instead).

    Raises
    ------
    InputError
        Unsupported extension, bad shapes, non-finite vertex coordinates, face indices out of
        range, vertex properties for an OBJ file.
    """
    p = Path(path)
    xyz = _absolute(vertices, origin)
    bad = np.flatnonzero(~np.isfinite(xyz).all(axis=1))
    if len(bad):  # read_mesh refuses them: a file no reader takes back
        raise input_error(
            p,
            f"cannot write non-finite coordinates (in {_vertices_named(bad)}): a mesh file "
            "holds finite coordinates only",
        )
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
    if ext not in (".ply", ".obj"):
        raise input_error(p, f"cannot write meshes as '{p.suffix}'; use .ply or .obj")
    rgb = _check_colors(colors, xyz.shape[0])
    extra = _vertex_properties(vertex_properties, xyz.shape[0])
    if extra and ext != ".ply":
        names = ", ".join(name for name, _, _ in extra)
        raise input_error(p, f"OBJ has no vertex properties ({names}); write a .ply mesh")
    extra = _with_rgb(rgb, extra)
    with atomic_output(p, outputs) as tmp, open(tmp, "wb") as fh:
        if ext == ".ply":
            ply.write(fh, xyz, nrm, f.astype(np.int64), ascii, extra)
        else:
            cn = None
            if corner_normals is not None and nrm is not None:
                cn = np.asarray(corner_normals, dtype=np.float64)
                if cn.shape != (len(f), 3, 3):
                    raise InputError(
                        f"corner_normals: expected shape ({len(f)}, 3, 3), got {cn.shape}"
                    )
            obj.write(fh, xyz, nrm, f.astype(np.int64), rgb, cn)


def _with_rgb(
    rgb: np.ndarray | None, extra: list[tuple[str, np.ndarray, str]]
) -> list[tuple[str, np.ndarray, str]]:
    """PLY vertex columns: ``red green blue`` (uchar) from ``rgb`` first, then ``extra``."""
    if rgb is None:
        return extra
    return [(c, rgb[:, j], "u1") for j, c in enumerate(("red", "green", "blue"))] + extra


def _absolute(points: Any, origin: Any) -> np.ndarray:
    pts = as_input_points(points, "points")
    if origin is None:
        return pts
    o = np.asarray(origin, dtype=np.float64).reshape(-1)
    if o.shape != (3,):
        raise InputError(f"origin: expected 3 numbers, got shape {np.shape(origin)}")
    return pts + o if np.any(o) else pts


def _check_colors(colors: Any, n: int) -> np.ndarray | None:
    if colors is None:
        return None
    rgb = np.asarray(colors)
    if rgb.shape != (n, 3) or rgb.dtype != np.uint8:
        raise InputError(f"colors: expected a ({n}, 3) uint8 array, got {rgb.dtype} {rgb.shape}")
    return rgb


_PROPERTY_TYPES = {np.dtype(np.uint8): "u1", np.dtype(np.uint16): "u2"}


def _vertex_properties(
    props: Any, n: int, exact: bool = False
) -> list[tuple[str, np.ndarray, str]]:
    """(name, values, PLY type) of each property; ``exact``: in the types of
    :func:`_exact_type` (``write_points``), else as :func:`write_mesh` says."""
    out = []
    for name, values in (props or {}).items():
        a = np.asarray(values)
        if a.shape != (n,):
            raise InputError(f"vertex property '{name}': expected shape ({n},), got {a.shape}")
        if name in ("x", "y", "z", "nx", "ny", "nz", "red", "green", "blue"):
            raise InputError(f"vertex property '{name}': the name is taken")
        if exact and (a.dtype.kind in "biuf"):
            t = _exact_type(a)
        elif a.dtype in _PROPERTY_TYPES:
            t = _PROPERTY_TYPES[a.dtype]
        elif np.issubdtype(a.dtype, np.integer):
            t = "i4"
        elif np.issubdtype(a.dtype, np.floating):
            t = "f4"
        else:
            raise InputError(f"vertex property '{name}': unsupported type {a.dtype}")
        out.append((str(name), a, t))
    return out


def _exact_type(a: np.ndarray) -> str:
    """The PLY type that holds every value of the numeric array ``a`` exactly: its own type
    where PLY has it, the narrower ``float`` for float64 values that float32 holds exactly,
    ``int`` or ``uint`` for 64-bit integers that fit, ``double`` for the others."""
    if a.dtype.kind == "b":
        return "u1"
    if a.dtype.kind == "f":
        if a.dtype.itemsize <= 4:
            return "f4"
        with np.errstate(over="ignore", invalid="ignore"):
            narrow = a.astype(np.float32).astype(a.dtype)
        return "f4" if np.array_equal(narrow, a, equal_nan=True) else "f8"
    if a.dtype.itemsize <= 4:
        return a.dtype.kind + str(a.dtype.itemsize)
    lo, hi = (int(a.min()), int(a.max())) if a.size else (0, 0)
    if -(2**31) <= lo and hi < 2**31:
        return "i4"
    if 0 <= lo and hi < 2**32:
        return "u4"
    return "f8"


def _check_normals(normals: Any, n: int) -> np.ndarray | None:
    if normals is None:
        return None
    nrm = as_input_points(normals, "normals")
    if nrm.shape != (n, 3):
        raise InputError(f"normals: expected shape ({n}, 3), got {nrm.shape}")
    return nrm
