"""PCD (Point Cloud Library): reading ascii and binary point files.

``binary_compressed`` data is refused with a hint to convert it. Fields x, y, z are required;
normal_x, normal_y, normal_z (or nx, ny, nz) and a packed ``rgb``/``rgba`` are used when present;
other fields, including descriptor arrays with COUNT > 1, are skipped. In ascii data an ``rgb``
of TYPE F is written either as the packed integer (PCL) or as the float with those bits; a file
whose values are all integers is read as the former.

References
----------
[PCD] Point Cloud Library. "The PCD (Point Cloud Data) file format".
      https://pointclouds.org/documentation/tutorials/pcd_file_format.html
"""

from __future__ import annotations

import io as _io
import logging
from pathlib import Path
from typing import Any

import numpy as np

from .common import MAX_HEADER_BYTES, check_count, input_error, loadtxt, loadtxt_message, pick

__all__ = ["read_points"]

logger = logging.getLogger("recon.io")


#: Largest element COUNT of a PCD field (descriptor arrays such as FPFH have 33 or 308).
_MAX_PCD_COUNT = 1 << 16

_PCD_KINDS = {"F": "f", "I": "i", "U": "u"}


def _ascii_packed_color(vals: np.ndarray) -> np.ndarray:
    """The float32 values of an ascii ``rgb`` field of TYPE F, whose bits are 0xAARRGGBB.

    Two encodings exist. PCL writes the packed colour as an integer (``13107250``), since the
    float of an opaque colour can be NaN; older writers print the float itself, a tiny
    (``1.8367e-38``) or huge (``-1.7014e+38``) value, or NaN. The decision is one for the whole
    file: values that are all integers of 32 bits (signed or not) are packed integers, any
    other value means printed floats. Such a float is an integer of 32 bits only for alpha
    values 0x4B to 0x4F (or 0xCB to 0xCF), which no writer uses; black is 0 in both.
    """
    with np.errstate(invalid="ignore"):
        ints = np.isfinite(vals) & (vals == np.round(vals)) & (vals >= -(2**31)) & (vals < 2**32)
    if not np.all(ints):
        return vals.astype(np.float32)  # the printed float (NaN keeps no colour)
    # negative values are signed 32-bit writes of the same bits
    return (vals.astype(np.int64) & 0xFFFFFFFF).astype(np.uint32).view(np.float32)


def read_points(
    path: Path, size: int, max_points: int, info: dict[str, Any]
) -> tuple[str, np.ndarray, np.ndarray | None, np.ndarray | None]:
    colors_lost = None  # an ascii float rgb field with 'nan' values: no colour to read
    with open(path, "rb") as fh:
        meta: dict[str, list[str]] = {}
        while True:
            raw = fh.readline(MAX_HEADER_BYTES)
            if fh.tell() > MAX_HEADER_BYTES:
                raise input_error(path, "PCD header has no DATA line within 1 MB")
            if not raw:
                raise input_error(path, "truncated PCD header (no DATA line)")
            try:
                line = raw.decode("ascii").strip()
            except UnicodeDecodeError:
                raise input_error(path, "not a PCD file (non-ASCII header)") from None
            if not line or line.startswith("#"):
                continue
            words = line.split()
            meta[words[0].upper()] = words[1:]
            if words[0].upper() == "DATA":
                break
        offset = fh.tell()
        for key in ("FIELDS", "SIZE", "TYPE"):
            if key not in meta:
                raise input_error(path, f"PCD header has no {key} line")
        names = meta["FIELDS"]
        counts = meta.get("COUNT", ["1"] * len(names))
        if not (len(meta["SIZE"]) == len(meta["TYPE"]) == len(counts) == len(names)):
            raise input_error(path, "PCD header: FIELDS, SIZE, TYPE and COUNT differ in length")
        try:
            sizes = [int(s) for s in meta["SIZE"]]
            counts_i = [int(c) for c in counts]
            n = (
                int(meta["POINTS"][0])
                if "POINTS" in meta
                else (int(meta["WIDTH"][0]) * int(meta.get("HEIGHT", ["1"])[0]))
            )
        except (ValueError, IndexError, KeyError):
            raise input_error(
                path, "PCD header: SIZE, COUNT, WIDTH or POINTS is not an integer"
            ) from None
        if n < 0:
            raise input_error(path, "PCD header: negative point count")
        if any(c < 1 or c > _MAX_PCD_COUNT for c in counts_i):
            raise input_error(
                path, f"PCD header: COUNT values must be 1 to {_MAX_PCD_COUNT}, got {counts_i}"
            )
        used = {"x", "y", "z", "normal_x", "normal_y", "normal_z", "nx", "ny", "nz", "rgb"}
        used.add("rgba")
        for name, c in zip(names, counts_i, strict=True):
            if name in used and c != 1:
                raise input_error(path, f"PCD header: field '{name}' has COUNT {c}, expected 1")
        fields_dt = []
        seen: dict[str, int] = {}
        for name, sz, tp, c in zip(names, sizes, meta["TYPE"], counts_i, strict=True):
            if tp.upper() not in _PCD_KINDS or sz not in (
                (4, 8) if tp.upper() == "F" else (1, 2, 4, 8)
            ):
                raise input_error(path, f"PCD header: unsupported field type {tp}{sz} for '{name}'")
            key = name if name not in seen else f"{name}__{seen[name]}"
            seen[name] = seen.get(name, 0) + 1
            base = "<" + _PCD_KINDS[tp.upper()] + str(sz)
            fields_dt.append((key, base, (c,)) if c != 1 else (key, base))
        dtype = np.dtype(fields_dt)
        data_kind = meta["DATA"][0].lower() if meta["DATA"] else ""
        if data_kind == "binary_compressed":
            raise input_error(
                path,
                "PCD 'binary_compressed' data is not supported; convert it to binary or ascii "
                "(e.g. pcl_convert_pcd_ascii_binary in.pcd out.pcd 1)",
            )
        if not {"x", "y", "z"} <= set(names):
            raise input_error(path, f"PCD file lacks x, y, z fields (has: {', '.join(names)})")
        check_count(path, n, max_points)
        info["elements"] = {"vertex": n}
        info["properties"] = list(names)
        if data_kind == "binary":
            nbytes = n * dtype.itemsize
            if size - offset < nbytes:
                raise input_error(
                    path,
                    f"truncated PCD: {n} points need {nbytes} bytes, only {size - offset} "
                    "bytes follow the header",
                )
            rows = np.frombuffer(fh.read(nbytes), dtype=dtype, count=n)
            fmt = "pcd-binary"
        elif data_kind == "ascii":
            ncols = sum(counts_i)
            if size - offset < 2 * ncols * n - 1:
                raise input_error(path, f"truncated PCD: the header declares {n} points")
            text = _io.TextIOWrapper(fh, encoding="ascii", newline=None)
            try:
                arr = loadtxt(text, dtype=np.float64, ndmin=2, max_rows=n, comments=None)
            except UnicodeDecodeError:
                raise input_error(path, "PCD data: non-ASCII bytes in ascii data") from None
            except ValueError as exc:
                raise input_error(path, f"PCD data: {loadtxt_message(exc)}") from None
            finally:
                text.detach()
            if arr.shape[0] < n or arr.shape[1] != ncols:
                raise input_error(
                    path,
                    f"PCD data: expected {n} rows of {ncols} values, got {arr.shape[0]} rows of "
                    f"{arr.shape[1]}",
                )
            rows = np.zeros(n, dtype=dtype)
            col = 0
            for name, c in zip(dtype.names or (), counts_i, strict=True):
                vals = arr[:, col : col + c] if c != 1 else arr[:, col]
                if name in ("rgb", "rgba") and dtype[name].kind == "f":
                    rows[name] = _ascii_packed_color(vals)
                    if not np.all(np.isfinite(vals)):
                        colors_lost = name
                else:
                    rows[name] = vals
                col += c
            fmt = "pcd-ascii"
        else:
            raise input_error(path, f"PCD header: unknown DATA kind '{data_kind}'")
    xyz = np.stack([rows[c].astype(np.float64) for c in ("x", "y", "z")], axis=1)
    nn = pick(set(names), (("normal_x", "normal_y", "normal_z"), ("nx", "ny", "nz")))
    normals = np.stack([rows[c].astype(np.float64) for c in nn], axis=1) if nn else None
    colors = None
    cname = "rgb" if "rgb" in names else ("rgba" if "rgba" in names else None)
    if cname is not None and cname == colors_lost:
        logger.warning(
            "%s: some '%s' values are written as nan or inf, which keeps no colour; the file's "
            "colours are not used",
            path,
            cname,
        )
    elif cname is not None:
        packed = np.ascontiguousarray(rows[cname])
        packed = packed.view(np.uint32) if packed.dtype.itemsize == 4 else packed.astype(np.uint32)
        colors = np.stack([(packed >> s) & 255 for s in (16, 8, 0)], axis=1) / 255.0
    return fmt, xyz, normals, colors
