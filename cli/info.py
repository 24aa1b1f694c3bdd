"""``oprecon info``: what is in a point-cloud file."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import click

from recon.serialize import dumps

from .common import catch_errors


def describe(path: Path) -> dict[str, Any]:
    """Read ``path`` and summarise it as a JSON-ready dict (absolute coordinates)."""
    import numpy as np

    from recon.geometry import (
        SPACING_SAMPLE_SEED,
        bbox_diagonal,
        median_nearest_neighbor_distance,
    )
    from recon.io import read_points

    cloud = read_points(path)
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
        "spacing_median_nn": median_nearest_neighbor_distance(
            cloud.points, rng=np.random.default_rng(SPACING_SAMPLE_SEED)
        ),
        "origin": cloud.origin.tolist(),
        "has_normals": cloud.normals is not None,
        "invalid_normals": info.get("n_invalid_normals", 0),
        "normals_dropped": bool(info.get("normals_dropped", False)),
        "has_colors": cloud.colors is not None,
        "has_faces": bool(info.get("has_faces", False)),
        "elements": dict(info.get("elements", {})),
        "properties": list(info.get("properties", [])),
    }


def _num(x: float) -> str:
    return f"{x:.10g}" if math.isfinite(x) else str(x)


def _vec(v: list[float]) -> str:
    return "  ".join(_num(x) for x in v)


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
        ("spacing", f"{_num(d['spacing_median_nn'])} (median nearest-neighbour distance)"),
        ("normals", normals),
        ("colours", "yes" if d["has_colors"] else "no"),
        ("faces", "yes (ignored for fitting)" if d["has_faces"] else "no"),
    ]
    if any(d["origin"]):
        rows.append(("origin", f"{_vec(d['origin'])} (subtracted internally for precision)"))
    width = max(len(k) for k, _ in rows)
    return "\n".join(f"{k.ljust(width)}  {v}" for k, v in rows)


@click.command("info")
@click.argument("file", type=click.Path(path_type=Path))
@click.option("--json", "as_json", is_flag=True, help="Print a JSON object instead of a table.")
@catch_errors
def command(file: Path, as_json: bool) -> None:
    """Describe a point-cloud FILE: format, counts, bounding box, spacing, attributes.

    Reads PLY (ascii/binary), XYZ/XYZN/PTS/TXT/CSV text, PCD (ascii/binary) and OBJ. Counts are
    after cleaning: non-finite rows dropped, exactly repeated points merged. Coordinates are
    the file's (absolute). The spacing is the median nearest-neighbour distance.

    \b
    Examples:
      oprecon info scan.ply
      oprecon info scan.xyz --json | jq .spacing_median_nn
    """
    d = describe(file)
    click.echo(dumps(d) if as_json else format_table(d))
