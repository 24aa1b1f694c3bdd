"""``oprecon info``: what is in a point-cloud file."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import click

from recon.serialize import dumps

from .common import catch_errors, format_rows
from .fit import parse_classes


def describe(path: Path, classes: list[int] | None = None) -> dict[str, Any]:
    """Read ``path`` and summarise it as a JSON-ready dict (absolute coordinates).

    LAS/LAZ files add ``point_format``, ``las_version``, ``crs`` (WKT or EPSG codes, None when
    the file has none) and ``classes`` (class -> count in the file, before ``classes``
    filtering); E57 files add ``scans``.
    """
    import numpy as np

    from recon.cloud import spatial_order
    from recon.fitting.scale import median_surround, sampled_spacing
    from recon.geometry import (
        SPACING_SAMPLE_SEED,
        bbox_diagonal,
        median_nearest_neighbor_distance,
    )
    from recon.io import read_points

    cloud = read_points(path, classes=classes)
    # in the fit's (Morton) order: the same samples, whatever the order of the file's rows
    ordered = cloud.points[spatial_order(cloud.points)]
    nearest = median_nearest_neighbor_distance(
        ordered, rng=np.random.default_rng(SPACING_SAMPLE_SEED)
    )
    surround = median_surround(ordered) if len(cloud) > 2 else 0.0
    pts = cloud.absolute_points()
    lo = pts.min(axis=0)
    hi = pts.max(axis=0)
    info = cloud.info
    return {
        "file": str(path),
        "format": cloud.format,
        "points": len(cloud),
        "points_read": info.get("n_read"),
        "nonfinite_dropped": info.get("n_nonfinite_dropped", 0),
        "duplicates_merged": info.get("n_duplicates_merged", 0),
        "bbox_min": lo.tolist(),
        "bbox_max": hi.tolist(),
        "bbox_size": (hi - lo).tolist(),
        "bbox_diagonal": bbox_diagonal(cloud.points),
        "spacing_median_nn": nearest,
        "spacing_surround": surround,
        "spacing": sampled_spacing(nearest, surround),
        "origin": cloud.origin.tolist(),
        "has_normals": cloud.normals is not None,
        "invalid_normals": info.get("n_invalid_normals", 0),
        "normals_dropped": bool(info.get("normals_dropped", False)),
        "has_colors": cloud.colors is not None,
        "has_faces": bool(info.get("has_faces", False)),
        "elements": dict(info.get("elements", {})),
        "properties": list(info.get("properties", [])),
        "attributes": sorted(cloud.attributes),
        **{k: info[k] for k in _LIDAR_KEYS if k in info},
    }


#: LAS/LAZ and E57 header facts copied from ``PointCloud.info``.
_LIDAR_KEYS = ("point_format", "las_version", "compressed", "crs", "classes", "classes_kept")
_LIDAR_KEYS += ("scans", "scan_positions")

#: ASPRS standard class names (LAS 1.4, point formats 6-10; 0-12 also for formats 0-5).
CLASS_NAMES = {
    0: "never classified",
    1: "unassigned",
    2: "ground",
    3: "low vegetation",
    4: "medium vegetation",
    5: "high vegetation",
    6: "building",
    7: "low point (noise)",
    9: "water",
    10: "rail",
    11: "road surface",
    13: "wire guard",
    14: "wire conductor",
    15: "transmission tower",
    17: "bridge deck",
    18: "high noise",
}


def _num(x: float) -> str:
    return f"{x:.10g}" if math.isfinite(x) else str(x)


def _vec(v: list[float]) -> str:
    return "  ".join(_num(x) for x in v)


def _spacing(d: dict[str, Any]) -> str:
    """The spacing row: the median nearest-neighbour distance, and the spacing across scan
    lines when the fit takes that one instead and says so (``NOTE_SPACING_RATIO``)."""
    from recon.fitting.scale import NOTE_SPACING_RATIO

    out = f"{_num(d['spacing_median_nn'])} (median nearest-neighbour distance)"
    if d["spacing"] >= NOTE_SPACING_RATIO * d["spacing_median_nn"]:  # as the fit says it
        out += (
            f"; in lines or clumps {_num(d['spacing_surround'])} apart: a fit takes "
            f"{_num(d['spacing'])}"
        )
    return out


def format_table(d: dict[str, Any]) -> str:
    """The summary as two aligned columns."""
    normals = "no"
    if d["has_normals"]:
        normals = "yes" + (
            f" ({d['invalid_normals']} invalid, re-estimated)" if d["invalid_normals"] else ""
        )
    elif d["normals_dropped"]:
        normals = f"ignored ({d['invalid_normals']} invalid)"
    elements = ", ".join(f"{k} {v:,}" for k, v in d["elements"].items()) or "-"
    rows = [
        ("file", d["file"]),
        ("format", d["format"]),
        ("points", f"{d['points']:,}"),
        (
            "read",
            f"{d['points_read']:,} rows, {d['nonfinite_dropped']:,} non-finite dropped, "
            f"{d['duplicates_merged']:,} duplicates merged",
        ),
        ("elements", elements),
        ("properties", " ".join(d["properties"]) or "-"),
        ("bbox min", _vec(d["bbox_min"])),
        ("bbox max", _vec(d["bbox_max"])),
        ("bbox size", _vec(d["bbox_size"])),
        ("bbox diagonal", _num(d["bbox_diagonal"])),
        ("spacing", _spacing(d)),
        ("normals", normals),
        ("colours", "yes" if d["has_colors"] else "no"),
        ("faces", "yes (ignored for fitting)" if d["has_faces"] else "no"),
    ]
    if d.get("attributes"):
        rows.append(("attributes", " ".join(d["attributes"])))
    if "point_format" in d:
        fmt = f"LAS {d['las_version']}, point format {d['point_format']}"
        rows.append(("point format", fmt + (" (LAZ)" if d.get("compressed") else "")))
    if "scans" in d:
        known = "scanner positions known (the normals face them)"
        where = known if "scan_positions" in d else "scanner positions unknown"
        rows.append(("scans", f"{d['scans']}, {where}"))
    if "crs" in d:
        crs = d["crs"] or "none in the file"
        rows.append(("CRS", crs if len(crs) <= 200 else crs[:197] + "..."))
    if "classes" in d:
        classes = ", ".join(
            f"{c} {CLASS_NAMES.get(int(c), '')} {n:,}".replace("  ", " ")
            for c, n in d["classes"].items()
        )
        rows.append(("classes", classes or "-"))
        if d.get("classes_kept"):
            rows.append(("classes kept", ", ".join(map(str, d["classes_kept"]))))
    if any(d["origin"]):
        rows.append(("origin", f"{_vec(d['origin'])} (subtracted internally for precision)"))
    return "\n".join(format_rows(rows, indent=""))


@click.command("info")
@click.argument("file", type=click.Path(path_type=Path))
@click.option("--json", "as_json", is_flag=True, help="Print a JSON object instead of a table.")
@click.option(
    "--classes",
    callback=parse_classes,
    help="LAS/LAZ: describe only the points of these classes, e.g. 2,6.",
)
@catch_errors
def command(file: Path, as_json: bool, classes: list[int] | None) -> None:
    """Describe a point-cloud FILE: format, counts, bounding box, spacing, attributes.

    Reads PLY (ascii/binary), XYZ/XYZN/PTS/TXT/CSV text, PCD (ascii/binary), OBJ, LAS/LAZ and
    E57 (LAS/LAZ/E57 need: pip install "oprecon[lidar]"). Counts are after cleaning:
    non-finite rows dropped, exactly repeated points merged. Coordinates are the file's
    (absolute). The spacing is the median nearest-neighbour distance; points in scan lines
    (or clumps) farther apart than random samples would be also show the distance between
    the lines, from which a fit takes its spacing (JSON: spacing_surround, spacing). LAS/LAZ
    files also show
    the point format, the coordinate reference system (WKT or EPSG) and the classes with their
    counts.

    \b
    Examples:
      oprecon info scan.ply
      oprecon info scan.xyz --json | jq .spacing_median_nn
      oprecon info city.laz --classes 2,6
    """
    d = describe(file, classes)
    click.echo(dumps(d) if as_json else format_table(d))
