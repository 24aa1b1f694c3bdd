"""The fit schedule: seeds, growth rounds, release, with one divergence retry per phase.

Steps 2 to 4 of the reconstruction (see :mod:`recon.fitting`), in normalised units (lengths in r0):

2. seeds: Poisson-disk thinned samples on their local data planes, pinned;
3. growth rounds: relax ``relax_steps`` steps with the fidelity pull on, then the growing and
   stretching rules propose particles that are accepted when supported by the data; stop when
   a round adds fewer than ``min_add_fraction`` of the particles and the sheet is at rest;
4. release the seeds and relax ``release_steps`` steps (smoothing, fidelity pull kept), refilling
   the gaps the release opens during the first chunks.

The step counts are caps: a relaxation ends early once the sheet is at rest (kinetic energy per
particle below ``dynamics.kinetic_tolerance``, checked at every anchor refresh), and the release
ends after its refills once a chunk ends at rest. The release starts from the grown state (the
velocities of the last growth relaxation carry over). Particles are kept sorted by grid cell
(after seeding and after every growth round) so that neighbours lie near in memory.

If the dynamics diverge during a phase, the phase restarts once from its start with the time
step halved (:meth:`_Schedule.run_phase`). :class:`Clock` accounts the wall time per phase and
enforces ``dynamics.time_limit``.

References
----------
[ST92] Szeliski & Tonnesen 1992, §7 "Surface fitting".
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from ..config import ReconConfig
from ..dynamics import Simulation
from ..errors import DivergenceError, LimitExceeded
from ..growth import accept_candidates, grow_candidates, stretch_candidates
from ..neighbors import PointGrid
from ..params import PhysicsParams
from ..seeds import seed_particles
from ..state import ParticleState
from ..surface import DataSurface, feature_spacing

__all__ = [
    "ANCHOR_MOVE",
    "ANCHOR_REFRESH",
    "COVER_RADIUS",
    "COVER_SAMPLE",
    "EXPLODING_ENERGY",
    "PLATEAU_ADD_FRACTION",
    "PLATEAU_AFTER_ROUND",
    "RELEASE_CHUNK",
    "RELEASE_REFILLS",
    "RETRY_DT_FACTOR",
    "Clock",
    "ProgressFn",
    "ScheduleResult",
    "run_schedule",
]

log = logging.getLogger(__name__)

#: Covering radius of a hexagonal sheet at spacing 1 is 1/sqrt(3) ~ 0.577; a data point
#: within this distance [r0] of a particle counts as covered by the sheet.
COVER_RADIUS = 0.65
#: The coverage is measured on at most this many data points, drawn once from the fit's
#: generator (so the size changes which seeds are drawn, hence the mesh).
COVER_SAMPLE = 20_000
#: Anchors (nearest data planes) are refreshed this often during relaxation [steps].
ANCHOR_REFRESH = 5
#: ... for the particles that moved more than this [r0] since their anchor was found; the
#: others keep theirs. 0: every particle that moved at all, which gives the same anchors as a
#: full refresh (pinned seeds, most of the sheet during growth, are skipped). Measured on the
#: regression samples, 0.02-0.05 r0 halves the queries but changes the sparse fits beyond their
#: float noise (face-sparse chamfer +4-8 %), so the refresh stays exact.
ANCHOR_MOVE = 0.0
#: The release phase runs in chunks of this many steps; after each chunk the history gets a
#: record and, during the first ``RELEASE_REFILLS`` chunks, a growth round refills gaps.
RELEASE_CHUNK = 20
#: Growth rounds run during the release phase: unpinning the seeds lets the sheet relax, which
#: opens small gaps; refilling them keeps ball pivoting from bridging them with long edges.
RELEASE_REFILLS = 3
#: Growth also stops on a plateau: after round PLATEAU_AFTER_ROUND (0-based), a round that adds
#: at least as many particles as the previous one, but fewer than PLATEAU_ADD_FRACTION of the
#: sheet, is taken as the rules re-filling their own churn rather than covering new data.
PLATEAU_AFTER_ROUND = 5
#: See ``PLATEAU_AFTER_ROUND``.
PLATEAU_ADD_FRACTION = 0.05
#: Potential energy per particle above which the dynamics count as exploding (a sheet at rest
#: has |E| of order 1 per particle; coincident particles make it grow without bound).
EXPLODING_ENERGY = 1e6
#: Cell side [r0] of the grid that answers a growth round's nearest-particle queries (the
#: candidates lie about one spacing from the particles).
PARTICLE_GRID_CELL = 1.0
#: A phase that diverged restarts once with its time step multiplied by this factor.
RETRY_DT_FACTOR = 0.5

#: ``on_progress(phase, info)``: called after every growth round and release chunk.
ProgressFn = Callable[[str, dict[str, Any]], None]


class Clock:
    """Wall-clock accounting per phase, and the run's time limit.

    Parameters
    ----------
    limit : float or None [s]
        :meth:`check` raises :class:`~recon.errors.LimitExceeded` once the run took longer.
    """

    def __init__(self, limit: float | None) -> None:
        self.start = time.perf_counter()
        self.limit = limit
        #: Seconds per phase, in the order the phases ended.
        self.phases: dict[str, float] = {}
        self._t = self.start

    def lap(self, phase: str) -> None:
        """Add the time since the previous lap (or the start) to ``phase``."""
        now = time.perf_counter()
        self.phases[phase] = self.phases.get(phase, 0.0) + now - self._t
        self._t = now

    def check(self) -> None:
        """Raise :class:`~recon.errors.LimitExceeded` when the time limit is reached."""
        if self.limit is not None and time.perf_counter() - self.start > self.limit:
            raise LimitExceeded(
                f"time limit of {self.limit:g} s reached "
                "(raise dynamics.time_limit or --time-limit)"
            )


@dataclass
class ScheduleResult:
    """The particle sheet after the release, and how the schedule went.

    Attributes
    ----------
    state : ParticleState
        Final particles (normalised units).
    n_seeds : int
        Number of seed particles.
    dt : float
        The time step in use at the end (``dynamics.dt``, halved after a restart).
    steps : dict
        Dynamics steps per phase: ``grow``, ``release``.
    history : dict of lists
        ``step``, ``particles``, ``kinetic``, ``coverage``, ``phase``: one entry per growth
        round and release chunk.
    warnings : list of str
    stop_reason : str
        Why growth stopped (empty when growth is disabled and nothing capped it).

    The per-particle rest spacings [r0] are ``state.rest`` (all 1 unless ``seeds.adaptive``):
    the local spacing for the triangulation.
    """

    state: ParticleState
    n_seeds: int
    dt: float
    steps: dict[str, int]
    history: dict[str, list]
    warnings: list[str]
    stop_reason: str


def run_schedule(
    surface: DataSurface,
    cfg: ReconConfig,
    rng: np.random.Generator,
    clock: Clock,
    on_progress: ProgressFn | None = None,
) -> ScheduleResult:
    """Seed, grow and release a particle sheet over the data surface (normalised units).

    Parameters
    ----------
    surface : DataSurface
        The data, in units of r0.
    cfg : ReconConfig
        Resolved configuration (``growth.max_gap`` set).
    rng : numpy.random.Generator
        The fit's generator: draws the coverage sample, then the seeds' visiting order.
    clock : Clock
        Checked during the dynamics; laps ``grow`` and ``release``.
    on_progress : callable(phase, info), optional
        See :data:`ProgressFn`.

    Returns
    -------
    ScheduleResult

    Raises
    ------
    DivergenceError
        A phase diverged twice.
    LimitExceeded
        Too many seeds for ``dynamics.max_particles``, or the time limit.
    """
    schedule = _Schedule(surface, cfg, rng, clock, on_progress)
    state, seed_points = schedule.make_seeds()
    n_seeds = state.n
    params = PhysicsParams.from_config(cfg, spacing=1.0)
    state, params = schedule.run_phase(
        "growth", state, params, lambda sim, st: schedule.grow(sim, st, seed_points)
    )
    clock.lap("grow")
    beta = cfg.dynamics.release_damping
    if beta is not None:  # the release's own damping
        params = replace(params, damping_linear=beta, damping_angular=beta)
    state, params = schedule.run_phase("release", state, params, schedule.release)
    clock.lap("release")
    return ScheduleResult(
        state=state,
        n_seeds=int(n_seeds),
        dt=params.dt,
        steps=dict(schedule.steps),
        history=schedule.history,
        warnings=schedule.warnings,
        stop_reason=schedule.stop_reason,
    )


class _Schedule:
    """State of one run of the schedule (normalised units)."""

    def __init__(
        self,
        surface: DataSurface,
        cfg: ReconConfig,
        rng: np.random.Generator,
        clock: Clock,
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
        self.forget_anchors()
        n = surface.n_points
        take = (
            rng.choice(n, size=min(n, COVER_SAMPLE), replace=False)
            if n > COVER_SAMPLE
            else np.arange(n)
        )
        self.cover_sample = surface.points[np.sort(take)]
        sd = cfg.seeds
        self.target = (
            feature_spacing(surface, sd.spacing_min, sd.spacing_max) if sd.adaptive else None
        )

    def target_at(self, positions: np.ndarray) -> np.ndarray | None:
        """Target rest spacings [r0] at the data nearest to ``positions`` (None: uniform)."""
        if self.target is None:
            return None
        _, idx = self.surface.nearest(positions)
        return self.target[idx]

    def update_rest(self, sim: Simulation, state: ParticleState) -> np.ndarray | None:
        """Move each rest spacing toward its target by at most ``seeds.spacing_step`` (held
        fixed during the steps that follow, so the update injects little energy); return the
        mask of the particles whose rest changed (None: uniform spacing, none did)."""
        target = self.target_at(state.position)
        if target is None or state.n == 0:
            return None
        step = self.cfg.seeds.spacing_step
        old = state.rest.copy()
        state.rest = np.clip(target, old * (1.0 - step), old * (1.0 + step))
        sim.notify_changed()
        return state.rest != old

    def hold_far(self, state: ParticleState, changed: np.ndarray | None) -> np.ndarray | None:
        """Active set of a growth relaxation (``growth.active_radius`` > 0): pin the free
        particles farther than the radius from the last round's additions whose rest spacing
        did not change either; return the mask of those held (to free after the steps), or
        None when every free particle moves (also when the crease hook changed the particle
        count since ``changed`` was taken)."""
        radius = self.cfg.growth.active_radius
        added = self.added_positions
        if radius <= 0.0 or added is None or state.n == 0:
            return None
        if changed is not None and len(changed) != state.n:
            return None
        near = (
            PointGrid(added, radius).covered(state.position, radius)
            if len(added)
            else np.zeros(state.n, dtype=bool)
        )
        if changed is not None:
            near |= changed
        held = ~(near | state.is_pinned)
        state.is_pinned[held] = True  # at rest already: nothing to zero but float noise
        state.velocity[held] = 0.0
        state.angular_velocity[held] = 0.0
        return held

    # -- helpers -------------------------------------------------------------------------
    def total_steps(self) -> int:
        return self.steps["grow"] + self.steps["release"]

    def coverage(self, positions: np.ndarray) -> float:
        if len(positions) == 0:
            return 0.0
        covered = PointGrid(positions, COVER_RADIUS).covered(self.cover_sample, COVER_RADIUS)
        return float(np.mean(covered))

    def relax(
        self,
        sim: Simulation,
        state: ParticleState,
        n_steps: int,
        phase: str,
        changed: np.ndarray | bool = False,
    ) -> float:
        """Relax up to ``n_steps`` steps in chunks of ``ANCHOR_REFRESH`` (anchors refreshed,
        creases constrained before each); return the last kinetic energy per particle.
        ``changed`` (a growth relaxation): the mask of :meth:`update_rest`, or None, and only
        the active set of :meth:`hold_far` moves in each chunk; False: every free particle."""
        dyn = self.cfg.dynamics
        kinetic = 0.0
        done = 0
        while done < n_steps:
            if self.total_steps() >= dyn.max_steps or self._all_held(state):
                break  # (only pinned seeds: at rest before any step, none would move)
            chunk = min(ANCHOR_REFRESH, n_steps - done, dyn.max_steps - self.total_steps())
            self.constrain_creases(sim, state)
            held = None if changed is False else self.hold_far(state, changed)
            try:
                if held is not None and self._all_held(state):
                    break
                pts, nrm = self.refresh_anchors(state)
                sim.set_anchors(pts, nrm, dyn.fidelity, dyn.fidelity_normal)
                stats = sim.run(chunk)
            finally:
                if held is not None:
                    state.is_pinned[held] = False
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
            if self.at_rest(kinetic):
                break
        return kinetic

    def _all_held(self, state: ParticleState) -> bool:
        """Every particle is pinned or held, and at rest: no step would move any."""
        return bool(state.n and np.all(state.is_pinned) and self.at_rest(0.0))

    def refresh_anchors(self, state: ParticleState) -> tuple[np.ndarray, np.ndarray]:
        """Anchor points and normals of every particle, recomputed only for the particles that
        moved more than ``ANCHOR_MOVE`` since their anchor was found (all of them after
        :meth:`forget_anchors`)."""
        pos = state.position
        hint = None
        if self._anchor_ref is not None and len(self._anchor_ref) == state.n:
            d = pos - self._anchor_ref
            moved = np.flatnonzero(np.einsum("ij,ij->i", d, d) > ANCHOR_MOVE * ANCHOR_MOVE)
            # the previous anchors' data points start the search (same anchors, found sooner)
            hint = self._anchor_idx
            if len(moved) < state.n:
                if len(moved):
                    pts, nrm, _, idx = self.surface.anchors(
                        pos[moved], state.normal[moved], hint=hint[moved], with_index=True
                    )
                    self._anchor_pts[moved], self._anchor_nrm[moved] = pts, nrm
                    self._anchor_ref[moved], self._anchor_idx[moved] = pos[moved], idx
                return self._anchor_pts, self._anchor_nrm
        # every anchor is new, or every particle moved (each step of the release): one call
        # over all of them, without gathering and scattering the rows
        pts, nrm, _, idx = self.surface.anchors(pos, state.normal, hint=hint, with_index=True)
        self._anchor_ref, self._anchor_pts, self._anchor_nrm = pos.copy(), pts, nrm
        self._anchor_idx = idx
        return pts, nrm

    def reorder_anchors(self, added: int, order: np.ndarray) -> None:
        """``added`` particles were appended and then all reordered by ``order`` (new i = old
        ``order[i]``): the kept anchors follow their particles and the new particles get theirs
        at the next refresh (the others keep theirs until they move, as between rounds)."""
        if self._anchor_ref is None:
            return
        pad = np.full((added, 3), np.inf)  # never equal to a position: refreshed next
        self._anchor_ref = np.vstack([self._anchor_ref, pad])[order]
        self._anchor_pts = np.vstack([self._anchor_pts, np.zeros((added, 3))])[order]
        self._anchor_nrm = np.vstack([self._anchor_nrm, np.zeros((added, 3))])[order]
        self._anchor_idx = np.concatenate([self._anchor_idx, np.full(added, -1)])[order]

    def forget_anchors(self) -> None:
        """The particles changed (added, reordered, restored): refresh every anchor next."""
        self._anchor_ref = self._anchor_pts = self._anchor_nrm = self._anchor_idx = None

    def at_rest(self, kinetic: float) -> bool:
        """Whether the kinetic energy per particle is below ``dynamics.kinetic_tolerance``."""
        return kinetic < self.cfg.dynamics.kinetic_tolerance

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
        self.forget_anchors()
        steps, stop_reason = dict(self.steps), self.stop_reason
        n_history, n_warnings = len(self.history["step"]), len(self.warnings)
        try:
            run(Simulation(state, params), state)
            return state, params
        except DivergenceError as exc:
            first = exc
        params = replace(params, dt=RETRY_DT_FACTOR * params.dt)
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
        self.forget_anchors()
        try:
            run(Simulation(state, params), state)
        except DivergenceError as exc:
            raise DivergenceError(
                f"the particle dynamics diverged during {phase}, also after restarting it with "
                f"dynamics.dt halved to {params.dt:g} ({exc}); lower dynamics.dt or raise the "
                "spacing, and check the input for clusters of near-duplicate points"
            ) from None
        return state, params

    def constrain_creases(
        self, sim: Simulation, state: ParticleState, settle: bool = False
    ) -> None:
        """Crease hook (issue 12): snap particles near crease lines and corners onto them and
        mark them unoriented (:meth:`recon.crease_surface.CreaseField.constrain`). The
        neighbour list is kept while it still holds every interacting pair (most calls snap a
        few particles by less than the skin); dropped or added particles rebuild it."""
        if self.surface.creases is not None and state.n:
            n = state.n
            self.surface.creases.constrain(state, settle=settle)
            if state.n == n:
                sim.notify_moved()
            else:
                sim.notify_changed()

    # -- phases --------------------------------------------------------------------------
    def make_seeds(self) -> tuple[ParticleState, np.ndarray]:
        s = self.surface
        idx, pos, pn = seed_particles(s, self.cfg.seeds.thinning, self.rng)
        cap = self.cfg.dynamics.max_particles
        if len(idx) > cap:
            raise LimitExceeded(
                f"{len(idx)} seed particles exceed dynamics.max_particles={cap}; "
                "raise the cap or the spacing"
            )
        state = ParticleState.from_points(pos, pn, pinned=True)
        if self.target is not None:
            state.rest = self.target[idx]
        return state, pos

    def grow_round(self, sim: Simulation, state: ParticleState) -> int:
        """One application of the growing and stretching rules; returns particles added."""
        g = self.cfg.growth
        dyn = self.cfg.dynamics
        pos, nrm = state.position, state.normal
        tree = PointGrid(pos, PARTICLE_GRID_CELL)  # nearest-particle queries of this round
        rest = state.rest if self.target is not None else None
        if rest is None:
            offsets, indices = sim.neighbors_within(g.grow_radius)
        else:
            offsets, indices = _scaled_neighbors(pos, rest, g.grow_radius, sim)
        frontier = np.diff(offsets) <= g.max_neighbors
        grown, grown_n = grow_candidates(
            pos, nrm, offsets, indices, g, with_normals=True, rest=rest
        )
        mid, mid_n = stretch_candidates(pos, nrm, tree, frontier, g, with_normals=True)
        if self.surface.creases is not None:  # crease hook: particles along the crease lines
            line, line_n = self.surface.creases.line_candidates()
            grown, grown_n = np.vstack([line, grown]), np.vstack([line_n, grown_n])
        cands = np.vstack([grown, mid])
        acc = accept_candidates(
            cands,
            tree,
            self.surface,
            self.seed_tree,
            self.seed_points,
            g,
            normals=np.vstack([grown_n, mid_n]),
            rest=self.target_at(cands),
        )
        added = len(acc.positions)
        room = dyn.max_particles - state.n
        if added > room:
            acc.positions, acc.normals = acc.positions[:room], acc.normals[:room]
            added = room
            self.stop_reason = f"particle cap dynamics.max_particles={dyn.max_particles} reached"
            self.warnings.append(self.stop_reason)
        self.added_positions = acc.positions
        if added:
            new_rest = self.target_at(acc.positions)
            state.add(
                acc.positions,
                acc.normals,
                pinned=False,
                rest=1.0 if new_rest is None else new_rest,
            )
            sim.notify_changed()
            order = sim.sort_particles()  # the new particles were appended at the end
            self.reorder_anchors(added, order)
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
        sim.sort_particles()  # seeds come in input order: neighbours near in memory
        self.forget_anchors()
        self.added_positions = None
        previous_added = None
        for rnd in range(g.max_rounds if g.enabled else 0):
            changed = self.update_rest(sim, state)
            kinetic = self.relax(sim, state, dyn.relax_steps, "grow", changed)
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
            plateau = (
                not_shrinking
                and rnd > PLATEAU_AFTER_ROUND
                and added < PLATEAU_ADD_FRACTION * state.n
            )
            if small or plateau:
                self.stop_reason = "converged: additions stopped"
                break
            previous_added = added
        else:
            if g.enabled:
                self.stop_reason = f"growth.max_rounds={g.max_rounds} reached"
        # settle what the last round added before the seeds let go
        kinetic = self.relax(sim, state, dyn.relax_steps, "grow", None)
        self.record("grow", state, kinetic, self.coverage(state.position))

    def release(self, sim: Simulation, state: ParticleState) -> None:
        """Unpin the seeds and smooth; the first chunks also refill gaps the release opens."""
        state.set_pinned(False)
        sim.notify_changed()
        dyn = self.cfg.dynamics
        remaining = dyn.release_steps
        refills = RELEASE_REFILLS if self.cfg.growth.enabled else 0
        quench = dyn.release_quench_steps if dyn.release_damping is not None else 0
        while remaining > 0:
            n = min(RELEASE_CHUNK, remaining)
            if remaining > quench:
                n = min(n, remaining - quench)
            elif remaining == quench:  # the last steps: the configured heavy damping
                sim.set_damping(dyn.damping_linear, dyn.damping_angular)
            kinetic = self.relax(sim, state, n, "release")
            remaining -= n
            if refills > 0 and remaining > 0 and not self.stop_reason.startswith("particle cap"):
                refills -= 1
                self.grow_round(sim, state)
            self.record("release", state, kinetic, self.coverage(state.position))
            if self.total_steps() >= dyn.max_steps:
                break
            if refills == 0 and self.at_rest(kinetic):  # refills done and nothing moves
                break
        self.constrain_creases(sim, state, settle=True)  # crease particles end on their lines


def _scaled_neighbors(
    position: np.ndarray, rest: np.ndarray, radius: float, sim: Simulation
) -> tuple[np.ndarray, np.ndarray]:
    """CSR neighbours within ``radius`` x (rest_i + rest_j)/2 (adaptive spacing); ``sim``
    holds ``position``."""
    offsets, indices = sim.neighbors_within(radius * float(np.max(rest)))
    row = np.repeat(np.arange(len(position)), np.diff(offsets))
    d = np.linalg.norm(position[indices] - position[row], axis=1)
    keep = d < radius * 0.5 * (rest[row] + rest[indices])
    counts = np.bincount(row[keep], minlength=len(position))
    new_offsets = np.zeros(len(position) + 1, dtype=offsets.dtype)
    np.cumsum(counts, out=new_offsets[1:])
    return new_offsets, np.ascontiguousarray(indices[keep])
