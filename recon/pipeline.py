"""The one entry point of the reconstruction: points in, mesh + particles + report out.

Schedule (S&T92 §7, with the changes of ``DESIGN.md`` §4):

1. normals (estimated or from the file) and the rest spacing r0 from the data;
2. seeds: Poisson-disk thinned samples on their local data planes, pinned;
3. growth rounds: relax ``relax_steps`` steps with the fidelity pull on, then the growing and
   stretching rules propose particles that are accepted when supported by the data; stop when
   a round adds fewer than ``min_add_fraction`` of the particles and the sheet is at rest;
4. release the seeds and relax ``release_steps`` steps (smoothing, fidelity pull kept);
5. drop particles farther than ``trim_distance`` from the data, triangulate, fill small holes;
6. measure the result (topology, triangle quality, fidelity to the input).

All dynamics run in normalised coordinates (positions relative to the cloud's origin, divided
by r0), so nothing depends on the input's units or offset.

References
----------
[ST92] Szeliski & Tonnesen 1992, §7 "Surface fitting" and §8.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from . import __version__
from .config import ReconConfig, config_to_dict, with_values
from .dynamics import PhysicsParams, Simulation
from .errors import DivergenceError, InputError, LimitExceeded
from .geometry import bbox_diagonal, median_nearest_neighbor_distance
from .growth import accept_candidates, grow_candidates, neighbor_csr, stretch_candidates
from .io import PointCloud
from .metrics import distance_stats, point_to_mesh_distance, quality_report, sample_surface
from .normals import choose_neighborhood_size, compute_normals
from .seeds import select_seeds
from .state import ParticleState
from .surface import DataSurface
from .triangulate import triangulate_particles

log = logging.getLogger(__name__)

#: Covering radius of a hexagonal sheet at spacing 1 is 1/sqrt(3) ~ 0.577; a data point
#: within this distance [r0] of a particle counts as covered by the sheet.
COVER_RADIUS = 0.65
#: Anchors (nearest data planes) are refreshed this often during relaxation [steps].
ANCHOR_REFRESH = 5
#: Growth rounds run during the release phase: unpinning the seeds lets the sheet relax, which
#: opens small gaps; refilling them keeps ball pivoting from bridging them with long edges.
RELEASE_REFILLS = 3

#: Potential energy per particle above which the dynamics count as exploding (a sheet at rest
#: has |E| of order 1 per particle; coincident particles make it grow without bound).
EXPLODING_ENERGY = 1e6
#: Largest cell grid (cells of side r0 over the data's bounding box) the neighbour search accepts.
MAX_GRID_CELLS = 2.0**60

ProgressFn = Callable[[str, dict[str, Any]], None]


@dataclass
class Mesh:
    """A triangle mesh in absolute (file) coordinates."""

    vertices: np.ndarray  # (V, 3) float64 [length]
    faces: np.ndarray  # (F, 3) int64
    normals: np.ndarray  # (V, 3) float64 unit vertex normals


@dataclass
class Particles:
    """The final oriented particles in absolute (file) coordinates."""

    positions: np.ndarray  # (n, 3) float64 [length]
    normals: np.ndarray  # (n, 3) float64


@dataclass
class FitResult:
    mesh: Mesh
    particles: Particles
    report: dict[str, Any]
    origin: np.ndarray = field(default_factory=lambda: np.zeros(3))


#: Area per point of a uniform random sample is about AREA_PER_POINT x (median NN distance)^2,
#: and a hexagonal sheet at spacing r0 holds one particle per 0.866 r0^2: together they predict
#: the particle count for a given r0 (used by the resolution floor).
AREA_PER_POINT = 4.0


def choose_spacing(points: np.ndarray, cfg: ReconConfig) -> tuple[float, float]:
    """Rest spacing r0 [length] and the median nearest-neighbour distance of the data.

    By default r0 = ``spacing_factor`` x median spacing, lowered (not below 0.8 x median
    spacing) so that the sheet gets about ``min_particles`` particles: sparse inputs get
    particles between their samples (S&T92 §7) instead of a mesh coarser than the shape.
    """
    d_nn = median_nearest_neighbor_distance(points)
    s = cfg.seeds
    if s.spacing is not None:
        r0 = s.spacing
    elif s.spacing_relative is not None:
        r0 = s.spacing_relative * bbox_diagonal(points)
    else:
        factor = s.spacing_factor
        if s.min_particles > 0:
            floor = math.sqrt(AREA_PER_POINT * len(points) / (0.866 * s.min_particles))
            factor = min(factor, max(floor, 0.8))
        r0 = factor * d_nn
    if not (r0 > 0 and math.isfinite(r0)):
        msg = f"cannot derive a rest spacing: the median point spacing is {d_nn!r}"
        if d_nn == 0.0:
            msg += " (most points are exact duplicates: set io.merge_duplicates: true)"
        raise InputError(msg + "; or give --spacing")
    return float(r0), float(d_nn)


#: On a surface sampled uniformly at random, 95 % of the surface lies within about 2.1 median
#: nearest-neighbour spacings of a sample (Poisson process: P(d > t) = exp(-pi rho t^2), with
#: rho ~ 0.22 / spacing^2). Mesh farther than max(r0, this) from every input point has grown
#: past the data rather than between samples.
SAMPLING_REACH = 2.1
#: Default max_gap, in median data spacings.
AUTO_GAP = 10.0


class _Clock:
    """Wall-clock accounting per phase, and the run's time limit."""

    def __init__(self, limit: float | None) -> None:
        self.start = time.perf_counter()
        self.limit = limit
        self.phases: dict[str, float] = {}
        self._t = self.start

    def lap(self, phase: str) -> None:
        now = time.perf_counter()
        self.phases[phase] = self.phases.get(phase, 0.0) + now - self._t
        self._t = now

    def check(self) -> None:
        if self.limit is not None and time.perf_counter() - self.start > self.limit:
            raise LimitExceeded(
                f"time limit of {self.limit:g} s reached "
                "(raise dynamics.time_limit or --time-limit)"
            )


class _Fitter:
    """State of one reconstruction (normalised units)."""

    def __init__(
        self,
        surface: DataSurface,
        cfg: ReconConfig,
        rng: np.random.Generator,
        clock: _Clock,
        on_progress: ProgressFn | None,
    ) -> None:
        self.surface = surface
        self.cfg = cfg
        self.rng = rng
        self.clock = clock
        self.on_progress = on_progress
        self.steps = {"grow": 0, "release": 0}
        self.history: dict[str, list] = {
            "step": [],
            "particles": [],
            "kinetic": [],
            "coverage": [],
            "phase": [],
        }
        self.warnings: list[str] = []
        self.stop_reason = ""
        n = surface.n_points
        take = rng.choice(n, size=min(n, 20000), replace=False) if n > 20000 else np.arange(n)
        self.cover_sample = surface.points[np.sort(take)]

    # -- helpers -------------------------------------------------------------------------
    def total_steps(self) -> int:
        return self.steps["grow"] + self.steps["release"]

    def coverage(self, positions: np.ndarray) -> float:
        d, _ = cKDTree(positions).query(self.cover_sample, k=1, workers=-1)
        return float(np.mean(d <= COVER_RADIUS))

    def relax(self, sim: Simulation, state: ParticleState, n_steps: int, phase: str) -> float:
        dyn = self.cfg.dynamics
        kinetic = 0.0
        done = 0
        while done < n_steps:
            if self.total_steps() >= dyn.max_steps:
                break
            chunk = min(ANCHOR_REFRESH, n_steps - done, dyn.max_steps - self.total_steps())
            pts, nrm, _ = self.surface.anchors(state.position)
            sim.set_anchors(pts, nrm, dyn.fidelity, dyn.fidelity_normal)
            stats = sim.run(chunk)
            if not (
                math.isfinite(stats.kinetic)
                and math.isfinite(stats.potential)
                and stats.potential <= EXPLODING_ENERGY * max(state.n, 1)
            ):
                raise DivergenceError(
                    f"particle dynamics diverged at step {self.total_steps() + chunk}: energy "
                    f"kinetic {stats.kinetic:.3g}, potential {stats.potential:.3g} for "
                    f"{state.n} particles"
                )
            kinetic = stats.kinetic / max(state.n, 1)
            done += chunk
            self.steps[phase] += chunk
            self.clock.check()
        return kinetic

    def record(self, phase: str, state: ParticleState, kinetic: float, coverage: float) -> None:
        h = self.history
        h["step"].append(self.total_steps())
        h["particles"].append(int(state.n))
        h["kinetic"].append(float(kinetic))
        h["coverage"].append(float(coverage))
        h["phase"].append(phase)
        if self.on_progress is not None:
            self.on_progress(
                phase,
                {
                    "step": self.total_steps(),
                    "particles": int(state.n),
                    "kinetic": kinetic,
                    "coverage": coverage,
                    "max_steps": self.cfg.dynamics.max_steps,
                },
            )

    def run_phase(
        self,
        phase: str,
        state: ParticleState,
        params: PhysicsParams,
        run: Callable[[Simulation, ParticleState], None],
    ) -> tuple[ParticleState, PhysicsParams]:
        """Run one phase; if the dynamics diverge, restart it once from its start, dt halved.

        Returns the state after the phase (a restored copy after a restart) and the physics
        parameters in use (with the halved dt after a restart, for the phases that follow).
        """
        saved = state.copy()
        steps, stop_reason = dict(self.steps), self.stop_reason
        n_history, n_warnings = len(self.history["step"]), len(self.warnings)
        try:
            run(Simulation(state, params), state)
            return state, params
        except DivergenceError as exc:
            first = exc
        params = replace(params, dt=0.5 * params.dt)
        log.warning(
            "%s; restarting the %s phase with dynamics.dt halved to %g", first, phase, params.dt
        )
        self.steps, self.stop_reason = steps, stop_reason
        for values in self.history.values():
            del values[n_history:]
        del self.warnings[n_warnings:]
        self.warnings.append(
            f"the dynamics diverged during {phase} ({first}); the phase was "
            f"restarted with dynamics.dt = {params.dt:g}"
        )
        state = saved
        try:
            run(Simulation(state, params), state)
        except DivergenceError as exc:
            raise DivergenceError(
                f"the particle dynamics diverged during {phase}, also after restarting it with "
                f"dynamics.dt halved to {params.dt:g} ({exc}); lower dynamics.dt or raise the "
                "spacing, and check the input for clusters of near-duplicate points"
            ) from None
        return state, params

    # -- phases --------------------------------------------------------------------------
    def make_seeds(self) -> tuple[ParticleState, np.ndarray]:
        s = self.surface
        idx = select_seeds(s.points, self.cfg.seeds.thinning, self.rng)
        pos, pn, _ = s.project(s.points[idx])
        cap = self.cfg.dynamics.max_particles
        if len(idx) > cap:
            raise LimitExceeded(
                f"{len(idx)} seed particles exceed dynamics.max_particles={cap}; "
                "raise the cap or the spacing"
            )
        state = ParticleState.from_points(pos, pn, pinned=True)
        return state, pos

    def grow_round(self, sim: Simulation, state: ParticleState) -> int:
        """One application of the growing and stretching rules; returns particles added."""
        g = self.cfg.growth
        dyn = self.cfg.dynamics
        pos, nrm = state.position, state.normal
        tree = cKDTree(pos)
        offsets, indices = neighbor_csr(tree, state.n, g.grow_radius)
        frontier = np.diff(offsets) <= g.max_neighbors
        cands = np.vstack(
            [
                grow_candidates(pos, nrm, offsets, indices, g),
                stretch_candidates(pos, nrm, tree, frontier, g),
            ]
        )
        acc = accept_candidates(cands, tree, self.surface, self.seed_tree, self.seed_points, g)
        added = len(acc.positions)
        room = dyn.max_particles - state.n
        if added > room:
            acc.positions, acc.normals = acc.positions[:room], acc.normals[:room]
            added = room
            self.stop_reason = f"particle cap dynamics.max_particles={dyn.max_particles} reached"
            self.warnings.append(self.stop_reason)
        if added:
            state.add(acc.positions, acc.normals, pinned=False)
            sim.notify_changed()
        log.debug(
            "growth: %d candidates, %d added (%d close, %d unsupported, %d off-plane), "
            "%d particles",
            acc.n_candidates,
            added,
            acc.n_too_close,
            acc.n_unsupported,
            acc.n_off_plane,
            state.n,
        )
        return added

    def grow(self, sim: Simulation, state: ParticleState, seed_points: np.ndarray) -> None:
        g = self.cfg.growth
        dyn = self.cfg.dynamics
        self.seed_points = seed_points
        self.seed_tree = cKDTree(seed_points)
        previous_added = None
        for rnd in range(g.max_rounds if g.enabled else 0):
            kinetic = self.relax(sim, state, dyn.relax_steps, "grow")
            if self.total_steps() >= dyn.max_steps:
                self.stop_reason = f"step cap dynamics.max_steps={dyn.max_steps} reached"
                self.warnings.append(self.stop_reason + " during growth")
                break
            added = self.grow_round(sim, state)
            self.record("grow", state, kinetic, self.coverage(state.position))
            if self.stop_reason:
                break
            small = added <= g.min_add_fraction * state.n
            not_shrinking = previous_added is not None and added >= previous_added and added > 0
            if small or (not_shrinking and rnd > 5 and added < 0.05 * state.n):
                self.stop_reason = "converged: additions stopped"
                break
            previous_added = added
        else:
            if g.enabled:
                self.stop_reason = f"growth.max_rounds={g.max_rounds} reached"
        # settle what the last round added before the seeds let go
        kinetic = self.relax(sim, state, dyn.relax_steps, "grow")
        self.record("grow", state, kinetic, self.coverage(state.position))

    def release(self, sim: Simulation, state: ParticleState) -> None:
        """Unpin the seeds and smooth; the first chunks also refill gaps the release opens."""
        state.set_pinned(False)
        sim.notify_changed()
        dyn = self.cfg.dynamics
        remaining = dyn.release_steps
        chunk = 20
        refills = RELEASE_REFILLS if self.cfg.growth.enabled else 0
        while remaining > 0:
            n = min(chunk, remaining)
            kinetic = self.relax(sim, state, n, "release")
            remaining -= n
            if refills > 0 and remaining > 0 and not self.stop_reason.startswith("particle cap"):
                refills -= 1
                self.grow_round(sim, state)
            self.record("release", state, kinetic, self.coverage(state.position))
            if self.total_steps() >= dyn.max_steps:
                break


def reconstruct(
    cloud: PointCloud, config: ReconConfig | None = None, on_progress: ProgressFn | None = None
) -> FitResult:
    """Reconstruct a mesh from a point cloud.

    Parameters
    ----------
    cloud : PointCloud
        Points relative to ``cloud.origin``; normals are used when present and
        ``normals.mode`` allows it.
    config : ReconConfig, optional
        Defaults when omitted.
    on_progress : callable(phase, info), optional
        Called after every growth round and release chunk with the step count, particle
        count, kinetic energy and coverage.

    Returns
    -------
    FitResult
        Mesh and particles in absolute coordinates, and the report dictionary.
    """
    cfg = config if config is not None else ReconConfig()
    clock = _Clock(cfg.dynamics.time_limit)
    rng = np.random.default_rng(cfg.seed)
    points = np.asarray(cloud.points, dtype=np.float64)

    if cfg.normals.auto_scale:
        # resolve once: the normals and the local data surfaces share the neighbourhood size
        k = choose_neighborhood_size(points, cfg.normals.k)
        cfg = with_values(cfg, normals={"k": k, "auto_scale": False})
    normals, normals_info = compute_normals(cloud, cfg.normals)
    clock.lap("normals")
    clock.check()

    r0, d_nn = choose_spacing(points, cfg)
    span = points.max(axis=0) - points.min(axis=0)
    if float(np.prod(np.floor(span / r0) + 1.0)) > MAX_GRID_CELLS:
        raise InputError(
            f"the points span {', '.join(f'{x:.3g}' for x in span)} (x, y, z) but the rest "
            f"spacing r0 is {r0:.3g}: far too many cells for the neighbour search; remove far "
            "outliers or raise the spacing"
        )
    if cfg.growth.max_gap is None:
        cfg = with_values(cfg, growth={"max_gap": max(AUTO_GAP * d_nn / r0, 1.0)})
    diag = bbox_diagonal(points)
    surface = DataSurface.build(points / r0, normals, k=cfg.normals.k)
    clock.lap("setup")
    clock.check()

    fitter = _Fitter(surface, cfg, rng, clock, on_progress)
    state, seed_points = fitter.make_seeds()
    n_seeds = state.n
    params = PhysicsParams.from_config(cfg, spacing=1.0)
    state, params = fitter.run_phase(
        "growth", state, params, lambda sim, st: fitter.grow(sim, st, seed_points)
    )
    clock.lap("grow")
    state, params = fitter.run_phase("release", state, params, fitter.release)
    clock.lap("release")
    if params.dt != cfg.dynamics.dt:
        cfg = with_values(cfg, dynamics={"dt": params.dt})

    tri_cfg = cfg.triangulation
    projected, _, offset = surface.project(state.position)
    dist, _ = surface.nearest(state.position)
    keep = (np.abs(offset) <= tri_cfg.trim_distance) & (dist <= 0.5 * cfg.growth.max_gap)
    if tri_cfg.project_to_data:
        state.position = projected
    n_trimmed = int((~keep).sum())
    if n_trimmed:
        state.remove(keep)
    max_hole = tri_cfg.max_hole if tri_cfg.max_hole is not None else cfg.growth.max_gap
    tri = triangulate_particles(
        state.position,
        state.normal,
        tri_cfg,
        max_hole,
        is_covered=lambda c: surface.nearest(surface.project(c)[0])[0] < 1.0,
        project=lambda c: surface.project(c)[0],
    )
    clock.lap("triangulate")
    clock.check()

    origin = np.asarray(cloud.origin, dtype=np.float64)
    vertices = tri.vertices * r0 + origin
    mesh = Mesh(vertices, tri.faces, tri.normals)
    particles = Particles(state.position * r0 + origin, state.normal.copy())

    if len(tri.faces) == 0:
        raise InputError(
            "the reconstruction produced no triangles: the data may be too sparse "
            "for the spacing (try a smaller --spacing or a larger --max-gap)"
        )
    quality = quality_report(None, tri.vertices * r0, tri.faces)
    dist = point_to_mesh_distance(points, tri.vertices * r0, tri.faces)
    quality["fidelity"] = {
        "diag": diag,
        **distance_stats(dist, diag),
        "within_r0": float(np.mean(dist <= r0)),
    }
    # the other direction: does the mesh stay on the data (nothing grown past it)?
    samples, _ = sample_surface(tri.vertices, tri.faces, min(20_000, 4 * len(tri.faces)), cfg.seed)
    d_mesh, _ = surface.nearest(samples)
    reach = max(1.0, SAMPLING_REACH * d_nn / r0)
    quality["mesh_to_input"] = {
        **distance_stats(d_mesh * r0, diag),
        "within_r0": float(np.mean(d_mesh <= 1.0)),
        "reach": reach * r0,
        "within_reach": float(np.mean(d_mesh <= reach)),
    }
    clock.lap("report")
    report = {
        "oprecon_version": __version__,
        "input": {
            "points": int(len(points)),
            "bbox_diagonal": diag,
            "median_spacing": d_nn,
            "normals": normals_info,
        },
        "spacing": r0,
        "seeds": int(n_seeds),
        "particles": int(state.n),
        "particles_trimmed": n_trimmed,
        "steps": dict(fitter.steps),
        "time_s": {k: round(v, 4) for k, v in clock.phases.items()},
        "time_total_s": round(sum(clock.phases.values()), 4),
        "coverage": fitter.history["coverage"][-1] if fitter.history["coverage"] else None,
        "stop_reason": fitter.stop_reason,
        "warnings": fitter.warnings,
        "triangulation": tri.stats,
        "noise_estimate": surface.noise * r0,
        "history": fitter.history,
        "config": config_to_dict(cfg),
    }
    report.update(quality)
    return FitResult(mesh, particles, report, origin)


def fit(
    points: np.ndarray,
    config: ReconConfig | None = None,
    *,
    normals: np.ndarray | None = None,
    on_progress: ProgressFn | None = None,
) -> FitResult:
    """Python API: reconstruct from an (n, 3) array (and optional (n, 3) normals).

    Mirrors ``oprecon fit``: ``recon.fit(points, config) -> FitResult(mesh, particles, report)``.
    """
    from .io import cloud_from_arrays

    cloud = cloud_from_arrays(points, normals)
    return reconstruct(cloud, config, on_progress)


def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


def report_path_for(mesh_path: Path) -> Path:
    """``mesh.ply`` -> ``mesh.report.json`` beside it."""
    return mesh_path.with_name(mesh_path.stem + ".report.json")


def fit_file(
    input_path: str | Path,
    output_path: str | Path,
    config: ReconConfig | None = None,
    *,
    particles_path: str | Path | None = None,
    preview_path: str | Path | None = None,
    write_report: bool | None = None,
    mkdir: bool = False,
    on_progress: ProgressFn | None = None,
) -> FitResult:
    """Read ``input_path``, reconstruct, and write the mesh (+ report, particles, preview).

    Every output is written to a temporary file beside its target and renamed into place only
    after all of them were written, so a failure or an interrupt leaves no partial file.
    Writing onto the input is refused.
    """
    import json

    from .io import (
        atomic_output,
        atomic_outputs,
        check_output_path,
        read_points,
        write_mesh,
        write_points,
    )

    cfg = config if config is not None else ReconConfig()
    input_path = Path(input_path)
    output_path = check_output_path(Path(output_path), inputs=[input_path], mkdir=mkdir)
    want_report = cfg.output.write_report if write_report is None else write_report
    extra = [p for p in (particles_path, preview_path) if p is not None]
    if want_report:
        extra.append(report_path_for(output_path))
    for p in extra:
        check_output_path(Path(p), inputs=[input_path, output_path], mkdir=mkdir)
    cloud = read_points(
        input_path, max_points=cfg.io.max_points, merge_duplicates=cfg.io.merge_duplicates
    )
    result = reconstruct(cloud, cfg, on_progress)
    result.report["input"]["path"] = str(input_path)
    result.report["output"] = {"mesh": str(output_path)}
    normals = result.mesh.normals if cfg.output.vertex_normals else None
    with atomic_outputs() as outputs:  # all files appear together, or none
        write_mesh(
            output_path,
            result.mesh.vertices,
            result.mesh.faces,
            normals,
            ascii=cfg.io.ascii,
            outputs=outputs,
        )
        if particles_path is not None:
            result.report["output"]["particles"] = str(particles_path)
            write_points(
                Path(particles_path),
                result.particles.positions,
                result.particles.normals,
                ascii=cfg.io.ascii,
                outputs=outputs,
            )
        if preview_path is not None:
            from .render import render_mesh_png

            result.report["output"]["preview"] = str(preview_path)
            render_mesh_png(
                Path(preview_path),
                result.mesh.vertices,
                result.mesh.faces,
                history=result.report["history"],
                title=input_path.name,
                outputs=outputs,
            )
        if want_report:
            rpath = report_path_for(output_path)
            result.report["output"]["report"] = str(rpath)
            with atomic_output(rpath, outputs) as tmp:
                tmp.write_text(json.dumps(result.report, indent=1, default=_json_default) + "\n")
    return result
