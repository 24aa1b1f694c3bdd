"""Seed particles on a mesh by area and relax them with the oriented-particle engine.

All lengths here are normalised by the target spacing s (r0 = s, as in the fit): a particle's
rest spacing is ``rest_i`` (1 when uniform).

1. Feature particles: every feature line (:class:`~recon.remesh.surface.FeatureLines`) gets
   particles at equal steps of ``∫ ds / rest(s)`` along it; its corners get fixed particles.
2. Interior particles: area-uniform samples are Poisson-disk thinned against the feature
   particles and each other, then trimmed or topped up to the count a hexagonal sheet of that
   spacing has (a cell of area √3/2 · rest² per particle), so the sheet is at its rest density
   from the start and needs no growth (S&T92 §9). With a graded spacing the samples are drawn
   with density ∝ 1/rest² and thinned with a radius per sample, ∝ its rest spacing
   (:func:`recon.geometry.poisson_disk_thin_graded`), so that the seeds keep that density and
   are as evenly spread as the uniform ones.
3. Relax in chunks of :data:`CHUNK` steps with :class:`~recon.dynamics.Simulation` (spacing
   term only: the mesh fixes every particle's normal), anchored to the closest points of the
   mesh; after every chunk each interior particle is moved onto its
   closest point on the mesh and takes its face normal, each feature particle onto its own
   line (it slides along it), and corners stay where they are (pinned).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from ..config import ReconConfig
from ..dynamics import Simulation
from ..errors import DivergenceError
from ..geometry import poisson_disk_thin, poisson_disk_thin_graded
from ..kernels.options import query_workers
from ..params import PhysicsParams
from ..state import ParticleState
from .surface import FeatureLines, MeshSurface

__all__ = ["CELL_AREA", "CHUNK", "Particles", "place_feature_particles", "relax", "seed"]

#: Area of a particle's cell in a hexagonal sheet of spacing 1.
CELL_AREA = math.sqrt(3.0) / 2.0
#: Steps between two projections onto the mesh.
CHUNK = 10
#: Interior seeds are Poisson-disk thinned at this fraction of the local spacing.
SEED_THINNING = 0.75
#: The thinning radius is corrected once when the seed count is off by more than this fraction.
SEED_COUNT_TOLERANCE = 0.02
#: Area samples drawn per interior particle before thinning.
CANDIDATES_PER_PARTICLE = 4
#: Potential energy per particle above which the relaxation counts as diverged.
EXPLODING_ENERGY = 1e6

#: ``rest_at(points (m, 3), faces (m,)) -> (m,)`` rest spacing at points on the mesh.
RestFn = Callable[[np.ndarray, np.ndarray], np.ndarray]


@dataclass
class Particles:
    """Particles on the mesh (normalised units).

    ``kind``: 0 interior, 1 on a feature line (``chain`` gives which), 2 fixed corner.
    """

    position: np.ndarray
    normal: np.ndarray
    rest: np.ndarray
    kind: np.ndarray
    chain: np.ndarray

    @property
    def n(self) -> int:
        return len(self.position)


def place_feature_particles(
    surface: MeshSurface, lines: FeatureLines, rest_at: RestFn | None
) -> Particles:
    """Corners, then particles spread along every chain at its local spacing."""
    v = surface.vertices
    pos = [v[lines.corners]]
    kind = [np.full(len(lines.corners), 2, dtype=np.int8)]
    chain = [np.full(len(lines.corners), -1, dtype=np.int64)]
    for c, verts in enumerate(lines.chains):
        p = v[verts]
        seg = np.linalg.norm(np.diff(p, axis=0), axis=1)
        if rest_at is None:
            rest = np.ones(len(p))
        else:
            _, face, _ = surface.closest(p)
            rest = rest_at(p, face)
        # arc length measured in local spacings: particles at its integer steps
        steps = seg / np.maximum(0.5 * (rest[1:] + rest[:-1]), 1e-12)
        cum = np.concatenate([[0.0], np.cumsum(steps)])
        closed = bool(lines.closed[c])
        k = max(3 if closed else 1, int(round(cum[-1])))
        at = np.linspace(0.0, cum[-1], k + 1)
        # a closed loop without a corner repeats its start; a chain's ends are corners
        at = at[:-1] if closed and verts[0] not in set(lines.corners.tolist()) else at[1:-1]
        if len(at) == 0:
            continue
        i = np.clip(np.searchsorted(cum, at, side="right") - 1, 0, len(seg) - 1)
        t = (at - cum[i]) / np.maximum(steps[i], 1e-300)
        pos.append(p[i] + t[:, None] * (p[i + 1] - p[i]))
        kind.append(np.ones(len(at), dtype=np.int8))
        chain.append(np.full(len(at), c, dtype=np.int64))
    position = np.concatenate(pos) if pos else np.zeros((0, 3))
    normal = _feature_normals(surface, lines, position)
    return Particles(
        position=position,
        normal=normal,
        rest=np.ones(len(position)),
        kind=np.concatenate(kind),
        chain=np.concatenate(chain),
    )


def _feature_normals(surface: MeshSurface, lines: FeatureLines, position: np.ndarray):
    """Vertex normal of the nearest line vertex (mean of the faces on both sides)."""
    if len(position) == 0:
        return np.zeros((0, 3))
    verts = np.unique(np.concatenate([*lines.chains, lines.corners]))
    _, near = cKDTree(surface.vertices[verts]).query(position, workers=query_workers())
    return surface.vertex_normal[verts[near]]


def seed(
    surface: MeshSurface,
    features: Particles,
    n_interior: int,
    rest_at: RestFn | None,
    rng: np.random.Generator,
) -> Particles:
    """Add ``n_interior`` area-sampled interior particles to the feature particles."""
    if n_interior <= 0:
        return features
    m = CANDIDATES_PER_PARTICLE * n_interior
    cand, face = surface.sample(m, rng)
    foot, nrm = cand, surface.face_normal[face]
    rest = np.ones(m) if rest_at is None else rest_at(foot, face)
    if rest_at is not None:
        # density ~ 1/rest^2: keep each sample with probability (min rest / rest)^2, from
        # enough samples that ~m are kept
        prob = (rest.min() / rest) ** 2
        extra = int(m / max(float(prob.mean()), 1e-6)) - m
        if extra > 0:
            more, more_face = surface.sample(extra, rng)
            cand, face = np.vstack([cand, more]), np.concatenate([face, more_face])
            foot, nrm = cand, surface.face_normal[face]
            rest = rest_at(foot, face)
            prob = (rest.min() / rest) ** 2
        keep = rng.random(len(cand)) < prob
        cand, foot, face, nrm, rest = cand[keep], foot[keep], face[keep], nrm[keep], rest[keep]
    n_feat = features.n
    pts = np.vstack([features.position, foot])
    order = np.concatenate([np.arange(n_feat), n_feat + rng.permutation(len(foot))])
    if rest_at is None:
        radius = SEED_THINNING * float(rest.min())

        def thin(scale: float) -> np.ndarray:
            return poisson_disk_thin(pts, scale * radius, order, keep_first=n_feat)[n_feat:]
    else:
        # graded: a radius per sample, SEED_THINNING x its rest spacing, so that the kept
        # density follows 1/rest^2 (one radius for all evened it out: bunny realized/target
        # spacing 1.36 finest, 0.75 coarsest) and the seeds are as evenly spread as the
        # uniform ones (random seeds of density 1/rest^2 left clumps that the relaxation did
        # not undo: error 2-14 % above a uniform mesh of the same edge length)
        radius_i = SEED_THINNING * np.concatenate([features.rest, rest])

        def thin(scale: float) -> np.ndarray:
            return poisson_disk_thin_graded(pts, scale * radius_i, order, n_feat)[n_feat:]

    scale = 1.0
    kept = thin(scale)
    if abs(int(kept.sum()) - n_interior) > SEED_COUNT_TOLERANCE * n_interior:
        # the count of a maximal Poisson-disk set goes as 1/radius^2: one correction brings
        # it near the target, so that few particles are dropped or added at random below
        scale *= math.sqrt(max(int(kept.sum()), 1) / n_interior)
        kept = thin(scale)
    idx = np.flatnonzero(kept)
    if len(idx) > n_interior:
        idx = np.sort(rng.choice(idx, n_interior, replace=False))
    elif len(idx) < n_interior:
        rest_idx = np.flatnonzero(~kept)
        tree = cKDTree(np.vstack([features.position, foot[idx]]))
        d, _ = tree.query(foot[rest_idx], workers=query_workers())
        far = rest_idx[np.argsort(-d / rest[rest_idx], kind="stable")]
        idx = np.sort(np.concatenate([idx, far[: n_interior - len(idx)]]))
    return Particles(
        position=np.vstack([features.position, foot[idx]]),
        normal=np.vstack([features.normal, nrm[idx]]),
        rest=np.concatenate([features.rest, rest[idx]]),
        kind=np.concatenate([features.kind, np.zeros(len(idx), dtype=np.int8)]),
        chain=np.concatenate([features.chain, np.full(len(idx), -1, dtype=np.int64)]),
    )


def relax(
    surface: MeshSurface,
    lines: FeatureLines,
    particles: Particles,
    steps: int,
    rest_at: RestFn | None,
    cfg: ReconConfig | None = None,
) -> Particles:
    """Relax the particles over the mesh (module docstring); returns the moved particles (in
    the order given).

    Raises
    ------
    DivergenceError
        The energy became non-finite or exploded.
    """
    cfg = cfg if cfg is not None else ReconConfig()
    params = PhysicsParams.from_config(cfg, spacing=1.0)
    state = ParticleState.from_points(particles.position, particles.normal)
    state.rest = particles.rest
    state.set_pinned(particles.kind == 2)
    # the surface gives every particle its normal (it takes its face's normal after each
    # projection), so the orientation terms have nothing to do: spacing only, as in Turk's
    # repulsion (the same mesh quality, a third less time)
    state.set_oriented(False)
    sim = Simulation(state, params)
    # seeds come in random order; sorted by grid cell, neighbours sit close in memory (the
    # pair loop, the neighbour lists and the closest-point queries all run faster)
    order = sim.sort_particles()
    kind, chain_of = particles.kind[order], particles.chain[order]
    interior = kind == 0
    sliding = kind == 1
    chain = chain_of[sliding]
    dyn = cfg.dynamics
    done = 0
    while done < steps:
        n = min(CHUNK, steps - done)
        # every particle is on the mesh here (seeded on it, then projected after each chunk):
        # its own position and normal are its anchor
        sim.set_anchors(
            state.position.copy(), state.normal.copy(), dyn.fidelity, dyn.fidelity_normal
        )
        stats = sim.run(n)
        if not (
            math.isfinite(stats.kinetic)
            and math.isfinite(stats.potential)
            and stats.potential <= EXPLODING_ENERGY * max(state.n, 1)
        ):
            raise DivergenceError(
                f"particle dynamics diverged during the relaxation (energy kinetic "
                f"{stats.kinetic:.3g}, potential {stats.potential:.3g})"
            )
        done += n
        # moved in place: the engine measures displacements against its own reference
        # positions, so the neighbour list is rebuilt when the projections add up
        _project(surface, lines, state, interior, sliding, chain, rest_at)
    # back in the order given: corners are matched to the input's by their order
    back = np.argsort(order)
    return Particles(
        position=state.position[back],
        normal=_normals_after(surface, lines, state, kind)[back],
        rest=state.rest[back],
        kind=particles.kind.copy(),
        chain=particles.chain.copy(),
    )


def _project(surface, lines, state, interior, sliding, chain, rest_at) -> None:
    pos = state.position.copy()
    nrm = state.normal.copy()
    foot, face, fn = surface.closest(pos[interior])
    pos[interior], nrm[interior] = foot, fn
    if sliding.any():
        pos[sliding] = lines.project(pos[sliding], chain)
    state.position = pos
    state.normal = nrm
    if rest_at is not None and interior.any():
        rest = state.rest.copy()
        rest[interior] = rest_at(foot, face)
        state.rest = rest


def _normals_after(surface, lines, state, kind) -> np.ndarray:
    nrm = state.normal.copy()
    feat = kind != 0
    if feat.any():
        nrm[feat] = _feature_normals(surface, lines, state.position[feat])
    return nrm


def drop_near_lines(particles: Particles, lines: FeatureLines, gap: float) -> Particles:
    """Remove interior particles closer than ``gap`` x their rest spacing to a feature line.

    Closest-point projection puts any point beyond a convex crease onto the crease itself, so
    interior particles collect along creases during the relaxation; meshed, they would cut the
    crease with triangles that skip its own particles.
    """
    interior = np.flatnonzero(particles.kind == 0)
    if lines.empty or len(interior) == 0:
        return particles
    seg = lines.segments
    length = np.linalg.norm(seg[:, 1] - seg[:, 0], axis=1)
    step = 0.1 * gap * float(particles.rest.min())
    k = np.maximum(1, np.ceil(length / step).astype(np.int64))
    which = np.repeat(np.arange(len(seg)), k + 1)
    t = np.concatenate([np.linspace(0.0, 1.0, m + 1) for m in k])
    samples = seg[which, 0] + t[:, None] * (seg[which, 1] - seg[which, 0])
    d, _ = cKDTree(samples).query(particles.position[interior], workers=query_workers())
    drop = interior[d < gap * particles.rest[interior]]
    keep = np.ones(particles.n, dtype=bool)
    keep[drop] = False
    return Particles(
        position=particles.position[keep],
        normal=particles.normal[keep],
        rest=particles.rest[keep],
        kind=particles.kind[keep],
        chain=particles.chain[keep],
    )


def line_edges(particles: Particles, lines: FeatureLines) -> np.ndarray:
    """(k, 2) particle index pairs that follow each feature line: its particles in arc-length
    order, from the corner at its start to the corner at its end (closed loops wrap)."""
    from .surface import chain_order

    corner_set = {int(w): i for i, w in enumerate(lines.corners)}
    corner_index = np.flatnonzero(particles.kind == 2)
    sliding = np.flatnonzero(particles.kind == 1)
    arc = chain_order(lines, particles.position[sliding], particles.chain[sliding])
    pairs = []
    for c, verts in enumerate(lines.chains):
        members = sliding[particles.chain[sliding] == c]
        members = members[np.argsort(arc[particles.chain[sliding] == c], kind="stable")]
        seq = list(members)
        start, end = corner_set.get(int(verts[0])), corner_set.get(int(verts[-1]))
        if start is not None:
            seq.insert(0, int(corner_index[start]))
        if end is not None:
            seq.append(int(corner_index[end]))
        elif lines.closed[c] and len(seq) > 2:
            seq.append(seq[0])
        pairs.extend((a, b) for a, b in zip(seq[:-1], seq[1:], strict=True) if a != b)
    return np.array(pairs, dtype=np.int64).reshape(-1, 2)
