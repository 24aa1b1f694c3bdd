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
time (:func:`~recon.tiling.stitch.repair_cell`), seeing the faces of the neighbouring cells
that touch it as a fixed frame; then measures the topology one unit (a tile's interior or a
cell's zone) at a time with the same frame (:class:`TopologyAccumulator`); then streams the
mesh into the output file tile by tile (:func:`write_streamed`). What it holds at any moment
is one unit's faces, the vertices they use (:class:`VertexStore` keeps a few tiles' vertices
loaded), one byte per vertex of the scan (which vertices the mesh uses), and the boundary
edges of the whole mesh (for the loop count).
"""

from __future__ import annotations

import itertools
from collections import OrderedDict
from collections.abc import Callable
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
from scipy import sparse
from scipy.sparse import csgraph

from ..mesh import vertex_fans
from .grid import TileGrid

__all__ = [
    "RIM_BAND",
    "ZONE_BAND",
    "TopologyAccumulator",
    "VertexStore",
    "dual_cell_of",
    "dual_neighbours",
    "dual_shape",
    "mesh_path",
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
    moved_ids: np.ndarray | None = None,
    moved_positions: np.ndarray | None = None,
) -> dict:
    """File a tile's faces as zone, rim and interior faces (see the module docstring).

    ``vertices`` are the absolute positions of the faces' vertices, ``faces`` index them and
    ``codes`` maps them to global particle ids (``-1 - j``: the tile's ``j``-th new vertex).
    ``moved_ids`` / ``moved_positions``: the tile's own particles that untangling moved.
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
        moved_ids=np.zeros(0, np.int64) if moved_ids is None else moved_ids,
        moved_positions=np.zeros((0, 3)) if moved_positions is None else moved_positions,
    )
    return {
        "faces": int(len(faces)),
        "zone_faces": int(zone.sum()),
        "new_vertices": int(len(new_vertices)),
    }


class VertexStore:
    """Positions and normals by global vertex id, from blocks loaded on demand.

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
        """A block of ``count`` vertices; ``loader()`` returns (positions, normals, colours),
        colours a (count, 3) uint8 array or empty when the scan has none."""
        start = self.total
        self.starts.append(start)
        self.counts.append(int(count))
        self.loaders.append(loader)
        self.total += int(count)
        return start

    def add_arrays(self, pos: np.ndarray, nrm: np.ndarray, rgb: np.ndarray | None = None) -> int:
        pos, nrm = np.asarray(pos, dtype=np.float64), np.asarray(nrm, dtype=np.float64)
        rgb = np.zeros((0, 3), np.uint8) if rgb is None else rgb
        return self.add(len(pos), lambda: (pos, nrm, rgb))

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
            p, n, _ = self.block(int(k))
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


def face_keys(faces: np.ndarray) -> np.ndarray:
    """One int64 key per face, the same for the same three vertices in any order."""
    s = np.sort(np.asarray(faces, dtype=np.int64), axis=1)
    if len(s) == 0 or s.max() >= 2**21:
        return np.unique(s, axis=0, return_inverse=True)[1].reshape(-1).astype(np.int64)
    return (s[:, 0] << 42) | (s[:, 1] << 21) | s[:, 2]  # three local ids in 63 bits


def same_winding(faces: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Whether each face runs its three vertices in the cyclic order of ``reference``."""
    if len(faces) == 0:
        return np.zeros(0, dtype=bool)
    pos0 = np.argmax(reference == faces[:, [0]], axis=1)
    nxt = reference[np.arange(len(faces)), (pos0 + 1) % 3]
    return nxt == faces[:, 1]


class TopologyAccumulator:
    """:func:`recon.topology.mesh_topology`, triangle quality and seam statistics of a mesh
    seen one unit at a time.

    Every unit is a set of faces with a unit number; :meth:`add` gets a unit's faces with the
    faces of other units that share a vertex with them (so every vertex of the unit has its
    whole star). A vertex or an edge is counted by the lowest-numbered unit among its faces, a
    face by its own; components are joined across units through shared vertices; boundary
    edges are kept (with their lengths) to count the loops at the end.
    """

    ANGLE_BINS = np.linspace(0.0, 60.0, 6001)
    RATIO_BINS = np.logspace(0.0, 8.0, 8001)

    def __init__(self, grid: TileGrid, r0: float, seam_band: float) -> None:
        self.grid, self.r0, self.seam_band = grid, r0, seam_band
        self.v = self.e = self.f = 0
        self.nm_edges = self.nm_vertices = self.degenerate = self.duplicates = 0
        self.inconsistent = 0
        self.seam_edges = self.seam_boundary = self.near_boundary = 0
        self.boundary: list[np.ndarray] = []
        self.boundary_len: list[np.ndarray] = []
        self.node_counts: list[np.ndarray] = []  # (k, 3): V, E, F per local component
        self.links: list[np.ndarray] = []  # (vertex id, node) for vertices shared with others
        self.n_nodes = 0
        # triangle quality
        self.q_n = 0
        self.q_min_sum = 0.0
        self.q_min_min = np.inf
        self.q_max_max = 0.0
        self.q_ratio_sum = 0.0
        self.q_ratio_max = 0.0
        self.q_len_sum = 0.0
        self.q_len_sq = 0.0
        self.q_len_n = 0
        self.angle_hist = np.zeros(len(self.ANGLE_BINS) - 1, dtype=np.int64)
        self.ratio_hist = np.zeros(len(self.RATIO_BINS) - 1, dtype=np.int64)
        self.max_faces_held = 0

    def add(self, unit: int, faces: np.ndarray, frame: np.ndarray, frame_unit: np.ndarray, store):
        """Count the unit's faces (global ids); ``frame`` are the other units' faces that share
        a vertex with them, ``frame_unit`` their unit numbers."""
        if len(faces) == 0:
            return
        self.max_faces_held = max(self.max_faces_held, len(faces) + len(frame))
        allf = np.vstack([faces, frame]).astype(np.int64)
        units = np.concatenate([np.full(len(faces), unit), frame_unit]).astype(np.int64)
        ids, local = np.unique(allf, return_inverse=True)
        local = local.reshape(-1, 3)
        pos, _ = store.get(ids)
        n_own = len(faces)
        own = np.arange(len(local)) < n_own
        a, b, c = local.T
        repeated = (a == b) | (b == c) | (a == c)
        p = pos[local]
        e_next = np.roll(p, -1, axis=1) - p
        lengths = np.linalg.norm(e_next, axis=2)
        area2 = np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
        flat = area2 <= 1e-12 * lengths.max(axis=1) ** 2
        self.degenerate += int((own & (repeated | flat)).sum())
        self._quality(p[own & ~repeated & ~flat], lengths[own & ~repeated & ~flat])
        keep = ~repeated
        local, units, own = local[keep], units[keep], own[keep]
        self.f += int(own.sum())
        nv = len(ids)
        # duplicates: a face is one when a face of a lower unit (or the same, earlier) has
        # the same three vertices
        key = face_keys(local)
        order = np.lexsort((np.arange(len(key)), units, key))
        dup = np.zeros(len(key), dtype=bool)
        dup[order[1:]] = key[order[1:]] == key[order[:-1]]
        self.duplicates += int((dup & own).sum())
        # vertex owners: the lowest unit among the faces using the vertex
        v_owner = np.full(nv, np.iinfo(np.int64).max)
        np.minimum.at(v_owner, local.ravel(), np.repeat(units, 3))
        in_own = np.zeros(nv, dtype=bool)
        in_own[local[own].ravel()] = True
        owned_v = in_own & (v_owner == unit)
        # edges
        he_from = local.ravel()
        he_to = np.roll(local, -1, axis=1).ravel()
        he_unit = np.repeat(units, 3)
        lo, hi = np.minimum(he_from, he_to), np.maximum(he_from, he_to)
        ekey = lo * np.int64(nv) + hi
        uk, inv, cnt = np.unique(ekey, return_inverse=True, return_counts=True)
        e_owner = np.full(len(uk), np.iinfo(np.int64).max)
        np.minimum.at(e_owner, inv, he_unit)
        e_in_own = np.zeros(len(uk), dtype=bool)
        e_in_own[inv[np.repeat(own, 3)]] = True
        owned_e = e_in_own & (e_owner == unit)
        e_lo, e_hi = uk // nv, uk % nv
        self.e += int(owned_e.sum())
        self.nm_edges += int((owned_e & (cnt > 2)).sum())
        # orientation on manifold edges: the two half-edges must run opposite ways
        fwd = (he_from < he_to).astype(np.int64)
        fwd_sum = np.bincount(inv, weights=fwd, minlength=len(uk))
        self.inconsistent += int((owned_e & (cnt == 2) & (fwd_sum != 1)).sum())
        bnd = owned_e & (cnt == 1)
        if bnd.any():
            self.boundary.append(np.stack([ids[e_lo[bnd]], ids[e_hi[bnd]]], axis=1))
            self.boundary_len.append(np.linalg.norm(pos[e_lo[bnd]] - pos[e_hi[bnd]], axis=1))
        # seam statistics over owned edges
        tile_of = self.grid.cell_of(pos)
        cross = owned_e & (tile_of[e_lo] != tile_of[e_hi])
        mid = 0.5 * (pos[e_lo] + pos[e_hi])
        near = owned_e & (self.grid.seam_distance(mid) <= self.seam_band * self.r0)
        self.seam_edges += int(cross.sum())
        self.seam_boundary += int((cross & (cnt == 1)).sum())
        self.near_boundary += int((near & (cnt == 1)).sum())
        # non-manifold vertices: more than one fan among all faces around an owned vertex
        fan = vertex_fans(local).ravel()
        span = np.int64(3 * len(local))
        fan_keys = np.unique(local.ravel() * span + fan)
        fans = np.bincount(fan_keys // span, minlength=nv)
        self.nm_vertices += int((owned_v & (fans > 1)).sum())
        self.v += int(owned_v.sum())
        # components of the unit's own faces, linked to the others through shared vertices
        of = local[own]
        rows = np.concatenate([of[:, 0], of[:, 1]])
        cols = np.concatenate([of[:, 1], of[:, 2]])
        graph = sparse.coo_matrix((np.ones(len(rows), np.int8), (rows, cols)), (nv, nv))
        _, label = csgraph.connected_components(graph, directed=False)
        used_labels, comp = np.unique(label[in_own], return_inverse=True)
        comp_of = np.full(nv, -1, dtype=np.int64)
        comp_of[in_own] = comp
        k = len(used_labels)
        counts = np.zeros((k, 3), dtype=np.int64)
        np.add.at(counts[:, 0], comp_of[owned_v], 1)
        np.add.at(counts[:, 1], comp_of[e_lo[owned_e]], 1)
        np.add.at(counts[:, 2], comp_of[of[:, 0]], 1)
        self.node_counts.append(counts)
        shared = in_own & (v_owner != unit)
        in_frame = np.zeros(nv, dtype=bool)
        in_frame[local[~own].ravel()] = True
        shared |= in_own & in_frame
        if shared.any():
            self.links.append(
                np.stack([ids[shared], self.n_nodes + comp_of[shared]], axis=1).astype(np.int64)
            )
        self.n_nodes += k

    def _quality(self, p: np.ndarray, lengths: np.ndarray) -> None:
        if len(p) == 0:
            return
        e_next = np.roll(p, -1, axis=1) - p
        e_prev = np.roll(p, 1, axis=1) - p
        cross = np.linalg.norm(np.cross(e_next, e_prev), axis=2)
        dot = np.einsum("fkd,fkd->fk", e_next, e_prev)
        angles = np.degrees(np.arctan2(cross, dot))
        mn = angles.min(axis=1)
        area2 = np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
        ratio = np.prod(lengths, axis=1) * lengths.sum(axis=1) / (4.0 * area2**2)
        self.q_n += len(p)
        self.q_min_sum += float(mn.sum())
        self.q_min_min = min(self.q_min_min, float(mn.min()))
        self.q_max_max = max(self.q_max_max, float(angles.max()))
        self.q_ratio_sum += float(ratio.sum())
        self.q_ratio_max = max(self.q_ratio_max, float(ratio.max()))
        self.q_len_sum += float(lengths.sum())
        self.q_len_sq += float((lengths**2).sum())
        self.q_len_n += lengths.size
        self.angle_hist += np.histogram(np.clip(mn, 0, 60), self.ANGLE_BINS)[0]
        self.ratio_hist += np.histogram(np.clip(ratio, 1, 1e8), self.RATIO_BINS)[0]

    @staticmethod
    def _percentile(hist: np.ndarray, bins: np.ndarray, q: float) -> float:
        c = np.cumsum(hist)
        i = int(np.searchsorted(c, q / 100.0 * c[-1]))
        return float(0.5 * (bins[i] + bins[i + 1]))

    def quality(self) -> dict[str, Any]:
        keys = (
            "min_angle_mean_deg",
            "min_angle_p5_deg",
            "min_angle_min_deg",
            "max_angle_max_deg",
            "aspect_ratio_mean",
            "aspect_ratio_p95",
            "aspect_ratio_max",
            "edge_length_mean",
            "edge_length_cv",
        )
        if self.q_n == 0:
            return {"n_measured": 0, **dict.fromkeys(keys)}
        mean_len = self.q_len_sum / self.q_len_n
        var = max(0.0, self.q_len_sq / self.q_len_n - mean_len**2)
        return {
            "n_measured": self.q_n,
            "min_angle_mean_deg": self.q_min_sum / self.q_n,
            "min_angle_p5_deg": self._percentile(self.angle_hist, self.ANGLE_BINS, 5),
            "min_angle_min_deg": self.q_min_min,
            "max_angle_max_deg": self.q_max_max,
            "aspect_ratio_mean": self.q_ratio_sum / self.q_n,
            "aspect_ratio_p95": self._percentile(self.ratio_hist, self.RATIO_BINS, 95),
            "aspect_ratio_max": self.q_ratio_max,
            "edge_length_mean": mean_len,
            "edge_length_cv": float(np.sqrt(var) / mean_len) if mean_len > 0 else 0.0,
        }

    def topology(self, n_vertices_written: int) -> dict[str, Any]:
        """The report's ``topology`` (the keys of :func:`recon.topology.mesh_topology`)."""
        counts = np.vstack(self.node_counts) if self.node_counts else np.zeros((0, 3), int)
        n_nodes = len(counts)
        parent_rows: list[np.ndarray] = []
        if self.links:
            links = np.vstack(self.links)
            order = np.lexsort((links[:, 1], links[:, 0]))
            links = links[order]
            same = links[1:, 0] == links[:-1, 0]
            parent_rows = [links[1:][same, 1], links[:-1][same, 1]]
        if parent_rows and len(parent_rows[0]):
            g = sparse.coo_matrix(
                (np.ones(len(parent_rows[0]), np.int8), (parent_rows[0], parent_rows[1])),
                (n_nodes, n_nodes),
            )
            _, comp = csgraph.connected_components(g, directed=False)
        else:
            comp = np.arange(n_nodes)
        n_comp = len(np.unique(comp)) if n_nodes else 0
        n_boundary = int(sum(len(b) for b in self.boundary))
        n_loops, largest = 0, 0.0
        if n_boundary:
            b = np.vstack(self.boundary)
            blen = np.concatenate(self.boundary_len)
            vid, inv = np.unique(b, return_inverse=True)
            inv = inv.reshape(-1, 2)
            g = sparse.coo_matrix(
                (np.ones(len(inv), np.int8), (inv[:, 0], inv[:, 1])), (len(vid), len(vid))
            )
            n_loops, lab = csgraph.connected_components(g, directed=False)
            largest = float(np.bincount(lab[inv[:, 0]], weights=blen).max())
        consistent = self.inconsistent == 0
        chi = self.v - self.e + self.f
        watertight = n_boundary == 0 and self.nm_edges == 0 and self.nm_vertices == 0
        genus = None
        if watertight and consistent and n_nodes:
            per = np.zeros((n_comp, 3), dtype=np.int64)
            _, c = np.unique(comp, return_inverse=True)
            np.add.at(per, c, counts)
            genus = int(np.sum((2 - (per[:, 0] - per[:, 1] + per[:, 2])) // 2))
        return {
            "n_vertices": int(n_vertices_written),
            "n_faces": int(self.f + self.degenerate_repeated_faces()),
            "n_edges": int(self.e),
            "components": int(n_comp),
            "boundary_edges": n_boundary,
            "boundary_loops": int(n_loops),
            "non_manifold_edges": int(self.nm_edges),
            "non_manifold_vertices": int(self.nm_vertices),
            "watertight": bool(watertight),
            # tiled fits check the winding edge by edge; orientability beyond that is not
            # measured (a consistently oriented mesh is orientable)
            "orientable": bool(consistent),
            "consistently_oriented": bool(consistent),
            "euler_characteristic": int(chi),
            "genus": genus,
            "degenerate_faces": int(self.degenerate),
            "duplicate_faces": int(self.duplicates),
            "unreferenced_vertices": 0,
            "largest_hole_perimeter": largest,
        }

    def degenerate_repeated_faces(self) -> int:
        return 0  # faces with a repeated vertex are never written (the repair drops them)

    def seams(self) -> dict[str, int]:
        return {
            "seam_edges": int(self.seam_edges),
            "seam_boundary_edges": int(self.seam_boundary),
            "boundary_edges_near_seams": int(self.near_boundary),
            "non_manifold_edges": int(self.nm_edges),
        }


# --- streamed output ---------------------------------------------------------------------


def _ply_vertex_props(coord_type: str, normals: bool, colors: bool) -> list[tuple[str, str]]:
    props = [("x", coord_type), ("y", coord_type), ("z", coord_type)]
    if normals:
        props += [("nx", "f4"), ("ny", "f4"), ("nz", "f4")]
    if colors:
        props += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    return props


def write_vertex_rows(
    fh: BinaryIO,
    fmt: str,
    pos: np.ndarray,
    nrm: np.ndarray | None,
    coord_type: str,
    ascii: bool,
    rgb: np.ndarray | None = None,
) -> None:
    """Append vertex rows as :func:`recon.io.write_mesh` writes them (OBJ: ``v`` lines, the
    ``vn`` lines are written apart)."""
    if fmt == "obj":
        if rgb is None:
            np.savetxt(fh, pos, fmt="v %.17g %.17g %.17g")
        else:
            data = np.hstack([pos, rgb.astype(np.float64) / 255.0])
            np.savetxt(fh, data, fmt="v %.17g %.17g %.17g %.6g %.6g %.6g")
        return
    if ascii:
        cols = [pos] + ([nrm] if nrm is not None else []) + ([rgb] if rgb is not None else [])
        data = np.hstack([np.asarray(c, dtype=np.float64) for c in cols])
        f = ["%.17g" if coord_type == "f8" else "%.9g"] * 3 + ["%.9g"] * (0 if nrm is None else 3)
        f += ["%d"] * (0 if rgb is None else 3)
        np.savetxt(fh, data, fmt=f, delimiter=" ")
        return
    props = _ply_vertex_props(coord_type, nrm is not None, rgb is not None)
    rows = np.zeros(len(pos), dtype=[(n, "<" + t) for n, t in props])
    for j, c in enumerate("xyz"):
        rows[c] = pos[:, j]
    if nrm is not None:
        for j, c in enumerate(("nx", "ny", "nz")):
            rows[c] = nrm[:, j]
    if rgb is not None:
        for j, c in enumerate(("red", "green", "blue")):
            rows[c] = rgb[:, j]
    fh.write(rows.tobytes())


def write_face_rows(fh: BinaryIO, fmt: str, faces: np.ndarray, ascii: bool, normals: bool) -> None:
    if len(faces) == 0:
        return
    if fmt == "obj":
        f1 = faces + 1
        if normals:
            np.savetxt(fh, np.repeat(f1, 2, axis=1), fmt="f %d//%d %d//%d %d//%d")
        else:
            np.savetxt(fh, f1, fmt="f %d %d %d")
        return
    if ascii:
        np.savetxt(fh, np.hstack([np.full((len(faces), 1), 3), faces]), fmt="%d")
        return
    rows = np.zeros(len(faces), dtype=[("n", "u1"), ("v", "<i4", (3,))])
    rows["n"] = 3
    rows["v"] = faces
    fh.write(rows.tobytes())


def coordinate_type(lo: np.ndarray, hi: np.ndarray) -> str:
    """PLY coordinate type for vertices within ``[lo, hi]`` (as :mod:`recon.io.ply` chooses)."""
    from ..io.ply import _coordinate_type

    corners = np.array(list(itertools.product(*zip(lo, hi, strict=True))), dtype=np.float64)
    return _coordinate_type(corners)


def ply_header(
    n_vertices: int,
    n_faces: int | None,
    coord_type: str,
    normals: bool,
    ascii: bool,
    colors: bool = False,
) -> bytes:
    from ..io.ply import _ply_header

    props = _ply_vertex_props(coord_type, normals, colors)
    return _ply_header(n_vertices, props, n_faces, ascii)


# --- the coordinator's stitch ------------------------------------------------------------


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
) -> dict[str, Any]:
    """Repair the seam zone cell by cell and measure the mesh unit by unit.

    Returns a dict with ``store`` (:class:`VertexStore`), ``units`` (a list of callables
    each returning one unit's final faces in global ids), ``used`` (vertices the mesh uses),
    ``topology``, ``quality``, ``seams``, ``repair`` and ``memory`` (the largest sub-meshes
    held, for the report and the tests).
    """
    from .stitch import SEAM_BAND, repair_cell

    store = VertexStore()
    tiles = sorted(particle_counts)

    def particle_loader(t: int):
        def load():
            with np.load(particles_path(work, t)) as z:
                rgb = z["colors"] if "colors" in z.files else np.zeros((0, 3), np.uint8)
                pos, nrm = z["positions"], z["normals"] * flips.get(t, 1.0)
            if t in mesh_results:  # the moves of the tile's untangling
                with np.load(mesh_path(work, t)) as z:
                    if "moved_ids" in z.files and len(z["moved_ids"]):
                        pos = pos.copy()
                        pos[z["moved_ids"] - store.starts[index[t]]] = z["moved_positions"]
            return pos, nrm, rgb

        return load

    index = {t: k for k, t in enumerate(tiles)}
    for t in tiles:
        store.add(particle_counts[t], particle_loader(t))

    def new_loader(t: int):
        def load():
            with np.load(mesh_path(work, t)) as z:
                return z["new_vertices"], z["new_normals"], z["new_colors"]

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
        cand = []
        for c2 in dual_neighbours(grid, c):
            if c2 != c:
                if c2 in done:
                    cand.append(np.load(out_path(c2)))
                elif c2 in zone_files:
                    cand.append(_load_faces(zone_files[c2]))
            cand += [np.load(p) for _, p in rim_files.get(c2, [])]
        cand_f = np.vstack(cand) if cand else np.zeros((0, 3), dtype=np.int64)
        frame = cand_f[_touching(cand_f, edit)]
        both = np.vstack([frame, edit])
        ids, local = np.unique(both, return_inverse=True)
        local = local.reshape(-1, 3)
        max_cell_faces = max(max_cell_faces, len(both))
        pos, nrm = store.get(ids)
        v2, n2, fl, st = repair_cell(grid, pos, nrm, local, len(frame), r0, max_hole)
        for k in ("faces_dropped", "seam_loops_zipped", "cut_orientation_conflicts"):
            repair[k] += st[k]
        gmap = np.concatenate([ids, np.full(len(v2) - len(ids), -1, dtype=np.int64)])
        extra = np.unique(fl[fl >= len(ids)])
        if len(extra):
            # a copy of a bow-tie vertex takes the colour of the vertex it copies (the nearest)
            from scipy.spatial import cKDTree

            src = cKDTree(pos).query(v2[extra])[1]
            start = store.add_arrays(v2[extra], n2[extra], store.get_colors(ids[src]))
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
        used[faces.ravel()] = True
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
        used[faces.ravel()] = True
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
        "quality": acc.quality(),
        "seams": acc.seams(),
        "repair": repair,
        "memory": {
            "largest_seam_cell_faces": int(max_cell_faces),
            "largest_unit_faces": int(acc.max_faces_held),
            "largest_cached_vertices": int(store.max_cached),
        },
    }


def write_streamed(
    path: Path,
    stitched: dict[str, Any],
    coord_type: str,
    normals: bool,
    ascii: bool,
    colors: bool = False,
) -> None:
    """Write the stitched mesh to ``path`` (an open temporary, see :mod:`recon.io.files`):
    vertices block by block, then faces unit by unit, renumbered to the used vertices."""
    store: VertexStore = stitched["store"]
    used: np.ndarray = stitched["used"]
    starts = np.asarray(store.starts)
    blocks = list(zip(store.starts, store.counts, strict=True))
    prefix = np.concatenate([[0], np.cumsum([int(used[s : s + n].sum()) for s, n in blocks])])
    fmt = "obj" if path.suffix.lower() == ".obj" else "ply"
    ranks: OrderedDict[int, np.ndarray] = OrderedDict()

    def new_ids(ids: np.ndarray) -> np.ndarray:
        b = np.searchsorted(starts, ids, side="right") - 1
        out = np.empty(len(ids), dtype=np.int64)
        for k in np.unique(b):
            k = int(k)
            if k not in ranks:
                s, n = store.starts[k], store.counts[k]
                ranks[k] = np.cumsum(used[s : s + n]) - 1
                if len(ranks) > CACHED_BLOCKS:
                    ranks.popitem(last=False)
            sel = b == k
            out[sel] = prefix[k] + ranks[k][ids[sel] - store.starts[k]]
        return out

    with open(path, "wb") as fh:
        if fmt == "ply":
            n_used = int(used.sum())
            fh.write(ply_header(n_used, stitched["n_faces"], coord_type, normals, ascii, colors))
        else:
            fh.write(b"# written by oprecon\n")
        for k, (s, n) in enumerate(zip(store.starts, store.counts, strict=True)):
            sel = used[s : s + n]
            if not sel.any():
                continue
            p, nr, rgb = store.block(k)
            if colors and len(rgb) != len(p):
                rgb = np.zeros((len(p), 3), dtype=np.uint8)
            write_vertex_rows(
                fh,
                fmt,
                p[sel],
                nr[sel] if normals else None,
                coord_type,
                ascii,
                rgb[sel] if colors else None,
            )
        if fmt == "obj" and normals:
            for k, (s, n) in enumerate(zip(store.starts, store.counts, strict=True)):
                sel = used[s : s + n]
                if sel.any():
                    np.savetxt(fh, store.block(k)[1][sel], fmt="vn %.9g %.9g %.9g")
        for unit in stitched["units"]:
            f = unit()
            f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])]
            if len(f):
                write_face_rows(fh, fmt, new_ids(f.ravel()).reshape(-1, 3), ascii, normals)


def write_particles_streamed(
    path: Path, store: VertexStore, n_blocks: int, coord_type: str, ascii: bool
) -> None:
    """The particles (the store's first ``n_blocks`` blocks) as a PLY point cloud."""
    n = int(sum(store.counts[:n_blocks]))
    with open(path, "wb") as fh:
        fh.write(ply_header(n, None, coord_type, True, ascii))
        for k in range(n_blocks):
            p, nr, _ = store.block(k)
            write_vertex_rows(fh, "ply", p, nr, coord_type, ascii)
