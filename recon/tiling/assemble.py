"""The stitched mesh of a tiled fit, assembled with memory bounded by a tile, not the scan.

The tiles' faces arrive on disk (:func:`write_tile_mesh`, run by every
:func:`~recon.tiling.tasks.mesh_task`), split three ways by their vertices' distance to the
nearest inner tile face (a *seam*):

* **zone** faces have a vertex within :data:`ZONE_BAND` r0 of a seam: the only faces the
  coordinator may change (tile interiors were already repaired by the tile's own fit);
* **rim** faces are the other faces within :data:`RIM_BAND` r0 of a seam: unchanged, but seen
  by the repair of the zone next to them (every vertex of a zone face has all its faces among
  zone and rim faces, so its star is complete);
* **interior** faces (rim included) are written as they are.

Zone and rim faces are filed by the *dual cell* of their centroid: the cell of side
``tile size`` centred on a corner of the tile grid (:func:`dual_cell_of`), so one dual cell
holds the seams around one grid corner. The coordinator repairs the zone one dual cell at a
time (:func:`~recon.tiling.stitch.repair_cell`), seeing the zone and rim faces of the cells
around it (3 x 3 in a 2-D grid) as a fixed frame, so that a crack along a seam that runs on
into the next cell is one loop there (:func:`cut_stars` marks the vertices whose star this
sub-mesh cuts off; no loop through them is closed). Then it measures the topology one unit
(a tile's interior or a cell's zone) at a time, with the faces of other units that touch it
(:class:`recon.tiling.measure.TopologyAccumulator`), and streams the mesh into the output
file tile by tile (:func:`recon.tiling.writer.write_streamed`). What it holds at any moment
is one unit's faces, or the zone and rim faces of 3 x 3 dual cells during the repair, the
vertices they use (:class:`VertexStore` keeps a few tiles' vertices loaded), one byte per
vertex of the scan (which vertices the mesh uses), and the boundary edges of the whole mesh
(for the loop count).
"""

from __future__ import annotations

import itertools
from collections import OrderedDict
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from .grid import TileGrid
from .measure import TopologyAccumulator
from .stitch import repair_cell

__all__ = [
    "RIM_BAND",
    "ZONE_BAND",
    "VertexStore",
    "cut_stars",
    "dual_cell_of",
    "dual_neighbours",
    "dual_shape",
    "mesh_path",
    "proper_faces",
    "stitch_streamed",
    "write_tile_mesh",
]

#: Faces with a vertex within this many r0 of a seam are repaired by the coordinator ...
ZONE_BAND = 4.0
#: ... and faces with a vertex within this many r0 are the frame those repairs see.
RIM_BAND = 8.0
#: Tiles' vertex blocks a :class:`VertexStore` keeps loaded.
CACHED_BLOCKS = 48


def mesh_path(work: Path, tile: int) -> Path:
    return Path(work) / f"mesh-{tile}.npz"


def dual_shape(grid: TileGrid) -> tuple[int, ...]:
    """Dual cells along each axis: one per grid corner (``n + 1``), 1 along an uncut axis."""
    return tuple(n + 1 if n > 1 else 1 for n in grid.shape)


def dual_cell_of(grid: TileGrid, points: np.ndarray) -> np.ndarray:
    """The flat index of the dual cell (centred on a grid corner) holding each point."""
    shape = np.asarray(dual_shape(grid))
    u = (np.asarray(points, dtype=np.float64) - grid.lo) / grid.size + 0.5
    ijk = np.clip(np.floor(u), 0, shape - 1).astype(np.int64)
    ijk[:, shape == 1] = 0
    return np.ravel_multi_index(tuple(ijk.T), tuple(shape))


def dual_neighbours(grid: TileGrid, cell: int) -> list[int]:
    """The dual cells around ``cell`` (itself included)."""
    shape = dual_shape(grid)
    ijk = np.unravel_index(int(cell), shape)
    out = []
    for d in itertools.product((-1, 0, 1), repeat=3):
        q = [i + di for i, di in zip(ijk, d, strict=True)]
        if all(0 <= a < n for a, n in zip(q, shape, strict=True)):
            out.append(int(np.ravel_multi_index(tuple(q), shape)))
    return sorted(set(out))


def tile_dual_cells(grid: TileGrid, tile: int) -> list[int]:
    """The dual cells that overlap a tile (its corners' cells)."""
    shape = dual_shape(grid)
    ijk = grid.ijk(tile)
    ranges = [(i, i + 1) if n > 1 else (0,) for i, n in zip(ijk, shape, strict=True)]
    return sorted({int(np.ravel_multi_index(q, shape)) for q in itertools.product(*ranges)})


def write_tile_mesh(
    work: Path,
    tile: int,
    grid: TileGrid,
    r0: float,
    vertices: np.ndarray,
    faces: np.ndarray,
    codes: np.ndarray,
    new_vertices: np.ndarray,
    new_normals: np.ndarray,
    new_colors: np.ndarray | None = None,
    new_properties: np.ndarray | None = None,
    moved_ids: np.ndarray | None = None,
    moved_positions: np.ndarray | None = None,
    moved_attributes: tuple[np.ndarray, np.ndarray] | None = None,
) -> dict:
    """File a tile's faces as zone, rim and interior faces (see the module docstring).

    ``vertices`` are the absolute positions of the faces' vertices, ``faces`` index them and
    ``codes`` maps them to global particle ids (``-1 - j``: the tile's ``j``-th new vertex).
    ``new_colors`` / ``new_properties``: the new vertices' colours and properties
    (:func:`recon.tiling.tasks.vertex_attributes`).
    ``moved_ids`` / ``moved_positions``: the tile's own particles that untangling moved;
    ``moved_attributes``: their colours and properties where they moved to.
    Returns the counts.
    """
    dist = grid.seam_distance(vertices)
    near = dist[faces].min(axis=1) if len(faces) else np.zeros(0)
    zone = near <= ZONE_BAND * r0
    rim = ~zone & (near <= RIM_BAND * r0)
    centroid = vertices[faces].mean(axis=1) if len(faces) else np.zeros((0, 3))
    cell = dual_cell_of(grid, centroid) if len(faces) else np.zeros(0, dtype=np.int64)
    g = codes[faces] if len(faces) else np.zeros((0, 3), dtype=np.int64)
    np.savez(
        mesh_path(work, tile),
        interior=g[~zone],
        zone=g[zone],
        zone_cell=cell[zone],
        rim=g[rim],
        rim_cell=cell[rim],
        new_vertices=np.asarray(new_vertices, dtype=np.float64).reshape(-1, 3),
        new_normals=np.asarray(new_normals, dtype=np.float64).reshape(-1, 3),
        new_colors=np.zeros((0, 3), np.uint8) if new_colors is None else new_colors,
        new_properties=(
            np.zeros((len(new_vertices), 0)) if new_properties is None else new_properties
        ),
        moved_ids=np.zeros(0, np.int64) if moved_ids is None else moved_ids,
        moved_positions=np.zeros((0, 3)) if moved_positions is None else moved_positions,
        moved_colors=np.zeros((0, 3), np.uint8)
        if moved_attributes is None
        else moved_attributes[0],
        moved_properties=np.zeros((0, 0)) if moved_attributes is None else moved_attributes[1],
    )
    return {
        "faces": int(len(faces)),
        "zone_faces": int(zone.sum()),
        "new_vertices": int(len(new_vertices)),
    }


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


# --- the coordinator's stitch ------------------------------------------------------------


def cut_stars(
    grid: TileGrid,
    cell: int,
    positions: np.ndarray,
    faces: np.ndarray,
    zone_rows: np.ndarray,
    margin: float,
) -> np.ndarray:
    """The vertices of a dual cell's sub-mesh (the zone and rim faces of the cell and of the
    cells around it) whose star the sub-mesh may cut off: those no zone face uses (a rim
    face's far vertices also belong to interior faces, not loaded), and those within
    ``margin`` of the outer edge of the cells around (their faces may lie beyond). Every zone
    face's vertex has its whole star among zone and rim faces (see the module docstring)."""
    cut = np.ones(len(positions), dtype=bool)
    cut[np.asarray(faces)[zone_rows].ravel()] = False
    shape = np.asarray(dual_shape(grid))
    ijk = np.asarray(np.unravel_index(int(cell), tuple(shape)))
    u = (np.asarray(positions, dtype=np.float64) - grid.lo) / grid.size + 0.5
    m = margin / grid.size
    for axis in range(3):
        if shape[axis] == 1:
            continue
        lo_open, hi_open = ijk[axis] - 1 <= 0, ijk[axis] + 1 >= shape[axis] - 1
        if not lo_open:
            cut |= u[:, axis] < ijk[axis] - 1 + m
        if not hi_open:
            cut |= u[:, axis] > ijk[axis] + 2 - m
    return cut


def proper_faces(faces: np.ndarray) -> np.ndarray:
    """The faces with three distinct vertices: the only ones written (so the vertices that
    only faces with a repeated vertex use are not written either)."""
    f = np.asarray(faces)
    return f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])]


def _load_faces(paths: list[Path]) -> np.ndarray:
    parts = [np.load(p) for p in paths]
    return np.vstack(parts) if parts else np.zeros((0, 3), dtype=np.int64)


def _touching(cand: np.ndarray, faces: np.ndarray) -> np.ndarray:
    if len(cand) == 0 or len(faces) == 0:
        return np.zeros(len(cand), dtype=bool)
    return np.isin(cand, np.unique(faces)).any(axis=1)


def stitch_streamed(
    work: Path,
    grid: TileGrid,
    particle_counts: dict[int, int],
    flips: dict[int, float],
    mesh_results: dict[int, dict],
    r0: float,
    max_hole: float,
    particles_path: Callable[[Path, int], Path],
    n_properties: int = 0,
) -> dict[str, Any]:
    """Repair the seam zone cell by cell and measure the mesh unit by unit.

    Returns a dict with ``store`` (:class:`VertexStore`), ``units`` (a list of callables
    each returning one unit's final faces in global ids), ``used`` (vertices the mesh uses),
    ``topology``, ``quality``, ``seams``, ``repair``, ``coordinate_type`` (the PLY coordinate
    type of the written vertices, :class:`recon.tiling.measure.CoordinateRange`) and ``memory``
    (the largest sub-meshes held, for the report and the tests). ``n_properties``: per-vertex
    properties the tiles wrote (copies of bow-tie vertices take their source's).
    """
    from .stitch import SEAM_BAND

    store = VertexStore()
    tiles = sorted(particle_counts)

    def particle_loader(t: int):
        def load():
            with np.load(particles_path(work, t)) as z:
                rgb = z["colors"] if "colors" in z.files else np.zeros((0, 3), np.uint8)
                pos, nrm = z["positions"], z["normals"] * flips.get(t, 1.0)
                props = z["properties"] if "properties" in z.files else np.zeros((len(pos), 0))
            if t in mesh_results:  # the moves of the tile's untangling
                with np.load(mesh_path(work, t)) as z:
                    if "moved_ids" in z.files and len(z["moved_ids"]):
                        j = z["moved_ids"] - store.starts[index[t]]
                        pos = pos.copy()
                        pos[j] = z["moved_positions"]
                        # their colours and properties where they moved to
                        if len(rgb) and len(z["moved_colors"]) == len(j):
                            rgb = rgb.copy()
                            rgb[j] = z["moved_colors"]
                        if props.shape[1] and len(z["moved_properties"]) == len(j):
                            props = props.copy()
                            props[j] = z["moved_properties"]
            return pos, nrm, rgb, props

        return load

    index = {t: k for k, t in enumerate(tiles)}
    for t in tiles:
        store.add(particle_counts[t], particle_loader(t))

    def new_loader(t: int):
        def load():
            with np.load(mesh_path(work, t)) as z:
                return z["new_vertices"], z["new_normals"], z["new_colors"], z["new_properties"]

        return load

    newbase = {
        t: store.add(mesh_results[t]["new_vertices"], new_loader(t)) for t in sorted(mesh_results)
    }

    def convert(t: int, a: np.ndarray) -> np.ndarray:
        a = np.asarray(a, dtype=np.int64)
        return np.where(a < 0, newbase[t] + (-1 - a), a)

    # file the zone and rim faces by dual cell
    zone_files: dict[int, list[Path]] = {}
    rim_files: dict[int, list[tuple[int, Path]]] = {}
    for t in sorted(mesh_results):
        with np.load(mesh_path(work, t)) as z:
            for name in ("zone", "rim"):
                f, cell = convert(t, z[name]), z[f"{name}_cell"]
                for c in np.unique(cell):
                    p = Path(work) / f"{name}-{int(c)}-{t}.npy"
                    np.save(p, f[cell == c])
                    if name == "zone":
                        zone_files.setdefault(int(c), []).append(p)
                    else:
                        rim_files.setdefault(int(c), []).append((t, p))

    def out_path(c: int) -> Path:
        return Path(work) / f"seam-{c}.npy"

    done: set[int] = set()
    repair = {"faces_merged": 0, "faces_dropped": 0, "seam_loops_zipped": 0}
    repair["cut_orientation_conflicts"] = 0
    max_cell_faces = 0
    for c in sorted(zone_files):
        edit = _load_faces(zone_files[c])
        repair["faces_merged"] += len(edit)
        zone_like, rims = [], []
        for c2 in dual_neighbours(grid, c):
            if c2 != c:
                if c2 in done:
                    zone_like.append(np.load(out_path(c2)))
                elif c2 in zone_files:
                    zone_like.append(_load_faces(zone_files[c2]))
            rims += [np.load(p) for _, p in rim_files.get(c2, [])]
        # the frame: the zone and rim faces of the cells around (not only those touching the
        # cell's), so that a crack running from this cell into the next is seen whole
        frame = np.vstack([*zone_like, *rims]) if zone_like or rims else np.zeros((0, 3), int)
        both = np.vstack([frame, edit]).astype(np.int64)
        ids, local = np.unique(both, return_inverse=True)
        local = local.reshape(-1, 3)
        max_cell_faces = max(max_cell_faces, len(both))
        pos, nrm = store.get(ids)
        n_rim = sum(len(f) for f in rims)
        zone_rows = np.ones(len(both), dtype=bool)
        zone_rows[len(frame) - n_rim : len(frame)] = False
        cut = cut_stars(grid, c, pos, local, zone_rows, RIM_BAND * r0)
        v2, n2, fl, st = repair_cell(grid, pos, nrm, local, len(frame), r0, max_hole, cut)
        for k in ("faces_dropped", "seam_loops_zipped", "cut_orientation_conflicts"):
            repair[k] += st[k]
        gmap = np.concatenate([ids, np.full(len(v2) - len(ids), -1, dtype=np.int64)])
        extra = np.unique(fl[fl >= len(ids)])
        if len(extra):
            # a copy of a bow-tie vertex takes the colour of the vertex it copies (the nearest)
            from scipy.spatial import cKDTree

            src = cKDTree(pos).query(v2[extra])[1]
            start = store.add_arrays(
                v2[extra],
                n2[extra],
                store.get_colors(ids[src]),
                store.get_properties(ids[src], n_properties),
            )
            gmap[extra] = start + np.arange(len(extra))
        np.save(out_path(c), gmap[fl])
        done.add(c)

    n_tiles = grid.count

    def tile_faces(t: int) -> np.ndarray:
        with np.load(mesh_path(work, t)) as z:
            return convert(t, z["interior"])

    acc = TopologyAccumulator(grid, r0, SEAM_BAND)
    used = np.zeros(store.total, dtype=bool)
    for t in sorted(mesh_results):
        faces = tile_faces(t)
        cand, units = [], []
        for c in tile_dual_cells(grid, t):
            if c in done:
                f = np.load(out_path(c))
                cand.append(f)
                units.append(np.full(len(f), n_tiles + c))
        cand_f = np.vstack(cand) if cand else np.zeros((0, 3), dtype=np.int64)
        cand_u = np.concatenate(units) if units else np.zeros(0, dtype=np.int64)
        touch = _touching(cand_f, faces)
        acc.add(t, faces, cand_f[touch], cand_u[touch], store)
        used[proper_faces(faces).ravel()] = True
    for c in sorted(done):
        faces = np.load(out_path(c))
        cand, units = [], []
        for c2 in dual_neighbours(grid, c):
            if c2 != c and c2 in done:
                f = np.load(out_path(c2))
                cand.append(f)
                units.append(np.full(len(f), n_tiles + c2))
            for t, p in rim_files.get(c2, []):
                f = np.load(p)
                cand.append(f)
                units.append(np.full(len(f), t))
        cand_f = np.vstack(cand) if cand else np.zeros((0, 3), dtype=np.int64)
        cand_u = np.concatenate(units) if units else np.zeros(0, dtype=np.int64)
        touch = _touching(cand_f, faces)
        acc.add(n_tiles + c, faces, cand_f[touch], cand_u[touch], store)
        used[proper_faces(faces).ravel()] = True
    units_out: list[Callable[[], np.ndarray]] = [
        (lambda t=t: tile_faces(t)) for t in sorted(mesh_results)
    ] + [(lambda c=c: np.load(out_path(c))) for c in sorted(done)]
    n_used = int(used.sum())
    return {
        "store": store,
        "units": units_out,
        "used": used,
        "n_faces": acc.f,
        "topology": acc.topology(n_used),
        "coordinate_type": acc.coordinates.type(),
        "bounds": (acc.coordinates.lo, acc.coordinates.hi),
        "defects": acc.defects(),
        "quality": acc.quality(),
        "seams": acc.seams(),
        "repair": repair,
        "memory": {
            "largest_seam_cell_faces": int(max_cell_faces),
            "largest_unit_faces": int(acc.max_faces_held),
            "largest_cached_vertices": int(store.max_cached),
        },
    }
