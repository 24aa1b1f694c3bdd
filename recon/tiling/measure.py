"""The topology, triangle quality and seam statistics of a tiled mesh, measured one unit
(a tile's interior or a dual cell's seam zone) at a time: :class:`TopologyAccumulator`."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from scipy import sparse
from scipy.sparse import csgraph

from ..mesh import vertex_fans
from ..topology import TRIANGLE_QUALITY_KEYS
from .grid import TileGrid
from .stitch import face_keys
from .vertices import BlockFiles

__all__ = ["LINK_BATCH", "LINK_BUCKET", "CoordinateRange", "TopologyAccumulator"]

#: Vertex ids per file of the components' links (see :class:`TopologyAccumulator`) ...
LINK_BUCKET = 1 << 16
#: ... and pairs of linked components joined at a time.
LINK_BATCH = 1 << 20

#: float32 coordinates when they keep this fraction of the extent (as recon.io.ply).
FLOAT32_TOLERANCE = 1e-7


class CoordinateRange:
    """The PLY coordinate type of vertices seen block by block: 'f4' when float32 keeps
    :data:`FLOAT32_TOLERANCE` of their extent at every vertex, else 'f8' (the rule
    :func:`recon.io.write_mesh` applies to a whole mesh, so that a tiled mesh is written
    with the type its untiled twin would get)."""

    def __init__(self) -> None:
        self.lo = np.full(3, np.inf)
        self.hi = np.full(3, -np.inf)
        self.err = 0.0
        self.n = 0

    def add(self, xyz: np.ndarray) -> None:
        xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
        if len(xyz) == 0:
            return
        self.n += len(xyz)
        if not np.isfinite(xyz).all():
            self.err = np.inf
            return
        self.lo = np.minimum(self.lo, xyz.min(axis=0))
        self.hi = np.maximum(self.hi, xyz.max(axis=0))
        with np.errstate(over="ignore"):
            err = float(np.max(np.abs(xyz.astype(np.float32).astype(np.float64) - xyz)))
        self.err = max(self.err, err if np.isfinite(err) else np.inf)

    def type(self) -> str:
        if self.n == 0:
            return "f4"
        if not np.isfinite(self.err):
            return "f8"
        extent = float(np.max(self.hi - self.lo))
        return "f4" if self.err <= FLOAT32_TOLERANCE * extent else "f8"


class TopologyAccumulator:
    """:func:`recon.topology.mesh_topology`, triangle quality and seam statistics of a mesh
    seen one unit at a time.

    Every unit is a set of faces with a unit number; :meth:`add` gets a unit's faces with the
    faces of other units that share a vertex with them (so every vertex of the unit has its
    whole star). A vertex or an edge is counted by the lowest-numbered unit among its faces, a
    face by its own; components are joined across units through shared vertices; boundary
    edges are kept (with their lengths) to count the loops at the end.

    What grows with the scan waits in ``work`` (the tiled fit's work folder), not in memory:
    the links of each unit's components to the vertices it shares with other units go to one
    file per :data:`LINK_BUCKET` vertex ids and are joined bucket by bucket at the end; the
    components' counts are one row each. Held to the end: the boundary edges (the mesh's
    loops) and the non-manifold edges and vertices.

    :meth:`topology` also sets :attr:`largest_faces`, the faces of the mesh's largest
    component (the fragments warning's largest-share rule,
    :func:`recon.fitting.mesh_warnings.mesh_warnings`; not a key of the report's topology).
    """

    ANGLE_BINS = np.linspace(0.0, 60.0, 6001)
    RATIO_BINS = np.logspace(0.0, 8.0, 8001)

    def __init__(self, grid: TileGrid, r0: float, seam_band: float, work: Path) -> None:
        self.grid, self.r0, self.seam_band = grid, r0, seam_band
        self.v = self.e = self.f = 0
        self.nm_edges = self.nm_vertices = self.degenerate = self.duplicates = 0
        self.inconsistent = 0
        self.seam_edges = self.seam_boundary = self.near_boundary = 0
        self.boundary: list[np.ndarray] = []
        self.non_manifold: list[np.ndarray] = []  # (k, 2) edges, global ids
        self.bow_ties: list[np.ndarray] = []  # non-manifold vertices, global ids
        self.boundary_len: list[np.ndarray] = []
        self.node_counts = np.zeros((0, 3), dtype=np.int64)  # V, E, F per local component
        # (vertex id, node) for vertices shared with other units, by vertex id bucket
        self.links = BlockFiles(work, "links", 2)
        self.link_buckets: set[int] = set()
        self.n_nodes = 0
        #: faces of the largest component, set by :meth:`topology` (None before)
        self.largest_faces: int | None = None
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
        self.coordinates = CoordinateRange()  # of the vertices of the (written) own faces

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
        self.coordinates.add(pos[np.unique(local[own])])
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
        nm = owned_e & (cnt > 2)
        self.nm_edges += int(nm.sum())
        if nm.any():
            self.non_manifold.append(np.stack([ids[e_lo[nm]], ids[e_hi[nm]]], axis=1))
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
        bow = owned_v & (fans > 1)
        self.nm_vertices += int(bow.sum())
        if bow.any():
            self.bow_ties.append(ids[bow])
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
        self._add_nodes(counts)
        shared = in_own & (v_owner != unit)
        in_frame = np.zeros(nv, dtype=bool)
        in_frame[local[~own].ravel()] = True
        shared |= in_own & in_frame
        if shared.any():  # ids are sorted: one run per bucket
            rows = np.stack([ids[shared], self.n_nodes + comp_of[shared]], axis=1)
            bucket = rows[:, 0] // LINK_BUCKET
            cuts = np.flatnonzero(np.diff(bucket)) + 1
            for part in np.split(rows, cuts):
                key = int(part[0, 0] // LINK_BUCKET)
                self.links.append(key, part)
                self.link_buckets.add(key)
        self.n_nodes += k

    def _add_nodes(self, counts: np.ndarray) -> None:
        """Append the components' (V, E, F) rows (the array doubles when full)."""
        n, k = self.n_nodes, len(counts)
        if n + k > len(self.node_counts):
            grown = np.zeros((max(2 * len(self.node_counts), n + k, 64), 3), dtype=np.int64)
            grown[:n] = self.node_counts[:n]
            self.node_counts = grown
        self.node_counts[n : n + k] = counts

    def _components(self) -> np.ndarray:
        """The component of each node: nodes that share a vertex are joined, one bucket of
        links at a time, the pairs found joined every :data:`LINK_BATCH` pairs."""
        label = np.arange(self.n_nodes)
        pairs: list[np.ndarray] = []
        held = 0

        def join() -> None:
            nonlocal label, pairs, held
            if not pairs:
                return
            p = label[np.vstack(pairs)]
            g = sparse.coo_matrix(
                (np.ones(len(p), np.int8), (p[:, 0], p[:, 1])), (self.n_nodes, self.n_nodes)
            )
            label = csgraph.connected_components(g, directed=False)[1][label]
            pairs, held = [], 0

        for key in sorted(self.link_buckets):
            links = self.links.read(key)
            links = links[np.lexsort((links[:, 1], links[:, 0]))]
            same = links[1:, 0] == links[:-1, 0]
            if same.any():
                pairs.append(np.stack([links[1:][same, 1], links[:-1][same, 1]], axis=1))
                held += int(same.sum())
            if held >= LINK_BATCH:
                join()
        join()
        return label

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
        keys = TRIANGLE_QUALITY_KEYS
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
        """The report's ``topology`` (the keys of :func:`recon.topology.mesh_topology`).

        Also sets :attr:`largest_faces`: the faces of the largest component (the nodes' face
        counts summed by component; 0 for a mesh without faces).
        """
        counts = self.node_counts[: self.n_nodes]
        n_nodes = len(counts)
        comp = self._components()
        n_comp = len(np.unique(comp)) if n_nodes else 0
        per_comp = np.bincount(comp, weights=counts[:, 2], minlength=1)
        self.largest_faces = int(per_comp.max())
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
            # measured: a consistently oriented mesh is orientable, else unknown (None; it
            # said false for an orientable mesh wound inconsistently at small tiles' seams)
            "orientable": True if consistent else None,
            "consistently_oriented": bool(consistent),
            "euler_characteristic": int(chi),
            "genus": genus,
            "degenerate_faces": int(self.degenerate),
            "duplicate_faces": int(self.duplicates),
            "unreferenced_vertices": 0,
            "largest_hole_perimeter": largest,
        }

    def defects(self) -> dict[str, np.ndarray]:
        """Boundary and non-manifold edges ((k, 2) global ids) and non-manifold vertices."""
        z2 = np.zeros((0, 2), dtype=np.int64)
        return {
            "boundary": np.vstack(self.boundary) if self.boundary else z2,
            "non_manifold": np.vstack(self.non_manifold) if self.non_manifold else z2,
            "bow_ties": np.concatenate(self.bow_ties) if self.bow_ties else np.zeros(0, np.int64),
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
