"""Combinatorial and geometric checks of triangle meshes: topology and triangle quality.

Two public functions, both returning plain JSON-ready dicts (Python ints, floats, bools):

- :func:`mesh_topology`: components, boundary edges and loops, non-manifold edges and vertices,
  orientation, Euler characteristic, genus, degenerate faces and unreferenced vertices.
- :func:`triangle_quality`: minimum/maximum angle, radius-ratio aspect and edge-length statistics.

Everything is vectorised NumPy plus :mod:`scipy.sparse.csgraph`; no Python loop runs over faces
or vertices, so a 160k-face scan takes a fraction of a second.

Definitions (the ones used by every number this module reports):

- A *degenerate* face has a repeated vertex index or (near-)zero area: twice its area is at most
  ``1e-12`` times its longest edge squared (its smallest angle is below ~1e-12 rad). Faces with
  a repeated index are left out of the edge, boundary, manifold, orientation and Euler counts
  (they have no proper edges), but they reference their vertices and join them into a
  component, and a mesh with one is not watertight; faces that are merely flat are kept.
- An *edge* is an unordered vertex pair used by at least one face. It is a *boundary* edge if one
  face uses it, manifold if two do and *non-manifold* if three or more do.
- A vertex is *referenced* when a face (degenerate or not) uses it.
- *Components* are connected components of the referenced vertices, two vertices being connected
  when a face uses both (so a bow-tie is one component; :func:`recon.mesh.vertex_components`).
  The Euler characteristic ``chi = V - E + F`` (over the vertices, edges and faces of the faces
  without a repeated index) is additive over these components.
- *Boundary loops* are connected components of the graph of boundary edges
  (:func:`recon.mesh.boundary_components`). On a manifold mesh each is one closed polygon;
  loops that touch at a (non-manifold) vertex count as one. Hole repair walks the *simple*
  loops instead (:func:`recon.mesh.boundary_loops`); both agree on a manifold boundary.
- A *non-manifold vertex* is a vertex whose incident faces form more than one fan, a fan being a
  set of faces around the vertex connected through edges that contain the vertex (a bow-tie
  tip). Faces joined by a non-manifold edge count as connected, so a vertex that only lies on a
  non-manifold edge is reported through ``non_manifold_edges``, not here.
- *Consistently oriented*: every manifold edge is traversed in opposite directions by its two
  faces. *Orientable*: some choice of per-face flips makes it so (a Moebius strip is not).
  Non-manifold edges are ignored for both.
- *Watertight* (the standard definition, as Open3D's ``is_watertight`` and MeshLab use it,
  without their self-intersection test): every edge in exactly two faces (no boundary edge, no
  non-manifold edge) and every vertex's faces forming one fan (no non-manifold vertex). A face
  with a repeated index (``[0, 0, 1]``) uses an edge once more (Open3D: not edge-manifold), so
  a mesh with one is not watertight.
- A *closed component* (:func:`closed_orientation`) is a component whose faces all lie on edges
  in exactly two faces, wound consistently, with no repeated-index face: it bounds a volume.
  It *faces inward* (is inside out) when its signed volume (divergence theorem, the sum of
  ``p0 . (p1 x p2) / 6`` over its faces) is negative.
- *Genus* (sum over components of ``(2 - chi_c) / 2``) is reported only for closed orientable
  manifolds: watertight and orientable; otherwise it is ``None``.
- ``largest_hole_perimeter``: the perimeter of the largest boundary loop (0 when closed), in
  the mesh's units (:func:`recon.mesh.boundary_loop_perimeters`).

References
----------
[Bot10] M. Botsch, L. Kobbelt, M. Pauly, P. Alliez, B. Levy. "Polygon Mesh Processing".
        AK Peters, 2010, ch. 1 (manifolds, Euler-Poincare formula, orientability).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .errors import InputError
from .kernels.mesh_tables import fan_labels, half_edge_order
from .mesh import (
    boundary_components,
    boundary_loop_perimeters,
    count_edge_faces,
    first_faces,
    orientation_flips,
    vertex_components,
)

__all__ = [
    "closed_orientation",
    "count_edge_faces",
    "degenerate_face_mask",
    "mesh_topology",
    "power_of_two_near",
    "topology_and_quality",
    "triangle_quality",
    "validate_mesh",
]

#: A face is degenerate when ``2 * area <= DEGENERATE_AREA_RATIO * longest_edge**2``.
DEGENERATE_AREA_RATIO = 1e-12
#: A closed component faces inward when its signed volume is below ``-VOLUME_SIGN_RATIO`` times
#: the sum of its faces' absolute contributions (a flat, doubly covered one has none).
VOLUME_SIGN_RATIO = 1e-9
#: The keys :func:`closed_orientation` (and ``orientation=True``) adds.
ORIENTATION_KEYS = ("closed_components", "closed_components_inward")
#: The fields of :func:`triangle_quality` (also measured tile by tile by ``recon.tiling``).
TRIANGLE_QUALITY_KEYS = (
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


def validate_mesh(vertices: Any, faces: Any) -> tuple[np.ndarray, np.ndarray]:
    """Check and convert a triangle mesh.

    Parameters
    ----------
    vertices : (V, 3) array_like of float [length]
        Vertex positions; must be finite.
    faces : (F, 3) array_like of int
        Vertex indices per triangle, each in ``[0, V)``. ``F`` may be 0.

    Returns
    -------
    vertices : (V, 3) float64
    faces : (F, 3) int64

    Raises
    ------
    InputError
        Wrong shape or dtype, non-finite coordinates or out-of-range indices (the message gives
        the expected and the received value).
    """
    v = np.asarray(vertices)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3:
        raise InputError(f"vertices must have shape (V, 3), got {v.shape}")
    if f.size == 0:
        f = f.reshape(0, 3)
    if f.ndim != 2 or f.shape[1] != 3:
        raise InputError(f"faces must have shape (F, 3) (triangles), got {f.shape}")
    if f.size and not np.issubdtype(f.dtype, np.integer):
        if not np.all(np.mod(f, 1) == 0):
            raise InputError(f"faces must hold integer vertex indices, got dtype {f.dtype}")
    v = v.astype(np.float64, copy=False)
    f = f.astype(np.int64, copy=False)
    if not np.all(np.isfinite(v)):
        raise InputError(f"vertices contain {int(np.sum(~np.isfinite(v)))} non-finite values")
    if f.size and (f.min() < 0 or f.max() >= len(v)):
        raise InputError(
            f"face indices must lie in [0, {len(v)}), got range [{f.min()}, {f.max()}]"
        )
    return v, f


def _unit_scaled(vertices: np.ndarray) -> tuple[np.ndarray, float]:
    """``vertices`` divided by the power of two nearest their bounding box's largest side,
    and that factor. The measures here are scale-free but for lengths (multiplied back by the
    factor); a power of two changes no bit of them, while squared areas of a mesh 1e-90 across
    underflowed (every face "degenerate") and those of one 1e160 across overflowed."""
    if len(vertices) == 0:
        return vertices, 1.0
    factor = power_of_two_near(float(np.max(vertices.max(axis=0) - vertices.min(axis=0))))
    return (vertices / factor if factor != 1.0 else vertices), factor


def power_of_two_near(extent: float) -> float:
    """The power of two nearest ``extent`` (1 for 0 or a non-finite extent): dividing by it
    brings a mesh to unit size without changing a bit of its coordinates' mantissas.

    Examples
    --------
    >>> power_of_two_near(1e-10), power_of_two_near(3.0), power_of_two_near(0.0)
    (1.1641532182693481e-10, 4.0, 1.0)
    """
    if not (np.isfinite(extent) and extent > 0.0):
        return 1.0
    return float(np.ldexp(1.0, int(np.round(np.log2(extent)))))


def _face_geometry(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Doubled areas ``(F,)`` and edge lengths ``(F, 3)`` (edge k runs corner k -> k+1)."""
    p = vertices[faces]
    e = np.roll(p, -1, axis=1) - p
    lengths = np.linalg.norm(e, axis=2)
    area2 = np.linalg.norm(np.cross(e[:, 0], -e[:, 2]), axis=1)
    return area2, lengths


def _degenerate_mask(
    vertices: np.ndarray,
    faces: np.ndarray,
    geometry: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """(repeated-index mask, degenerate mask) of the faces, both ``(F,)`` bool; ``geometry``:
    their :func:`_face_geometry` when already computed."""
    repeated = (
        (faces[:, 0] == faces[:, 1]) | (faces[:, 1] == faces[:, 2]) | (faces[:, 2] == faces[:, 0])
    )
    area2, lengths = _face_geometry(vertices, faces) if geometry is None else geometry
    longest = lengths.max(axis=1) if len(faces) else np.zeros(0)
    flat = area2 <= DEGENERATE_AREA_RATIO * longest**2
    return repeated, repeated | flat


def degenerate_face_mask(vertices: Any, faces: Any) -> np.ndarray:
    """``(F,)`` bool: the degenerate faces (a repeated vertex index or zero area; the module
    docstring), judged at any scale.

    Examples
    --------
    >>> import numpy as np
    >>> v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0]], float)
    >>> degenerate_face_mask(v, [[0, 1, 2], [0, 1, 3], [0, 0, 2]]).tolist()
    [False, True, True]
    """
    v, f = validate_mesh(vertices, faces)
    return _degenerate_mask(_unit_scaled(v)[0], f)[1]


def _empty_topology(
    n_vertices: int, n_faces: int, degenerate: int, components: int, referenced: int
) -> dict[str, Any]:
    return {
        "n_vertices": n_vertices,
        "n_faces": n_faces,
        "n_edges": 0,
        "components": components,
        "boundary_edges": 0,
        "boundary_loops": 0,
        "non_manifold_edges": 0,
        "non_manifold_vertices": 0,
        "watertight": False,
        "orientable": True,
        "consistently_oriented": True,
        "euler_characteristic": 0,
        "genus": None,
        "degenerate_faces": degenerate,
        "duplicate_faces": 0,
        "unreferenced_vertices": n_vertices - referenced,
        "largest_hole_perimeter": 0.0,
    }


def mesh_topology(vertices: Any, faces: Any) -> dict[str, Any]:
    """Count the topological features and defects of a triangle mesh.

    See the module docstring for the exact definition of every count.

    Parameters
    ----------
    vertices : (V, 3) array_like of float [length]
        Vertex positions.
    faces : (F, 3) array_like of int
        Triangles as vertex indices.

    Returns
    -------
    dict
        ``n_vertices``, ``n_faces``, ``n_edges`` (int): sizes of the input and the number of
        distinct edges. ``components``, ``boundary_edges``, ``boundary_loops``,
        ``non_manifold_edges``, ``non_manifold_vertices`` (int). ``watertight`` (bool): no
        boundary edge, no non-manifold edge, no non-manifold vertex and no face with a repeated
        index. ``orientable``, ``consistently_oriented`` (bool).
        ``euler_characteristic`` (int): ``V - E + F`` over the faces without a repeated index
        and their vertices.
        ``genus`` (int or None): total genus of a closed orientable manifold, ``None`` when the
        mesh is not one. ``degenerate_faces``, ``duplicate_faces`` (same three vertices in any
        order), ``unreferenced_vertices`` (int). ``largest_hole_perimeter`` (float): the
        perimeter of the largest boundary loop, 0 when there is none.

    Raises
    ------
    InputError
        If the arrays do not describe a triangle mesh (see :func:`validate_mesh`).

    Examples
    --------
    >>> import numpy as np
    >>> v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    >>> f = np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]])
    >>> t = mesh_topology(v, f)
    >>> t["watertight"], t["euler_characteristic"], t["genus"]
    (True, 2, 0)
    """
    v, f = validate_mesh(vertices, faces)
    v, factor = _unit_scaled(v)
    return _lengths_times(_mesh_topology(v, f, _degenerate_mask(v, f)), factor)


def _lengths_times(measures: dict[str, Any], factor: float) -> dict[str, Any]:
    """``measures`` with their lengths (``largest_hole_perimeter``, ``edge_length_mean``)
    multiplied by ``factor`` (back from :func:`_unit_scaled`)."""
    if factor != 1.0:
        for key in ("largest_hole_perimeter", "edge_length_mean"):
            if measures.get(key) is not None:
                measures[key] = measures[key] * factor
    return measures


def closed_orientation(vertices: Any, faces: Any) -> dict[str, int]:
    """How many closed components a mesh has, and how many of them face inward (inside out).

    Parameters
    ----------
    vertices : (V, 3) array_like of float [length]
    faces : (F, 3) array_like of int

    Returns
    -------
    dict
        ``closed_components`` (int): components that bound a volume (every edge in exactly two
        faces, wound consistently; the module docstring). ``closed_components_inward`` (int):
        those of them whose signed volume is negative (their faces' winding points inward).

    Examples
    --------
    >>> import numpy as np
    >>> v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    >>> f = np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]])
    >>> closed_orientation(v, f[:, ::-1])
    {'closed_components': 1, 'closed_components_inward': 1}
    """
    v, f = validate_mesh(vertices, faces)
    v, _ = _unit_scaled(v)
    measures = _mesh_topology(v, f, _degenerate_mask(v, f), orientation=True)
    return {key: measures[key] for key in ORIENTATION_KEYS}


def _mesh_topology(
    v: np.ndarray,
    f: np.ndarray,
    masks: tuple[np.ndarray, np.ndarray],
    orientation: bool = False,
) -> dict[str, Any]:
    """:func:`mesh_topology` of a validated mesh, given its :func:`_degenerate_mask`; with
    ``orientation``, also the counts of :func:`closed_orientation`."""
    n_vertices, n_faces = len(v), len(f)
    repeated, degenerate = masks
    n_degenerate = int(degenerate.sum())
    has_repeated = bool(repeated.any())
    f_all = f  # every face references its vertices and joins them (repeated index or not)
    if has_repeated:
        f = f[~repeated]
    if len(f) == 0:
        n_components, comp_of_vertex = vertex_components(f_all, n_vertices)
        empty = _empty_topology(
            n_vertices, n_faces, n_degenerate, n_components, int(np.sum(comp_of_vertex >= 0))
        )
        return {**empty, **dict.fromkeys(ORIENTATION_KEYS, 0)} if orientation else empty

    nf = len(f)
    referenced = np.zeros(n_vertices, dtype=bool)
    referenced[f.ravel()] = True

    # Half-edges: face i, corner k -> edge (f[i, k], f[i, k + 1]).
    he_from = f.ravel()
    he_to = np.roll(f, -1, axis=1).ravel()
    he_face = np.repeat(np.arange(nf), 3)
    lo = np.minimum(he_from, he_to)
    hi = np.maximum(he_from, he_to)
    forward = he_from < he_to  # direction of the half-edge along its undirected edge

    order = half_edge_order(f, n_vertices)  # = np.lexsort((he_face, hi, lo))
    lo_s, hi_s = lo[order], hi[order]
    is_new = np.ones(len(order), dtype=bool)
    is_new[1:] = (lo_s[1:] != lo_s[:-1]) | (hi_s[1:] != hi_s[:-1])
    edge_id_sorted = np.cumsum(is_new) - 1
    n_edges = int(edge_id_sorted[-1]) + 1
    edge_count = np.bincount(edge_id_sorted, minlength=n_edges)
    edge_lo, edge_hi = lo_s[is_new], hi_s[is_new]

    boundary = edge_count == 1
    n_boundary = int(boundary.sum())
    n_non_manifold_edges = int((edge_count > 2).sum())

    # Consecutive half-edges on the same edge (after sorting) are linked pairs.
    same = ~is_new[1:]
    a, b = order[:-1][same], order[1:][same]  # half-edge ids of each linked pair
    pair_edge = edge_id_sorted[1:][same]

    # Orientation: on manifold edges the two faces must run the edge in opposite directions.
    manifold_pair = edge_count[pair_edge] == 2
    flip_parity = (forward[a] == forward[b])[manifold_pair]  # True: the pair disagrees
    consistent = not bool(flip_parity.any())
    open_face = None
    if orientation:  # faces that keep their component from bounding a volume
        open_face = np.zeros(nf, dtype=bool)
        open_face[order[edge_count[edge_id_sorted] != 2] // 3] = True  # half-edge h: face h//3
        open_face[a[manifold_pair][flip_parity] // 3] = True
    orientable = consistent or not orientation_flips(f, order=order, consistent=False)[1].any()
    # the half-edge arrays are done with: free them before the component and fan passes
    # (at a million faces each is 24 MB and they held ~0.4 GB at the report's peak)
    del he_to, he_face, lo, hi, forward, lo_s, hi_s, is_new, edge_id_sorted
    del same, a, b, pair_edge, manifold_pair, flip_parity

    # Components over vertices (faces link their three vertices).
    n_components, comp_of_vertex = vertex_components(f_all, n_vertices)
    ref_idx = np.flatnonzero(referenced)  # the vertices of the faces without a repeated index
    comp_compact = comp_of_vertex[ref_idx]

    # Boundary loops: connected components of the boundary-edge graph (recon.mesh).
    n_loops = boundary_components(np.stack([edge_lo, edge_hi], axis=1), edge_count, n_vertices)

    # Non-manifold vertices: count fans of corners around each vertex (recon.mesh).
    fan = fan_labels(f, order)  # vertex_fans(f).ravel(): 0 .. n_fans - 1, each at one vertex
    del order
    vertex_of_fan = np.empty(int(fan.max()) + 1, dtype=np.int64)
    vertex_of_fan[fan] = f.ravel()
    fans_per_vertex = np.bincount(vertex_of_fan, minlength=n_vertices)
    n_non_manifold_vertices = int((fans_per_vertex > 1).sum())

    chi = int(len(ref_idx) - n_edges + nf)
    watertight = (
        n_boundary == 0
        and n_non_manifold_edges == 0
        and n_non_manifold_vertices == 0
        and not has_repeated
    )
    genus: int | None = None
    if watertight and orientable:
        v_c = np.bincount(comp_compact, minlength=n_components)
        e_c = np.bincount(comp_of_vertex[edge_lo], minlength=n_components)
        f_c = np.bincount(comp_of_vertex[f[:, 0]], minlength=n_components)
        genus = int(np.sum((2 - (v_c - e_c + f_c)) // 2))

    perimeters = boundary_loop_perimeters(v, f) if n_boundary else np.zeros(0)
    duplicates = len(f) - len(first_faces(f, n_vertices))
    n_referenced = len(ref_idx) if not has_repeated else int(np.sum(comp_of_vertex >= 0))

    measures = {
        "n_vertices": n_vertices,
        "n_faces": n_faces,
        "n_edges": n_edges,
        "components": n_components,
        "boundary_edges": n_boundary,
        "boundary_loops": n_loops,
        "non_manifold_edges": n_non_manifold_edges,
        "non_manifold_vertices": n_non_manifold_vertices,
        "watertight": bool(watertight),
        "orientable": bool(orientable),
        "consistently_oriented": bool(consistent),
        "euler_characteristic": chi,
        "genus": genus,
        "degenerate_faces": n_degenerate,
        "duplicate_faces": int(duplicates),
        "unreferenced_vertices": int(n_vertices - n_referenced),
        "largest_hole_perimeter": float(perimeters[0]) if len(perimeters) else 0.0,
    }
    if open_face is not None:
        not_closed = comp_of_vertex[f[open_face, 0]]
        if has_repeated:
            not_closed = np.concatenate([not_closed, comp_of_vertex[f_all[repeated, 0]]])
        measures.update(_closed_orientation(v, f, comp_of_vertex, n_components, not_closed))
    return measures


def _closed_orientation(
    v: np.ndarray,
    f: np.ndarray,
    comp_of_vertex: np.ndarray,
    n_components: int,
    not_closed: np.ndarray,
) -> dict[str, int]:
    """The counts of :func:`closed_orientation`: ``f`` the faces without a repeated index,
    ``comp_of_vertex`` the vertices' components (-1: unreferenced), ``not_closed`` the
    components (with repeats) that do not bound a volume."""
    closed = np.ones(n_components, dtype=bool)
    closed[not_closed] = False
    comp_of_face = comp_of_vertex[f[:, 0]]
    closed &= np.bincount(comp_of_face, minlength=n_components) > 0
    keep = closed[comp_of_face]
    f, comp_of_face = f[keep], comp_of_face[keep]
    # about each component's centroid: the volume does not depend on the origin, its rounding does
    used = comp_of_vertex >= 0
    label = comp_of_vertex[used]
    count = np.bincount(label, minlength=n_components).astype(np.float64)
    centre = (
        np.stack(
            [np.bincount(label, weights=v[used, k], minlength=n_components) for k in range(3)], 1
        )
        / np.maximum(count, 1.0)[:, None]
    )
    c = centre[comp_of_face]
    p0, p1, p2 = (v[f[:, k]] - c for k in range(3))
    six_volume = np.einsum("ij,ij->i", p0, np.cross(p1, p2))
    signed = np.bincount(comp_of_face, weights=six_volume, minlength=n_components)
    size = np.bincount(comp_of_face, weights=np.abs(six_volume), minlength=n_components)
    inward = closed & (signed < -VOLUME_SIGN_RATIO * size)
    return {
        "closed_components": int(closed.sum()),
        "closed_components_inward": int(inward.sum()),
    }


def topology_and_quality(
    vertices: Any, faces: Any, *, orientation: bool = False
) -> tuple[dict[str, Any], dict[str, Any]]:
    """``(mesh_topology(vertices, faces), triangle_quality(vertices, faces))``, validating the
    mesh and measuring its faces' areas and edge lengths once for both; with ``orientation``,
    the topology also holds the counts of :func:`closed_orientation`.

    Examples
    --------
    >>> import numpy as np
    >>> v = np.array([[0, 0, 0], [1, 0, 0], [0.5, 3**0.5 / 2, 0]])
    >>> topo, quality = topology_and_quality(v, [[0, 1, 2]])
    >>> topo["boundary_loops"], round(quality["min_angle_min_deg"], 6)
    (1, 60.0)
    """
    v, f = validate_mesh(vertices, faces)
    v, factor = _unit_scaled(v)
    geometry = _face_geometry(v, f)
    masks = _degenerate_mask(v, f, geometry)
    return (
        _lengths_times(_mesh_topology(v, f, masks, orientation), factor),
        _lengths_times(_triangle_quality(v, f, geometry, masks[1]), factor),
    )


def triangle_quality(vertices: Any, faces: Any) -> dict[str, Any]:
    """Angle, aspect-ratio and edge-length statistics of the non-degenerate triangles.

    Parameters
    ----------
    vertices : (V, 3) array_like of float [length]
        Vertex positions.
    faces : (F, 3) array_like of int
        Triangles as vertex indices.

    Returns
    -------
    dict
        ``n_measured`` (int): non-degenerate faces measured (degenerate ones, see
        :func:`mesh_topology`, are skipped; all statistics are ``None`` when none is left).
        ``min_angle_mean_deg``, ``min_angle_p5_deg``, ``min_angle_min_deg`` [deg]: statistics
        of each triangle's smallest angle (60 for an equilateral triangle).
        ``max_angle_max_deg`` [deg]: the largest angle anywhere.
        ``aspect_ratio_mean``, ``aspect_ratio_p95``, ``aspect_ratio_max``: radius ratio
        ``R / (2 r)`` (circumradius over twice the inradius; 1 for an equilateral triangle,
        growing without bound as it degenerates).
        ``edge_length_mean`` [length], ``edge_length_cv``: mean edge length and its
        coefficient of variation (std / mean) over all face edges.

    Examples
    --------
    >>> import numpy as np
    >>> v = np.array([[0, 0, 0], [1, 0, 0], [0.5, 3**0.5 / 2, 0]])
    >>> q = triangle_quality(v, [[0, 1, 2]])
    >>> round(q["min_angle_mean_deg"], 6), round(q["aspect_ratio_max"], 6)
    (60.0, 1.0)
    """
    v, f = validate_mesh(vertices, faces)
    v, factor = _unit_scaled(v)
    geometry = _face_geometry(v, f)
    return _lengths_times(
        _triangle_quality(v, f, geometry, _degenerate_mask(v, f, geometry)[1]), factor
    )


def _triangle_quality(
    v: np.ndarray,
    f: np.ndarray,
    geometry: tuple[np.ndarray, np.ndarray],
    degenerate: np.ndarray,
) -> dict[str, Any]:
    """:func:`triangle_quality` of a validated mesh, given its :func:`_face_geometry` and
    degenerate mask (the measured faces' geometry is their rows of it)."""
    keep = ~degenerate
    f = f[keep]
    keys = TRIANGLE_QUALITY_KEYS
    if len(f) == 0:
        return {"n_measured": 0, **dict.fromkeys(keys)}

    area2, lengths = geometry[0][keep], geometry[1][keep]
    # Angle at corner k lies between edges k (k -> k+1) and k-1 reversed (k -> k-1).
    p = v[f]
    e_next = np.roll(p, -1, axis=1) - p
    e_prev = np.roll(p, 1, axis=1) - p
    cross = np.linalg.norm(np.cross(e_next, e_prev), axis=2)
    dot = np.einsum("fkd,fkd->fk", e_next, e_prev)
    angles = np.degrees(np.arctan2(cross, dot))
    min_angle = angles.min(axis=1)

    # R = abc / (4 A), r = 2 A / (a + b + c)  =>  R / (2 r) = abc (a + b + c) / (4 (2A)^2).
    ratio = np.prod(lengths, axis=1) * lengths.sum(axis=1) / (4.0 * area2**2)
    edge_mean = float(lengths.mean())
    return {
        "n_measured": len(f),
        "min_angle_mean_deg": float(min_angle.mean()),
        "min_angle_p5_deg": float(np.percentile(min_angle, 5)),
        "min_angle_min_deg": float(min_angle.min()),
        "max_angle_max_deg": float(angles.max()),
        "aspect_ratio_mean": float(ratio.mean()),
        "aspect_ratio_p95": float(np.percentile(ratio, 95)),
        "aspect_ratio_max": float(ratio.max()),
        "edge_length_mean": edge_mean,
        "edge_length_cv": float(lengths.std() / edge_mean) if edge_mean > 0 else 0.0,
    }
