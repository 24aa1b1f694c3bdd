"""The one entry point of the reconstruction: points in, mesh + particles + report out.

:func:`reconstruct` runs the stages on a :class:`~recon.cloud.PointCloud`, :func:`fit` on arrays
and :func:`fit_file` from a file to the output files (mesh, report, particles, preview), written
all-or-nothing.

Schedule (S&T92 §7, with the changes of ``DESIGN.md`` §4):

1. normals (estimated or from the file) and the rest spacing r0 from the data
   (:mod:`recon.fitting.scale`);
2. seeds, 3. growth rounds, 4. release: :mod:`recon.fitting.schedule`;
5. drop particles farther than ``trim_distance`` from the data, triangulate, fill small holes;
6. measure the result (topology, triangle quality, fidelity to the input):
   :mod:`recon.fitting.report`.

All dynamics run in normalised coordinates (positions relative to the cloud's origin, divided
by r0), so nothing depends on the input's units or offset. One :class:`numpy.random.Generator`
seeded with ``config.seed`` draws the coverage sample and the seeds; the points sampled on the
mesh for the report come from a second generator with the same seed (as they always did, so
the numbers are unchanged).

References
----------
[ST92] Szeliski & Tonnesen 1992, §7 "Surface fitting" and §8.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial import cKDTree

from ..attributes import check_attribute_output, check_transfer, transfer_for_output
from ..cloud import PointCloud, spatial_order
from ..config import ReconConfig, config_to_dict, with_values
from ..crease_mesh import mesh_as_written
from ..crease_orient import orient_across_creases
from ..crease_surface import CreaseField
from ..creases import Creases, detect_creases
from ..errors import InputError
from ..exterior_signs import resign_by_exterior
from ..geometry import bbox_diagonal, snap_to_precision
from ..io.outliers import outlier_removal, outlier_summary, outlier_warnings
from ..kernels.options import query_workers, thread_count
from ..kernels.warm import warm_fit_kernels
from ..neighbors import PointGrid
from ..normal_scales import per_point_k_max
from ..normal_signs import outward_across, resign_thin_parts
from ..normals import compute_normals, neighbors_needed
from ..polish import polish_and_untangle
from ..serialize import dumps
from ..state import ParticleState
from ..surface import DataSurface
from ..thinning import line_gap, thinned_cloud, thinned_rows, thinning_notes
from ..triangulate import TriangulationResult, triangulate_particles
from ..two_sided import closed_two_sided
from ..version import __version__
from ..winding import turn_closed_outward, turned_with_faces
from .collector import survivors_frozen
from .library import ConfigLike, check_progress, checked_memory, cloud_from_input, resolve_config
from .memory import MemoryEstimate
from .mesh_warnings import fit_warnings
from .report import (
    SAMPLING_REACH,
    CreaseStats,
    FitReport,
    History,
    InputSummary,
    OutputPaths,
    StepCounts,
    Timings,
    TriangulationStats,
    measure_mesh,
    report_path_for,
)
from .results import FitResult, Mesh, ParticleFit, Particles
from .scale import check_grid_size, choose_spacing, with_max_gap, with_neighborhood_size
from .schedule import Clock, ProgressFn, run_schedule

__all__ = [
    "HOLE_COVER_DISTANCE",
    "TRIM_GAP_FRACTION",
    "FitResult",
    "Mesh",
    "ParticleFit",
    "Particles",
    "fit",
    "fit_file",
    "fit_particles",
    "local_density_scale",
    "shared_neighbors",
    "reconstruct",
]

#: After the release, particles farther than TRIM_GAP_FRACTION x ``growth.max_gap`` [r0] from
#: the nearest data point are dropped (as are those off the data plane by more than
#: ``triangulation.trim_distance``): they bridge a gap the mesh should keep open.
TRIM_GAP_FRACTION = 0.5
#: A hole candidate counts as covered by data (and is filled) when the data point nearest to
#: its projection onto the data lies within this distance [r0] times the local spacing, or
#: times that data point's sampling spacing (:func:`sampling_spacing`) over the median one
#: (clipped to ``triangulation.max_density_scale``), whichever is larger: where the data is k
#: times sparser than usual, a sample covers k times farther (uniformly sparse data keeps the
#: test at r0, so small true holes stay open), or within :func:`cover_reach` of the data's
#: median spacing where that is farther (sparse input, r0 near one point spacing).
HOLE_COVER_DISTANCE = 1.0
#: The local data spacing is the distance to this many-th nearest data point.
DENSITY_NEIGHBOURS = 6
#: ... and only a spacing more than this many times the median counts as sparse: the ball
#: radii (0.7-2 r0) and the hole tests at r0 already absorb a twofold density variation.
DENSITY_TOLERANCE = 1.5


def _trim(state: ParticleState, surface: DataSurface, cfg: ReconConfig) -> int:
    """Drop particles off the data (optionally projecting the rest onto it); returns how many."""
    tri_cfg = cfg.triangulation
    projected, _, offset = surface.project(state.position, state.normal)
    dist, _ = surface.nearest(state.position)
    keep = (np.abs(offset) <= tri_cfg.trim_distance) & (
        dist <= TRIM_GAP_FRACTION * cfg.growth.max_gap
    )
    if tri_cfg.project_to_data:
        # crease particles stay on their crease lines (the data's edge): a quadric's foot
        # rounds the edge and can sit under a face, with the particle's bisector normal
        line = ~np.asarray(state.is_oriented, dtype=bool)
        state.position = np.where(line[:, None], state.position, projected)
    n_trimmed = int((~keep).sum())
    if n_trimmed:
        state.remove(keep)
    return n_trimmed


def sampling_spacing(tree: Any, points: np.ndarray) -> np.ndarray:
    """Each of ``points``' distance to its ``DENSITY_NEIGHBOURS``-th nearest neighbour in
    their k-d ``tree`` (0 when there are too few points to tell)."""
    if len(points) <= DENSITY_NEIGHBOURS:
        return np.zeros(len(points))
    dk, _ = tree.query(points, DENSITY_NEIGHBOURS + 1, workers=query_workers())
    return dk[:, -1]


def density_spacing(
    surface: DataSurface,
    positions: np.ndarray,
    max_scale: float,
    local: np.ndarray | None = None,
) -> np.ndarray:
    """Per-particle spacing [r0] from the local data density: 1 where the data is less than
    ``DENSITY_TOLERANCE`` times sparser than its median, up to ``max_scale`` where it is sparser.

    The local point spacing is each data point's distance to its ``DENSITY_NEIGHBOURS``-th
    neighbour; a particle takes that of its nearest data point, divided by the median and by
    ``DENSITY_TOLERANCE``. ``local``: :func:`sampling_spacing` of ``surface`` when known.
    """
    return local_density_scale(surface.tree, surface.points, positions, max_scale, local=local)


def local_density_scale(
    tree: Any,
    points: np.ndarray,
    positions: np.ndarray,
    max_scale: float,
    median: float | None = None,
    local: np.ndarray | None = None,
) -> np.ndarray:
    """:func:`density_spacing` over a k-d ``tree`` of the data ``points`` [r0]; ``median`` is
    the median local spacing [r0] (default: that of ``points``; a tile of a tiled fit passes
    the whole scan's); ``local``: each point's spacing (:func:`sampling_spacing`), queried
    here when None."""
    if max_scale <= 1.0 or len(points) <= DENSITY_NEIGHBOURS:
        return np.ones(len(positions))
    if local is None:
        local = sampling_spacing(tree, points)
    _, nearest = tree.query(positions, workers=query_workers())
    if median is None:
        median = float(np.median(local))
    ratio = local[nearest] / max(float(median), 1e-12)
    return np.clip(ratio / DENSITY_TOLERANCE, 1.0, max_scale)


def cover_reach(median_spacing: float) -> float:
    """Distance [r0] within which data covers the surface: ``SAMPLING_REACH`` median point
    spacings ``median_spacing`` [r0] (95 % of a uniformly sampled surface lies that close to
    a sample), the same reach by which the report judges the mesh on the data.

    On dense input r0 is 2.5 spacings and this stays below ``HOLE_COVER_DISTANCE`` r0. On
    sparse input the resolution floor puts r0 near one spacing, where a test at r0 finds
    data beside only about half of the surface between samples: a narrow seam between two
    growth fronts then fails the coverage test of hole filling and stays open.

    Examples
    --------
    >>> cover_reach(1.0)
    2.1
    >>> cover_reach(0.5)
    1.05
    """
    return SAMPLING_REACH * float(median_spacing)


def sparse_cover(sampling: np.ndarray, median: float, max_density_scale: float) -> np.ndarray:
    """How many times farther than ``HOLE_COVER_DISTANCE`` each data point covers a hole's
    inside: a point ``k`` times sparser than the ``median`` sampling spacing (``sampling``:
    :func:`sampling_spacing`) covers ``k`` times farther, up to the same limit as the ball
    radii (``max_density_scale``; 1 when that is off)."""
    ratio = sampling / max(float(median), 1e-12) if len(sampling) else sampling
    return np.clip(ratio, 1.0, max(max_density_scale, 1.0))


def covered(
    dist: np.ndarray,
    sparser: np.ndarray,
    spacing: float | np.ndarray,
    reach: float,
    across: bool = False,
) -> np.ndarray:
    """Hole points whose nearest data point (at ``dist`` [r0], its :func:`sparse_cover`
    ``sparser``) covers them: within ``HOLE_COVER_DISTANCE`` times the larger of the local
    ``spacing`` and ``sparser``, or within ``reach`` (:func:`cover_reach`).

    ``across``: the points are those across a seam (:func:`recon.holes.across_points`), which
    the seam rule judges together (it asks for data at ``SEAM_SUPPORT`` of them). The reach
    then follows the local sampling as well: ``reach`` x ``sparser``, the distance within
    which 95 % of a surface sampled that sparsely lies from a sample. A single point (a
    hole's centroid, judged alone) keeps the median reach, so that a small real opening in
    sparse data stays open (face-sparse: a centroid 3.0 r0 from data 1.8x sparser than the
    median, 1.8 r0 of reach).
    """
    near = HOLE_COVER_DISTANCE * np.maximum(spacing, sparser)
    return dist < np.maximum(near, reach * sparser if across else reach)


def _triangulate(
    state: ParticleState, surface: DataSurface, cfg: ReconConfig, median_spacing: float = 0.0
) -> TriangulationResult:
    """Triangulate the particles; gaps up to ``max_hole`` (default ``max_gap``) are closed.

    Ball radii and hole sizes follow each particle's spacing [r0]: the larger of its rest
    spacing (``seeds.adaptive``; 1 otherwise) and the local data spacing
    (``triangulation.max_density_scale``). ``median_spacing`` [r0]: the data's median
    nearest-neighbour distance; a hole's inside counts as covered by data within
    ``SAMPLING_REACH`` of them (:func:`cover_reach`).
    """
    tri_cfg = cfg.triangulation
    max_hole = tri_cfg.max_hole if tri_cfg.max_hole is not None else cfg.growth.max_gap
    spacing = None
    sampling = sampling_spacing(surface.tree, surface.points)  # one k-NN query, both uses
    if tri_cfg.max_density_scale > 1.0:
        spacing = density_spacing(
            surface, state.position, tri_cfg.max_density_scale, local=sampling
        )
    if cfg.seeds.adaptive and state.n:
        rest = np.array(state.rest, dtype=float)
        spacing = rest if spacing is None else np.maximum(spacing, rest)
    median = float(np.median(sampling)) if len(sampling) else 0.0
    sparser = sparse_cover(sampling, median, tri_cfg.max_density_scale)

    def mesh(reach: float) -> tuple[TriangulationResult, int, int]:
        def is_covered(
            c: np.ndarray, spacing: float | np.ndarray = 1.0, across: bool = False
        ) -> np.ndarray:
            dist, idx = surface.nearest(surface.project(c)[0])
            return covered(dist, sparser[idx], spacing, reach, across)

        result = triangulate_particles(
            state.position,
            state.normal,
            tri_cfg,
            max_hole,
            is_covered,
            local_spacing=spacing,
            crease=None if surface.creases is None else ~np.asarray(state.is_oriented, dtype=bool),
        )
        # without project_to_data (noisy scans) the polish stays in the tangent planes too
        onto = surface if tri_cfg.project_to_data else None
        rounds, flips, tunnel = tri_cfg.smooth_rounds, tri_cfg.smooth_flips, np.pi * max_hole
        return polish_and_untangle(result, onto, rounds, flips, tunnel_perimeter=tunnel)

    reach = cover_reach(median_spacing)
    result, found, left = mesh(reach)
    if left and reach > HOLE_COVER_DISTANCE:
        # the reach closed a loop through a thin part (a loop round an under-sampled ear or
        # leg, whose inside lies within the reach): the mesh would cross itself, so the
        # loops the reach alone closed stay open
        result, found, left = mesh(0.0)
    stats = {**result.stats, "self_intersections_found": found, "self_intersections_left": left}
    # a part thinner than a spacing meshed as one open layer between its two faces
    closed = closed_two_sided(
        result.vertices, result.normals, result.faces, surface.points, result.crease
    )
    if closed is not None:
        v, n, f, crease, stats["two_sided_closed"] = closed
        result = replace(result, vertices=v, normals=n, faces=f, crease=crease)
    # a component the polish closed was wound by its normals' vote while open: outward now
    faces, turned = turn_closed_outward(result.vertices, result.faces)
    if turned.any():  # (their vertex normals follow their faces)
        normals = turned_with_faces(result.vertices, faces, result.normals, turned)
        result = replace(result, faces=faces, normals=normals)
        stats["closed_turned_outward"] = int(turned.sum())
    return replace(result, stats=stats)


#: The stages before the dynamics (normal estimate and orientation graph, crease detection,
#: local surfaces) share one k-nearest query of the data when together they need at most this
#: many neighbours per point (12 bytes each while it is held; wider: each queries its own).
SHARED_NEIGHBORS_MAX = 48
#: The shared query runs in blocks of this many points, each stored as it comes (the k-d
#: tree's int64 indices of the whole cloud would be a second copy at the peak).
SHARED_QUERY_BLOCK = 65536
#: The shared query is answered from a cell grid (:class:`recon.neighbors.PointGrid`: the same
#: neighbours, 35-45 % less CPU than the k-d tree's query on the dev set) whose cell side is
#: the median distance of the widest neighbour of this many points spread over the input.
SHARED_CELL_SAMPLE = 256


def shared_neighbors(
    points: np.ndarray, cfg: ReconConfig, tree: cKDTree | None = None
) -> tuple[np.ndarray, np.ndarray] | None:
    """One k-nearest query of the data for every stage before the dynamics: (distances
    float64, indices int32) of each point's nearest points, nearest first; None when the
    widest use exceeds ``SHARED_NEIGHBORS_MAX`` (noisy data with a raised ``normals.k``) or
    the data is tiny. The indices are int32 (the data holds fewer than 2^31 points: the
    same values at half the memory, 192 MB of the 576 MB held at 1M points). ``tree``: a
    k-d tree of ``points`` when one is built already."""
    n = len(points)
    widest = [2 * cfg.normals.k, neighbors_needed(cfg.normals)]  # local surfaces, normals
    if cfg.creases.enabled:
        widest.append(cfg.creases.k)
    m = max(widest)
    if m > SHARED_NEIGHBORS_MAX or m >= n or n >= 2**31:
        return None
    tree = cKDTree(points) if tree is None else tree
    sample, _ = tree.query(points[:: max(1, n // SHARED_CELL_SAMPLE)], k=m)
    cell = float(np.median(sample[:, -1]))
    grid = PointGrid(points, cell) if np.isfinite(cell) and cell > 0.0 else tree
    dist = np.empty((n, m))
    idx = np.empty((n, m), dtype=np.int32)
    for lo in range(0, n, SHARED_QUERY_BLOCK):  # each point's answer is its own: same values
        hi = min(lo + SHARED_QUERY_BLOCK, n)
        dist[lo:hi], idx[lo:hi] = grid.query(points[lo:hi], k=m, workers=query_workers())
    return dist, idx


def _detect_creases(
    points: np.ndarray,
    normals: np.ndarray,
    cfg: ReconConfig,
    diag: float,
    neighbors: tuple[np.ndarray, np.ndarray] | None = None,
    tree: cKDTree | None = None,
) -> tuple[Creases | None, CreaseStats | None]:
    """Sharp creases and corners of the data: the detection and the report's section."""
    if not cfg.creases.enabled:
        return None, None
    c = cfg.creases
    found = detect_creases(
        points, normals, angle_deg=c.angle_deg, k=c.k, neighbors=neighbors, tree=tree
    )
    return found, CreaseStats(
        angle_deg=cfg.creases.angle_deg,
        length=found.length,
        length_relative=found.length / diag if diag > 0 else 0.0,
        corners=len(found.corners),
        crease_points=found.n_crease_points,
        corner_points=found.n_corner_points,
    )


def reconstruct(
    cloud: PointCloud, config: ConfigLike = None, on_progress: ProgressFn | None = None
) -> FitResult:
    """Reconstruct a mesh from a point cloud.

    Parameters
    ----------
    cloud : PointCloud
        Points relative to ``cloud.origin``; normals are used when present and
        ``normals.mode`` allows it.
    config : ReconConfig, mapping, str or path-like, optional
        Defaults when omitted; as :func:`fit` takes it.
    on_progress : callable(phase, info), optional
        Called after every growth round and release chunk with the step count, particle
        count, kinetic energy and coverage.

    Returns
    -------
    FitResult
        Mesh and particles in absolute coordinates, and the report.
    """
    cfg = resolve_config(config)
    check_progress(on_progress)
    # the mesh depends on neither
    with thread_count(cfg.threads), survivors_frozen():
        return _reconstruct(cloud, cfg, on_progress)


@dataclass
class _Sheet:
    """What :func:`_fit_sheet` hands on to the triangulation and the report."""

    cfg: ReconConfig
    points: np.ndarray
    normals_info: dict
    creases: CreaseStats | None
    r0: float
    d_nn: float
    surface: DataSurface
    sched: Any
    n_trimmed: int
    clock: Clock


def _fit_sheet(
    cloud: PointCloud,
    cfg: ReconConfig,
    on_progress: ProgressFn | None,
    normals_k_max: int | None = None,
    detected: Creases | None = None,
    clock: Clock | None = None,
) -> _Sheet:
    """Normals, r0, the schedule and the trim: everything before the triangulation.

    ``normals_k_max``: the widest neighbourhood a point's normal may take
    (:func:`recon.normals.estimate_normals`); None: ``MAX_SCALE`` x ``normals.k`` when
    ``normals.per_point_scale``, else k only (a tile's resolved k comes with its scan's).
    ``detected``: :func:`fit_particles`' ``creases`` (no crease statistics then); ``clock``:
    the fit's so far (a fit started again on thinned points)."""
    clock, config = clock or Clock(cfg.dynamics.time_limit), cfg  # (config: for a refit)
    warm_fit_kernels()  # the kernels' cached code loads beside the first stages
    rng = np.random.default_rng(cfg.seed)
    # Morton order: every neighbour query and per-point pass below touches nearby memory,
    # and the fit no longer depends on the order of the input's rows
    order = spatial_order(cloud.points)
    cloud = cloud.take(order)
    points = np.asarray(cloud.points, dtype=np.float64)

    tree = cKDTree(points)  # one k-d tree of the data for the stages up to r0 (same queries)
    variations: dict[int, float] = {}  # median surface variation by k, measured once
    # each point's normal from the best determined neighbourhood up to the noise rule's widest
    k_max = normals_k_max
    if k_max is None:
        k_max = per_point_k_max(cfg.normals.k, cfg.normals.per_point_scale)
    cfg = with_neighborhood_size(points, cfg, tree, variations)
    knn = shared_neighbors(points, cfg, tree)
    notes = thinning_notes(cloud.info, cfg)  # clumps merged, lines thinned, r0 across lines
    nearest, gap = None if knn is None else knn[0][:, 1], line_gap(cloud.info)
    r0, d_nn = choose_spacing(points, cfg, tree, nearest, notes, gap)
    if (thin := thinned_rows(points, tree, knn, d_nn, cloud.info)) is not None:  # no normals yet
        again = None if detected is None else detected.take(order[thin[0]])  # (a tile's rows)
        return _fit_sheet(thinned_cloud(cloud, *thin), config, on_progress, k_max, again, clock)
    normals, normals_info = compute_normals(
        cloud, cfg.normals, neighbors=knn, k_max=k_max, tree=tree
    )
    normals_info["outliers"] = outlier_summary(cloud.info, points, cfg.io.outlier_k, knn, tree)
    clock.lap("normals")
    clock.check()
    if detected is None:
        found, creases = _detect_creases(points, normals, cfg, bbox_diagonal(points), knn, tree)
    else:
        found, creases = detected.take(order), None
    if found is not None:  # a crease fixes the normals' orientation across it
        normals, found, _ = orient_across_creases(points, normals, found, k=cfg.creases.k)
    if normals_info.get("source") == "estimated":  # signs where a thin part's faces meet
        variation = variations.get(cfg.normals.k)
        normals, _ = resign_thin_parts(points, normals, cfg.normals.k, tree, variation, knn)
        if cfg.normals.exterior_signs:  # signs of a closed scan's thin parts from outside
            normals, _ = resign_by_exterior(points, normals, d_nn, tree)
        if normals_info.get("component_methods") == {"up": 1}:  # one part, signed as open
            wide = None if knn is None else knn[1]
            gaps = cfg.normals.thin_gap, cfg.normals.thin_gap_taper
            normals, turned = outward_across(points, normals, wide, *gaps)
            if turned and found is not None:  # the creases' sides follow their members
                found = replace(found, side_normals=-found.side_normals)
    del tree
    check_grid_size(points, r0)
    cfg = with_max_gap(cfg, r0, d_nn)
    if knn is not None:
        knn[0][...] /= r0  # in place: the distances in r0 (no copy of the query is made)
    surface = DataSurface.build(points / r0, normals, k=cfg.normals.k, neighbors=knn)
    del knn
    if found is not None and cfg.creases.fit:  # per-side planes and crease particles
        surface.creases = CreaseField.build(found, surface.points, r0)
    clock.lap("setup")
    clock.check()

    sched = run_schedule(surface, cfg, rng, clock, on_progress)
    sched.warnings[:0] = notes
    if sched.dt != cfg.dynamics.dt:
        cfg = with_values(cfg, dynamics={"dt": sched.dt})
    n_trimmed = _trim(sched.state, surface, cfg)
    return _Sheet(cfg, points, normals_info, creases, r0, d_nn, surface, sched, n_trimmed, clock)


def fit_particles(
    cloud: PointCloud,
    config: ReconConfig | None = None,
    on_progress: ProgressFn | None = None,
    normals_k_max: int | None = None,
    creases: Creases | None = None,
) -> ParticleFit:
    """The particle sheet of a fit without its mesh: one tile of a tiled fit
    (:mod:`recon.tiling`), which gives r0 (``seeds.spacing``), ``growth.max_gap`` and
    ``normals.k`` fixed for the whole scan. ``creases``: those of ``cloud``'s rows detected
    on more points (:mod:`recon.fitting.wide_creases`); None: on ``cloud``'s."""
    cfg = config if config is not None else ReconConfig()
    with thread_count(cfg.threads):
        sheet = _fit_sheet(cloud, cfg, on_progress, normals_k_max, creases)
    state = sheet.sched.state
    origin = np.asarray(cloud.origin, dtype=np.float64)
    return ParticleFit(
        positions=state.position * sheet.r0 + origin,
        normals=state.normal.copy(),
        rest=np.array(state.rest, dtype=float) if sheet.cfg.seeds.adaptive else None,
        r0=sheet.r0,
        config=sheet.cfg,
        n_trimmed=sheet.n_trimmed,
        steps=dict(sheet.sched.steps),
        warnings=list(sheet.sched.warnings),
        stop_reason=sheet.sched.stop_reason,
        crease=None
        if sheet.surface.creases is None
        else ~np.asarray(state.is_oriented, dtype=bool).copy(),
    )


def _reconstruct(cloud: PointCloud, cfg: ReconConfig, on_progress: ProgressFn | None) -> FitResult:
    sheet = _fit_sheet(cloud, cfg, on_progress)
    cfg, points, surface, sched, clock = (
        sheet.cfg,
        sheet.points,
        sheet.surface,
        sheet.sched,
        sheet.clock,
    )
    r0, d_nn, n_trimmed = sheet.r0, sheet.d_nn, sheet.n_trimmed
    normals_info, creases = sheet.normals_info, sheet.creases
    sched.warnings[:0] = outlier_warnings(normals_info)  # a scan that looks outlier-ridden
    state = sched.state
    diag = bbox_diagonal(points)
    tri = _triangulate(state, surface, cfg, d_nn / r0)
    clock.lap("triangulate")
    clock.check()

    origin = np.asarray(cloud.origin, dtype=np.float64)
    # (the digits below the coordinates' own precision dropped: faces on a plane through 0
    # are exactly flat, as Open3D's self-intersection test needs; tiled fits are not snapped)
    vertices = snap_to_precision(tri.vertices * r0 + origin)
    mesh = Mesh(vertices, tri.faces, tri.normals, tri.crease)
    particles = Particles(state.position * r0 + origin, state.normal.copy())

    if len(tri.faces) == 0:
        raise InputError(
            "the reconstruction produced no triangles: the data may be too sparse "
            "for the spacing (try a smaller --spacing or a larger --max-gap)"
        )
    measures = measure_mesh(
        points,
        tri.vertices,
        tri.faces,
        surface,
        r0=r0,
        median_spacing=d_nn,
        diag=diag,
        rng=np.random.default_rng(cfg.seed),
    )
    clock.lap("report")
    coverage = sched.history["coverage"]
    report = FitReport(
        oprecon_version=__version__,
        input=InputSummary(
            points=int(len(points)),
            bbox_diagonal=diag,
            median_spacing=d_nn,
            normals=normals_info,
        ),
        spacing=r0,
        seeds=sched.n_seeds,
        particles=int(state.n),
        particles_trimmed=n_trimmed,
        steps=StepCounts.from_dict(sched.steps),
        timings=Timings.from_phases(clock.phases),
        coverage=coverage[-1] if coverage else None,
        stop_reason=sched.stop_reason,
        warnings=(*sched.warnings, *fit_warnings(measures, tri, state.n, r0, normals_info)),
        triangulation=TriangulationStats.from_dict(tri.stats),
        noise_estimate=surface.noise * r0,
        history=History.from_dict(sched.history),
        config=config_to_dict(cfg),
        topology=measures.topology,
        triangle_quality=measures.triangle_quality,
        mesh_bbox_diag=measures.mesh_bbox_diag,
        fidelity=measures.fidelity,
        mesh_to_input=measures.mesh_to_input,
        spacing_range=(
            (float(state.rest.min() * r0), float(state.rest.max() * r0))
            if cfg.seeds.adaptive and state.n
            else None
        ),
        creases=creases,
    )
    return FitResult(mesh, particles, report, origin)


def fit(
    points: ArrayLike,
    config: ConfigLike = None,
    *,
    normals: ArrayLike | None = None,
    on_progress: ProgressFn | None = None,
) -> FitResult:
    """Reconstruct a mesh from an (n, 3) array of points: ``recon.fit``, the library's main
    function.

    Mirrors ``oprecon fit``: the same cleaning (non-finite rows dropped, repeated points
    merged unless ``io.merge_duplicates`` is off), the same limits (``io.max_points``,
    ``io.max_memory``) and the same fit, without writing files.

    Parameters
    ----------
    points : (n, 3) array_like of real numbers [length]
        Absolute coordinates.
    config : ReconConfig, mapping, str or path-like, optional
        A :class:`~recon.config.ReconConfig` (``recon.load_config(path, overrides)``); a
        mapping of dotted overrides of the defaults, ``{"seeds.spacing": 0.02}``, as
        ``recon.load_config(overrides=...)`` takes it; or the path of a YAML configuration
        file, as ``recon.load_config(path)``. The defaults when omitted.
    normals : (n, 3) array_like of real numbers, optional
        Normals of the points (any length; used as ``normals.mode`` says); estimated when
        omitted.
    on_progress : callable(phase, info), optional
        Called after every growth round and release chunk (:func:`reconstruct`).

    Returns
    -------
    FitResult
        ``mesh`` and ``particles`` in absolute coordinates, ``report`` (its ``input``
        carries the memory estimate when ``io.max_memory`` is set).

    Raises
    ------
    InputError
        ``points`` or ``normals`` is not an (n, 3) array of real numbers (None, text,
        complex values, rows of different lengths, mismatched shapes); more rows than
        ``io.max_points``; an estimated peak memory over ``io.max_memory``; fewer than 4
        distinct finite points or all on one line; or a fit that produced no triangles.
    ConfigError
        An unknown key or an invalid value in a mapping or file given as ``config``.
    TypeError
        ``config`` of another kind (use ``recon.load_config``), or an ``on_progress`` that
        cannot be called (both before any work).
    OpreconError
        The other failures of a fit (``DivergenceError``, ``LimitExceeded``).

    Examples
    --------
    >>> import numpy as np, recon
    >>> p = np.random.default_rng(0).normal(size=(800, 3))
    >>> res = recon.fit(p / np.linalg.norm(p, axis=1, keepdims=True), {"seed": 1})  # doctest: +SKIP
    >>> res.report.topology.watertight  # doctest: +SKIP
    True
    """
    cfg = resolve_config(config)
    check_progress(on_progress)
    cloud = cloud_from_input(points, normals, cfg)
    memory = checked_memory(cloud, cfg)  # refuses early past io.max_memory
    return _with_input(reconstruct(cloud, cfg, on_progress), memory=memory)


def _with_input(
    result: FitResult, path: str | None = None, memory: MemoryEstimate | None = None
) -> FitResult:
    """``result`` with the input file and the memory estimate in its report's ``input``."""
    if path is None and memory is None:
        return result
    report = result.report
    mem = None if memory is None else memory.to_dict()
    result.report = replace(report, input=replace(report.input, path=path, memory_estimate=mem))
    return result


def fit_file(
    input_path: str | Path,
    output_path: str | Path,
    config: ConfigLike = None,
    *,
    particles_path: str | Path | None = None,
    preview_path: str | Path | None = None,
    write_report: bool | None = None,
    mkdir: bool = False,
    on_progress: ProgressFn | None = None,
    extra_meshes: Sequence[str | Path] = (),
) -> FitResult:
    """Read ``input_path``, reconstruct, and write the mesh (+ report, particles, preview).

    ``extra_meshes`` are more files of the same mesh (e.g. an OBJ beside the PLY), each with the
    colours and vertex properties its format holds. Every output is written to a temporary file
    beside its target and renamed into place only after all of them were written, so a failure
    or an interrupt leaves no partial file.
    Writing onto the input is refused. The report (``report_path_for(output_path)``) is written
    when ``write_report`` is true, or when it is None and ``output.write_report`` is.
    ``config`` as :func:`fit` takes it.
    """
    from ..io import (
        atomic_output,
        atomic_outputs,
        check_output_path,
        read_points,
        write_mesh,
        write_points,
    )

    cfg = resolve_config(config)
    check_progress(on_progress)
    input_path = Path(input_path)
    output_path = check_output_path(Path(output_path), inputs=[input_path], mkdir=mkdir)
    want_report = cfg.output.write_report if write_report is None else write_report
    report_path = report_path_for(output_path) if want_report else None
    meshes = [output_path] + [
        check_output_path(Path(p), inputs=[input_path], mkdir=mkdir) for p in extra_meshes
    ]
    taken = [(m, "the mesh output") for m in meshes]
    for p in (q for q in (particles_path, preview_path, report_path) if q is not None):
        check_output_path(Path(p), inputs=[input_path], mkdir=mkdir, taken=taken)
    for mesh_path in meshes:
        check_attribute_output(mesh_path, cfg.output)
    cloud = read_points(
        input_path,
        max_points=cfg.io.max_points,
        merge_duplicates=cfg.io.merge_duplicates,
        classes=cfg.io.classes,
        outliers=outlier_removal(cfg.io),
    )
    check_transfer(cloud, cfg.output.transfer)
    memory = checked_memory(cloud, cfg, always=True)  # refuses early past io.max_memory
    result = _with_input(reconstruct(cloud, cfg, on_progress), str(input_path), memory)
    report = result.report
    result.report = replace(
        report,
        output=OutputPaths(
            mesh=str(output_path),
            particles=None if particles_path is None else str(particles_path),
            preview=None if preview_path is None else str(preview_path),
            report=None if report_path is None else str(report_path),
        ),
    )
    normals = result.mesh.normals if cfg.output.vertex_normals else None
    m, cr = result.mesh, cfg.creases
    with atomic_outputs() as outputs:  # all files appear together, or none
        for mesh_path in meshes:
            obj = Path(mesh_path).suffix.lower() == ".obj"
            v, f, nrm, corners, split = mesh_as_written(
                m.vertices, m.faces, normals, m.crease, obj, cr.angle_deg, cr.split_ply
            )
            if split:  # the report says the PLY's topology opens along the creases
                out = replace(result.report.output, crease_vertices_split=split)
                result.report = replace(result.report, output=out)
            attributes = transfer_for_output(cloud, v, report.spacing, mesh_path, cfg)
            write_mesh(
                mesh_path,
                v,
                f,
                nrm,
                ascii=cfg.io.ascii,
                outputs=outputs,
                colors=attributes.colors,
                vertex_properties=attributes.properties,
                corner_normals=corners,
            )
        if particles_path is not None:
            write_points(
                Path(particles_path),
                result.particles.positions,
                result.particles.normals,
                ascii=cfg.io.ascii,
                outputs=outputs,
            )
        if preview_path is not None:
            from ..render import render_mesh_png

            render_mesh_png(
                Path(preview_path),
                result.mesh.vertices,
                result.mesh.faces,
                history=result.report.history.to_dict(),
                title=input_path.name,
                outputs=outputs,
                crease_vertices=result.mesh.crease,
            )
        if report_path is not None:
            with atomic_output(report_path, outputs) as tmp:
                tmp.write_text(dumps(result.report.to_dict()) + "\n")
    return result
