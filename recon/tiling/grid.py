"""The tile grid of a tiled fit: cubic cells of one side over the scan's bounding box.

Every point (and every particle) belongs to exactly one tile, the one whose *half-open* core
box ``[lo, hi)`` holds it (the last tile along an axis also takes the points on the upper face
of the bounding box). A tile fits its core plus a halo of ``halo`` [length] on every side.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import InputError

__all__ = ["MAX_TILES", "TileGrid", "choose_auto_tile_size"]

#: More tiles than this is a typo in --tile-size (or a unit mismatch), not a plan.
MAX_TILES = 100_000


@dataclass(frozen=True)
class TileGrid:
    """A regular grid of cubic tiles.

    Attributes
    ----------
    lo : (3,) float64 [length]
        The lower corner of the scan's bounding box (absolute coordinates).
    size : float [length]
        The side of a tile's core.
    shape : (3,) int
        Tiles along x, y, z.
    halo : float [length]
    """

    lo: np.ndarray
    size: float
    shape: tuple[int, int, int]
    halo: float

    @classmethod
    def cover(cls, lo: np.ndarray, hi: np.ndarray, size: float, halo: float) -> TileGrid:
        """The grid of side ``size`` over the box ``[lo, hi]``.

        Raises
        ------
        InputError
            ``size`` not positive and finite, smaller than the halo, or more than
            :data:`MAX_TILES` tiles.
        """
        if not (math.isfinite(size) and size > 0):
            raise InputError(f"tile size: expected a positive length, got {size!r}")
        if size < halo:
            raise InputError(
                f"tile size {size:.4g} is smaller than the halo {halo:.4g} (tiling.halo r0): "
                "give a larger --tile-size"
            )
        lo = np.asarray(lo, dtype=np.float64)
        span = np.asarray(hi, dtype=np.float64) - lo
        shape = tuple(int(max(1, math.ceil(float(s) / size))) for s in span)
        if math.prod(shape) > MAX_TILES:
            raise InputError(
                f"tile size {size:.4g} cuts the scan ({', '.join(f'{s:.4g}' for s in span)}) "
                f"into {math.prod(shape):,} tiles, more than {MAX_TILES:,}: give a larger "
                "--tile-size (in the input's length units)"
            )
        return cls(lo, float(size), shape, float(halo))  # type: ignore[arg-type]

    @property
    def count(self) -> int:
        return int(np.prod(self.shape))

    def cell_of(self, points: np.ndarray) -> np.ndarray:
        """The flat index of the tile owning each point (half-open cores, clipped ends)."""
        ijk = np.floor((np.asarray(points, dtype=np.float64) - self.lo) / self.size)
        ijk = np.clip(ijk, 0, np.asarray(self.shape) - 1).astype(np.int64)
        return np.ravel_multi_index(tuple(ijk.T), self.shape)

    def ijk(self, tile: int) -> tuple[int, int, int]:
        return tuple(int(v) for v in np.unravel_index(int(tile), self.shape))  # type: ignore[return-value]

    def core(self, tile: int) -> tuple[np.ndarray, np.ndarray]:
        """The core box ``[lo, hi)`` of a tile; on the grid's outer faces it is unbounded, so
        that every point lies in some core."""
        ijk = np.asarray(self.ijk(tile), dtype=np.float64)
        lo = self.lo + ijk * self.size
        hi = lo + self.size
        shape = np.asarray(self.shape)
        lo = np.where(ijk == 0, -np.inf, lo)
        hi = np.where(ijk == shape - 1, np.inf, hi)
        return lo, hi

    def bounds(self, tile: int) -> tuple[np.ndarray, np.ndarray]:
        """The finite core box of a tile (for messages and reports)."""
        ijk = np.asarray(self.ijk(tile), dtype=np.float64)
        lo = self.lo + ijk * self.size
        return lo, lo + self.size

    def in_core(self, tile: int, points: np.ndarray) -> np.ndarray:
        """Which points lie in the tile's half-open core (the same rule as :meth:`cell_of`)."""
        return self.cell_of(points) == int(tile)

    def in_halo_box(self, tile: int, points: np.ndarray, margin: float | None = None) -> np.ndarray:
        """Which points lie in the core grown by ``margin`` (default: the halo)."""
        m = self.halo if margin is None else margin
        lo, hi = self.core(tile)
        p = np.asarray(points, dtype=np.float64)
        return np.all((p >= lo - m) & (p < hi + m), axis=1)

    def neighbours(self, tile: int) -> list[int]:
        """The tiles around ``tile`` (up to 26), whose cores its halo reaches."""
        i, j, k = self.ijk(tile)
        out = []
        for di in (-1, 0, 1):
            for dj in (-1, 0, 1):
                for dk in (-1, 0, 1):
                    if di == dj == dk == 0:
                        continue
                    a, b, c = i + di, j + dj, k + dk
                    if 0 <= a < self.shape[0] and 0 <= b < self.shape[1] and 0 <= c < self.shape[2]:
                        out.append(int(np.ravel_multi_index((a, b, c), self.shape)))
        return out

    def seam_distance(self, points: np.ndarray) -> np.ndarray:
        """Distance [length] from each point to the nearest inner tile face (inf with one tile)."""
        p = np.asarray(points, dtype=np.float64)
        best = np.full(len(p), np.inf)
        for axis in range(3):
            n = self.shape[axis]
            if n < 2:
                continue
            u = (p[:, axis] - self.lo[axis]) / self.size
            nearest = np.clip(np.round(u), 1, n - 1)
            best = np.minimum(best, np.abs(u - nearest) * self.size)
        return best

    def describe(self, tile: int) -> str:
        """``'tile 3 (1, 1, 0) [x0, x1) x [y0, y1) x [z0, z1)'`` for messages."""
        lo, hi = self.bounds(tile)
        box = " x ".join(f"[{a:.6g}, {b:.6g})" for a, b in zip(lo, hi, strict=True))
        return f"tile {tile} {self.ijk(tile)} {box}"


def choose_auto_tile_size(
    lo: np.ndarray,
    hi: np.ndarray,
    n_points: int,
    peak_bytes_for,  # callable: n_points -> estimated peak bytes of one fit
    budget: int,
    halo: float,
) -> float | None:
    """The largest tile side whose fit (core + halo) stays within ``budget`` bytes, or None
    when the whole scan does.

    The points of a tile are predicted from the scan's two largest extents (a scan spreads
    over a surface: terrain, a façade, a city block), so a tile of side s with its halo holds
    about ``n_points * min(1, (s + 2 halo) / X) * min(1, (s + 2 halo) / Y)``.
    """
    span = np.sort(np.asarray(hi, dtype=np.float64) - np.asarray(lo, dtype=np.float64))[::-1]
    if peak_bytes_for(n_points) <= budget:
        return None
    x, y = max(float(span[0]), 1e-300), max(float(span[1]), 1e-300)

    def points_in(s: float) -> int:
        w = s + 2 * halo
        return int(n_points * min(1.0, w / x) * min(1.0, w / y))

    s = float(span[0])
    while s > 2 * halo and peak_bytes_for(points_in(s)) > budget:
        s *= 0.8
    if peak_bytes_for(points_in(s)) > budget:
        raise InputError(
            "no tile size keeps one tile's fit within the memory budget "
            f"({budget / 2**30:.2f} GiB): raise --max-memory (tiling.memory) or the spacing"
        )
    return s
