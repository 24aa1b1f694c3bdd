"""E57 (ASTM E2807, terrestrial scanners): reading points, colours and intensity.

Read with ``pye57`` (the optional extra ``oprecon[lidar]``). Every scan of the file is read,
its invalid points dropped and its pose applied (so several scans of one site land in one
coordinate frame), one scan at a time. Cartesian and spherical scans are both read (pye57
converts spherical to cartesian). Coordinates are float64 throughout. E57 has no point
classification; ``--classes`` is refused for E57 files.

Each scan's sensor position is known where the file says where the scan's own frame lies: a
scan with a pose (its translation is the sensor's position in the file's frame), or a scan in
spherical coordinates (range, azimuth, elevation from the sensor: the sensor is the frame's
origin). The points then carry it (``PointCloud.viewpoints``) and the normals face their own
scanner (``normals.orientation`` ``auto`` or ``viewpoint``). A cartesian scan without a pose
may hold points already moved into a shared frame (scans merged by the software that wrote the
file), so its frame's origin says nothing of where it was scanned from; a pose outside the
scan's own points (beyond ``SURROUND_MARGIN`` of their bounding box) only georeferences them.
Then no scan's position is used.

References
----------
[E57] ASTM E2807-11. "Standard specification for 3D imaging data exchange, version 1.0".
      http://www.libe57.org/
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np

from .common import check_count, input_error, optional_module

logger = logging.getLogger(__name__)

__all__ = ["SCAN_KEY", "SURROUND_MARGIN", "read_points", "sensor_position"]

_MAGIC = b"ASTM-E57"
#: The attribute that carries each point's scan (its row of ``info["scan_positions"]``) from
#: the reader to :func:`recon.io.clean.make_cloud`, which turns it into
#: ``PointCloud.viewpoints`` (it is not one of the cloud's attributes).
SCAN_KEY = "_scan"
#: A scan position farther outside its scan's bounding box than this share of the box's
#: diagonal is not where the scan was made from (:func:`sensor_position`).
SURROUND_MARGIN = 0.1


def _message(exc: BaseException) -> str:
    text = str(exc).strip() or type(exc).__name__
    return text.splitlines()[0]


def read_points(
    path: Path, max_points: int, info: dict[str, Any]
) -> tuple[str, np.ndarray, None, np.ndarray | None, dict[str, np.ndarray]]:
    """Read every scan of an E57 file.

    Returns
    -------
    format : str
        ``'e57'``.
    xyz : (n, 3) float64
        Absolute coordinates (scan poses applied).
    normals : None
    colors : (n, 3) float64 in [0, 1] or None
        When every scan has colours.
    attributes : dict
        ``intensity`` (float64, the file's scale) when every scan has it; ``SCAN_KEY``
        (int32, each point's scan) when every scan's sensor position is known, which then
        go into ``info["scan_positions"]`` (absolute coordinates, one row per scan).
    """
    with open(path, "rb") as fh:
        magic = fh.read(len(_MAGIC))
    if magic != _MAGIC:
        raise input_error(path, f"not an E57 file: wrong signature {magic!r} (expected 'ASTM-E57')")
    pye57 = optional_module("pye57", path, "E57 files")
    try:
        e57 = pye57.E57(str(path))
    except Exception as exc:  # libE57Format raises its own exception types
        raise input_error(path, f"not a valid E57 file: {_message(exc)}") from None
    xyz_parts: list[np.ndarray] = []
    rgb_parts: list[np.ndarray] = []
    int_parts: list[np.ndarray] = []
    positions: list[np.ndarray | None] = []
    has_rgb = has_int = True
    n_declared = 0
    try:
        n_scans = int(e57.scan_count)
        headers = [e57.get_header(i) for i in range(n_scans)]
        n_declared = sum(int(h.point_count) for h in headers)
        check_count(path, n_declared, max_points)
        fields = [set(h.point_fields) for h in headers]
        has_rgb = n_scans > 0 and all({"colorRed", "colorGreen", "colorBlue"} <= f for f in fields)
        has_int = n_scans > 0 and all("intensity" in f for f in fields)
        _warn_partial(path, fields, has_rgb, has_int)
        for i in range(n_scans):
            data = e57.read_scan(
                i, intensity=has_int, colors=has_rgb, transform=True, ignore_missing_fields=True
            )
            xyz_parts.append(
                np.stack([data[f"cartesian{c}"] for c in "XYZ"], axis=1).astype(np.float64)
            )
            if has_rgb:
                rgb_parts.append(
                    np.stack([data[f"color{c}"] for c in ("Red", "Green", "Blue")], axis=1)
                )
            if has_int:
                int_parts.append(np.asarray(data["intensity"], dtype=np.float64))
            positions.append(sensor_position(headers[i], fields[i], xyz_parts[-1]))
    except Exception as exc:
        if type(exc).__name__ == "InputError":
            raise
        raise input_error(path, f"not a valid E57 file: {_message(exc)}") from None
    finally:
        close = getattr(e57, "close", None)
        if close is not None:
            try:
                close()
            except Exception:  # noqa: BLE001 - closing a damaged file must not hide the error
                pass
    info["elements"] = {"vertex": n_declared}
    info["scans"] = len(xyz_parts)
    info["properties"] = ["x", "y", "z"] + (["red", "green", "blue"] if has_rgb else [])
    info["properties"] += ["intensity"] if has_int else []
    xyz = np.concatenate(xyz_parts) if xyz_parts else np.zeros((0, 3))
    colors = None
    if has_rgb and rgb_parts:
        rgb = np.concatenate(rgb_parts).astype(np.float64)
        colors = rgb / (255.0 if rgb.size == 0 or rgb.max() <= 255 else 65535.0)
    attributes = {"intensity": np.concatenate(int_parts)} if has_int and int_parts else {}
    if positions and all(p is not None for p in positions):  # (JSON in reports: lists)
        sizes = [len(part) for part in xyz_parts]
        attributes[SCAN_KEY] = np.repeat(np.arange(len(sizes), dtype=np.int32), sizes)
        info["scan_positions"] = [[float(c) for c in p] for p in positions]
    elif positions:
        logger.info(
            "%s: %d of %d scans say nothing of where they were made (cartesian without a "
            "pose, or a pose outside the scan's own points): no scanner position is used to "
            "orient the normals (--viewpoint gives one)",
            path, sum(p is None for p in positions), len(positions),
        )  # fmt: skip
    return "e57", xyz, None, colors, attributes


def sensor_position(
    header: Any, fields: set[str], points: np.ndarray | None = None
) -> np.ndarray | None:
    """Where the scan was made from, in the file's frame: its pose's translation when it has
    a pose, the origin for a spherical scan without one, else unknown (None).

    A scanner stands among what it scans: a position outside the bounding box of the scan's
    own ``points`` (absolute), grown by ``SURROUND_MARGIN`` of its diagonal, is a pose that
    only moves the points into place (a georeference: easting, northing and a height of 0
    under terrain 250 m up), and unknown too."""
    if header.has_pose():
        where = np.asarray(header.translation, dtype=np.float64).reshape(3)
    elif {"sphericalRange", "sphericalAzimuth", "sphericalElevation"} <= fields:
        where = np.zeros(3)
    else:
        return None
    if points is not None and len(points):
        lo, hi = points.min(axis=0), points.max(axis=0)
        grow = SURROUND_MARGIN * float(np.linalg.norm(hi - lo))
        if np.any(where < lo - grow) or np.any(where > hi + grow):
            return None
    return where


def _warn_partial(path: Path, fields: list[set[str]], has_rgb: bool, has_int: bool) -> None:
    """Warn when some scans have colours (intensity) and others not: the cloud then has none,
    as a mesh cannot take colours from a part of its points."""
    rgb = {"colorRed", "colorGreen", "colorBlue"}
    some_rgb = sum(rgb <= f for f in fields)
    some_int = sum("intensity" in f for f in fields)
    for what, some, kept in (("colours", some_rgb, has_rgb), ("intensity", some_int, has_int)):
        if some and not kept:
            logger.warning(
                "%s: %d of %d scans have %s, the other scans none; the file's %s are not read",
                path, some, len(fields), what, what,
            )  # fmt: skip
