"""The input mesh as the data surface of a remesh: exact closest points and feature lines.

:class:`MeshSurface` answers closest-point queries on the triangles (a cell grid in float64;
Open3D's ``RaycastingScene``, Embree, for far points and rays, on the mesh centred and divided
by the power of two nearest its size, as the fit's query; float32 inside, so exact to ~1e-7 of
the extent) and gives the face normal at the foot. :class:`FeatureLines` holds the polylines
particles must stay on (boundary loops and creases, split at corners) and projects points onto
their own line.

Feature lines (:func:`feature_lines`): the input edges used by one face (boundary) or whose two
face normals differ by more than the crease angle; a vertex of the feature graph whose degree is
not 2, or where the line turns by more than the corner angle, is a corner (kept fixed).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..mesh import corner_sum, face_area_vectors, runs_of_equal
from ..metrics import check_closest_found
from ..topology import power_of_two_near

__all__ = [
    "FeatureLines",
    "MeshSurface",
    "chain_order",
    "edge_faces",
    "feature_lines",
]

#: Points are projected onto a feature line in blocks of this many point-segment pairs.
PROJECT_BLOCK = 2_000_000
#: Closest-point grid: cell side in mean input edges ...
GRID_CELL_EDGES = 2.0
#: ... grown by half until the triangles are registered in at most this many cells on average
#: (a large triangle is registered in every cell its plane crosses within its bounding box).
GRID_MAX_CELLS_PER_TRIANGLE = 8.0
#: Queries farther than about this many cells from the surface go to Embree instead.
GRID_MAX_RING = 2


class MeshSurface:
    """Closest points, normals and areas of a triangle mesh (any consistent unit).

    Closest points come from a cell grid over the triangles, exact in float64
    (:mod:`recon.kernels.closest_point`; built at the first query), points far from the surface
    and ray casts from Open3D's ``RaycastingScene`` (Embree).

    Parameters
    ----------
    vertices : (V, 3) float64
    faces : (F, 3) int64, consistently wound
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray) -> None:
        import open3d as o3d

        self.vertices = np.ascontiguousarray(vertices, dtype=np.float64)
        self.faces = np.ascontiguousarray(faces, dtype=np.int64)
        cross = face_area_vectors(self.vertices, self.faces)
        area2 = np.linalg.norm(cross, axis=1)
        self.face_area = 0.5 * area2
        self.face_normal = cross / np.maximum(area2, 1e-300)[:, None]
        vn = corner_sum(self.faces, cross, len(self.vertices))
        self.vertex_normal = vn / np.maximum(np.linalg.norm(vn, axis=1), 1e-300)[:, None]
        lo, hi = self.vertices.min(axis=0), self.vertices.max(axis=0)
        self.centre = 0.5 * (lo + hi)
        # Embree's scene sees the mesh centred, at the power of two nearest its size (the fit's
        # closest-point query does the same: Embree's float32 tolerances are its own, and a
        # mesh 1e-16 or 1e16 across had its rays miss it; a power of two changes no bit)
        self._unit = power_of_two_near(float(np.max(hi - lo)))
        self._scene = o3d.t.geometry.RaycastingScene()
        self._scene.add_triangles(
            o3d.core.Tensor(np.ascontiguousarray(self._to_scene(self.vertices), dtype=np.float32)),
            o3d.core.Tensor(np.ascontiguousarray(self.faces, dtype=np.uint32)),
        )
        self._grid: tuple | None = None
        self._cell = 0.0

    def _triangle_grid(self) -> tuple:
        from ..kernels.closest_point import registrations, triangle_grid_build

        if self._grid is None:
            v, f = self.vertices, self.faces
            edge = np.linalg.norm(v[f] - v[np.roll(f, -1, axis=1)], axis=2)
            extent = float(np.max(v.max(axis=0) - v.min(axis=0)))
            cell = max(GRID_CELL_EDGES * float(edge.mean()), 1e-9 * max(extent, 1e-300))
            budget = GRID_MAX_CELLS_PER_TRIANGLE * len(f) + 1000
            while registrations(v, f, cell) > budget:
                cell *= 1.5
            self._cell = cell
            self._grid = triangle_grid_build(v, f, cell)
        return self._grid

    @property
    def area(self) -> float:
        """Total surface area."""
        return float(self.face_area.sum())

    def closest(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Closest points on the triangles, their face indices and the unit face normals there.

        Returns
        -------
        foot : (n, 3) float64
        face : (n,) int64
        normal : (n, 3) float64
        """
        from ..kernels.closest_point import closest_points_kernel

        pts = np.ascontiguousarray(points, dtype=np.float64)
        if len(pts) == 0:
            return np.zeros((0, 3)), np.zeros(0, dtype=np.int64), np.zeros((0, 3))
        grid = self._triangle_grid()
        foot = np.empty((len(pts), 3))
        face = np.zeros(len(pts), dtype=np.int64)
        ok = np.zeros(len(pts), dtype=bool)
        closest_points_kernel(pts, grid, self._cell, GRID_MAX_RING, foot, face, ok)
        far = np.flatnonzero(~ok)
        if len(far):
            foot[far], face[far] = self._closest_embree(pts[far])
        return foot, face, self.face_normal[face]

    def _closest_embree(self, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Closest points by Embree (float32), refined in float64 on the face it found."""
        import open3d as o3d

        query = o3d.core.Tensor(np.ascontiguousarray(self._to_scene(pts), dtype=np.float32))
        ans = self._scene.compute_closest_points(query)
        foot = ans["points"].numpy().astype(np.float64) * self._unit + self.centre
        face = ans["primitive_ids"].numpy().astype(np.int64)
        check_closest_found(face, len(self.faces), pts, self.vertices)
        return closest_on_triangles(pts, self.vertices[self.faces[face]], foot), face

    def sample(self, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """``n`` area-uniform random points and their face indices (Osada et al. 2002)."""
        cdf = np.cumsum(self.face_area)
        face = np.minimum(
            np.searchsorted(cdf, rng.random(n) * cdf[-1], side="right"), len(self.faces) - 1
        )
        u = np.sqrt(rng.random((n, 1)))
        w = rng.random((n, 1))
        p = self.vertices[self.faces[face]]
        points = (1.0 - u) * p[:, 0] + u * (1.0 - w) * p[:, 1] + u * w * p[:, 2]
        return points, face.astype(np.int64)

    def distance(self, points: np.ndarray) -> np.ndarray:
        """Unsigned distance of each point to the surface."""
        foot, _, _ = self.closest(points)
        return np.linalg.norm(np.asarray(points, dtype=np.float64) - foot, axis=1)

    def first_hit(self, rays: np.ndarray) -> np.ndarray:
        """Distance along each (n, 6) ray (unit direction) to the first hit (inf: none)."""
        import open3d as o3d

        r = np.array(rays, dtype=np.float64)
        r[:, :3] = self._to_scene(r[:, :3])
        ans = self._scene.cast_rays(o3d.core.Tensor(r.astype(np.float32)))
        return ans["t_hit"].numpy().astype(np.float64) * self._unit

    def _to_scene(self, points: np.ndarray) -> np.ndarray:
        """Points in the coordinates of the Embree scene (centred, divided by its unit)."""
        return (points - self.centre) / self._unit


def closest_on_triangles(p: np.ndarray, tri: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    """Exact closest point of each point ``p[i]`` on triangle ``tri[i]`` (float64).

    Ericson, "Real-Time Collision Detection", §5.1.5, vectorised; ``fallback`` is returned for
    degenerate triangles.
    """
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = _dot(ab, ap), _dot(ac, ap)
    bp = p - b
    d3, d4 = _dot(ab, bp), _dot(ac, bp)
    cp = p - c
    d5, d6 = _dot(ab, cp), _dot(ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    denom = va + vb + vc
    with np.errstate(divide="ignore", invalid="ignore"):
        v = vb / denom
        w = vc / denom
        out = a + ab * v[:, None] + ac * w[:, None]  # inside the face
        # edge regions
        t_ab = d1 / (d1 - d3)
        t_ac = d2 / (d2 - d6)
        t_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
    on_bc = (va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0)
    out = np.where(on_bc[:, None], b + t_bc[:, None] * (c - b), out)
    on_ac = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
    out = np.where(on_ac[:, None], a + t_ac[:, None] * ac, out)
    on_ab = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
    out = np.where(on_ab[:, None], a + t_ab[:, None] * ab, out)
    # vertex regions
    out = np.where(((d6 >= 0) & (d5 <= d6))[:, None], c, out)
    out = np.where(((d3 >= 0) & (d4 <= d3))[:, None], b, out)
    out = np.where(((d1 <= 0) & (d2 <= 0))[:, None], a, out)
    bad = ~np.all(np.isfinite(out), axis=1)
    out[bad] = fallback[bad]
    return out


def edge_faces(
    faces: np.ndarray, n_vertices: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Unique edges ``(E, 2)`` (lo, hi), their face counts, and the first two faces of each
    (``-1`` where there is none)."""
    he = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    key = he[:, 0] * np.int64(n_vertices) + he[:, 1]
    order, first, counts = runs_of_equal(key)
    face_of = order // 3
    f0 = face_of[first]
    second = first + 1
    has2 = counts >= 2
    f1 = np.full(len(first), -1, dtype=np.int64)
    f1[has2] = face_of[second[has2]]
    edges = he[order[first]]
    return edges, counts, f0, f1


def _dot(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return np.einsum("ij,ij->i", x, y)


@dataclass
class FeatureLines:
    """Polylines that particles must stay on, split at corners.

    Attributes
    ----------
    chains : list of (m,) int64 arrays
        Vertex indices of each line; a closed loop repeats its first vertex at the end.
    closed : (c,) bool
    corners : (k,) int64
        Vertex indices of the corners (fixed).
    n_boundary_edges, n_crease_edges : int
    segments : (S, 2, 3) float64
        All line segments; ``segment_chain`` (S,) int64 gives the chain of each.
    chain_is_boundary : (c,) bool
        The chain runs along a boundary of the input (else along a crease).
    face_patch : (F,) int64
        Patch of every input face: faces joined through edges that are not on a line (so every
        component is one patch or more).
    chain_patches, corner_patches : lists of int64 arrays
        The patches on the sides of each chain, and around each corner.
    """

    chains: list[np.ndarray]
    closed: np.ndarray
    corners: np.ndarray
    n_boundary_edges: int
    n_crease_edges: int
    segments: np.ndarray
    segment_chain: np.ndarray
    chain_is_boundary: np.ndarray
    face_patch: np.ndarray
    chain_patches: list[np.ndarray]
    corner_patches: list[np.ndarray]

    @property
    def empty(self) -> bool:
        return len(self.chains) == 0

    def chain_length(self, vertices: np.ndarray, i: int) -> float:
        p = vertices[self.chains[i]]
        return float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum())

    def project(self, points: np.ndarray, chain: np.ndarray) -> np.ndarray:
        """Closest point of each point on its own chain ``chain[i]``."""
        out = np.array(points, dtype=np.float64, copy=True)
        if len(out) == 0:
            return out
        order = np.argsort(chain, kind="stable")
        seg_order = np.argsort(self.segment_chain, kind="stable")
        seg_start = np.searchsorted(self.segment_chain[seg_order], np.arange(len(self.chains) + 1))
        p_start = np.searchsorted(chain[order], np.arange(len(self.chains) + 1))
        for c in range(len(self.chains)):
            idx = order[p_start[c] : p_start[c + 1]]
            if len(idx) == 0:
                continue
            seg = self.segments[seg_order[seg_start[c] : seg_start[c + 1]]]
            block = max(1, PROJECT_BLOCK // max(len(seg), 1))
            for s in range(0, len(idx), block):
                sub = idx[s : s + block]
                out[sub] = _closest_on_segments(out[sub], seg)
        return out

    def distance(self, points: np.ndarray, boundary: bool | None = None) -> np.ndarray:
        """Distance of each point to the nearest line (inf: none); with ``boundary`` True or
        False, to the nearest boundary or crease line only."""
        pts = np.asarray(points, dtype=np.float64)
        seg = self.segments
        if boundary is not None:
            seg = seg[self.chain_is_boundary[self.segment_chain] == boundary]
        out = np.full(len(pts), np.inf)
        if len(pts) == 0 or len(seg) == 0:
            return out
        # the nearest segment's midpoint lies within (the distance to the nearest midpoint)
        # + (the longest half segment): only the segments with a midpoint that near are measured
        from scipy.spatial import cKDTree

        mid = 0.5 * (seg[:, 0] + seg[:, 1])
        half = 0.5 * float(np.linalg.norm(seg[:, 1] - seg[:, 0], axis=1).max())
        tree = cKDTree(mid)
        d0, _ = tree.query(pts)
        near = tree.query_ball_point(pts, d0 * (1.0 + 1e-12) + half + 1e-300)
        counts = np.fromiter((len(x) for x in near), dtype=np.int64, count=len(pts))
        which = np.concatenate([np.asarray(x, dtype=np.int64) for x in near])
        point = np.repeat(np.arange(len(pts)), counts)
        for s in range(0, len(which), PROJECT_BLOCK):
            w, q = which[s : s + PROJECT_BLOCK], point[s : s + PROJECT_BLOCK]
            a, b = seg[w, 0], seg[w, 1]
            d = b - a
            t = np.clip(
                np.einsum("ij,ij->i", pts[q] - a, d)
                / np.maximum(np.einsum("ij,ij->i", d, d), 1e-300),
                0.0,
                1.0,
            )
            np.minimum.at(out, q, np.linalg.norm(a + t[:, None] * d - pts[q], axis=1))
        return out


def chain_order(lines: FeatureLines, points: np.ndarray, chain: np.ndarray) -> np.ndarray:
    """Arc-length position of each point along its own chain ``chain[i]`` (from its start)."""
    arc = np.zeros(len(points))
    for c in np.unique(chain):
        idx = np.flatnonzero(chain == c)
        seg = lines.segments[lines.segment_chain == c]
        length = np.linalg.norm(seg[:, 1] - seg[:, 0], axis=1)
        cum = np.concatenate([[0.0], np.cumsum(length)])
        _, k, t = _closest_on_segments(points[idx], seg, with_param=True)
        arc[idx] = cum[k] + t * length[k]
    return arc


def _closest_on_segments(points: np.ndarray, seg: np.ndarray, with_param: bool = False):
    """Closest point on any of the segments ``seg`` (S, 2, 3) for every point (brute force);
    with ``with_param`` also the segment index and the parameter t in [0, 1] on it."""
    a = seg[None, :, 0]
    d = seg[None, :, 1] - a
    dd = np.maximum(np.einsum("psk,psk->ps", d, d), 1e-300)
    t = np.clip(np.einsum("psk,psk->ps", points[:, None] - a, d) / dd, 0.0, 1.0)
    foot = a + t[..., None] * d
    dist = np.einsum("psk,psk->ps", foot - points[:, None], foot - points[:, None])
    best = np.argmin(dist, axis=1)
    rows = np.arange(len(points))
    if with_param:
        return foot[rows, best], best, t[rows, best]
    return foot[rows, best]


def feature_lines(
    vertices: np.ndarray,
    faces: np.ndarray,
    crease_angle_deg: float | None,
    corner_angle_deg: float,
) -> FeatureLines:
    """Boundary and crease lines of a manifold mesh, split at corners (module docstring)."""
    edges, counts, f0, f1 = edge_faces(faces, len(vertices))
    boundary = counts == 1
    crease = np.zeros(len(edges), dtype=bool)
    if crease_angle_deg is not None:
        cross = face_area_vectors(vertices, faces)
        n = cross / np.maximum(np.linalg.norm(cross, axis=1), 1e-300)[:, None]
        inner = counts == 2
        cosang = np.einsum("ij,ij->i", n[f0[inner]], n[f1[inner]])
        crease[inner] = cosang < np.cos(np.radians(crease_angle_deg))
    feat = edges[boundary | crease]
    is_bnd = boundary[boundary | crease]
    nv = len(vertices)
    degree = np.bincount(feat.ravel(), minlength=nv)
    # adjacency lists of the feature graph
    ends = np.concatenate([feat, feat[:, ::-1]])
    e_id = np.concatenate([np.arange(len(feat))] * 2)
    order = np.lexsort((ends[:, 1], ends[:, 0]))
    ends, e_id = ends[order], e_id[order]
    start = np.searchsorted(ends[:, 0], np.arange(nv + 1))
    corner = (degree > 0) & (degree != 2)
    two = np.flatnonzero(degree == 2)
    if len(two):
        nb = ends[start[two], 1], ends[start[two] + 1, 1]
        u = vertices[nb[0]] - vertices[two]
        w = vertices[nb[1]] - vertices[two]
        cosang = np.einsum("ij,ij->i", u, w) / np.maximum(
            np.linalg.norm(u, axis=1) * np.linalg.norm(w, axis=1), 1e-300
        )
        # interior angle below 180 - corner angle: the line turns by more than corner_angle
        turn = np.degrees(np.pi - np.arccos(np.clip(cosang, -1.0, 1.0)))
        corner[two[turn > corner_angle_deg]] = True
    used = np.zeros(len(feat), dtype=bool)
    chains: list[np.ndarray] = []
    closed: list[bool] = []
    chain_bnd: list[bool] = []

    def walk(v0: int, e0: int) -> list[int]:
        path = [v0]
        v, e = v0, e0
        while True:
            used[e] = True
            a, b = feat[e]
            nxt = b if a == v else a
            path.append(int(nxt))
            if corner[nxt] or nxt == v0:
                return path
            nbrs = e_id[start[nxt] : start[nxt + 1]]
            cand = [int(x) for x in nbrs if not used[x]]
            if not cand:
                return path
            v, e = nxt, cand[0]

    for v0 in np.flatnonzero(corner):
        for e in e_id[start[v0] : start[v0 + 1]]:
            if not used[e]:
                path = walk(int(v0), int(e))
                chains.append(np.array(path, dtype=np.int64))
                closed.append(path[0] == path[-1] and len(path) > 2)
                chain_bnd.append(bool(is_bnd[e]))
    for e in range(len(feat)):
        if not used[e]:
            path = walk(int(feat[e, 0]), e)
            chains.append(np.array(path, dtype=np.int64))
            closed.append(path[0] == path[-1])
            chain_bnd.append(bool(is_bnd[e]))
    face_patch = _patches(faces, f0, f1, (counts == 2) & ~crease)
    # the patches on both sides of every feature edge, looked up by the edge's key
    key = edges[:, 0] * np.int64(nv) + edges[:, 1]

    def side_patches(u: np.ndarray, w: np.ndarray) -> np.ndarray:
        k = np.minimum(u, w) * np.int64(nv) + np.maximum(u, w)
        i = np.searchsorted(key, k)
        sides = np.concatenate([f0[i], f1[i]])
        return np.unique(face_patch[sides[sides >= 0]])

    chain_patches = [side_patches(c[:-1], c[1:]) for c in chains]
    corner_list = np.flatnonzero(corner)
    vf_v, vf_f = faces.ravel(), np.repeat(np.arange(len(faces)), 3)
    order_v = np.argsort(vf_v, kind="stable")
    vstart = np.searchsorted(vf_v[order_v], np.arange(nv + 1))
    corner_patches = [
        np.unique(face_patch[vf_f[order_v[vstart[w] : vstart[w + 1]]]]) for w in corner_list
    ]
    segs = [np.stack([vertices[c[:-1]], vertices[c[1:]]], axis=1) for c in chains]
    seg_chain = [np.full(len(c) - 1, i, dtype=np.int64) for i, c in enumerate(chains)]
    return FeatureLines(
        chains=chains,
        closed=np.array(closed, dtype=bool),
        corners=np.flatnonzero(corner).astype(np.int64),
        n_boundary_edges=int(boundary.sum()),
        n_crease_edges=int(crease.sum()),
        segments=np.concatenate(segs) if segs else np.zeros((0, 2, 3)),
        segment_chain=np.concatenate(seg_chain) if seg_chain else np.zeros(0, dtype=np.int64),
        chain_is_boundary=np.array(chain_bnd, dtype=bool),
        face_patch=face_patch,
        chain_patches=chain_patches,
        corner_patches=corner_patches,
    )


def _patches(faces: np.ndarray, f0: np.ndarray, f1: np.ndarray, join: np.ndarray) -> np.ndarray:
    """Connected components of the faces, two faces joined when an edge in ``join`` links them."""
    from scipy import sparse
    from scipy.sparse import csgraph

    n = len(faces)
    a, b = f0[join], f1[join]
    graph = sparse.coo_matrix((np.ones(len(a)), (a, b)), shape=(n, n))
    _, labels = csgraph.connected_components(graph, directed=False)
    return labels.astype(np.int64)
