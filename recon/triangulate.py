"""Triangulate the final particles into a manifold, consistently oriented mesh.

Two methods:

* ``ball_pivoting`` (default): Open3D's ball-pivoting algorithm [B99] over the particles with
  radii of about 0.7-2 r0. On the near-uniform particle sheet it is manifold and fast (DESIGN
  §4.7: 0 non-manifold edges on the bunny); the small holes it leaves are filled afterwards when
  their perimeter is below ``pi * max_hole``. Larger loops are real boundaries and stay.
* ``circumsphere``: the test of S&T92 §8: a triangle (i, j, k) of mutual neighbours is kept when
  the smallest sphere through its corners contains no other particle. Kept for comparison; it
  cannot be made manifold on co-circular quads (both diagonals pass).

Lengths are in units of r0 (the particles' rest spacing).

References
----------
[ST92] Szeliski & Tonnesen 1992, §8 "Triangulating the particles".
[B99]  F. Bernardini, J. Mittleman, H. Rushmeier, C. Silva, G. Taubin. "The ball-pivoting
       algorithm for surface reconstruction". IEEE TVCG 5(4), 1999.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np
import open3d as o3d
from scipy.spatial import cKDTree

from .config import TriangulationConfig
from .crease_mesh import flip_straddling_edges, insert_crease_edges, pivot_positions
from .holes import fill_small_holes, join_closed_parts, loft_nearest_loops, zip_supported_loops
from .kernels.circumsphere import circumsphere_kernel
from .kernels.mesh_tables import circumradii
from .mesh import (
    boundary_loops,
    capped_volume,
    drop_unreferenced,
    face_components,
    first_faces,
    handle_bridges,
    handle_count,
    opposed_faces,
    overlapping_faces,
    ranked_fans,
    unique_edges,
)
from .neighbors import build_neighbor_list
from .particle_signs import consistent_normals
from .thin_sheets import thicken_sheets
from .winding import (
    MIN_COMPONENT_FACES,
    consistently_wound,
    orient_consistently,
    orient_faces,
)

log = logging.getLogger(__name__)


@dataclass
class TriangulationResult:
    vertices: np.ndarray  # (V, 3) float64 [r0]
    faces: np.ndarray  # (F, 3) int64
    normals: np.ndarray  # (V, 3) float64 unit vertex normals
    stats: dict = field(default_factory=dict)
    crease: np.ndarray | None = None  # (V,) bool: vertices on a crease line or corner


#: Loops whose interior holds data are triangulation gaps: closed up to this many times the
#: ``max_hole`` perimeter.
COVERED_HOLE_FACTOR = 3.0
#: At a thin edge (where opposed faces closed it), two boundary loops are joined by a strip
#: when each lies within this many ball diameters (of the largest ball, ``2 max(cfg.radii)``;
#: local spacings) of the other in median, and a one-sided sheet that near the body joins it
#: (:func:`_sheets_thickened`): the widest gap a ball-pivoted face spans, had the normals
#: agreed. (Ball pivoting's faces across such an edge are the ones the strip replaces.)
EDGE_REACH = 1.0
#: ... tried after strips between loops within this median distance [local spacings].
LOFT_GAP = 2.0
#: Elsewhere a one-sided open sheet this close [r0] to the closed main body continues its edge
#: (:func:`_sheets_thickened`) ...
SHEET_NECK_GAP = 1.0
#: ... and is made a closed body this far [r0] either side of it.
SHEET_HALF_THICKNESS = 0.15
#: A closed part this close [r0] to the closed body joins it (the largest ball's diameter).
PART_NECK_GAP = 4.0
#: Debris removal: components with fewer faces than ``MIN_COMPONENT_FACES``
#: (:mod:`recon.winding`) and than this fraction of the largest component are dropped.
MIN_COMPONENT_FRACTION = 0.01
#: Hole-filling passes: a fill can meet an edge that already exists elsewhere; the repair after
#: it can open a new small loop, which the second pass closes.
FILL_PASSES = 4
#: Triangles kept per particle by the circumsphere test (a hexagonal sheet has ~6).
CIRCUMSPHERE_CAPACITY = 64
#: Rounds of dropping faces on over-shared edges (each round settles the worst edges).
NON_MANIFOLD_EDGE_ROUNDS = 10
#: Rounds of dropping extra fans at bow-tie vertices (``repair_non_manifold(split=False)``).
NON_MANIFOLD_VERTEX_ROUNDS = 5
#: A bow-tie vertex is split into one copy per fan; each extra copy moves this fraction of the
#: way to its fan's centroid, so the copies do not coincide (coincident vertices of different
#: faces read as a self-intersection to Open3D's ``is_watertight``).
SPLIT_SHIFT = 0.3


def triangulate_particles(
    positions: np.ndarray,
    normals: np.ndarray,
    cfg: TriangulationConfig,
    max_hole: float,
    is_covered: Callable[..., np.ndarray] | None = None,
    local_spacing: np.ndarray | None = None,
    crease: np.ndarray | None = None,
    resign: bool = True,
    join_sheets: bool = True,
) -> TriangulationResult:
    """Mesh the particles (normalised units, r0 = 1) with a topology guarantee.

    The result has no non-manifold edge and no non-manifold vertex, every component is
    consistently oriented (closed ones outward), and every gap of the triangulation (a hole
    narrower than ``max_hole`` whose inside holds data) is closed. Real boundaries stay open.

    Parameters
    ----------
    positions : (n, 3) float64 [r0]
    normals : (n, 3) float64, unit, consistently oriented
    cfg : TriangulationConfig
    max_hole : float [r0]
        Diameter of the largest hole to fill (loops with perimeter <= pi * max_hole), and the
        width of the widest seam to zip.
    is_covered : callable, optional
        ``points (m, 3) -> (m,) bool``: does data lie at these points? Loops over data are
        closed up to ``COVERED_HOLE_FACTOR`` times the ``max_hole`` perimeter, and narrow seams
        over data however long. With ``local_spacing`` it is called as
        ``is_covered(points, spacing)`` with the local spacing [r0] at each point. For the
        points across a seam, judged together, it is called with the keyword ``across=True``
        as well, which it must accept (:func:`recon.fitting.pipeline.covered`).
    local_spacing : (n,) float64 [r0], optional
        Each particle's rest spacing (None: 1 everywhere, the uniform r0). Ball-pivoting radii
        (:func:`ball_radii`; a face is kept when its circumradius fits the largest radius times
        the largest spacing of its corners), hole perimeters, seam widths and the coverage
        test scale with it.
    crease : (n,) bool, optional
        Crease particles (issue 12): a quad whose diagonal joins the two faces of a crease beside
        two crease particles takes the diagonal along the crease
        (:func:`recon.crease_mesh.flip_straddling_edges`); the result's ``crease`` marks them.
    resign : bool
        Re-sign the normals over the particle sheet first (:func:`consistent_normals`), as
        normals from a point cloud need. False when their signs are known (taken from an
        oriented mesh, as ``remesh`` does).
    join_sheets : bool
        Join two open sheets that are a thin part's two faces along their rims
        (:func:`_rims_lofted`). False for a tile (its cut leaves such rims) and a remesh.
    """
    positions = np.ascontiguousarray(positions, dtype=np.float64)
    normals = np.ascontiguousarray(normals, dtype=np.float64)
    scale = None
    if local_spacing is not None:
        scale = np.asarray(local_spacing, dtype=np.float64).reshape(-1)
        if scale.shape != (len(positions),) or not np.all(np.isfinite(scale) & (scale > 0)):
            raise ValueError(
                f"local_spacing must hold {len(positions)} positive finite values, "
                f"got shape {scale.shape}"
            )
    if len(positions) < 3:
        return TriangulationResult(
            positions, np.zeros((0, 3), dtype=np.int64), normals, {"method": cfg.method}
        )
    if cfg.method == "ball_pivoting":
        if resign:
            normals = consistent_normals(positions, normals)
        pivot = positions if crease is None else pivot_positions(positions, normals, crease)
        faces = ball_pivoting(pivot, normals, ball_radii(cfg.radii, scale))
        if scale is not None:
            # a face must fit the largest ball of its region (at its sparsest corner)
            fits = circumradius(positions, faces) <= max(cfg.radii) * scale[faces].max(axis=1)
            faces = faces[fits]
    else:
        faces = circumsphere_triangles(positions, normals, radius=max(cfg.radii))
    stats: dict = {"method": cfg.method, "faces_raw": int(len(faces))}
    args = (cfg, max_hole, is_covered, scale, crease)
    result = _repair(positions, normals, faces, dict(stats), *args)
    handles = _count(result)[2]
    if handles == 0 and not _open_along_opposed(result):
        result = _rims_lofted(result, positions, args) if join_sheets else result
        return _parts_joined(result, resign)  # no handle, no thin edge left open in places
    # A tunnel between the two faces of a thin part (a bridge of faces joining opposed sheets
    # away from the part's rim) is a handle the surface does not have: drop the bridges that
    # carry one (:func:`recon.mesh.handle_bridges`, smallest first) and repair again; hole
    # filling caps their ends on each face.
    bridges = handle_bridges(result.normals, result.faces) if handles else None
    if bridges is not None and bridges.any():
        here = _spacing_at(scale, positions, result.vertices)
        alt = _repair(
            result.vertices,
            result.normals,
            result.faces[~bridges],
            dict(result.stats),
            cfg,
            max_hole,
            is_covered,
            here,
            result.crease,
        )
        alt.stats["holes_filled"] += result.stats["holes_filled"]
        alt.stats["vertices_split"] += result.stats["vertices_split"]
        if _better(alt, result):
            log.debug("dropped %d faces of tunnels between opposed sheets", int(bridges.sum()))
            result = alt
    opposed = opposed_faces(normals, faces)
    if opposed.any():
        # Opposite sheets never merge: a face whose corners face more than 90 deg apart can
        # bridge the two faces of a thin part into a handle (a 30 deg knife edge whose
        # particles near the tip carry the other face's normal). Without all of those faces
        # the mesh is kept when it has no more handles, components or boundary loops and
        # fewer of one; where they closed a real rim (a blade's edge thinner than a spacing)
        # dropping them tears it: kept.
        alt = _repair(positions, normals, faces[~opposed], dict(stats), *args)
        if _better(alt, result):
            log.debug("dropped %d faces joining opposed sheets", int(opposed.sum()))
            result = alt
        else:
            # the opposed band closed the edge of a part thinner than a spacing, and carried
            # the handles or left it open in places: close the edge again with a plain strip
            # between the two faces' rims, judged with the edge's one-sided sheets made part of
            # the body (the two steps mend one edge: alone, the strip can trade the handles
            # for the rim the sheets continue)
            # for the edge's sheets, the strip first between the nearest rims only: a wider
            # strip can join rims that are not the edge's two faces (knife, seed 7)
            reach = EDGE_REACH * 2.0 * max(cfg.radii)
            for gap in (LOFT_GAP, reach):
                strip = _relofted(alt, positions, gap, args)
                thick = None if strip is None else _sheets_thickened(strip, reach, open_body=True)
                zipped = (
                    None if thick is None else _rest_zipped(thick, strip, positions, reach, args)
                )
                good = [m for m in (zipped, thick, strip) if m is not None and _better(m, result)]
                if good:
                    log.debug("re-closed a thin edge without its %d opposed faces", opposed.sum())
                    result = good[0]
                    break
    thick = _sheets_thickened(result)
    if thick is not None and _better(thick, result):
        result = thick
    result = _rims_lofted(result, positions, args) if join_sheets else result
    return _parts_joined(result, resign)


def _parts_joined(result: TriangulationResult, cloud: bool = True) -> TriangulationResult:
    """``result`` with the closed parts beside its body joined to it, when that has fewer
    components (:func:`recon.holes.join_closed_parts`: a sparse thin part meshed on its own);
    else ``result``. Only for a point cloud's particles (``cloud``): a remeshed input's
    components are its own. A join wound consistently as it stands keeps both parts'
    windings; one that is not is oriented again (:func:`recon.winding.orient_consistently`)."""
    joined = join_closed_parts(result.vertices, result.faces, PART_NECK_GAP) if cloud else None
    if joined is None:
        return result
    if not consistently_wound(joined, len(result.vertices)):
        joined = orient_consistently(result.vertices, result.normals, joined)
    # else the parts keep their windings, the tubes wound as both (neck_between): each part
    # was wound outward on its own, by its volume where its normals' vote disagreed (a sparse
    # tail's normals can face in); one vote over the joined body would turn it against it
    alt = replace(result, faces=joined)
    return alt if _better(alt, result) else result


def _sheets_thickened(
    result: TriangulationResult, reach: float = SHEET_NECK_GAP, open_body: bool = False
) -> TriangulationResult | None:
    """``result`` with each one-sided open sheet within ``reach`` [r0] of the main body made a
    closed part ``SHEET_HALF_THICKNESS`` either side of it and joined to the body
    (:func:`recon.thin_sheets.thicken_sheets`: the merged faces of a part thinner than a
    spacing, such as a knife's edge), then consistently oriented; None when none is.
    ``open_body``: the body may have boundary loops (where a thin edge's opposed band was
    dropped and its rims joined, a loop left beside the sheets is the edge's rest); else only
    a closed body takes sheets (an open scan's separate patch is one-sided data).
    """
    v, f = result.vertices, result.faces
    thick = thicken_sheets(v, result.normals, f, reach, SHEET_HALF_THICKNESS, open_body)
    if thick is None:
        return None
    vertices_all, normals_all, faces_all = thick
    crease = result.crease
    if crease is not None:
        crease = np.concatenate([crease, np.zeros(len(vertices_all) - len(crease), dtype=bool)])
    vertices_all, normals_all, faces_all, crease = drop_unreferenced(
        vertices_all, normals_all, faces_all, crease
    )
    faces_all = orient_consistently(vertices_all, normals_all, faces_all)
    if open_body:
        # an open component takes the winding its normals vote for, which on a thin part can
        # be the inside: this one is a closed part's surface open only at its mended edge
        _, label = face_components(faces_all, len(vertices_all))
        body = label == np.argmax(np.bincount(label))
        if capped_volume(vertices_all, faces_all[body]) < 0:
            faces_all[body] = faces_all[body][:, ::-1]
    log.debug("thickened one-sided sheets at a thin edge: %d -> %d faces", len(f), len(faces_all))
    return TriangulationResult(vertices_all, faces_all, normals_all, dict(result.stats), crease)


def _rest_zipped(
    thick: TriangulationResult,
    strip: TriangulationResult,
    positions: np.ndarray,
    reach: float,
    args: tuple,
) -> TriangulationResult | None:
    """``thick`` (``strip`` with the edge's one-sided sheets joined to its open body) with
    the body's loops within ``reach`` [r0] of a joined sheet zipped where data lies
    across them all round (:func:`recon.holes.zip_supported_loops`): the rest of the edge,
    folded round the tip's merged faces; None when none is."""
    is_covered, scale = args[2], args[3]
    v, f = thick.vertices, thick.faces
    joined = cKDTree(strip.vertices).query(v)[0] > 0  # the sheets' thick copies
    if is_covered is None or not joined.any():
        return None
    sheets = cKDTree(v[joined])
    _, label = face_components(f, len(v))
    body = f[label == np.argmax(np.bincount(label))]
    loops = [loop for loop in boundary_loops(body) if sheets.query(v[loop])[0].min() <= reach]
    faces = zip_supported_loops(v, f, loops, is_covered, _spacing_at(scale, positions, v))
    return None if len(faces) == len(f) else replace(thick, faces=faces)


def _open_along_opposed(result: TriangulationResult) -> bool:
    """Does a boundary loop of ``result`` touch a face whose corners face more than 90 deg
    apart (:func:`recon.mesh.opposed_faces`)? Such a loop is where the band of opposed faces
    across the edge of a part thinner than a spacing left the edge open; a real boundary (a
    scan's rim) has one sheet's normals round it."""
    loops = boundary_loops(result.faces)
    if not loops:
        return False
    on_band = np.zeros(len(result.vertices), dtype=bool)
    on_band[result.faces[opposed_faces(result.normals, result.faces)].reshape(-1)] = True
    return any(on_band[loop].any() for loop in loops)


def _rims_lofted(
    result: TriangulationResult, positions: np.ndarray, args: tuple
) -> TriangulationResult:
    """``result`` with two open sheets joined by a strip where they are the two faces of one
    thin part, if that is :func:`_better`. A part's faces mesh as two sheets when no particle
    reaches round its edge (a blade thinner than a spacing): their rims are mutually nearest
    loops, facing opposite ways, each behind the other (:func:`recon.holes.loft_nearest_loops`
    with the normals). Gaps up to ``max_hole``: the strip closes the hole between the rims."""
    c, b, _ = _count(result)
    if c < 2 or b < 2:
        return result
    cfg, max_hole = args[:2]
    reach = EDGE_REACH * 2.0 * max(cfg.radii)
    gaps = sorted({g for g in (LOFT_GAP, reach, max_hole) if g <= max_hole})
    for gap in gaps:
        strip = _relofted(result, positions, gap, args, opposed=True)
        if strip is not None and _better(strip, result):
            log.debug("joined the rims of two opposed sheets within %.1f spacings", gap)
            return strip
    return result


def _relofted(
    alt: TriangulationResult,
    positions: np.ndarray,
    reach: float,
    args: tuple,
    opposed: bool = False,
) -> TriangulationResult | None:
    """``alt`` with its pairs of boundary loops within ``reach`` (local spacings) of each
    other joined by strips (:func:`recon.holes.loft_nearest_loops`; with ``opposed`` only a
    thin part's two rims, facing apart, each behind the other) and repaired; None without."""
    scale = args[3]
    local = _spacing_at(scale, positions, alt.vertices)
    normals = alt.normals if opposed else None
    faces = loft_nearest_loops(alt.vertices, alt.faces, reach, local, normals)
    if len(faces) == len(alt.faces):
        return None
    return _repair(alt.vertices, alt.normals, faces, dict(alt.stats), *args[:3], local, alt.crease)


def _better(alt: TriangulationResult, result: TriangulationResult) -> bool:
    """Has ``alt`` no more components, boundary loops or handles than ``result``, and fewer of
    one? Handles of a manifold mesh: ``(2 c - b - chi) / 2`` (c components, b loops)."""
    a, r = _count(alt), _count(result)
    return all(x <= y for x, y in zip(a, r, strict=True)) and a != r


def _count(result: TriangulationResult) -> tuple[int, int, int]:
    """Components, boundary loops and handles of a repaired mesh
    (:func:`recon.mesh.handle_count`)."""
    return handle_count(result.faces, len(result.vertices))


def _repair(
    positions: np.ndarray,
    normals: np.ndarray,
    faces: np.ndarray,
    stats: dict,
    cfg: TriangulationConfig,
    max_hole: float,
    is_covered: Callable[..., np.ndarray] | None,
    scale: np.ndarray | None,
    crease: np.ndarray | None,
) -> TriangulationResult:
    """Ball-pivoted (or circumsphere) faces to the guaranteed mesh: oriented, manifold, gaps
    closed, debris removed, crease edges inserted (:func:`triangulate_particles`)."""
    faces = orient_faces(positions, normals, faces)
    faces = drop_overlaps(positions, faces)
    vertices, vnormals, faces = repair_non_manifold(positions, normals, faces)
    oriented = orient_consistently(vertices, vnormals, faces)
    # a repaired mesh that orienting dropped no face from is manifold and oriented: repairing
    # or orienting it again changes nothing (each pass rescans the whole mesh)
    clean, faces = len(oriented) == len(faces), oriented
    stats["faces_manifold"] = int(len(faces))
    stats["holes_filled"] = 0
    trees: dict = {}  # the particles' k-d tree for _extend, built once
    for _ in range(FILL_PASSES if cfg.fill_holes else 0):
        # a fill can meet an edge that already exists elsewhere; repair, then fill what opened
        vertices, vnormals, faces, n_filled = fill_small_holes(
            vertices,
            vnormals,
            faces,
            np.pi * max_hole,
            is_covered,
            COVERED_HOLE_FACTOR * np.pi * max_hole,
            scale=_extend(scale, positions, vertices, trees),
        )
        stats["holes_filled"] += n_filled
        if n_filled == 0 and clean:
            break  # nothing filled: the faces are the clean ones of the last pass
        vertices, vnormals, faces = repair_non_manifold(vertices, vnormals, faces)
        oriented = orient_consistently(vertices, vnormals, faces)
        clean, faces = len(oriented) == len(faces), oriented
        if n_filled == 0:
            break
    faces, n_small = remove_small_components(
        faces, len(vertices), MIN_COMPONENT_FRACTION, MIN_COMPONENT_FACES
    )
    stats["small_components_removed"] = n_small
    stats["vertices_split"] = int(len(vertices) - len(positions))
    on_crease = None
    if crease is not None:  # crease hook: edges along the crease lines (split copies are not)
        on_crease = np.zeros(len(vertices), dtype=bool)
        on_crease[: len(crease)] = np.asarray(crease, dtype=bool)
        faces, n_in, n_left = insert_crease_edges(vertices, faces, on_crease)
        faces, n_flips = flip_straddling_edges(faces, vnormals, on_crease)
        log.debug("crease: %d line edges inserted (%d not), %d flips", n_in, n_left, n_flips)
    unchanged = clean and np.array_equal(faces, oriented)  # no debris or crease edit
    vertices, vnormals, faces, on_crease = drop_unreferenced(vertices, vnormals, faces, on_crease)
    if not unchanged:  # (renumbering the vertices keeps the winding)
        faces = orient_consistently(vertices, vnormals, faces)
    return TriangulationResult(vertices, faces, vnormals, stats, on_crease)


def ball_radii(radii: list[float], scale: np.ndarray | None = None) -> list[float]:
    """Ball-pivoting radii [r0]: ``radii``, or with a local spacing, ``radii`` times its 5th,
    50th and 95th percentiles (balls are pivoted smallest first, so each region is meshed by
    the balls that suit its spacing before larger ones close what is left).

    Examples
    --------
    >>> ball_radii([1.0, 2.0])
    [1.0, 2.0]
    >>> ball_radii([1.0], np.array([1.0, 1.0, 3.0]))
    [1.0, 2.8]
    """
    if scale is None:
        return sorted(float(r) for r in radii)
    q = np.percentile(scale, [5, 50, 95])
    out = {round(float(r) * float(x), 6) for r in radii for x in q}
    return sorted(out)


def circumradius(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Circumradius of every face ``(F,)`` [units of ``vertices``]; inf for degenerate faces
    (:func:`recon.kernels.mesh_tables.circumradii`)."""
    v = np.ascontiguousarray(vertices, dtype=np.float64)
    return circumradii(v, np.ascontiguousarray(faces, dtype=np.int64).reshape(-1, 3))


def _spacing_at(
    scale: np.ndarray | None, positions: np.ndarray, vertices: np.ndarray
) -> np.ndarray | None:
    """The per-vertex spacing of a repaired mesh whose vertices were renumbered: each takes
    its nearest particle's (None stays None)."""
    return scale if scale is None else scale[cKDTree(positions).query(vertices)[1]]


def _extend(scale: np.ndarray | None, positions: np.ndarray, vertices: np.ndarray, trees: dict):
    """The per-vertex spacing after repair added vertices: a new vertex takes its nearest
    particle's. ``trees`` keeps the particles' k-d tree between calls (same ``positions``)."""
    if scale is None or len(vertices) == len(positions):
        return scale
    if "positions" not in trees:
        trees["positions"] = cKDTree(positions)
    _, nearest = trees["positions"].query(vertices[len(positions) :])
    return np.concatenate([scale, scale[nearest]])


def ball_pivoting(positions: np.ndarray, normals: np.ndarray, radii: list[float]) -> np.ndarray:
    """Faces (F, 3) from Open3D ball pivoting with the given radii [r0] [B99]."""
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(positions))
    pcd.normals = o3d.utility.Vector3dVector(normals)
    mesh = o3d.geometry.TriangleMesh.create_from_point_cloud_ball_pivoting(
        pcd, o3d.utility.DoubleVector(sorted(float(r) for r in radii))
    )
    faces = np.asarray(mesh.triangles, dtype=np.int64).reshape(-1, 3)
    # Open3D keeps vertex order; guard against a future version that reorders
    if len(mesh.vertices) != len(positions):  # pragma: no cover - defensive
        tree = cKDTree(positions)
        _, remap = tree.query(np.asarray(mesh.vertices))
        faces = remap[faces]
    return faces


def circumsphere_triangles(
    positions: np.ndarray, normals: np.ndarray, radius: float = 2.0
) -> np.ndarray:
    """Faces from the empty-circumsphere test over neighbours within ``radius`` [r0] (S&T92 §8).

    Only neighbours of the first corner are tested for emptiness, as in the paper (the sphere of
    an accepted triangle has a radius below ``radius``).
    """
    offsets, indices = build_neighbor_list(positions, radius)
    cap = CIRCUMSPHERE_CAPACITY
    out = np.zeros((len(positions), cap, 3), dtype=np.int64)
    count = np.zeros(len(positions), dtype=np.int64)
    circumsphere_kernel(positions, offsets, indices, out, count)
    mask = np.arange(cap)[None, :] < count[:, None]
    return out[mask]


def drop_overlaps(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Drop the later face of every pair that covers the same wedge at a shared vertex
    (:func:`recon.mesh.overlapping_faces`; faces oriented by their vertex normals first).

    Ball pivoting can take both diagonals of a nearly co-circular quad: every edge stays
    manifold, but the faces lie over each other and the mesh gains a tiny handle (a second
    sheet over one wedge). Faces come in ball order (smallest ball first), so the face a
    smaller ball found is kept; hole filling closes what the drop opens.
    """
    pairs = overlapping_faces(vertices, faces)
    drop = np.zeros(len(faces), dtype=bool)
    for i, j in pairs[np.lexsort((pairs[:, 0], pairs[:, 1]))].tolist():
        drop[j] |= not drop[i]
    return faces[~drop]


def remove_non_manifold_faces(faces: np.ndarray, n_vertices: int) -> np.ndarray:
    """Drop degenerate and duplicate faces, then faces on edges shared by more than two faces.

    For an over-shared edge, the faces with the largest index are dropped first, so the
    result is deterministic.
    """
    if len(faces) == 0:
        return faces
    ok = (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])
    faces = faces[ok]
    faces = faces[first_faces(faces, n_vertices)]
    for _ in range(NON_MANIFOLD_EDGE_ROUNDS):
        uniq, inv, cnt = unique_edges(faces, n_vertices)
        over = cnt[inv] > 2
        if not over.any():
            break
        face_of = np.repeat(np.arange(len(faces)), 3)
        # for each over-shared edge keep the two lowest face indices
        bad_edges = np.flatnonzero(cnt > 2)
        drop = np.zeros(len(faces), dtype=bool)
        sel = np.isin(inv, bad_edges)
        e_inv, e_face = inv[sel], face_of[sel]
        order = np.lexsort((e_face, e_inv))
        e_inv, e_face = e_inv[order], e_face[order]
        rank = np.arange(len(e_inv)) - np.searchsorted(e_inv, e_inv)
        drop[e_face[rank >= 2]] = True
        faces = faces[~drop]
    return faces


def split_non_manifold_vertices(
    vertices: np.ndarray, normals: np.ndarray, faces: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Give every extra fan of a bow-tie vertex its own copy of the vertex.

    The largest fan (ties: the lowest fan label) keeps the vertex; every other fan gets a new
    vertex moved ``SPLIT_SHIFT`` of the way towards its fan's centroid, with the same normal.
    No face is dropped, so a closed fan stays closed and an open one leaves a simple boundary
    loop that hole filling can walk. Expects no non-manifold edges.

    Returns
    -------
    vertices, normals, faces, n_new_vertices
    """
    if len(faces) == 0:
        return vertices, normals, faces, 0
    fan_vertex, corner_fan, rank = ranked_fans(faces)
    extra = np.flatnonzero(rank > 0)
    if len(extra) == 0:
        return vertices, normals, faces, 0  # one fan per used vertex: no bow-tie
    new_id = np.full(len(fan_vertex), -1, dtype=np.int64)
    new_id[extra] = len(vertices) + np.arange(len(extra))
    # centroid of each extra fan: mean of its faces' centroids
    face_centre = vertices[faces].mean(axis=1)
    corner_face = np.repeat(np.arange(len(faces)), 3)
    sel = new_id[corner_fan] >= 0
    slot = np.searchsorted(extra, corner_fan[sel])
    acc = np.zeros((len(extra), 3))
    np.add.at(acc, slot, face_centre[corner_face[sel]])
    cnt = np.bincount(slot, minlength=len(extra))[:, None]
    base = vertices[fan_vertex[extra]]
    new_v = base + SPLIT_SHIFT * (acc / cnt - base)
    faces = faces.copy().reshape(-1)
    faces[sel] = new_id[corner_fan[sel]]
    vertices = np.vstack([vertices, new_v])
    normals = np.vstack([normals, normals[fan_vertex[extra]]])
    return vertices, normals, faces.reshape(-1, 3), len(extra)


def extra_fan_faces(faces: np.ndarray) -> np.ndarray:
    """Faces of every fan but the largest at each bow-tie vertex: a boolean mask over faces.

    Fans come from :func:`recon.mesh.vertex_fans`, so a vertex where two closed fans touch (a
    pinch between two sheets) is found as well as one where open fans meet; they are ranked by
    :func:`recon.mesh.ranked_fans`, as :func:`split_non_manifold_vertices` ranks them.
    """
    drop = np.zeros(len(faces), dtype=bool)
    _, corner_fan, rank = ranked_fans(faces)
    drop[np.flatnonzero(rank[corner_fan] > 0) // 3] = True
    return drop


def repair_non_manifold(
    vertices: np.ndarray, normals: np.ndarray, faces: np.ndarray, split: bool = True
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A manifold mesh: faces on over-shared edges dropped, then bow-tie vertices repaired.

    With ``split`` every extra fan of a bow-tie vertex gets its own vertex
    (:func:`split_non_manifold_vertices`: nothing is dropped); without it the extra fans' faces
    are dropped (:func:`extra_fan_faces`), leaving a hole that hole filling re-triangulates
    without the shared vertex. Either way every edge ends up in one or two faces and every
    vertex with one fan.
    """
    faces = remove_non_manifold_faces(faces, len(vertices))
    if not split:
        for _ in range(NON_MANIFOLD_VERTEX_ROUNDS):
            bad = extra_fan_faces(faces)
            if not bad.any():
                break
            faces = remove_non_manifold_faces(faces[~bad], len(vertices))
    vertices, normals, faces, _ = split_non_manifold_vertices(vertices, normals, faces)
    return vertices, normals, faces


def remove_small_components(
    faces: np.ndarray,
    n_vertices: int,
    min_fraction: float = MIN_COMPONENT_FRACTION,
    min_faces: int = MIN_COMPONENT_FACES,
) -> tuple[np.ndarray, int]:
    """Drop debris: components smaller than ``min_faces`` and ``min_fraction`` of the largest."""
    n, labels = face_components(faces, n_vertices)
    if n <= 1:
        return faces, 0
    sizes = np.bincount(labels)
    small = (sizes < min_faces) & (sizes < min_fraction * sizes.max())
    if not small.any():
        return faces, 0
    return faces[~small[labels]], int(small.sum())
