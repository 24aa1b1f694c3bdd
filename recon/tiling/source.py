"""The scan cut into per-tile files, so that no process ever holds all of its points.

:func:`split_input` writes, for every tile of a :class:`~recon.tiling.grid.TileGrid` that holds
points, one raw file of float64 rows (x, y, z and, when the input has them, nx, ny, nz) in a
work folder. LAS/LAZ inputs are read chunk by chunk (:data:`SPLIT_CHUNK_POINTS` points at a
time), so the splitting process holds one chunk, whatever the file's size; other formats
are read whole (they are not made for scans of that size). A tile's fit then reads its own file
and its neighbours' (:func:`read_box`).
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import InputError
from ..geometry import median_nearest_neighbor_distance
from .grid import TileGrid

if TYPE_CHECKING:
    from ..cloud import PointCloud

__all__ = ["ScanHeader", "TileStore", "read_box", "scan_header", "split_input", "spacing_sample"]

#: Size of the random sample that estimates the point spacing before tiling (--tiles auto
#: on a LAS/LAZ file).
SAMPLE_POINTS = 100_000
#: Points the coordinator reads from a LAS/LAZ file at a time. Its peak while splitting is
#: one chunk's working set: measured on the benchmark's LAZ scenes (VmHWM of the splitting
#: process, 204 MiB after the imports), 338 / 392 MiB at 1M / 4M points with chunks of 1M,
#: 258 / 265 MiB with chunks of 250k.
SPLIT_CHUNK_POINTS = 250_000


@dataclass
class ScanHeader:
    """What is known of a scan before its points are split.

    ``points`` is None for formats read whole (then ``cloud`` holds them).
    """

    path: Path
    kind: str
    n_points: int
    lo: np.ndarray
    hi: np.ndarray
    cloud: Any = None
    info: dict = field(default_factory=dict)


@dataclass
class TileStore:
    """The per-tile files of a split scan."""

    directory: Path
    grid: TileGrid
    counts: dict[int, int]
    #: x y z, nx ny nz (has_normals), r g b (has_colors), the attributes, then the viewpoint
    columns: int
    has_normals: bool = False
    has_colors: bool = False
    color_scale: float = 1.0  # stored colour values times this are in [0, 1]
    #: per-point scalars (--transfer), one column each: float64 holds every value of every
    #: PLY and LAS type as it is (classes beyond 0-255 too: :func:`recon.attributes.class_values`)
    attributes: tuple[str, ...] = ()
    #: the bounding box of the points kept (``--classes`` drops some of the header's box)
    lo: np.ndarray | None = None
    hi: np.ndarray | None = None
    #: each point's scanner position (three columns, last; ``PointCloud.viewpoints``)
    has_viewpoints: bool = False

    def path(self, tile: int) -> Path:
        return self.directory / f"points-{tile}.f64"

    def normals(self, rows: np.ndarray) -> np.ndarray | None:
        return rows[:, 3:6] if self.has_normals else None

    def colors(self, rows: np.ndarray) -> np.ndarray | None:
        """Colours in [0, 1] of a tile's rows, or None."""
        if not self.has_colors:
            return None
        c = 3 + 3 * self.has_normals
        return np.clip(rows[:, c : c + 3] * self.color_scale, 0.0, 1.0)

    def point_attributes(self, rows: np.ndarray) -> dict[str, np.ndarray]:
        """The per-point scalars of a tile's rows (name -> (n,) float64)."""
        c = 3 + 3 * self.has_normals + 3 * self.has_colors
        return {name: rows[:, c + j] for j, name in enumerate(self.attributes)}

    def viewpoints(self, rows: np.ndarray) -> np.ndarray | None:
        """Where a tile's rows were scanned from (absolute), or None."""
        return rows[:, self.columns - 3 :] if self.has_viewpoints else None

    def cloud(self, rows: np.ndarray) -> PointCloud:
        """A tile's rows as a cleaned cloud (:func:`recon.io.cloud_from_arrays`) with what the
        fit needs of them: normals and viewpoints.

        Not whether they were seen from above (LAS/LAZ, ``PointCloud.info["seen_from_above"]``):
        a tile holds an open piece of a closed object, whose vote for facing up can be decisive
        where the whole object's is not, and a tiled fit does not turn closed parts outward
        after stitching (a statue in a LAS file, its underside sampled twice as densely, came
        out wound inward in tiles of 1.0 and 1.3)."""
        from ..io import cloud_from_arrays

        return cloud_from_arrays(rows[:, :3], self.normals(rows), viewpoints=self.viewpoints(rows))

    def tiles(self) -> list[int]:
        """The tiles that hold points, in index order."""
        return sorted(t for t, n in self.counts.items() if n > 0)

    def for_tasks(self) -> TileStore:
        """The store as the tasks get it: without the per-tile counts (a task reads its
        files), so that a task's arguments do not grow with the tile count."""
        return replace(self, counts={})


def _is_las(path: Path) -> bool:
    with open(path, "rb") as fh:
        return fh.read(4) == b"LASF"


def scan_header(path: Path, cfg: Any) -> ScanHeader:
    """Point count and bounds: from the header of a LAS/LAZ file, else by reading the file."""
    from ..io import read_points
    from ..io.common import check_readable

    check_readable(path)
    if _is_las(path):
        import laspy

        from ..io.las import check_header

        check_header(path)  # counts that do not fit the file (laspy then reads without end)
        try:
            with laspy.open(str(path)) as reader:
                h = reader.header
                n = int(h.point_count)
                lo = np.asarray(h.mins, dtype=np.float64)
                hi = np.asarray(h.maxs, dtype=np.float64)
        except Exception:  # noqa: BLE001 - let the full reader say what is wrong
            read_points(path, max_points=cfg.io.max_points, classes=cfg.io.classes)
            raise
        if n < 4 or not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
            read_points(path, max_points=cfg.io.max_points, classes=cfg.io.classes)
            raise InputError(f"{path}: the header's point count or bounds are not usable")
        return ScanHeader(path, "las", n, lo, hi)
    cloud = read_points(
        path,
        max_points=cfg.io.max_points,
        merge_duplicates=cfg.io.merge_duplicates,
        classes=cfg.io.classes,
    )
    pts = cloud.absolute_points()
    return ScanHeader(
        path, "whole", len(pts), pts.min(axis=0), pts.max(axis=0), cloud, dict(cloud.info)
    )


def _las_chunks(
    path: Path,
    classes: Sequence[int] | None,
    max_points: int,
    colors: bool = False,
    attributes: Sequence[str] = (),
) -> Iterator[np.ndarray]:
    """Absolute xyz of a LAS/LAZ file, chunk by chunk, filtered by class; with ``colors``
    (and a point format that has them) the raw red, green, blue values follow as 3 more
    columns, then one column per name of ``attributes`` (``intensity``, ``classification``:
    every LAS point format has both)."""
    import laspy

    keep = None if not classes else np.asarray(sorted(set(classes)), dtype=np.int64)
    n_seen = 0
    n_kept = 0
    per_class = np.zeros(256, dtype=np.int64)  # for the message when no point is kept
    with laspy.open(str(path)) as reader:
        n_total = int(reader.header.point_count)
        dims = set(reader.header.point_format.dimension_names)
        rgb = colors and {"red", "green", "blue"} <= dims
        try:
            for chunk in reader.chunk_iterator(SPLIT_CHUNK_POINTS):
                xyz = np.stack(
                    [np.asarray(chunk.x), np.asarray(chunk.y), np.asarray(chunk.z)], axis=1
                ).astype(np.float64, copy=False)
                n_seen += len(xyz)
                if rgb:
                    xyz = np.hstack(
                        [xyz]
                        + [
                            np.asarray(chunk[c], dtype=np.float64)[:, None]
                            for c in ("red", "green", "blue")
                        ]
                    )
                if attributes:
                    xyz = np.hstack(
                        [xyz]
                        + [np.asarray(chunk[a], dtype=np.float64)[:, None] for a in attributes]
                    )
                if keep is not None:
                    cls = np.asarray(chunk.classification)
                    per_class += np.bincount(cls.astype(np.int64), minlength=256)[:256]
                    xyz = xyz[np.isin(cls, keep)]
                xyz = xyz[np.all(np.isfinite(xyz[:, :3]), axis=1)]
                n_kept += len(xyz)
                if n_kept > max_points:
                    raise InputError(f"{path}: more than io.max_points = {max_points:,} points")
                yield xyz
        except InputError:
            raise
        except Exception as exc:  # noqa: BLE001 - corrupt chunks
            raise InputError(
                f"{path}: not a valid LAS/LAZ file: reading the points failed after "
                f"{n_seen} of {n_total} ({str(exc).splitlines()[0] if str(exc) else exc!r})"
            ) from None
    if n_seen < n_total:
        raise InputError(
            f"{path}: truncated LAS/LAZ file: {n_seen} of the {n_total} declared points present"
        )
    if keep is not None and n_kept == 0:  # as the untiled fit says it (it said "fewer than 4")
        from ..io.las import no_point_of_classes

        raise no_point_of_classes(path, keep, per_class)


def spacing_sample(header: ScanHeader, cfg: Any, seed: int = 0) -> float:
    """Median point spacing [length] estimated from a random sample of a LAS/LAZ file.

    A random fraction f of a surface sample is sparser by 1/sqrt(f), so the median
    nearest-neighbour distance of the sample times sqrt(f) estimates the scan's (good to a few
    % on near-uniform scans); only used to choose the tile size of ``--tiles auto``.
    """
    rng = np.random.default_rng(seed)
    keep: list[np.ndarray] = []
    n = 0
    frac = min(1.0, SAMPLE_POINTS / max(header.n_points, 1))
    for xyz in _las_chunks(header.path, cfg.io.classes, cfg.io.max_points):
        n += len(xyz)
        keep.append(xyz[rng.random(len(xyz)) < frac])
    sample = np.concatenate(keep) if keep else np.zeros((0, 3))
    if len(sample) < 4 or n == 0:
        raise InputError(f"{header.path}: fewer than 4 points to fit")
    d = median_nearest_neighbor_distance(sample, rng=rng)
    return float(d) * float(np.sqrt(len(sample) / n))


def split_input(header: ScanHeader, grid: TileGrid, directory: Path, cfg: Any) -> TileStore:
    """Write every tile's points to ``directory`` (see the module docstring)."""
    directory.mkdir(parents=True, exist_ok=True)
    counts: dict[int, int] = {}
    want_colors = bool(cfg.output.colors)
    attributes = tuple(cfg.output.transfer)
    use_normals = has_colors = has_view = False
    if header.kind == "las":
        chunks: Iterator[np.ndarray] = _las_chunks(
            header.path, cfg.io.classes, cfg.io.max_points, want_colors, attributes
        )
        first = next(chunks, np.zeros((0, 3 + len(attributes))))
        has_colors = first.shape[1] == 6 + len(attributes)
        chunks = itertools.chain([first], chunks)
    else:
        cloud = header.cloud
        rows = cloud.absolute_points()
        use_normals = cloud.normals is not None and cfg.normals.mode != "estimate"
        if use_normals:
            nrm = np.nan_to_num(cloud.normals, nan=0.0)
            rows = np.hstack([rows, nrm])
        has_colors = want_colors and cloud.colors is not None
        if has_colors:
            rows = np.hstack([rows, np.asarray(cloud.colors, dtype=np.float64)])
        if attributes:
            from ..attributes import check_transfer

            check_transfer(cloud, attributes)
            cols = [np.asarray(cloud.attributes[a], dtype=np.float64) for a in attributes]
            rows = np.hstack([rows, np.column_stack(cols)])
        if has_view := cloud.viewpoints is not None:
            rows = np.hstack([rows, cloud.viewpoints + cloud.origin])
        chunks = iter([rows])
    columns = 3 + 3 * use_normals + 3 * has_colors + len(attributes) + 3 * has_view
    store = TileStore(
        directory, grid, counts, columns, use_normals, has_colors, 1.0, attributes,
        has_viewpoints=has_view,
    )  # fmt: skip
    top = 0.0
    c_rgb = 3 + 3 * use_normals
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for rows in chunks:
        if has_colors and len(rows):
            top = max(top, float(rows[:, c_rgb : c_rgb + 3].max()))
        if len(rows) == 0:
            continue
        lo = np.minimum(lo, rows[:, :3].min(axis=0))
        hi = np.maximum(hi, rows[:, :3].max(axis=0))
        cell = grid.cell_of(rows[:, :3])
        order = np.argsort(cell, kind="stable")
        cell = cell[order]
        rows = rows[order]
        starts = np.flatnonzero(np.r_[True, cell[1:] != cell[:-1]])
        ends = np.r_[starts[1:], len(cell)]
        for a, b in zip(starts, ends, strict=True):
            t = int(cell[a])
            with open(store.path(t), "ab") as fh:
                fh.write(np.ascontiguousarray(rows[a:b], dtype="<f8").tobytes())
            counts[t] = counts.get(t, 0) + int(b - a)
    if has_colors and header.kind == "las":
        # as recon.io.las: 8-bit values when no channel exceeds 255, else 16-bit
        store.color_scale = 1.0 / 255.0 if top <= 255.0 else 1.0 / 65535.0
    header.cloud = None  # the coordinator keeps no points
    if sum(counts.values()) < 4:
        raise InputError(f"{header.path}: fewer than 4 points to fit")
    store.lo, store.hi = lo, hi
    return store


def read_tile(store: TileStore, tile: int) -> np.ndarray:
    """The rows of one tile's file, (n, columns) float64."""
    p = store.path(tile)
    if not p.exists():
        return np.zeros((0, store.columns))
    return np.fromfile(p, dtype="<f8").reshape(-1, store.columns)


def read_box(store: TileStore, tile: int, margin: float) -> np.ndarray:
    """The rows within ``margin`` [length] of a tile's core: its file and its neighbours'."""
    parts = []
    for t in [tile, *store.grid.neighbours(tile)]:
        rows = read_tile(store, t)
        if len(rows):
            parts.append(rows[store.grid.in_halo_box(tile, rows[:, :3], margin)])
    return np.concatenate(parts) if parts else np.zeros((0, store.columns))
