"""Tiled fits of scans too large for one process: split, fit tiles on workers, stitch.

See :mod:`recon.tiling.run` for the stages and :func:`fit_tiled` for the entry point.
"""

from __future__ import annotations

from .executors import EXECUTORS, TileError, TileEvent, run_tasks, tile_runner
from .grid import TileGrid, choose_auto_tile_size
from .run import TiledResult, fit_tiled, plan_tile_size

__all__ = [
    "EXECUTORS",
    "TileError",
    "TileEvent",
    "TileGrid",
    "TiledResult",
    "choose_auto_tile_size",
    "fit_tiled",
    "plan_tile_size",
    "run_tasks",
    "tile_runner",
]
