"""Point cleaning shared by every reader: non-finite rows, duplicates, normals, origin, degeneracy.

:func:`make_cloud` turns the raw columns a format module read into a
:class:`~recon.cloud.PointCloud`: non-finite rows dropped, exact duplicates merged,
statistical outliers removed when asked (:func:`recon.io.outliers.statistical_outliers`),
normals validated and normalised, colours clipped to [0, 1], and coordinates made relative
to :func:`choose_origin`. Inputs with fewer
than 4 distinct points, unusable magnitudes, or all points on one line are refused.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np

from ..cloud import PointCloud
from .common import input_error
from .e57 import SCAN_KEY
from .outliers import statistical_outliers

#: The viewpoints' columns among the attributes while the points are cleaned.
_VIEW_KEYS = ("_view_x", "_view_y", "_view_z")

#: One logger for the io package (its messages name the file).
logger = logging.getLogger("recon.io")

__all__ = ["check_coordinate_range", "choose_origin", "make_cloud"]


#: A normal is invalid when it is non-finite or shorter than this.
_MIN_NORMAL_LENGTH = 1e-12

#: More invalid input normals than this fraction: drop the file's normals altogether.
_MAX_INVALID_NORMAL_FRACTION = 0.05

#: Largest coordinate magnitude accepted: squares and products of lengths stay finite.
_MAX_COORDINATE = 1e100

#: Smallest extent accepted: squared spacings stay normal floating-point numbers.
_MIN_EXTENT = 1e-100


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


def make_cloud(
    path: Path | None,
    fmt: str,
    xyz: np.ndarray,
    normals: np.ndarray | None,
    colors: np.ndarray | None,
    merge_duplicates: bool,
    info: dict[str, Any],
    attributes: dict[str, np.ndarray] | None = None,
    outliers: tuple[int, float] | None = None,
    viewpoints: np.ndarray | None = None,
) -> PointCloud:
    """The cleaned :class:`~recon.cloud.PointCloud` of the columns a reader found.

    Parameters
    ----------
    path : Path or None
        The file (None for arrays), named in messages.
    fmt : str
        ``PointCloud.format``.
    xyz : (n, 3) array_like [length]
        Absolute coordinates as read.
    normals, colors : (n, 3) array_like or None
    merge_duplicates : bool
        Merge exactly repeated points (the first occurrence is kept).
    info : dict
        The reader's ``PointCloud.info``; the cleaning counts are added to it.
    attributes : dict of str -> (n,) array, optional
        Per-point scalars (``PointCloud.attributes``), filtered like the points.
    outliers : (k, std_ratio), optional
        Remove statistical outliers after merging duplicates
        (:func:`~recon.io.outliers.statistical_outliers`; ``io.outliers``); the count goes
        into ``info["n_outliers_removed"]``. None keeps every point.
    viewpoints : (n, 3) array_like [length], optional
        Where each point was scanned from, absolute (``PointCloud.viewpoints``); an E57
        reader's ``SCAN_KEY`` attribute and ``info["scan_positions"]`` give them too.

    Returns
    -------
    PointCloud

    Raises
    ------
    InputError
        Fewer than 4 distinct finite points (before or after the outlier removal), unusable
        magnitudes, points on one line.
    """
    xyz = np.ascontiguousarray(xyz, dtype=np.float64)
    attrs = dict(attributes or {})
    if (scan := attrs.pop(SCAN_KEY, None)) is not None:  # each point's scanner (E57)
        viewpoints = np.asarray(info["scan_positions"], dtype=np.float64)[scan]
    if viewpoints is not None:  # (filtered with the points as three more columns)
        view = np.asarray(viewpoints, dtype=np.float64)
        attrs.update({key: view[:, j] for j, key in enumerate(_VIEW_KEYS)})
    points, origin, normals, colors = _clean_points(
        path, xyz, normals, colors, merge_duplicates, info, attrs, outliers
    )
    if _VIEW_KEYS[0] in attrs:
        viewpoints = np.stack([attrs.pop(key) for key in _VIEW_KEYS], axis=1) - origin
    return PointCloud(points, origin, normals, colors, path, fmt, info, attrs, viewpoints)


def _clean_points(
    path: Path | None,
    xyz: np.ndarray,
    normals: np.ndarray | None,
    colors: np.ndarray | None,
    merge_duplicates: bool,
    info: dict[str, Any],
    attrs: dict[str, np.ndarray],
    outliers: tuple[int, float] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]:
    """Drop non-finite rows, merge duplicates, remove outliers (``outliers``: k, std_ratio),
    validate normals; returns relative points.

    ``attrs`` (per-point scalars) is filtered in place like the points.
    """
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
        attrs.update({k: v[finite] for k, v in attrs.items()})
    n_dup = 0
    if merge_duplicates and xyz.shape[0] > 1:
        keep = _first_occurrences(xyz)
        n_dup = int(xyz.shape[0] - keep.size)
        if n_dup:
            xyz = xyz[keep]
            normals = normals[keep] if normals is not None else None
            colors = colors[keep] if colors is not None else None
            attrs.update({k: v[keep] for k, v in attrs.items()})
            logger.info("%s: merged %d exactly repeated point(s)", path, n_dup)
    info["n_duplicates_merged"] = n_dup
    if outliers is not None:
        _check_spans_plane(path, xyz)  # (the removal needs a usable cloud to judge)
        xyz, normals, colors = _remove_outliers(path, xyz, normals, colors, attrs, outliers, info)
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


def _remove_outliers(
    path: Path | None,
    xyz: np.ndarray,
    normals: np.ndarray | None,
    colors: np.ndarray | None,
    attrs: dict[str, np.ndarray],
    outliers: tuple[int, float],
    info: dict[str, Any],
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """The rows :func:`~recon.io.outliers.statistical_outliers` keeps (``attrs`` filtered in
    place); the count goes into ``info["n_outliers_removed"]``."""
    from ..kernels.options import query_workers

    k, std_ratio = outliers
    drop = statistical_outliers(xyz, k, std_ratio, workers=query_workers())
    n_out = int(np.count_nonzero(drop))
    info["n_outliers_removed"] = n_out
    if n_out:
        keep = ~drop
        xyz = xyz[keep]
        normals = normals[keep] if normals is not None else None
        colors = colors[keep] if colors is not None else None
        attrs.update({key: v[keep] for key, v in attrs.items()})
        logger.info(
            "%s: removed %d statistical outlier(s) (k=%d, std_ratio=%g)", path, n_out, k, std_ratio
        )
    return xyz, normals, colors


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


def check_coordinate_range(path: Path | None, xyz: np.ndarray) -> None:
    """Raise :class:`~recon.errors.InputError` (naming ``path``) when a coordinate's
    magnitude passes ``_MAX_COORDINATE``: squared distances would overflow."""
    biggest = float(np.max(np.abs(xyz))) if xyz.size else 0.0
    if biggest > _MAX_COORDINATE:
        raise input_error(
            path,
            f"coordinates up to {biggest:.3g} are too large (their magnitude must stay below "
            f"{_MAX_COORDINATE:g}); rescale the data",
        )


def _check_spans_plane(path: Path | None, xyz: np.ndarray) -> None:
    """Enough points, coordinates in a usable range, not all identical, not all on one line.

    The line test ignores a few far outliers (the 1 % extremes on each axis, when there are at
    least 100 points): one stray point 1e12 away must not make a sphere look like a line.
    """
    n = xyz.shape[0]
    if n < 4:
        raise input_error(path, f"only {n} distinct finite point(s); at least 4 are needed")
    check_coordinate_range(path, xyz)
    extent = float(np.max(xyz.max(axis=0) - xyz.min(axis=0)))
    if extent == 0.0:
        raise input_error(path, "all points are identical; the points must span at least a plane")
    if extent < _MIN_EXTENT:
        raise input_error(
            path,
            f"the points span only {extent:.3g} units, too small to compute with (at least "
            f"{_MIN_EXTENT:g}); rescale the data",
        )
    sample = xyz if n <= 200_000 else xyz[:: n // 200_000 + 1]
    if _is_collinear(sample) and (len(sample) < 100 or _is_collinear(_core(sample))):
        raise input_error(path, "all points lie on one line; the points must span at least a plane")


def _is_collinear(xyz: np.ndarray) -> bool:
    s = np.linalg.svd(xyz - xyz.mean(axis=0), compute_uv=False)
    return bool(s[0] == 0.0 or s[1] <= 1e-9 * s[0])


def _core(xyz: np.ndarray) -> np.ndarray:
    """Rows inside the 1st-99th percentile box of every axis."""
    lo, hi = np.percentile(xyz, [1.0, 99.0], axis=0)
    inside = np.all((xyz >= lo) & (xyz <= hi), axis=1)
    return xyz[inside] if np.count_nonzero(inside) >= 4 else xyz
