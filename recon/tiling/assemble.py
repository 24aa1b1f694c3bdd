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
vertices they use (:class:`~recon.tiling.vertices.VertexStore` keeps a few tiles' vertices
loaded), and the boundary edges of the whole mesh (for the loop count). Which vertices the
mesh uses (:class:`~recon.tiling.vertices.UsedVertices`), the links between the units'
components and the vertices the repair added wait in the work folder; per tile, a few
hundred bytes of bookkeeping stay (the vertex blocks and their loaders, one flag per dual
cell).
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from .grid import TileGrid
from .measure import TopologyAccumulator
from .stitch import repair_cell
from .vertices import UsedVertices, VertexStore

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


def cell_tiles(grid: TileGrid, cell: int) -> list[int]:
    """The tiles that overlap a dual cell (the tiles around its grid corner), in index order:
    the inverse of :func:`tile_dual_cells`."""
    ijk = np.unravel_index(int(cell), dual_shape(grid))
    ranges = [
        [i for i in (c - 1, c) if 0 <= i < n] if n > 1 else [0]
        for c, n in zip(ijk, grid.shape, strict=True)
    ]
    return sorted(int(np.ravel_multi_index(q, grid.shape)) for q in itertools.product(*ranges))


def _filed(work: Path, name: str, cell: int, tile: int) -> Path:
    """The zone or rim faces of a tile in a dual cell (global ids)."""
    return Path(work) / f"{name}-{cell}-{tile}.npy"


def _load_filed(work: Path, grid: TileGrid, name: str, cell: int) -> list[np.ndarray]:
    """The ``name`` ("zone" or "rim") faces the tiles filed in ``cell``, tile by tile."""
    out = []
    for t in cell_tiles(grid, cell):
        p = _filed(work, name, cell, t)
        if p.exists():
            out.append(np.load(p))
    return out


class _Units:
    """The final faces (global ids) unit by unit: each meshed tile's interior, then each
    repaired dual cell's zone, read from the work folder when iterated."""

    def __init__(self, tile_faces: Callable[[int], np.ndarray], tiles: list[int], cells, work):
        self.tile_faces, self.tiles, self.cells, self.work = tile_faces, tiles, cells, work

    def __len__(self) -> int:
        return len(self.tiles) + len(self.cells)

    def __iter__(self):
        for t in self.tiles:
            yield self.tile_faces(t)
        for c in self.cells:
            yield np.load(_seam_path(self.work, int(c)))


def _seam_path(work: Path, cell: int) -> Path:
    return Path(work) / f"seam-{cell}.npy"


def _extra_loader(path: Path) -> Callable[[], tuple]:
    def load():
        with np.load(path) as z:
            return z["positions"], z["normals"], z["colors"], z["properties"]

    return load


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

    Returns a dict with ``store`` (:class:`VertexStore`), ``units`` (an iterable of the
    units' final faces in global ids, read when iterated), ``used``
    (:class:`~recon.tiling.vertices.UsedVertices`: the vertices the mesh uses),
    ``topology``, ``largest_component_faces`` (the faces of the mesh's largest component,
    for the fragments warning; not in the report), ``quality``, ``seams``, ``repair``,
    ``coordinate_type`` (the PLY coordinate type of the written vertices,
    :class:`recon.tiling.measure.CoordinateRange`) and ``memory`` (the largest sub-meshes
    held, for the report and the tests). ``n_properties``: per-vertex
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
    n_cells = int(np.prod(dual_shape(grid)))
    has_zone = np.zeros(n_cells, dtype=bool)
    for t in sorted(mesh_results):
        with np.load(mesh_path(work, t)) as z:
            for name in ("zone", "rim"):
                f, cell = convert(t, z[name]), z[f"{name}_cell"]
                for c in np.unique(cell):
                    np.save(_filed(work, name, int(c), t), f[cell == c])
                    if name == "zone":
                        has_zone[c] = True

    done = np.zeros(n_cells, dtype=bool)
    repair = {"faces_merged": 0, "faces_dropped": 0, "seam_loops_zipped": 0}
    repair["cut_orientation_conflicts"] = 0
    repair["small_handles_cut"] = 0
    max_cell_faces = 0
    for c in np.flatnonzero(has_zone).tolist():
        edit = np.vstack(_load_filed(work, grid, "zone", c))
        repair["faces_merged"] += len(edit)
        zone_like, rims = [], []
        for c2 in dual_neighbours(grid, c):
            if c2 != c:
                if done[c2]:
                    zone_like.append(np.load(_seam_path(work, c2)))
                elif has_zone[c2]:
                    zone_like += _load_filed(work, grid, "zone", c2)
            rims += _load_filed(work, grid, "rim", c2)
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
        for k in ("faces_dropped", "seam_loops_zipped", "cut_orientation_conflicts",
                  "small_handles_cut"):  # fmt: skip
            repair[k] += st[k]
        gmap = np.concatenate([ids, np.full(len(v2) - len(ids), -1, dtype=np.int64)])
        extra = np.unique(fl[fl >= len(ids)])
        if len(extra):
            # a copy of a bow-tie vertex takes the colour of the vertex it copies (the nearest)
            from scipy.spatial import cKDTree

            src = cKDTree(pos).query(v2[extra])[1]
            path = Path(work) / f"extra-{c}.npz"  # on disk, as the tiles' vertices
            np.savez(
                path,
                positions=np.asarray(v2[extra], dtype=np.float64),
                normals=np.asarray(n2[extra], dtype=np.float64),
                colors=store.get_colors(ids[src]),
                properties=store.get_properties(ids[src], n_properties),
            )
            start = store.add(len(extra), _extra_loader(path))
            gmap[extra] = start + np.arange(len(extra))
        np.save(_seam_path(work, c), gmap[fl])
        done[c] = True

    n_tiles = grid.count

    def tile_faces(t: int) -> np.ndarray:
        with np.load(mesh_path(work, t)) as z:
            return convert(t, z["interior"])

    acc = TopologyAccumulator(grid, r0, SEAM_BAND, work)
    used = UsedVertices(work, store)
    for t in sorted(mesh_results):
        faces = tile_faces(t)
        cand, units = [], []
        for c in tile_dual_cells(grid, t):
            if done[c]:
                f = np.load(_seam_path(work, c))
                cand.append(f)
                units.append(np.full(len(f), n_tiles + c))
        cand_f = np.vstack(cand) if cand else np.zeros((0, 3), dtype=np.int64)
        cand_u = np.concatenate(units) if units else np.zeros(0, dtype=np.int64)
        touch = _touching(cand_f, faces)
        acc.add(t, faces, cand_f[touch], cand_u[touch], store)
        used.add(proper_faces(faces).ravel())
    cells = np.flatnonzero(done)
    for c in cells.tolist():
        faces = np.load(_seam_path(work, c))
        cand, units = [], []
        for c2 in dual_neighbours(grid, c):
            if c2 != c and done[c2]:
                f = np.load(_seam_path(work, c2))
                cand.append(f)
                units.append(np.full(len(f), n_tiles + c2))
            for t in cell_tiles(grid, c2):
                p = _filed(work, "rim", c2, t)
                if p.exists():
                    f = np.load(p)
                    cand.append(f)
                    units.append(np.full(len(f), t))
        cand_f = np.vstack(cand) if cand else np.zeros((0, 3), dtype=np.int64)
        cand_u = np.concatenate(units) if units else np.zeros(0, dtype=np.int64)
        touch = _touching(cand_f, faces)
        acc.add(n_tiles + c, faces, cand_f[touch], cand_u[touch], store)
        used.add(proper_faces(faces).ravel())
    used.finish()
    return {
        "store": store,
        "units": _Units(tile_faces, sorted(mesh_results), cells, work),
        "used": used,
        "n_faces": acc.f,
        "topology": acc.topology(used.total),
        "largest_component_faces": acc.largest_faces,  # set by acc.topology
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
