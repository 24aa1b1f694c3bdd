"""What a tiled fit keeps of each tile's fit and mesh task: one fixed-size row per tile
(:class:`TileRecords`), filled as the results arrive, instead of the tasks' result dicts.

A result dict of a tile is a few hundred bytes of Python objects (more with the
triangulation's statistics); at 10^9 points (~20,000 tiles of 50 m) the coordinator would hold
tens of MB of them to the end. A row is :data:`ROW` (98 bytes); warnings, rare, are kept as
text with their tile's description.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .grid import TileGrid

__all__ = ["ROW", "TileRecords"]

#: One tile's row: the fit's and the mesh task's counts and seconds.
ROW = np.dtype(
    [
        ("fitted", "?"),
        ("meshed", "?"),
        ("points", "<i8"),
        ("points_with_halo", "<i8"),
        ("particles", "<i8"),
        ("fit_s", "<f8"),
        ("mesh_s", "<f8"),
        ("crease_particles", "<i8"),
        ("own_crease_particles", "<i8"),
        ("cover_reach", "<f8"),
        ("new_vertices", "<i8"),
        ("self_intersections_found", "<i8"),
        ("self_intersections_left", "<i8"),
        ("small_handles_cut", "<i8"),
    ]
)


class TileRecords:
    """Per-tile statistics of a tiled fit, one :data:`ROW` per tile of the grid."""

    def __init__(self, grid: TileGrid) -> None:
        self.grid = grid
        self.rows = np.zeros(grid.count, dtype=ROW)
        self._warnings: list[tuple[int, str]] = []

    def add_fit(self, tile: int, result: dict[str, Any]) -> None:
        """A :func:`recon.tiling.tasks.fit_task` result."""
        r = self.rows[tile]
        r["fitted"] = True
        r["points"] = result["points"]
        r["points_with_halo"] = result.get("points_with_halo", result["points"])
        r["particles"] = result["particles"]
        r["fit_s"] = result["seconds"]
        r["own_crease_particles"] = result.get("own_crease_particles", 0)
        self._warnings += [(tile, w) for w in result.get("warnings", [])]

    def add_mesh(self, tile: int, result: dict[str, Any]) -> None:
        """A :func:`recon.tiling.tasks.mesh_task` result."""
        r = self.rows[tile]
        r["meshed"] = True
        r["mesh_s"] = result.get("seconds", 0.0)
        r["new_vertices"] = result.get("new_vertices", 0)
        for key in (
            "crease_particles",
            "cover_reach",
            "self_intersections_found",
            "self_intersections_left",
            "small_handles_cut",
        ):
            r[key] = result.get(key, 0)

    def warnings(self) -> list[str]:
        """The tiles' warnings, each with its tile's bounds, in tile order."""
        return [
            f"{self.grid.describe(t)}: {w}" for t, w in sorted(self._warnings, key=lambda x: x[0])
        ]

    def fitted(self) -> list[int]:
        return np.flatnonzero(self.rows["fitted"]).tolist()

    def with_particles(self) -> np.ndarray:
        """The tiles with particles, in index order (the order of the global particle ids)."""
        return np.flatnonzero(self.rows["particles"] > 0)

    def offsets(self) -> np.ndarray:
        """The global id of each tile's first particle (one per tile of the grid)."""
        counts = self.rows["particles"]
        return np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)

    def particle_counts(self) -> dict[int, int]:
        """tile -> particles, for the tiles with particles."""
        t = self.with_particles()
        return dict(zip(t.tolist(), self.rows["particles"][t].tolist(), strict=True))

    def new_vertices(self) -> dict[int, dict[str, int]]:
        """tile -> {"new_vertices": n} for the meshed tiles (the stitch's ``mesh_results``)."""
        t = np.flatnonzero(self.rows["meshed"])
        return {int(k): {"new_vertices": int(self.rows["new_vertices"][k])} for k in t}

    def total(self, key: str) -> int:
        return int(self.rows[key].sum())

    def tile_times(self) -> np.ndarray:
        """Fit plus mesh seconds of each fitted tile."""
        r = self.rows[self.rows["fitted"]]
        return r["fit_s"] + r["mesh_s"]

    def per_tile(self, flips: dict[int, float]) -> list[dict[str, Any]]:
        """The report's ``tiles.per_tile`` entries (built when the report is written)."""
        out = []
        for t in self.fitted():
            r = self.rows[t]
            lo, hi = self.grid.bounds(t)
            out.append(
                {
                    "tile": t,
                    "index": list(self.grid.ijk(t)),
                    "bounds": [lo.tolist(), hi.tolist()],
                    "points": int(r["points"]),
                    "points_with_halo": int(r["points_with_halo"]),
                    "particles": int(r["particles"]),
                    "fit_s": float(r["fit_s"]),
                    "mesh_s": float(r["mesh_s"]),
                    "crease_particles": int(r["crease_particles"]),
                    "cover_reach_r0": float(r["cover_reach"]),
                    "sign_flipped": flips.get(t, 1.0) < 0,
                }
            )
        return out
