"""Creases in the mesh (issue 12, step 3): edges along crease lines and split normals.

* :func:`insert_crease_edges`: every *line edge* (two crease vertices next to each other on a
  crease line, :func:`crease_line_edges`) becomes a mesh edge. Ball pivoting bridges a concave
  edge (a ball rolling in the 90 deg air wedge cannot reach the line: it rests on both faces a
  ball radius away and cuts across), and at a corner it may lay a triangle on the plane of a
  third face over the notch. The missing edge is inserted by edge flips as in a constrained
  Delaunay triangulation (Sloan 1993), in the *unfolded* neighbourhood of the edge: each
  vertex near the line ``a-b`` goes to ``(t, +-e)``, its coordinate along the line and its
  distance from it, signed by the face (of the two around the line) it lies on. Edges whose
  ends lie on different faces and that pass the line between ``a`` and ``b`` cross it; they
  are flipped while their quad is convex until ``a-b`` is an edge (else the flips are undone).
* :func:`flip_straddling_edges`: ball pivoting sometimes joins a particle of one face to one of
  the other face across a crease, beside two crease particles (the quad ``u, a, w, b`` with ``a``
  and ``b`` on the crease took the diagonal ``u-w``). Such a triangle straddles the crease: its
  corners lie on both faces and none on the crease, so it cuts the edge. Flipping the diagonal
  to ``a-b`` puts a mesh edge on the crease line. The flip keeps the outer edges of the quad, so
  the mesh stays manifold, closed and consistently oriented.
* :func:`corner_normals`: per face corner normals that are not averaged across a crease: the
  area-weighted mean of the normals of the faces around the vertex whose normal is within
  ``angle_deg`` of the corner's face (at a crease vertex each side gets its own normal; on a
  smooth surface this is the usual vertex normal).
* :func:`split_crease_vertices`: the same as a vertex list for formats with one normal per
  vertex (PLY): crease vertices are duplicated, one copy per side, faces re-pointed.
"""

from __future__ import annotations

from collections.abc import Container

import numpy as np
from scipy.spatial import cKDTree

from .mesh import face_area_vectors

__all__ = [
    "corner_normals",
    "crease_line_edges",
    "flip_straddling_edges",
    "insert_crease_edges",
    "mesh_as_written",
    "split_crease_vertices",
    "straddling",
]

#: Two non-crease vertices whose normals differ by more than this lie on different faces of
#: a crease [deg].
SIDE_ANGLE_DEG = 30.0
#: Passes of :func:`flip_straddling_edges` (a face flips at most once per pass).
FLIP_PASSES = 3
#: Vertex normals are split at a crease vertex between faces turning by more than this
#: fraction of ``creases.angle_deg``.
SPLIT_ANGLE_FRACTION = 0.75


#: Two crease vertices are a line edge when no crease vertex is nearer to both of them (the
#: relative neighbourhood graph) and they are at most LINE_EDGE_RATIO times the median mesh
#: edge length around them apart.
LINE_EDGE_RATIO = 1.8
#: The unfolded neighbourhood of a line edge of length L: vertices within INSERT_RADIUS * L of
#: its midpoint.
INSERT_RADIUS = 2.5
#: Vertices within SIDE_MIN_OFFSET * L of the line lie on it (no side).
SIDE_MIN_OFFSET = 0.15
#: The faces beside a line edge are found from the vertices between its ends (SIDE_WINDOW_END
#: in from a corner or a line's end) and beyond a line's inner end (up to SIDE_WINDOW).
SIDE_WINDOW = 1.5
SIDE_WINDOW_END = 0.1
#: A vertex whose direction from the line is farther than this from both faces' lies on a
#: third face (at a corner) and is left out of the unfolding [deg].
OFF_FACE_DEG = 60.0
#: An edge passing the line within CROSS_TOLERANCE * L beyond an end still crosses (at a
#: corner, the triangle over the notch lies in a third face's plane: its edge passes the end).
CROSS_TOLERANCE = 0.1
#: Rounds of flips per line edge.
INSERT_ROUNDS = 8
#: A vertex whose signed area with a diagonal is below this fraction of the other vertex's
#: lies on the diagonal (a corner on the diagonal of the lid over a concave corner's notch,
#: a rounding error off it).
ORIENT_TOLERANCE = 1e-3


def _edge_map(
    faces: np.ndarray, subset: np.ndarray | None = None
) -> dict[tuple[int, int], list[int]]:
    """The faces around each edge ``(min, max)`` (of the faces ``subset`` only, when given)."""
    ids = np.arange(len(faces)) if subset is None else np.asarray(subset, dtype=np.int64)
    out: dict[tuple[int, int], list[int]] = {}
    for t, (a, b, c) in zip(ids.tolist(), faces[ids].tolist(), strict=True):
        for u, w in ((a, b), (b, c), (c, a)):
            out.setdefault((min(u, w), max(u, w)), []).append(t)
    return out


def _has_edges(faces: np.ndarray, pairs: np.ndarray, n_vertices: int) -> np.ndarray:
    """Whether each vertex pair ``(m, 2)`` is an edge of ``faces`` (vectorised)."""
    if len(pairs) == 0:
        return np.zeros(0, dtype=bool)
    e = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    p = np.sort(np.asarray(pairs, dtype=np.int64), axis=1)
    n = np.int64(n_vertices)
    return np.isin(p[:, 0] * n + p[:, 1], e[:, 0] * n + e[:, 1])


def straddling(faces: np.ndarray, normals: np.ndarray, crease: np.ndarray) -> np.ndarray:
    """Mask of triangles with no crease corner and two corners whose normals differ by more
    than ``SIDE_ANGLE_DEG`` (corners on both faces of a crease)."""
    if len(faces) == 0:
        return np.zeros(0, dtype=bool)
    n = normals[faces]
    cos = np.cos(np.radians(SIDE_ANGLE_DEG))
    apart = (
        (np.einsum("ij,ij->i", n[:, 0], n[:, 1]) < cos)
        | (np.einsum("ij,ij->i", n[:, 1], n[:, 2]) < cos)
        | (np.einsum("ij,ij->i", n[:, 2], n[:, 0]) < cos)
    )
    return apart & ~crease[faces].any(axis=1)


def _flip_pass(
    faces: np.ndarray,
    normals: np.ndarray,
    crease: np.ndarray,
    candidates: dict[tuple[int, int], list[int]],
    edges: Container[tuple[int, int]],
    cos: float,
) -> int:
    """One pass of :func:`flip_straddling_edges` over ``candidates`` (edge -> its faces, in the
    mesh's edge order), in place; ``edges`` holds every edge that would block a flip to it.
    Returns the number of flips."""
    touched = np.zeros(len(faces), dtype=bool)
    created: set[tuple[int, int]] = set()
    done = 0
    for (u, w), owners in candidates.items():
        if len(owners) != 2 or crease[u] or crease[w] or normals[u] @ normals[w] >= cos:
            continue
        t1, t2 = owners
        if touched[t1] or touched[t2]:
            continue
        f1, f2 = faces[t1].tolist(), faces[t2].tolist()
        a = next(x for x in f1 if x != u and x != w)
        b = next(x for x in f2 if x != u and x != w)
        key = (min(a, b), max(a, b))
        if a == b or not (crease[a] and crease[b]) or key in edges or key in created:
            continue
        i = f1.index(u)
        if f1[(i + 1) % 3] != w:  # name them so that t1 runs u -> w
            u, w = w, u
        # t1 = (u, w, a), t2 = (w, u, b) -> (a, u, b), (b, w, a): same outer edges
        faces[t1] = (a, u, b)
        faces[t2] = (b, w, a)
        touched[t1] = touched[t2] = True
        created.add(key)
        done += 1
    return done


def flip_straddling_edges(
    faces: np.ndarray, normals: np.ndarray, crease: np.ndarray
) -> tuple[np.ndarray, int]:
    """Flip the diagonal ``u-w`` of every quad ``(u, w, a) + (w, u, b)`` where ``a`` and ``b``
    are crease vertices, ``u`` and ``w`` are not and lie on different faces (normals more than
    ``SIDE_ANGLE_DEG`` apart), and the edge ``a-b`` does not exist yet. Returns the faces and
    the number of flips."""
    faces = np.array(faces, dtype=np.int64, copy=True)
    if len(faces) == 0 or not crease.any():
        return faces, 0
    cos = np.cos(np.radians(SIDE_ANGLE_DEG))
    flips = 0
    for _ in range(FLIP_PASSES):
        # only edges between two non-crease vertices on different faces can flip, and only
        # edges between crease vertices can block a flip: the rest of the mesh (nearly all of
        # it) stays out of the Python loop, which sees the same edges in the same order
        he = faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
        lo, hi = he.min(axis=1), he.max(axis=1)
        apart = np.einsum("ij,ij->i", normals[lo], normals[hi]) < cos + 1e-9
        flippable = np.flatnonzero(~crease[lo] & ~crease[hi] & apart)
        candidates = _edge_map(faces, np.unique(flippable // 3))
        on_crease = crease[lo] & crease[hi]
        edges = set(zip(lo[on_crease].tolist(), hi[on_crease].tolist(), strict=True))
        done = _flip_pass(faces, normals, crease, candidates, edges, cos)
        flips += done
        if done == 0:
            break
    return faces, flips


def corner_normals(
    vertices: np.ndarray,
    faces: np.ndarray,
    vertex_normals: np.ndarray,
    crease: np.ndarray,
    angle_deg: float,
) -> np.ndarray:
    """(F, 3, 3) unit normal at each face corner: ``vertex_normals`` away from creases; at a
    crease vertex the area-weighted mean of the normals of the faces around it that turn by at
    most ``angle_deg`` from this face (each side of the crease its own normal)."""
    out = np.asarray(vertex_normals, dtype=np.float64)[faces].copy()
    if len(faces) == 0 or not np.any(crease):
        return out
    area = face_area_vectors(vertices, faces)
    unit = area / np.maximum(np.linalg.norm(area, axis=1, keepdims=True), 1e-300)
    cos = np.cos(np.radians(angle_deg))
    flat = faces.reshape(-1)
    order = np.argsort(flat, kind="stable")
    starts = np.searchsorted(flat[order], np.arange(len(vertices) + 1))
    owner = order // 3
    for k in np.flatnonzero(crease[flat]):
        t, c = divmod(int(k), 3)
        v = flat[k]
        ring = owner[starts[v] : starts[v + 1]]
        keep = ring[unit[ring] @ unit[t] >= cos]
        total = area[keep].sum(axis=0)
        norm = np.linalg.norm(total)
        if norm > 0:
            out[t, c] = total / norm
    return out


def split_crease_vertices(
    vertices: np.ndarray,
    faces: np.ndarray,
    vertex_normals: np.ndarray,
    crease: np.ndarray,
    angle_deg: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One vertex per distinct face-corner normal (:func:`corner_normals`), for formats with one
    normal per vertex (PLY): a crease vertex is duplicated, one copy per side, and faces are
    re-pointed. Returns ``(faces, normals, source)``: output vertex ``i`` is input vertex
    ``source[i]`` (the first ``len(vertices)`` are the input vertices, in order). The copies
    sit at the same place, so the mesh is closed but its topology opens along the creases
    (weld by ``source`` to close it)."""
    cn = corner_normals(vertices, faces, vertex_normals, crease, angle_deg).reshape(-1, 3)
    normals = np.asarray(vertex_normals, dtype=np.float64).copy()
    flat = faces.reshape(-1).copy()
    extra_src: list[int] = []
    extra_n: list[np.ndarray] = []
    first: dict[int, np.ndarray] = {}
    copies: dict[tuple[int, tuple[float, ...]], int] = {}
    for k in np.flatnonzero(crease[flat]):
        v = int(flat[k])
        key = (v, tuple(np.round(cn[k], 5).tolist()))
        if v not in first:
            first[v] = cn[k]
            normals[v] = cn[k]
            copies[key] = v
            continue
        idx = copies.get(key)
        if idx is None:
            idx = len(vertices) + len(extra_src)
            extra_src.append(v)
            extra_n.append(cn[k])
            copies[key] = idx
        flat[k] = idx
    source = np.r_[np.arange(len(vertices)), np.asarray(extra_src, dtype=np.int64)]
    normals = np.vstack([normals, np.asarray(extra_n, dtype=np.float64).reshape(-1, 3)])
    return flat.reshape(-1, 3), normals, source


def crease_line_edges(vertices: np.ndarray, faces: np.ndarray, crease: np.ndarray) -> np.ndarray:
    """Pairs ``(m, 2)`` of crease vertices next to each other on a crease line: the relative
    neighbourhood graph of the crease vertices (no crease vertex nearer to both), pairs at most
    ``LINE_EDGE_RATIO`` times the median length of the mesh edges at either end apart (on a
    line this links consecutive particles; at a corner, each line to the corner particle and
    not to the other lines' particles, which the corner is nearer to)."""
    cv = np.flatnonzero(crease)
    if len(cv) < 2 or len(faces) == 0:
        return np.zeros((0, 2), dtype=np.int64)
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    length = np.linalg.norm(vertices[e[:, 0]] - vertices[e[:, 1]], axis=1)
    # median edge length per vertex (every edge appears at both ends over the faces' cycles)
    ends = np.concatenate([e[:, 0], e[:, 1]])
    lens = np.concatenate([length, length])
    order = np.lexsort((lens, ends))
    ends, lens = ends[order], lens[order]
    start = np.searchsorted(ends, np.arange(len(vertices)))
    stop = np.searchsorted(ends, np.arange(len(vertices)), side="right")
    mid = (start + stop) // 2
    spacing = np.where(stop > start, lens[np.minimum(mid, len(lens) - 1)], np.inf)
    pos = vertices[cv]
    tree = cKDTree(pos)
    reach = LINE_EDGE_RATIO * float(np.median(spacing[cv][np.isfinite(spacing[cv])]))
    pairs = tree.query_pairs(reach, output_type="ndarray")
    if len(pairs) == 0:
        return np.zeros((0, 2), dtype=np.int64)
    d = np.linalg.norm(pos[pairs[:, 0]] - pos[pairs[:, 1]], axis=1)
    limit = LINE_EDGE_RATIO * np.minimum(spacing[cv[pairs[:, 0]]], spacing[cv[pairs[:, 1]]])
    keep = d <= limit
    pairs, d = pairs[keep], d[keep]
    out = []
    for (i, j), dij in zip(pairs.tolist(), d.tolist(), strict=True):
        near = tree.query_ball_point(0.5 * (pos[i] + pos[j]), 0.5 * dij * 1.2)
        blocked = False
        for k in near:
            if k != i and k != j:
                if max(np.linalg.norm(pos[k] - pos[i]), np.linalg.norm(pos[k] - pos[j])) < dij:
                    blocked = True
                    break
        if not blocked:
            out.append((cv[i], cv[j]))
    return np.asarray(out, dtype=np.int64).reshape(-1, 2)


def _orient2d(p: np.ndarray, q: np.ndarray, r: np.ndarray) -> float:
    return float((q[0] - p[0]) * (r[1] - p[1]) - (q[1] - p[1]) * (r[0] - p[0]))


def _unfold(
    vertices: np.ndarray, a: int, b: int, near: np.ndarray, a_end: bool, b_end: bool
) -> dict[int, np.ndarray] | None:
    """2-D coordinates ``(t, s)`` of the vertices ``near`` the line edge ``a-b`` (unit: its
    length): ``t`` along the line from ``a``, ``s`` the distance from the line signed by the
    face the vertex lies on. The two faces are a 2-means of the directions from the line to
    the vertices beside the edge (``t`` between the ends; beyond an end too unless it is a
    corner or the end of its line, ``a_end``/``b_end``: there a third face meets, which the
    line does not lie in). Vertices farther than ``OFF_FACE_DEG`` from both faces' directions
    (on the third face) are left out. None when the vertices do not lie on two faces."""
    p, q = vertices[a], vertices[b]
    length = float(np.linalg.norm(q - p))
    d = (q - p) / length
    rel = vertices[near] - p
    t = (rel @ d) / length
    perp = rel - (t * length)[:, None] * d
    e = np.linalg.norm(perp, axis=1) / length
    off = e > SIDE_MIN_OFFSET
    u = perp / np.maximum(e * length, 1e-300)[:, None]
    lo = SIDE_WINDOW_END if a_end else -SIDE_WINDOW
    hi = 1.0 - SIDE_WINDOW_END if b_end else 1.0 + SIDE_WINDOW
    beside = off & (t > lo) & (t < hi)
    if np.count_nonzero(beside) < 2:
        return None
    w = u[beside]
    c1 = w[0]
    c2 = w[int(np.argmin(w @ c1))]
    for _ in range(10):  # 2-means on the directions about the line
        first = (w @ c1) >= (w @ c2)
        if first.all() or not first.any():
            return None
        c1 = w[first].sum(axis=0)
        c2 = w[~first].sum(axis=0)
        c1 /= np.linalg.norm(c1)
        c2 /= np.linalg.norm(c2)
    if c1 @ c2 > np.cos(np.radians(SIDE_ANGLE_DEG)):
        return None  # one face: no crease here
    cos1, cos2 = u @ c1, u @ c2
    keep = ~off | (np.maximum(cos1, cos2) >= np.cos(np.radians(OFF_FACE_DEG)))
    s = np.where(off, np.where(cos1 >= cos2, 1.0, -1.0) * e, 0.0)
    return {int(v): np.array([t[i], s[i]]) for i, v in enumerate(near) if keep[i]}


def insert_crease_edges(
    vertices: np.ndarray, faces: np.ndarray, crease: np.ndarray
) -> tuple[np.ndarray, int, int]:
    """Make every line edge (:func:`crease_line_edges`) a mesh edge by flips in its unfolded
    neighbourhood (see the module docstring). Flips keep the outer edges of their quads, so the
    mesh stays manifold and consistently oriented. Returns the faces, the number of line edges
    inserted and the number that could not be (left as they were)."""
    faces = np.array(faces, dtype=np.int64, copy=True)
    crease = np.asarray(crease, dtype=bool)
    if len(faces) == 0 or np.count_nonzero(crease) < 2:
        return faces, 0, 0
    wanted = crease_line_edges(vertices, faces, crease)
    missing = wanted[~_has_edges(faces, wanted, len(vertices))].tolist()
    if not missing:
        return faces, 0, 0
    # the flips stay within the unfolded neighbourhoods: only the faces touching them are
    # mapped (a smooth or big mesh's other faces cost nothing)
    tree = cKDTree(vertices)
    length = np.linalg.norm(
        vertices[[b for _, b in missing]] - vertices[[a for a, _ in missing]], axis=1
    )
    mids = 0.5 * (vertices[[a for a, _ in missing]] + vertices[[b for _, b in missing]])
    nears = [
        np.asarray(x, dtype=np.int64) for x in tree.query_ball_point(mids, INSERT_RADIUS * length)
    ]
    local = np.zeros(len(vertices), dtype=bool)
    local[np.concatenate(nears)] = True
    sub = np.flatnonzero(local[faces].any(axis=1))
    edges = _edge_map(faces, sub)
    incident: dict[int, set[int]] = {}
    for t, f in zip(sub.tolist(), faces[sub].tolist(), strict=True):
        for v in f:
            incident.setdefault(v, set()).add(t)
    degree = np.bincount(wanted.reshape(-1), minlength=len(vertices))
    done = failed = 0
    for (a, b), near in zip(missing, nears, strict=True):
        if (min(a, b), max(a, b)) in edges:
            done += 1
            continue
        coords = _unfold(vertices, a, b, near, degree[a] != 2, degree[b] != 2)
        if coords is None:
            failed += 1
            continue
        log: list[tuple[int, list[int], int, list[int]]] = []
        ok = _insert_one(faces, edges, incident, coords, a, b, log)
        if ok:
            done += 1
        else:
            failed += 1
            for t1, f1, t2, f2 in reversed(log):  # undo
                _set_face(faces, edges, incident, t1, f1)
                _set_face(faces, edges, incident, t2, f2)
    return faces, done, failed


def _set_face(
    faces: np.ndarray,
    edges: dict[tuple[int, int], list[int]],
    incident: dict[int, set[int]],
    t: int,
    new: list[int],
) -> None:
    old = faces[t].tolist()
    for u, w in ((old[0], old[1]), (old[1], old[2]), (old[2], old[0])):
        key = (min(u, w), max(u, w))
        edges[key].remove(t)
        if not edges[key]:
            del edges[key]
    for v in old:
        incident[v].discard(t)
    faces[t] = new
    for u, w in ((new[0], new[1]), (new[1], new[2]), (new[2], new[0])):
        edges.setdefault((min(u, w), max(u, w)), []).append(t)
    for v in new:
        incident.setdefault(v, set()).add(t)


def _crosses(coords: dict[int, np.ndarray], u: int, w: int) -> bool:
    """Does the unfolded edge ``u-w`` pass the line edge (from t = 0 to t = 1, s = 0)?"""
    pu, pw = coords[u], coords[w]
    if pu[1] * pw[1] >= 0.0:
        return False
    tc = pu[0] + (pw[0] - pu[0]) * pu[1] / (pu[1] - pw[1])
    return -CROSS_TOLERANCE < tc < 1.0 + CROSS_TOLERANCE


def _insert_one(
    faces: np.ndarray,
    edges: dict[tuple[int, int], list[int]],
    incident: dict[int, set[int]],
    coords: dict[int, np.ndarray],
    a: int,
    b: int,
    log: list,
) -> bool:
    """Flip the edges crossing the line edge ``a-b`` until it is a mesh edge (True)."""
    local = set(coords)
    for _ in range(INSERT_ROUNDS):
        if (min(a, b), max(a, b)) in edges:
            return True
        tris: set[int] = set()
        for v in local:
            tris |= incident.get(v, set())
        crossing = set()
        for t in tris:
            f = faces[t].tolist()
            if not all(v in local for v in f):
                continue
            for u, w in ((f[0], f[1]), (f[1], f[2]), (f[2], f[0])):
                if a in (u, w) or b in (u, w):
                    continue
                if _crosses(coords, u, w):
                    crossing.add((min(u, w), max(u, w)))
        if not crossing:
            return False
        flipped = False
        for key in sorted(crossing):
            owners = edges.get(key)
            if owners is None or len(owners) != 2:
                continue
            u, w = key
            t1, t2 = owners
            f1, f2 = faces[t1].tolist(), faces[t2].tolist()
            x = next(v for v in f1 if v != u and v != w)
            y = next(v for v in f2 if v != u and v != w)
            if x == y or (min(x, y), max(x, y)) in edges:
                continue
            if not all(v in coords for v in (x, y)):
                continue
            pu, pw, px, py = coords[u], coords[w], coords[x], coords[y]
            # the quad u, x, w, y is convex: u and w on both sides of x-y (strictly), x and y
            # not on the same side of u-w (one may lie on it: the corner case)
            if _orient2d(px, py, pu) * _orient2d(px, py, pw) >= 0.0:
                continue
            # (on it within a rounding error: ORIENT_TOLERANCE of the area of the quad)
            ox, oy = _orient2d(pu, pw, px), _orient2d(pu, pw, py)
            tol = ORIENT_TOLERANCE * max(abs(ox), abs(oy))
            if (ox > tol and oy > tol) or (ox < -tol and oy < -tol):
                continue
            i = f1.index(u)
            if f1[(i + 1) % 3] != w:
                u, w = w, u
            # t1 = (u, w, x), t2 = (w, u, y) -> (x, u, y), (y, w, x): same outer edges
            log.append((t1, list(f1), t2, list(f2)))
            _set_face(faces, edges, incident, t1, [x, u, y])
            _set_face(faces, edges, incident, t2, [y, w, x])
            flipped = True
            if (min(a, b), max(a, b)) in edges:
                return True
        if not flipped:
            return False
    return (min(a, b), max(a, b)) in edges


#: Concave crease particles are lifted this many spacings off their line, along their normal
#: (into the air wedge), while ball pivoting runs (:func:`pivot_positions`).
CONCAVE_LIFT = 0.5


def pivot_positions(
    positions: np.ndarray, normals: np.ndarray, crease: np.ndarray, spacing: float = 1.0
) -> np.ndarray:
    """Positions for ball pivoting: concave crease particles lifted by ``CONCAVE_LIFT``
    spacings along their normal (the bisector, into the air). In the air wedge of a concave
    edge a ball resting on both faces cannot reach the line and lays a triangle from face to
    face across it; lifted, the line particle lies inside that ball, so the ball pivots over
    the line particles instead. A crease particle is concave when the particles around it lie
    on its normal's side."""
    out = np.array(positions, dtype=np.float64, copy=True)
    idx = np.flatnonzero(crease)
    if len(idx) == 0:
        return out
    tree = cKDTree(positions)
    near = tree.query_ball_point(positions[idx], 1.6 * spacing)
    for i, nb in zip(idx.tolist(), near, strict=True):
        nb = [j for j in nb if not crease[j]]
        if len(nb) < 2:
            continue
        h = (positions[nb] - positions[i]) @ normals[i]
        if np.mean(h) > 0.1 * spacing:
            out[i] = positions[i] + CONCAVE_LIFT * spacing * normals[i]
    return out


def mesh_as_written(
    vertices: np.ndarray,
    faces: np.ndarray,
    normals: np.ndarray | None,
    crease: np.ndarray | None,
    obj: bool,
    angle_deg: float,
    split_ply: bool,
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None, int]:
    """A mesh as a file holds it, its normals split at crease vertices (issue 12): vertices,
    faces, vertex normals, corner normals (OBJ) and how many vertices were added.

    OBJ (``obj``): one normal per face corner, vertices welded. PLY: with ``split_ply`` each
    crease vertex duplicated, one copy per side with its side's normal (the file's topology
    then opens along the creases); else unchanged (one welded vertex, the averaged normal).
    Normals split between faces turning by more than ``SPLIT_ANGLE_FRACTION x angle_deg``.
    """
    if normals is None or crease is None or not crease.any():
        return vertices, faces, normals, None, 0
    angle = SPLIT_ANGLE_FRACTION * angle_deg
    if obj:
        return vertices, faces, normals, corner_normals(vertices, faces, normals, crease, angle), 0
    if split_ply:
        f, nrm, source = split_crease_vertices(vertices, faces, normals, crease, angle)
        return vertices[source], f, nrm, None, len(source) - len(vertices)
    return vertices, faces, normals, None, 0
