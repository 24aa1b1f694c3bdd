"""The stitched mesh's vertices by global id, and which of them the mesh uses, with memory
bounded by a few tiles: :class:`VertexStore` (blocks loaded on demand) and
:class:`UsedVertices` (per block, in the work folder), both for
:mod:`recon.tiling.assemble` and :mod:`recon.tiling.writer`.

Global ids: every tile's particles (in tile order), then every tile's new vertices (those its
repair added), then the copies of bow-tie vertices the seam repair made, one block each.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable
from pathlib import Path

import numpy as np

__all__ = ["CACHED_BLOCKS", "BlockFiles", "UsedVertices", "VertexStore"]

#: Tiles' vertex blocks a :class:`VertexStore` keeps loaded.
CACHED_BLOCKS = 48


class BlockFiles:
    """Rows of int64 appended to one file per key in a folder, so that what grows with the
    scan (per vertex or per tile) waits on disk, not in the coordinator."""

    def __init__(self, folder: Path, prefix: str, columns: int) -> None:
        self.folder, self.prefix, self.columns = Path(folder), prefix, columns

    def path(self, key: int) -> Path:
        return self.folder / f"{self.prefix}-{key}.i8"

    def append(self, key: int, rows: np.ndarray) -> None:
        if len(rows):
            with open(self.path(key), "ab") as fh:
                np.ascontiguousarray(rows, dtype="<i8").tofile(fh)

    def read(self, key: int, remove: bool = False) -> np.ndarray:
        p = self.path(key)
        if not p.exists():
            return np.zeros((0, self.columns), dtype=np.int64)
        rows = np.fromfile(p, dtype="<i8").reshape(-1, self.columns)
        if remove:
            p.unlink()
        return rows


class VertexStore:
    """Positions, normals, colours and properties by global vertex id, from blocks loaded on
    demand.

    A block is a contiguous id range with a loader (a tile's particles, a tile's new vertices)
    or arrays held in memory (vertices the seam repair added). At most
    :data:`CACHED_BLOCKS` loaded blocks are kept.
    """

    def __init__(self) -> None:
        self.starts: list[int] = []
        self.counts: list[int] = []
        self.loaders: list[Callable[[], tuple]] = []
        self.cache: OrderedDict[int, tuple] = OrderedDict()
        self.total = 0
        self.max_cached = 0

    def add(self, count: int, loader: Callable[[], tuple]) -> int:
        """A block of ``count`` vertices; ``loader()`` returns (positions, normals, colours,
        properties): colours a (count, 3) uint8 array or empty when the scan has none,
        properties a (count, m) float64 array (m: the names of
        :func:`recon.tiling.tasks.property_names`)."""
        start = self.total
        self.starts.append(start)
        self.counts.append(int(count))
        self.loaders.append(loader)
        self.total += int(count)
        return start

    def add_arrays(
        self,
        pos: np.ndarray,
        nrm: np.ndarray,
        rgb: np.ndarray | None = None,
        props: np.ndarray | None = None,
    ) -> int:
        pos, nrm = np.asarray(pos, dtype=np.float64), np.asarray(nrm, dtype=np.float64)
        rgb = np.zeros((0, 3), np.uint8) if rgb is None else rgb
        props = np.zeros((len(pos), 0)) if props is None else props
        return self.add(len(pos), lambda: (pos, nrm, rgb, props))

    def block(self, b: int) -> tuple:
        if b in self.cache:
            self.cache.move_to_end(b)
            return self.cache[b]
        arrays = self.loaders[b]()
        self.cache[b] = arrays
        if len(self.cache) > CACHED_BLOCKS:
            self.cache.popitem(last=False)
        self.max_cached = max(self.max_cached, sum(len(a[0]) for a in self.cache.values()))
        return arrays

    def block_of(self, ids: np.ndarray) -> np.ndarray:
        return np.searchsorted(np.asarray(self.starts), ids, side="right") - 1

    def get(self, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        ids = np.asarray(ids, dtype=np.int64)
        pos = np.empty((len(ids), 3))
        nrm = np.empty((len(ids), 3))
        if len(ids) == 0:
            return pos, nrm
        b = self.block_of(ids)
        for k in np.unique(b):
            sel = b == k
            p, n = self.block(int(k))[:2]
            j = ids[sel] - self.starts[k]
            pos[sel] = p[j]
            nrm[sel] = n[j]
        return pos, nrm

    def get_colors(self, ids: np.ndarray) -> np.ndarray:
        """Colours (uint8) by global id; black where a block has none."""
        ids = np.asarray(ids, dtype=np.int64)
        rgb = np.zeros((len(ids), 3), dtype=np.uint8)
        b = self.block_of(ids) if len(ids) else ids
        for k in np.unique(b):
            c = self.block(int(k))[2]
            if len(c):
                sel = b == k
                rgb[sel] = c[ids[sel] - self.starts[k]]
        return rgb

    def get_properties(self, ids: np.ndarray, m: int) -> np.ndarray:
        """The ``m`` properties by global id (0 where a block has none)."""
        ids = np.asarray(ids, dtype=np.int64)
        out = np.zeros((len(ids), m))
        b = self.block_of(ids) if len(ids) else ids
        for k in np.unique(b):
            q = self.block(int(k))[3]
            if q.shape[1] == m and len(q):
                sel = b == k
                out[sel] = q[ids[sel] - self.starts[k]]
        return out


class UsedVertices:
    """Which vertices of a :class:`VertexStore` the written faces use, per block: ids are
    appended to the block's file as units are measured (:meth:`add`), then :meth:`finish`
    keeps each block's sorted local ids. The coordinator holds a few blocks' ids, not one flag
    per vertex of the scan."""

    def __init__(self, work: Path, store: VertexStore) -> None:
        self.store = store
        self.files = BlockFiles(work, "used", 1)
        self.counts = np.zeros(0, dtype=np.int64)  # used vertices per block (after finish)
        self._cache: OrderedDict[int, np.ndarray] = OrderedDict()

    def add(self, ids: np.ndarray) -> None:
        ids = np.unique(np.asarray(ids, dtype=np.int64))
        if len(ids) == 0:
            return
        b = self.store.block_of(ids)
        cuts = np.flatnonzero(np.diff(b)) + 1
        for part, k in zip(np.split(ids, cuts), b[np.r_[0, cuts]], strict=True):
            self.files.append(int(k), part - self.store.starts[int(k)])

    def finish(self) -> None:
        self.counts = np.zeros(len(self.store.starts), dtype=np.int64)
        for k in range(len(self.counts)):
            local = np.unique(self.files.read(k, remove=True).ravel())
            if len(local):
                np.save(self._npy(k), local)
            self.counts[k] = len(local)

    def _npy(self, k: int) -> Path:
        return self.files.folder / f"used-{k}.npy"

    @property
    def total(self) -> int:
        return int(self.counts.sum())

    def local(self, k: int) -> np.ndarray:
        """The sorted local ids of block ``k`` that the mesh uses."""
        if self.counts[k] == 0:
            return np.zeros(0, dtype=np.int64)
        if k not in self._cache:
            self._cache[k] = np.load(self._npy(k))
            if len(self._cache) > CACHED_BLOCKS:
                self._cache.popitem(last=False)
        return self._cache[k]

    def global_ids(self) -> np.ndarray:
        """Every used vertex's global id (for tests and small meshes)."""
        parts = [self.local(k) + self.store.starts[k] for k in range(len(self.counts))]
        return np.concatenate(parts) if parts else np.zeros(0, dtype=np.int64)
