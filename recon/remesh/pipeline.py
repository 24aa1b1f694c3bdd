"""``remesh``: particles on an existing mesh give a near-equilateral, feature-keeping mesh.

S&T92 §9 proposes to "distribute the particles over the surface of a CAD model and allow the
particles to change position and orientation while remaining on the surface of the model". The
steps, with every length normalised by the target spacing s:

1. check and repair the input (:mod:`recon.remesh.mesh_check`);
2. feature lines: boundary loops and, with a crease angle, sharp edges, split at corners
   (:func:`recon.remesh.surface.feature_lines`);
3. spacing: uniform s, or with ``adaptive`` a field from curvature and local thickness
   (:func:`spacing_field`);
4. seed and relax the particles on the mesh (:mod:`recon.remesh.relax`), no growth;
5. triangulate patch by patch with the fit's :func:`recon.triangulate.triangulate_particles`
   (:mod:`recon.remesh.patches`: manifold, oriented; triangles reaching out across a patch's
   outline dropped, gaps closed, one loop kept per boundary loop of the input, pieces of one
   input component joined, stray closed pieces dropped; the input's holes have no surface,
   so they stay open);
6. polish with flips and tangential smoothing (:mod:`recon.remesh.improve`; the mesh's rim
   stays where it is);
7. measure: triangle quality and topology before and after, distances to the input, the
   largest deviation of the input's feature lines from the output.

Spacing and face count: a hexagonal sheet of spacing s has triangles of area √3/4 s², so a
surface of area A takes F ≈ A / (√3/4 s²) faces, and F = 2V − B − 2χ for V vertices, B of them
on the boundary, and Euler characteristic χ. ``faces=N`` sets s from A and N and the particle
count from that identity.

References
----------
[ST92] Szeliski & Tonnesen 1992, §9.
[T92]  G. Turk. "Re-tiling polygonal surfaces". SIGGRAPH 1992.
[WH94] A. Witkin, P. Heckbert. "Using particles to sample and control implicit surfaces".
       SIGGRAPH 1994 (adaptive radii).
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from ..errors import InputError
from ..kernels.options import query_workers, thread_count
from ..mesh import corner_sum
from ..metrics import compare_meshes, point_to_mesh_distance
from ..topology import mesh_topology, triangle_quality
from .improve import improve
from .mesh_check import check_mesh
from .patches import (
    close_gaps,
    on_boundary,
    particle_of,
    rim_labels,
    stray_pieces,
    triangulate_patches,
)
from .relax import (
    CELL_AREA,
    Particles,
    drop_near_lines,
    line_edges,
    place_feature_particles,
    relax,
    seed,
)
from .surface import FeatureLines, MeshSurface, edge_faces, feature_lines

__all__ = [
    "RemeshOptions",
    "RemeshResult",
    "absolute_curvature",
    "remesh",
    "remesh_file",
    "spacing_field",
]

#: Relaxation steps (chunks of :data:`recon.remesh.relax.CHUNK`).
RELAX_STEPS = 40
#: Rounds of flips and smoothing after the triangulation.
SMOOTH_ROUNDS = 5
#: A boundary line turning by more than this [deg] at a vertex has a corner there (without a
#: crease angle; with one, the crease angle is used).
CORNER_ANGLE = 50.0
#: Adaptive spacing: the given spacing is kept where the curvature is at this area-weighted
#: percentile; flatter regions get coarser, more curved ones finer.
REFERENCE_PERCENTILE = 75.0
#: Adaptive spacing: rounds of neighbour averaging of the curvature (against the noise of a
#: badly shaped input).
CURVATURE_SMOOTHING = 1
#: Adaptive spacing: the curvature is fitted over at least this many input edge lengths.
CURVATURE_REACH = 2.0
#: Adaptive spacing: no larger than this fraction of the local thickness.
THICKNESS_FRACTION = 0.5
#: Adaptive spacing grows by at most this much per unit length (a gentle grading keeps the
#: triangles near equilateral where the spacing changes).
GRADATION = 0.25
#: Adaptive defaults for min/max spacing, as factors of the spacing.
ADAPTIVE_MIN = 0.5
ADAPTIVE_MAX = 3.0
#: Interior particles closer than this to a feature line [local spacing] are dropped.
LINE_GAP = 0.5
#: The default spacing, the input's mean edge length, is at most this fraction of the
#: bounding-box diagonal: a coarse mesh whose edges are long for its shape (a CAD cube of 12
#: triangles: mean edge 0.66 x diagonal, about 5 particles) gets ten spacings across its
#: diagonal instead; a mesh with more than ten mean edges across it keeps its mean edge.
MAX_DEFAULT_SPACING = 0.1
#: Refuse a spacing that needs more particles than this (``dynamics.max_particles``'s default).
MAX_PARTICLES = 2_000_000
#: Points sampled per mesh for the distance measures.
DISTANCE_SAMPLES = 100_000


@dataclass(frozen=True)
class RemeshOptions:
    """What to make. Give at most one of ``spacing``, ``spacing_relative``, ``faces``; with
    none the spacing is the mean edge length of the input, at most
    :data:`MAX_DEFAULT_SPACING` (a tenth) of its bounding-box diagonal.

    Attributes
    ----------
    spacing : float [length]
        Target edge length.
    spacing_relative : float
        Target edge length as a fraction of the bounding-box diagonal.
    faces : int
        Target face count (the spacing follows from the area).
    adaptive : bool
        Spacing from curvature and thickness (:func:`spacing_field`), between ``min_spacing``
        and ``max_spacing`` (default 0.5x and 3x the spacing).
    crease_angle : float [deg] or None
        Edges whose two face normals differ by more than this are kept as creases.
    seed : int
    steps : int
        Relaxation steps.
    smooth_rounds : int
        Rounds of flips and tangential smoothing after the triangulation.
    check_intersections : bool
        Refuse self-intersecting input.
    threads : int or None
    """

    spacing: float | None = None
    spacing_relative: float | None = None
    faces: int | None = None
    adaptive: bool = False
    min_spacing: float | None = None
    max_spacing: float | None = None
    crease_angle: float | None = None
    seed: int = 0
    steps: int = RELAX_STEPS
    smooth_rounds: int = SMOOTH_ROUNDS
    check_intersections: bool = True
    threads: int | None = None

    def check(self) -> None:
        given = [
            k for k in ("spacing", "spacing_relative", "faces") if getattr(self, k) is not None
        ]
        if len(given) > 1:
            raise InputError(f"give one of spacing, spacing_relative, faces (got {given})")
        for k in ("spacing", "spacing_relative", "min_spacing", "max_spacing"):
            val = getattr(self, k)
            if val is not None and not (math.isfinite(val) and val > 0):
                raise InputError(f"{k} must be a positive length, got {val}")
        if self.faces is not None and self.faces < 4:
            raise InputError(f"faces must be at least 4, got {self.faces}")
        if self.crease_angle is not None and not 0 < self.crease_angle < 180:
            raise InputError(f"crease angle must lie in (0, 180) degrees, got {self.crease_angle}")
        if (
            self.min_spacing is not None
            and self.max_spacing is not None
            and self.min_spacing > self.max_spacing
        ):
            raise InputError(
                f"min spacing {self.min_spacing} exceeds max spacing {self.max_spacing}"
            )
        if self.steps < 0 or self.smooth_rounds < 0:
            raise InputError("steps and smooth_rounds must be >= 0")


@dataclass
class RemeshResult:
    """The new mesh (input units) and its report (a JSON-ready dict)."""

    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray
    report: dict[str, Any] = field(default_factory=dict)


def _summary(topo: dict[str, Any]) -> dict[str, Any]:
    keys = (
        "n_vertices",
        "n_faces",
        "components",
        "boundary_loops",
        "euler_characteristic",
        "genus",
        "watertight",
        "non_manifold_edges",
        "non_manifold_vertices",
    )
    return {k: topo[k] for k in keys}


def topology_preserved(before: dict[str, Any], after: dict[str, Any]) -> bool:
    """Same components, boundary loops and Euler characteristic (hence genus), and manifold."""
    return (
        before["components"] == after["components"]
        and before["boundary_loops"] == after["boundary_loops"]
        and before["euler_characteristic"] == after["euler_characteristic"]
        and after["non_manifold_edges"] == 0
        and after["non_manifold_vertices"] == 0
    )


def spacing_field(surface: MeshSurface, spacing: float, lo: float, hi: float) -> np.ndarray:
    """Per-vertex target spacing (same units as the surface) from curvature and thickness.

    The chord of a circle of curvature κ at spacing h deviates by about κ h² / 8, so a spacing
    h = sqrt(8 e / κ) keeps the deviation at e everywhere. e is set so that ``spacing`` is kept
    where the curvature is at the :data:`REFERENCE_PERCENTILE` (by area); the spacing is also at
    most :data:`THICKNESS_FRACTION` of the local thickness (the distance to the opposite side,
    by a ray cast inward), then clipped to [lo, hi].

    Curvature per vertex: |κ1| + |κ2| of a quadric fitted to the vertices within ``spacing``
    (:func:`absolute_curvature`; at least :data:`CURVATURE_REACH` input edges), the scale of
    the chord, so that noise and facets finer than the new edges (a marching-cubes staircase,
    scanner noise) do not count as curvature; averaged once with its neighbours.
    """
    v, f, vn = surface.vertices, surface.faces, surface.vertex_normal
    e = np.unique(np.sort(f[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1), axis=0)
    mean_edge = float(np.linalg.norm(v[e[:, 1]] - v[e[:, 0]], axis=1).mean())
    kappa = absolute_curvature(v, vn, max(spacing, CURVATURE_REACH * mean_edge))
    deg = np.bincount(e.ravel(), minlength=len(v)).astype(float)
    for _ in range(CURVATURE_SMOOTHING):
        smooth = kappa.copy()
        smooth += np.bincount(e[:, 0], weights=kappa[e[:, 1]], minlength=len(v))
        smooth += np.bincount(e[:, 1], weights=kappa[e[:, 0]], minlength=len(v))
        kappa = smooth / (1.0 + deg)
    vertex_area = np.zeros(len(v))
    for k in range(3):
        np.add.at(vertex_area, f[:, k], surface.face_area / 3.0)
    order = np.argsort(kappa)
    cum = np.cumsum(vertex_area[order])
    ref = kappa[order[min(np.searchsorted(cum, cum[-1] * REFERENCE_PERCENTILE / 100), len(v) - 1)]]
    tol = max(ref, 1e-12) * spacing**2 / 8.0
    h = np.sqrt(8.0 * tol / np.maximum(kappa, 1e-12))
    # local thickness: first hit of a ray from just inside the surface, inward
    eps = 1e-3 * spacing
    rays = np.hstack([v - eps * vn, -vn])
    thick = surface.first_hit(rays) + eps
    h = np.minimum(h, THICKNESS_FRACTION * np.where(np.isfinite(thick), thick, np.inf))
    return grade(np.clip(h, lo, hi), v, e, GRADATION)


def absolute_curvature(vertices: np.ndarray, normals: np.ndarray, radius: float) -> np.ndarray:
    """Per vertex, |κ1| + |κ2| (principal curvatures) of the surface at scale ``radius``.

    The vertices within ``radius`` of vertex i, in a frame with the normal axis along
    ``normals[i]``, are fitted (least squares) with the height z = a x² + b x y + c y² + d x +
    e y + g; the principal curvatures are the eigenvalues of [[2a, b], [b, 2c]] (exact for a
    small slope d, e). A vertex with fewer than six neighbours in reach gets 0.

    Why the sum: a linear triangle of edge h deviates from z = ½ xᵀ H x at its centroid by
    ½ R² times the mean normal curvature over its three corner directions, on average over
    the triangle's orientation (κ1 + κ2) R² / 4 (R = h / √3): a sphere deviates twice as much
    as a cylinder of the same largest curvature. The sum of absolute values keeps saddles
    (κ1 = −κ2, no deviation at the centroid but elsewhere) from counting as flat.
    """
    v = np.asarray(vertices, dtype=np.float64)
    n = len(v)
    near = cKDTree(v).query_ball_point(v, radius, workers=query_workers())
    counts = np.fromiter((len(x) for x in near), dtype=np.int64, count=n)
    j = np.concatenate([np.asarray(x, dtype=np.int64) for x in near])
    i = np.repeat(np.arange(n), counts)
    nz = np.asarray(normals, dtype=np.float64)
    # a tangent frame per vertex
    helper = np.where(np.abs(nz[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    t1 = np.cross(nz, helper)
    t1 /= np.maximum(np.linalg.norm(t1, axis=1), 1e-300)[:, None]
    t2 = np.cross(nz, t1)
    d = (v[j] - v[i]) / radius  # scaled: the normal equations stay well conditioned
    x = np.einsum("ij,ij->i", d, t1[i])
    y = np.einsum("ij,ij->i", d, t2[i])
    z = np.einsum("ij,ij->i", d, nz[i])
    design = np.stack([x * x, x * y, y * y, x, y, np.ones_like(x)], axis=1)
    ata = np.zeros((n, 6, 6))
    atz = np.zeros((n, 6))
    for p in range(6):
        atz[:, p] = np.bincount(i, weights=design[:, p] * z, minlength=n)
        for q in range(p, 6):
            ata[:, p, q] = ata[:, q, p] = np.bincount(
                i, weights=design[:, p] * design[:, q], minlength=n
            )
    ok = counts >= 6
    ata[~ok] = np.eye(6)
    ata += 1e-9 * np.eye(6)
    coef = np.linalg.solve(ata, atz[:, :, None])[:, :, 0]
    a, b, c = coef[:, 0], coef[:, 1], coef[:, 2]
    # eigenvalues of [[2a, b], [b, 2c]]: a + c ± sqrt((a - c)² + b²)
    root = np.sqrt((a - c) ** 2 + b * b)
    k = np.abs(a + c + root) + np.abs(a + c - root)
    return np.where(ok, k / radius, 0.0)


def grade(h: np.ndarray, vertices: np.ndarray, edges: np.ndarray, rate: float) -> np.ndarray:
    """The largest field below ``h`` that grows by at most ``rate`` per unit length along the
    mesh edges: h_i = min_j (h_j + rate · d_ij), d the edge-path distance (one Dijkstra run
    from a virtual source tied to every vertex j at length h_j / rate)."""
    from scipy import sparse
    from scipy.sparse import csgraph

    n = len(h)
    length = np.linalg.norm(vertices[edges[:, 1]] - vertices[edges[:, 0]], axis=1)
    rows = np.concatenate([edges[:, 0], edges[:, 1], np.full(n, n)])
    cols = np.concatenate([edges[:, 1], edges[:, 0], np.arange(n)])
    w = np.concatenate([length, length, np.maximum(h / rate, 1e-12)])
    graph = sparse.csr_matrix((w, (rows, cols)), shape=(n + 1, n + 1))
    dist = csgraph.dijkstra(graph, directed=True, indices=n)
    return np.minimum(h, rate * dist[:n])


def _feature_deviation(
    v_in: np.ndarray, lines: FeatureLines, v_out: np.ndarray, f_out: np.ndarray, step: float
) -> float:
    """Largest distance from the input's feature lines (sampled every ``step``) to the output."""
    if lines.empty:
        return 0.0
    pts = []
    for c in lines.chains:
        p = v_in[c]
        for a, b in zip(p[:-1], p[1:], strict=True):
            k = max(1, int(np.ceil(np.linalg.norm(b - a) / step)))
            t = np.linspace(0.0, 1.0, k + 1)[:, None]
            pts.append(a + t * (b - a))
    return float(point_to_mesh_distance(np.vstack(pts), v_out, f_out).max())


def remesh(
    vertices: np.ndarray,
    faces: np.ndarray,
    options: RemeshOptions | None = None,
    *,
    name: str = "mesh",
) -> RemeshResult:
    """Remesh a triangle mesh (module docstring). Raises :class:`InputError` for bad input."""
    opts = options if options is not None else RemeshOptions()
    opts.check()
    with thread_count(opts.threads):
        return _remesh(vertices, faces, opts, name)


def _remesh(vertices, faces, opts: RemeshOptions, name: str) -> RemeshResult:
    times: dict[str, float] = {}
    t_start = t = time.perf_counter()

    def lap(key: str) -> None:
        nonlocal t
        now = time.perf_counter()
        times[key] = now - t
        t = now

    checked = check_mesh(vertices, faces, name, intersections=opts.check_intersections)
    v_in, f_in = checked.vertices, checked.faces
    lap("check")
    lo, hi = v_in.min(axis=0), v_in.max(axis=0)
    diag = float(np.linalg.norm(hi - lo))
    if not diag > 0:
        raise InputError(f"{name}: all vertices coincide; nothing to remesh")
    centre = 0.5 * (lo + hi)
    area = float(
        0.5
        * np.linalg.norm(
            np.cross(*(v_in[f_in[:, 1:]] - v_in[f_in[:, :1]]).transpose(1, 0, 2)), axis=1
        ).sum()
    )
    if opts.spacing is not None:
        s0 = float(opts.spacing)
    elif opts.spacing_relative is not None:
        s0 = float(opts.spacing_relative) * diag
    elif opts.faces is not None:
        s0 = math.sqrt(4.0 * area / (math.sqrt(3.0) * opts.faces))
    else:
        e = v_in[f_in] - v_in[np.roll(f_in, -1, axis=1)]
        s0 = min(float(np.linalg.norm(e, axis=2).mean()), MAX_DEFAULT_SPACING * diag)
    estimate = area / (CELL_AREA * s0**2)
    if opts.adaptive:
        lo_abs = opts.min_spacing if opts.min_spacing is not None else ADAPTIVE_MIN * s0
        estimate = area / (CELL_AREA * lo_abs**2)
    if estimate > MAX_PARTICLES:
        raise InputError(
            f"{name}: a spacing of {s0:.4g} needs about {estimate:,.0f} particles, more than "
            f"{MAX_PARTICLES:,}; raise --spacing (or --min-spacing) or lower --faces"
        )
    topo_in = mesh_topology(v_in, f_in)
    surface = MeshSurface((v_in - centre) / s0, f_in)
    corner = opts.crease_angle if opts.crease_angle is not None else CORNER_ANGLE
    lines = feature_lines(surface.vertices, f_in, opts.crease_angle, corner)
    lap("features")

    rest_at = None
    field_v = None
    if opts.adaptive:
        lo_s = (opts.min_spacing / s0) if opts.min_spacing is not None else ADAPTIVE_MIN
        hi_s = (opts.max_spacing / s0) if opts.max_spacing is not None else ADAPTIVE_MAX
        if lo_s > hi_s:
            raise InputError(f"min spacing exceeds max spacing ({lo_s * s0} > {hi_s * s0})")
        field_v = spacing_field(surface, 1.0, lo_s, hi_s)
        if opts.faces is not None:
            # a face budget: scale the field so that its hexagonal cells hold ~N / 2 particles
            rest_f = field_v[f_in].mean(axis=1)
            cells = float(np.sum(surface.face_area / (CELL_AREA * rest_f**2)))
            field_v = field_v * math.sqrt(cells / max(0.5 * opts.faces, 1.0))

        def rest_at(points: np.ndarray, face: np.ndarray) -> np.ndarray:
            return field_v[f_in[face]].mean(axis=1)

    feats = place_feature_particles(surface, lines, rest_at)
    if rest_at is not None and feats.n:
        _, ff, _ = surface.closest(feats.position)
        feats.rest = rest_at(feats.position, ff)
    n_interior = _interior_count(surface, lines, feats, opts, topo_in, field_v)
    rng = np.random.default_rng(opts.seed)
    particles = seed(surface, feats, n_interior, rest_at, rng)
    lap("seed")
    particles = relax(surface, lines, particles, opts.steps, rest_at)
    particles = drop_near_lines(particles, lines, LINE_GAP)
    lap("relax")
    rim = rim_labels(surface, lines, particles)
    tv, tn, tf, tri_stats = triangulate_patches(surface, lines, particles, rest_at is not None, rim)
    match = particle_of(tv, particles)
    at = np.where(match >= 0, rim[np.maximum(match, 0)], -1)
    # one patch is one connected input: pieces of its triangulation are joined
    one = tri_stats["patches"] == 1
    tv, tn, tf, n_closed = close_gaps(tv, tn, tf, at, "rim", join=one)
    tri_stats["gaps_closed"] = n_closed
    match = np.concatenate([match, np.full(len(tv) - len(match), -1)])
    stray = stray_pieces(surface, tv, tf)
    tri_stats["stray_faces_dropped"] = int(stray.sum())
    tf = tf[~stray]
    # the vertices of what was dropped (here or as debris by close_gaps) go too
    used = np.zeros(len(tv), dtype=bool)
    used[tf.ravel()] = True
    tv, tn, match, tf = tv[used], tn[used], match[used], (np.cumsum(used) - 1)[tf]
    lap("triangulate")
    fixed = (match >= 0) & (particles.kind[np.maximum(match, 0)] != 0)
    # the rim of the mesh stays too: a vertex on it that is no feature particle (a particle
    # where the triangulation cut inside the rim, a copy a repair split off a pinch) has
    # neighbours on one side only, and smoothing pulled it onto the chord of its two rim
    # neighbours (triangles of zero area on fitted face scans)
    e, counts, _, _ = edge_faces(tf, len(tv))
    fixed[e[counts == 1].ravel()] = True
    vertex_of = np.full(particles.n, -1)
    vertex_of[match[match >= 0]] = np.flatnonzero(match >= 0)
    pairs = vertex_of[line_edges(particles, lines)]
    edges = pairs[(pairs >= 0).all(axis=1)]
    # the plain centroid also for adaptive meshes: weighting it by the spacing kept the grading
    # no better (same Hausdorff) and left worse triangles (bunny: worst 20 vs 28 deg)
    vn, fn, stats = improve(tv, tf, fixed, surface, opts.smooth_rounds, None, edges)
    lap("improve")
    v_out = vn * s0 + centre
    f_out = fn
    normals = _vertex_normals(v_out, f_out)
    topo_out = mesh_topology(v_out, f_out)
    t_total = time.perf_counter() - t_start
    if len(f_out) == 0:
        raise InputError(
            f"{name}: the remeshed surface has no faces; the spacing {s0:.6g} is too large for "
            "this mesh (lower --spacing or raise --faces)"
        )
    cmp = compare_meshes((v_out, f_out), (v_in, f_in), n_samples=DISTANCE_SAMPLES, seed=opts.seed)
    deviation = _feature_deviation(v_in, lines, v_out, f_out, 0.25 * s0)
    quality_in, quality_out = triangle_quality(v_in, f_in), triangle_quality(v_out, f_out)
    lap("measure")
    preserved = topology_preserved(topo_in, topo_out)
    warnings = []
    if not preserved:
        warnings.append(
            "topology changed: input "
            f"{_topo_text(topo_in)}, output {_topo_text(topo_out)}; a spacing below the "
            "narrowest part or hole of the input keeps it"
        )
    report = {
        "input": {
            "vertices": int(len(vertices)),
            "faces": int(len(faces)),
            "repairs": checked.repairs,
            "area": area,
            "bbox_diag": diag,
            "topology": _summary(topo_in),
            "triangle_quality": quality_in,
        },
        "options": asdict(opts),
        "spacing": s0,
        "spacing_range": (
            None if field_v is None else [float(field_v.min() * s0), float(field_v.max() * s0)]
        ),
        "particles": {
            "total": int(particles.n),
            "interior": int(np.sum(particles.kind == 0)),
            "on_lines": int(np.sum(particles.kind == 1)),
            "corners": int(np.sum(particles.kind == 2)),
        },
        "features": {
            "boundary_edges": lines.n_boundary_edges,
            "crease_edges": lines.n_crease_edges,
            "lines": len(lines.chains),
            "corners": int(len(lines.corners)),
            "deviation_max": deviation,
            "deviation_max_relative": deviation / diag,
        },
        "output": {
            "topology": _summary(topo_out),
            "triangle_quality": quality_out,
        },
        "topology_preserved": bool(preserved),
        "distance": {
            "hausdorff": cmp["hausdorff"],
            "hausdorff_relative": cmp["hausdorff_relative"],
            "hausdorff95": cmp["hausdorff95"],
            "hausdorff95_relative": cmp["hausdorff95_relative"],
            "mean_to_input": cmp["mesh_to_reference"]["mean"],
            "mean_to_input_relative": cmp["mesh_to_reference"]["mean"] / diag,
            "chamfer_l1_relative": cmp["chamfer_l1_relative"],
            "samples": DISTANCE_SAMPLES,
        },
        "triangulation": {**tri_stats, **stats},
        "timings": {**times, "total": t_total + times["measure"]},
        "warnings": warnings,
    }
    return RemeshResult(v_out, f_out, normals, report)


def _topo_text(t: dict[str, Any]) -> str:
    return (
        f"{t['components']} component(s), {t['boundary_loops']} boundary loop(s), "
        f"Euler characteristic {t['euler_characteristic']}"
    )


def _interior_count(surface, lines, feats: Particles, opts, topo_in, field_v) -> int:
    n_b = int(on_boundary(lines, feats).sum())
    n_feat = feats.n
    if opts.faces is not None:
        # F = 2 V - B - 2 chi
        chi = topo_in["euler_characteristic"]
        total = (opts.faces + n_b + 2 * chi) / 2.0
        return max(0, int(round(total - n_feat)))
    if field_v is None:
        cells = surface.area / CELL_AREA
    else:
        rest_f = field_v[surface.faces].mean(axis=1)
        cells = float(np.sum(surface.face_area / (CELL_AREA * rest_f**2)))
    # a boundary particle owns half a cell, a crease particle a whole one
    return max(0, int(round(cells - (n_feat - n_b) - 0.5 * n_b)))


def _vertex_normals(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    from ..mesh import face_area_vectors

    cross = face_area_vectors(v, f)
    out = corner_sum(f, cross, len(v))
    return out / np.maximum(np.linalg.norm(out, axis=1), 1e-300)[:, None]


def report_path_for(mesh_path: str | Path) -> Path:
    """``out.ply`` -> ``out.report.json``."""
    p = Path(mesh_path)
    return p.with_name(p.stem + ".report.json")


def remesh_file(
    input_path: str | Path,
    output_path: str | Path,
    options: RemeshOptions | None = None,
    *,
    write_report: bool = True,
    mkdir: bool = False,
    ascii: bool = False,
) -> RemeshResult:
    """Read a mesh, remesh it, and write the mesh and its report together (or nothing)."""
    from ..io import atomic_output, atomic_outputs, check_output_path, read_mesh, write_mesh
    from ..serialize import dumps

    input_path = Path(input_path)
    if Path(output_path).suffix.lower() not in (".ply", ".obj"):
        raise InputError(f"{output_path}: the mesh is written as .ply or .obj")
    output_path = check_output_path(Path(output_path), inputs=[input_path], mkdir=mkdir)
    report_path = report_path_for(output_path) if write_report else None
    if report_path is not None:
        check_output_path(report_path, inputs=[input_path, output_path], mkdir=mkdir)
    vertices, faces = read_mesh(input_path)
    result = remesh(vertices, faces, options, name=str(input_path))
    result.report["input"]["path"] = str(input_path)
    result.report["output"]["path"] = str(output_path)
    result.report["output"]["report"] = None if report_path is None else str(report_path)
    with atomic_outputs() as outputs:
        write_mesh(
            output_path, result.vertices, result.faces, result.normals, ascii=ascii, outputs=outputs
        )
        if report_path is not None:
            with atomic_output(report_path, outputs) as tmp:
                tmp.write_text(dumps(result.report) + "\n")
    return result
