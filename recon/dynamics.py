"""The oriented-particle engine: the simulation loop and kernel warm-up.

The parameters (:class:`~recon.params.PhysicsParams`, in absolute units) live in
:mod:`recon.params`. :class:`Simulation` owns the neighbour list, the anchors and the scratch
buffers of one :class:`~recon.state.ParticleState` and advances it with one fused, damped semi-
implicit Euler step per :meth:`Simulation.step` (:mod:`recon.integrate`).

The model (DESIGN §1–3, S&T92 §4, T-thesis ch. 4): soft 4-2 Lennard-Jones spacing with a
shifted-force cutoff, co-planarity (S&T92 eq. 3), co-normality (eq. 4) and co-circularity
(eq. 5) weighted by ψ (poly, Gaussian or the anisotropic eq. 7), a point-to-plane anchor pull,
linear/angular and relative damping, per-step displacement and rotation caps, pinned and
unoriented particles. Dynamics are those of x/r0 with m = I = 1, so a run at spacing r0 is the
run at spacing 1 scaled by r0 (``dt`` is in model time units).

References
----------
.. [ST92] R. Szeliski, D. Tonnesen. "Surface Modeling with Oriented Particle Systems".
   SIGGRAPH '92.
.. [T00] D. Tonnesen. PhD thesis, chapter 4.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from .forces import Anchors, accumulate_forces, evaluate_pair, kernel_extras, pack_coefficients
from .integrate import StepBuffers, integrate_step
from .kernels.options import ThreadChooser
from .neighbors import (
    PARALLEL_MIN_PARTICLES,
    NeighborList,
    build_neighbor_list,
    sort_order_by_cell,
)
from .params import PhysicsParams
from .state import ParticleState

__all__ = ["ALWAYS_THREADED", "PhysicsParams", "Simulation", "StepStats", "warmup"]

#: Steps and list builds of this many particles always run threaded; None: the
#: :class:`~recon.kernels.options.ThreadChooser` times both ways at every size (under load the
#: calling thread alone was faster even at 100k particles).
ALWAYS_THREADED: int | None = None


@dataclass(frozen=True)
class StepStats:
    """Summary of one step.

    Attributes
    ----------
    kinetic : float
        Kinetic energy after the step, ½ Σ (m |v|²/r0² + I |ω|²) [dimensionless].
    potential : float
        Potential energy at the positions the step started from [dimensionless]: the shares
        ½ Σ_j E_ij + E^A_i of the particles that are not pinned (a pinned particle does not
        move, so the step skips its terms; with none pinned this is the total energy).
    max_speed : float
        Largest particle speed after the step [length/time].
    rebuilt : bool
        The neighbour list was rebuilt at the start of this step.
    kinetic_before : float
        Kinetic energy at the start of the step; ``kinetic_before + potential`` is the total
        energy of the state the step started from.
    """

    kinetic: float
    potential: float
    max_speed: float
    rebuilt: bool
    kinetic_before: float = 0.0

    @property
    def total(self) -> float:
        """Total energy of the state the step started from (``kinetic_before + potential``)."""
        return self.kinetic_before + self.potential


class Simulation:
    """Advance a :class:`~recon.state.ParticleState` with the oriented-particle dynamics.

    Parameters
    ----------
    state : ParticleState
        Updated in place by :meth:`step`.
    params : PhysicsParams
    parallel : bool, optional
        Force the threaded (True) or single-threaded (False) kernels; default: whichever of
        the two was faster lately (:class:`recon.kernels.options.ThreadChooser`, by the
        machine's load; the states are bit-identical either way), threaded from
        :data:`ALWAYS_THREADED` particles if that is set.

    Attributes
    ----------
    n_steps_done : int
    n_threaded_steps : int
        Steps that ran on numba's threads (the others ran in the calling thread).
    n_rebuilds : int
        Neighbour-list builds so far.

    Notes
    -----
    After ``state.add``/``state.remove`` (or any direct change of positions) call
    :meth:`notify_changed`; it forces a neighbour rebuild and clears the anchors and the
    external force, which the caller sets again for the new particle count.
    """

    def __init__(
        self, state: ParticleState, params: PhysicsParams, *, parallel: bool | None = None
    ) -> None:
        if not isinstance(params, PhysicsParams):
            raise TypeError(f"params: expected PhysicsParams, got {type(params).__name__}")
        self.state = state
        self.params = params
        self.parallel = parallel
        self._neighbors = NeighborList(params.cutoff, params.skin)
        self._buffers = StepBuffers()
        self._anchors: Anchors | None = None
        self._external_force: np.ndarray | None = None
        self._mode = int(params.weighting)
        self._coefficients = pack_coefficients(params)
        self._needs_rebuild = True
        self._step_threads = ThreadChooser()
        self._build_threads = ThreadChooser()
        self.n_steps_done = 0
        self.n_threaded_steps = 0
        self.n_rebuilds = 0

    # ------------------------------------------------------------------ external terms
    def set_anchors(
        self,
        points: np.ndarray | None,
        normals: np.ndarray | None,
        stiffness: float = 0.0,
        normal_stiffness: float = 0.0,
    ) -> None:
        """Tie every particle to an anchor point and normal (point-to-plane pull).

        Parameters
        ----------
        points : (n, 3) float64 or None
            Anchor points a_i [length] (e.g. nearest data points); None disables anchors.
        normals : (n, 3) float64 or None
            Anchor normals m_i (normalised here).
        stiffness : float
            k_d in E = k_d/2 · (m_i·(x_i − a_i))²/r0² (``dynamics.fidelity``).
        normal_stiffness : float
            k_n in E = k_n/2 · |n_i − m_i|² (``dynamics.fidelity_normal``).
        """
        if points is None or normals is None:
            self._anchors = None
        else:
            self._anchors = Anchors.create(
                points, normals, self.state.n, stiffness, normal_stiffness
            )
        self._refresh_coefficients()

    @property
    def anchors(self) -> Anchors | None:
        """The current anchors (copies of what was set), or None."""
        return self._anchors

    @property
    def external_force(self) -> np.ndarray | None:
        """Optional (n, 3) force added to every particle [1/length, like −∂E/∂x]."""
        return self._external_force

    @external_force.setter
    def external_force(self, value: np.ndarray | None) -> None:
        if value is None:
            self._external_force = None
        else:
            arr = np.array(value, dtype=np.float64, order="C", copy=True)
            if arr.shape != (self.state.n, 3):
                raise ValueError(
                    f"external_force: expected shape ({self.state.n}, 3), got {arr.shape}"
                )
            if not np.all(np.isfinite(arr)):
                raise ValueError("external_force: contains non-finite values")
            self._external_force = arr
        self._refresh_coefficients()

    def set_damping(self, linear: float, angular: float) -> None:
        """Change β0 and β2 (the linear and angular damping) for the steps that follow."""
        self.params = replace(self.params, damping_linear=linear, damping_angular=angular)
        self._refresh_coefficients()

    def _refresh_coefficients(self) -> None:
        self._coefficients = pack_coefficients(
            self.params,
            anchors=self._anchors,
            has_external_force=self._external_force is not None,
        )

    # ------------------------------------------------------------------ neighbours
    def uses_parallel(self) -> bool:
        """Whether steps run the threaded kernels (``parallel``, else by the particle count)."""
        if self.parallel is not None:
            return bool(self.parallel)
        return self.state.n >= PARALLEL_MIN_PARTICLES

    def _choose(self, chooser: ThreadChooser) -> bool:
        if self.parallel is not None:
            return bool(self.parallel)
        return chooser.parallel(self.state.n, ALWAYS_THREADED)

    def _rebuild(self) -> None:
        # the cell grid and list radius follow the largest pair cutoff in use (adaptive spacing)
        largest = float(np.max(self.state.rest)) if self.state.n else 1.0
        self._neighbors.cutoff = self.params.cutoff * max(largest, 1.0)
        parallel = self._choose(self._build_threads)
        start = time.perf_counter()
        self._neighbors.build(self.state.position, parallel=parallel)
        self._build_threads.record(parallel, time.perf_counter() - start, self.state.n)
        self.n_rebuilds += 1
        self._needs_rebuild = False

    @property
    def neighbor_list(self) -> NeighborList:
        """The cached :class:`~recon.neighbors.NeighborList` (built lazily by :attr:`neighbors`)."""
        return self._neighbors

    @property
    def neighbors(self) -> tuple[np.ndarray, np.ndarray]:
        """CSR ``(offsets, indices)`` of the current list (radius cutoff + skin)."""
        if self._needs_rebuild or self._neighbors.n != self.state.n:
            self._rebuild()
        return self._neighbors.offsets, self._neighbors.indices

    def neighbors_within(self, radius: float) -> tuple[np.ndarray, np.ndarray]:
        """CSR ``(offsets, indices)`` of the pairs closer than ``radius`` at the current
        positions, rows ascending: exactly ``build_neighbor_list(position, radius)``.

        When the cached list is current and ``radius`` is within its cutoff, the pairs are
        read from it (it holds every pair within the cutoff): a filter of the list instead of
        a new cell-grid build (the growth rounds' lists). Otherwise they are built; the cached
        list is never rebuilt here, since the time of its builds orders the particles (the
        cell side of :meth:`sort_particles` follows the largest rest spacing at the last
        build) and so must not depend on who asked for a list."""
        stale = self._needs_rebuild or self._neighbors.n != self.state.n
        if not stale and radius <= self._neighbors.cutoff:
            return self._neighbors.within(self.state.position, radius)
        return build_neighbor_list(self.state.position, radius)

    def notify_changed(self) -> None:
        """Particles were added, removed or moved by the caller: rebuild before the next step.

        Also clears the anchors and the external force (set them again for the new particles).
        """
        self._needs_rebuild = True
        self._anchors = None
        self._external_force = None
        self._refresh_coefficients()

    def notify_moved(self) -> None:
        """Particles were moved in place by the caller (the same particles, e.g. snapped onto
        a crease line): the list is rebuilt before the next step only if it no longer holds
        every pair within the cutoff (:meth:`NeighborList.covers`, exact). Unlike
        :meth:`notify_changed`, the anchors and the external force are kept. A changed
        particle count needs :meth:`notify_changed`."""
        if self._neighbors.n != self.state.n or not self._neighbors.covers(self.state.position):
            self._needs_rebuild = True

    def sort_particles(self) -> np.ndarray:
        """Reorder the particles by grid cell for memory locality; return the permutation.

        New particle i is old particle ``order[i]``: apply ``order`` to any per-particle arrays
        the caller keeps. Anchors and the external force are permuted too.
        """
        order = sort_order_by_cell(self.state.position, self._neighbors.radius)
        self.state.reorder(order)
        if self._anchors is not None:
            a = self._anchors
            self._anchors = Anchors(
                a.points[order], a.normals[order], a.stiffness, a.normal_stiffness
            )
        if self._external_force is not None:
            self._external_force = np.ascontiguousarray(self._external_force[order])
        self._needs_rebuild = True
        return order

    # ------------------------------------------------------------------ stepping
    def _check_sizes(self) -> None:
        n = self.state.n
        if self._anchors is not None and self._anchors.points.shape[0] != n:
            raise ValueError(
                f"anchors were set for {self._anchors.points.shape[0]} particles but the state "
                f"has {n}; call notify_changed() and set_anchors() after add/remove"
            )
        if self._external_force is not None and self._external_force.shape[0] != n:
            raise ValueError(
                f"external_force has {self._external_force.shape[0]} rows but the state has "
                f"{n}; call notify_changed() after add/remove"
            )

    def step(self) -> StepStats:
        """Advance one step.

        Returns
        -------
        StepStats

        Raises
        ------
        DivergenceError
            If the state, a force or the new state is not finite (the state is unchanged).
        """
        self._check_sizes()
        rebuilt = False
        if self._needs_rebuild or self._neighbors.n != self.state.n:
            self._rebuild()
            rebuilt = True
        parallel = self._choose(self._step_threads)
        start = time.perf_counter()
        result = integrate_step(
            self.state,
            self._coefficients,
            self._mode,
            (self._neighbors.offsets, self._neighbors.indices),
            self._neighbors.reference_position,
            kernel_extras(self._anchors, self._external_force),
            self._buffers,
            parallel=parallel,
            step_index=self.n_steps_done,
        )
        self._step_threads.record(parallel, time.perf_counter() - start, self.state.n)
        self.n_threaded_steps += int(parallel)
        half_skin = 0.5 * self.params.skin
        # the usual rule (no particle moved more than skin/2) or, when a few did, the exact
        # per-particle test: the list still holds every interacting pair
        self._needs_rebuild = not (
            result.max_displacement2 <= half_skin * half_skin
            or self._neighbors.covers(self.state.position)
        )
        self.n_steps_done += 1
        return StepStats(
            kinetic=result.kinetic,
            potential=result.potential,
            max_speed=math.sqrt(result.max_speed2),
            rebuilt=rebuilt,
            kinetic_before=result.kinetic_before,
        )

    def run(
        self,
        n_steps: int,
        callback: Callable[[int, StepStats], bool | None] | None = None,
    ) -> StepStats:
        """Advance ``n_steps`` steps; return the last step's statistics.

        Parameters
        ----------
        n_steps : int
            Number of steps (0 returns the statistics of the current state).
        callback : callable, optional
            Called as ``callback(k, stats)`` after step k (0-based); returning True stops the
            run early.

        Returns
        -------
        StepStats
        """
        if n_steps < 0:
            raise ValueError(f"n_steps: expected >= 0, got {n_steps}")
        if n_steps == 0:
            return self.current_stats()
        stats = None
        for k in range(int(n_steps)):
            stats = self.step()
            if callback is not None and callback(k, stats):
                break
        return stats

    def current_stats(self) -> StepStats:
        """Energies and speed of the current state, without stepping."""
        self._check_sizes()
        st = self.state
        forces = accumulate_forces(
            st,
            self.params,
            neighbors=self.neighbors,
            anchors=self._anchors,
            external_force=self._external_force,
            parallel=self.uses_parallel(),
        )
        v2 = np.einsum("ij,ij->i", st.velocity, st.velocity)
        w2 = np.einsum("ij,ij->i", st.angular_velocity, st.angular_velocity)
        kinetic = float(
            0.5 * np.sum(st.mass * v2) / self.params.spacing**2 + 0.5 * np.sum(st.inertia * w2)
        )
        return StepStats(
            kinetic=kinetic,
            potential=forces.energy,
            max_speed=float(np.sqrt(v2.max())) if st.n else 0.0,
            rebuilt=False,
            kinetic_before=kinetic,
        )


def warmup() -> None:
    """Compile (or load from the cache) every kernel on a tiny input.

    Runs serial and threaded variants of the neighbour-list build, the force evaluation and the
    fused step with anchors and an external force, so that later timings exclude compilation.
    """
    from .config import ReconConfig

    ring = np.linspace(0.0, 2.0 * np.pi, 6, endpoint=False)
    position = np.zeros((7, 3))
    position[1:, 0] = np.cos(ring)
    position[1:, 1] = np.sin(ring)
    normal = np.tile([0.0, 0.0, 1.0], (7, 1))
    params = PhysicsParams.from_config(ReconConfig(), spacing=1.0)
    for parallel in (False, True):
        state = ParticleState.from_points(position, normal)
        state.set_oriented(np.arange(7) != 3)
        sim = Simulation(state, params, parallel=parallel)
        sim.step()
        sim.set_anchors(position, normal, 1.0, 0.5)
        sim.external_force = np.zeros((7, 3))
        sim.step()
        sim.current_stats()
        sim.sort_particles()
        sim.neighbors  # noqa: B018  (builds the list)
    evaluate_pair(position[0], position[1], normal[0], normal[1], params)
    sim.neighbor_list.needs_rebuild(state.position)
