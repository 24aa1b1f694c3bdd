"""LAS and LAZ (ASPRS LiDAR): reading points, colours, intensity and classification.

Read with ``laspy`` (LAZ through its ``lazrs`` backend), both from the optional extra
``oprecon[lidar]``. The points are read in chunks of :data:`CHUNK_POINTS` and filtered by class
chunk by chunk, so the memory used follows the points kept, not the file size.

Coordinates are the file's scaled integers, ``X * scale + offset``, in float64: for
georeferenced data (x ~ 5e6 m) that is exact to about 1e-9 m, and the reader's origin
(:func:`recon.io.clean.choose_origin`) then keeps them relative without loss.

Colours are 16-bit in the LAS specification, but many writers store 8-bit values in the 16-bit
fields: when no channel value exceeds 255 the colours are taken as 8-bit, else as 16-bit (so
that ``v16 = 257 * v8`` maps back to ``v8`` exactly).

References
----------
[LAS] ASPRS. "LAS specification 1.4 - R15", 2019. https://www.asprs.org/divisions-committees/
      lidar-division/laser-las-file-format-exchange-activities
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InputError
from .common import LIDAR_EXTRA, check_count, input_error, optional_module

__all__ = ["CHUNK_POINTS", "check_header", "no_point_of_classes", "read_points"]

#: Points per chunk read from a LAS/LAZ file.
CHUNK_POINTS = 1_000_000

#: Sizes [bytes] of the smallest LAS header (versions 1.0 to 1.2), of the fixed part of a
#: variable length record (VLR) and of an extended one (EVLR, LAS 1.4) ([LAS] tables 3, 4, 5).
_MIN_HEADER_BYTES = 227
_VLR_HEADER_BYTES = 54
_EVLR_HEADER_BYTES = 60

#: GeoTIFF keys of the GeoKeyDirectory VLR that hold an EPSG code: projected, geographic,
#: vertical.
_EPSG_KEYS = {3072: "projected", 2048: "geographic", 4096: "vertical"}


def _crs(header: Any) -> str | None:
    """The coordinate reference system: the WKT VLR's text, else EPSG codes from GeoKeys."""
    vlrs = list(header.vlrs) + list(getattr(header, "evlrs", None) or [])
    for vlr in vlrs:
        if type(vlr).__name__ == "WktCoordinateSystemVlr":
            text = str(vlr.string).strip("\x00").strip()
            if text:
                return text
    for vlr in vlrs:
        if type(vlr).__name__ == "GeoKeyDirectoryVlr":
            codes = [
                f"EPSG:{int(k.value_offset)} ({_EPSG_KEYS[int(k.id)]})"
                for k in vlr.geo_keys
                if int(k.id) in _EPSG_KEYS and 0 < int(k.value_offset) < 32767
            ]
            if codes:
                return ", ".join(codes)
    return None


def check_header(path: Path) -> None:
    """Check the sizes and counts of a LAS/LAZ header against each other and the file size.

    laspy trusts them: a corrupt number of VLRs (say 0xEB000000) makes it create empty VLRs
    past the end of the header for hours while its memory grows, and so does a corrupt number
    of EVLRs. So the records must fit where the header puts them before laspy sees the file:
    the VLRs between the header and the point data, the EVLRs between their start and the end
    of the file. Smaller damage (a bad point format, record length or point count) is left to
    laspy and to the chunked reading, which stop with an error.

    Raises
    ------
    InputError
        Naming the file and the header field (with its byte offsets) that is wrong.
    """
    size = path.stat().st_size
    with open(path, "rb") as fh:
        head = fh.read(_MIN_HEADER_BYTES + 148)  # up to the LAS 1.4 header's EVLR fields
    if len(head) < _MIN_HEADER_BYTES or head[:4] != b"LASF":
        return  # laspy says what is wrong (signature, too short)
    bad = "not a valid LAS/LAZ file: corrupt header:"
    header_size, data_offset, n_vlrs = struct.unpack_from("<HII", head, 94)
    if data_offset > size:
        raise input_error(
            path,
            f"{bad} the offset to point data (bytes 96-99) is {data_offset}, beyond the end "
            f"of the file ({size} bytes)",
        )
    if header_size > data_offset:
        raise input_error(
            path,
            f"{bad} the header size (bytes 94-95) is {header_size}, more than the offset to "
            f"point data (bytes 96-99, {data_offset})",
        )
    room = data_offset - header_size
    if n_vlrs * _VLR_HEADER_BYTES > room:
        raise input_error(
            path,
            f"{bad} the number of VLRs (bytes 100-103) is {n_vlrs}, but only {room} bytes lie "
            f"between the header and the point data (each VLR needs at least "
            f"{_VLR_HEADER_BYTES})",
        )
    if head[24] == 1 and head[25] >= 4 and len(head) >= 247 and header_size >= 247:
        evlr_start, n_evlrs = struct.unpack_from("<QI", head, 235)
        if n_evlrs and (
            evlr_start < data_offset or evlr_start + n_evlrs * _EVLR_HEADER_BYTES > size
        ):
            raise input_error(
                path,
                f"{bad} {n_evlrs} EVLRs (number at bytes 243-246) starting at byte {evlr_start} "
                f"(bytes 235-242) do not fit between the point data and the end of the file "
                f"({size} bytes; each EVLR needs at least {_EVLR_HEADER_BYTES})",
            )


def no_point_of_classes(path: Path, classes: Any, counts: np.ndarray) -> InputError:
    """The error for ``--classes`` that keep no point: the classes asked for, and those the
    file has with their point counts (``counts``: points per class value, 0-255)."""
    present = ", ".join(f"{c} ({int(counts[c]):,} points)" for c in np.flatnonzero(counts))
    return input_error(
        path,
        f"no point of class {', '.join(str(int(c)) for c in classes)} "
        f"(the file has classes: {present or 'none'})",
    )


def _open(laspy: Any, path: Path) -> Any:
    try:
        return laspy.open(str(path))
    except Exception as exc:  # laspy raises many kinds on a damaged header
        raise input_error(path, f"not a valid LAS/LAZ file: {_message(exc)}") from None


def _message(exc: BaseException) -> str:
    text = str(exc).strip() or type(exc).__name__
    return text.splitlines()[0]


def _rows(a: np.ndarray, keep: np.ndarray | None) -> np.ndarray:
    return a if keep is None else a[keep]


def read_points(
    path: Path,
    max_points: int,
    info: dict[str, Any],
    classes: Sequence[int] | None = None,
    chunk_points: int = CHUNK_POINTS,
) -> tuple[str, np.ndarray, None, np.ndarray | None, dict[str, np.ndarray]]:
    """Read a LAS/LAZ file chunk by chunk, keeping only ``classes`` when given.

    Returns
    -------
    format : str
        ``'las-1.4-pf7'`` style (``laz`` when compressed).
    xyz : (n, 3) float64
        Absolute coordinates.
    normals : None
    colors : (n, 3) float64 in [0, 1] or None
    attributes : dict
        ``intensity`` (float64) and ``classification`` (uint8).
    """
    laspy = optional_module("laspy", path, "LAS/LAZ files")
    with open(path, "rb") as fh:
        magic = fh.read(4)
    if magic != b"LASF":
        raise input_error(path, f"not a LAS/LAZ file: wrong signature {magic!r} (expected 'LASF')")
    check_header(path)
    reader = _open(laspy, path)
    with reader:
        header = reader.header
        compressed = bool(getattr(header, "are_points_compressed", False))
        if compressed and not laspy.LazBackend.detect_available():
            raise input_error(
                path, f"reading LAZ (compressed) files needs the package 'lazrs': {LIDAR_EXTRA}"
            )
        n_total = int(header.point_count)
        dims = set(header.point_format.dimension_names)
        has_rgb = {"red", "green", "blue"} <= dims
        keep_classes = None if not classes else np.asarray(sorted(set(classes)), dtype=np.int64)
        if keep_classes is None:
            check_count(path, n_total, max_points)
        pf = int(header.point_format.id)
        version = f"{header.version.major}.{header.version.minor}"
        info["point_format"] = pf
        info["las_version"] = version
        info["compressed"] = compressed
        info["crs"] = _crs(header)
        info["scales"] = [float(s) for s in header.scales]
        info["offsets"] = [float(o) for o in header.offsets]
        info["elements"] = {"vertex": n_total}
        info["properties"] = list(header.point_format.dimension_names)
        info["seen_from_above"] = True  # z is the elevation (recon.normals.scanner_positions)
        counts = np.zeros(256, dtype=np.int64)
        parts: dict[str, list[np.ndarray]] = {"xyz": [], "rgb": [], "intensity": [], "cls": []}
        n_kept = 0
        n_seen = 0
        try:
            for chunk in reader.chunk_iterator(max(1, int(chunk_points))):
                cls = np.asarray(chunk.classification, dtype=np.uint8)
                n_seen += cls.size
                counts += np.bincount(cls, minlength=256)
                keep = None if keep_classes is None else np.isin(cls, keep_classes)
                m = cls.size if keep is None else int(np.count_nonzero(keep))
                n_kept += m
                check_count(path, n_kept, max_points)
                if m == 0:
                    continue
                xyz = np.stack(
                    [np.asarray(chunk.x), np.asarray(chunk.y), np.asarray(chunk.z)], axis=1
                ).astype(np.float64, copy=False)
                parts["xyz"].append(_rows(xyz, keep))
                parts["cls"].append(_rows(cls, keep))
                intensity = np.asarray(chunk.intensity, dtype=np.uint16)
                parts["intensity"].append(_rows(intensity, keep))
                if has_rgb:
                    rgb = np.stack(
                        [np.asarray(chunk[c], dtype=np.uint16) for c in ("red", "green", "blue")],
                        axis=1,
                    )
                    parts["rgb"].append(_rows(rgb, keep))
        except Exception as exc:  # truncated data, corrupt LAZ chunks (lazrs), ...
            if type(exc).__name__ == "InputError":
                raise
            raise input_error(
                path,
                f"not a valid LAS/LAZ file: reading the points failed after {n_seen} of "
                f"{n_total} ({_message(exc)})",
            ) from None
    if n_seen < n_total:
        raise input_error(
            path, f"truncated LAS/LAZ file: {n_seen} of the {n_total} declared points present"
        )
    info["classes"] = {int(c): int(counts[c]) for c in np.flatnonzero(counts)}
    info["classes_kept"] = None if keep_classes is None else [int(c) for c in keep_classes]
    if keep_classes is not None and n_kept == 0:
        raise no_point_of_classes(path, keep_classes, counts)

    def cat(name: str, shape: tuple[int, ...], dtype: Any) -> np.ndarray:
        return np.concatenate(parts[name]) if parts[name] else np.zeros(shape, dtype=dtype)

    xyz = cat("xyz", (0, 3), np.float64)
    colors = None
    if has_rgb:
        rgb = cat("rgb", (0, 3), np.uint16)
        top = 255.0 if rgb.size == 0 or int(rgb.max()) <= 255 else 65535.0
        colors = rgb.astype(np.float64) / top
    attributes = {
        "intensity": cat("intensity", (0,), np.uint16).astype(np.float64),
        "classification": cat("cls", (0,), np.uint8),
    }
    fmt = f"{'laz' if compressed else 'las'}-{version}-pf{pf}"
    return fmt, xyz, None, colors, attributes
