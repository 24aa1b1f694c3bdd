r"""One damped semi-implicit Euler step, fused with the force evaluation.

:func:`integrate_step` runs :func:`recon.kernels.pair_loop.step_particles` (threaded, or in the
calling thread for small systems): every particle computes its force and torque from its
neighbour row and writes its new position, frame, velocity and angular velocity to a second set
of buffers, which are then swapped into the :class:`~recon.state.ParticleState`. If any
particle's input, force or new state is not finite, :class:`~recon.errors.DivergenceError` is
raised and the state is left as it was (no NaN is ever written into it).

In reduced units (x̃ = x/r0, m = I = 1 by default; T-thesis eqs. 4.9–4.10):

.. math::

    v' = \frac{v + \Delta t\,\bigl(r_0^2 f - \beta_1\sum_j (v - v_j)\bigr)/m}
              {1 + \Delta t\,\beta_0/m},\qquad
    x' = x + \Delta t\, v',\qquad
    q' = \exp\bigl(\tfrac12\omega'\Delta t\bigr) \otimes q

with |Δt v'| ≤ ``max_displacement`` and |Δt ω'| ≤ ``max_rotation`` (the velocity is scaled with
the step). Reported kinetic energy is in reduced units, ½ m |v|²/r0² + ½ I |ω|², so that kinetic
plus potential energy is the conserved (or, with damping, decreasing) quantity at any spacing.

References
----------
.. [T00] D. Tonnesen. PhD thesis, chapter 4, eqs. 4.9–4.10 (damped equations of motion).
.. [HLW06] E. Hairer, C. Lubich, G. Wanner. "Geometric Numerical Integration", §I.1
   (symplectic / semi-implicit Euler).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import DivergenceError
from .kernels import pair_loop as _pl
from .kernels.options import thread_limit
from .params import Coefficients
from .state import ParticleState

#: The kernels' ``rest`` for uniform spacing (see :func:`kernel_rest`).
_NO_REST = np.zeros(0)


@dataclass(frozen=True)
class StepResult:
    """Raw totals of one fused step.

    Attributes
    ----------
    potential : float
        Potential energy at the positions the forces were evaluated at (before the move).
    kinetic : float
        Kinetic energy of the new velocities (reduced units).
    kinetic_before : float
        Kinetic energy of the velocities the step started from.
    max_displacement2 : float
        Largest squared displacement since the neighbour-list reference [length²].
    max_speed2 : float
        Largest squared new speed [length²/time²].
    """

    potential: float
    kinetic: float
    kinetic_before: float
    max_displacement2: float
    max_speed2: float


class StepBuffers:
    """Second set of dynamic buffers (double buffering) plus per-particle statistics."""

    def __init__(self) -> None:
        self.capacity = -1
        self.position = np.zeros((0, 3))
        self.orientation = np.zeros((0, 4))
        self.velocity = np.zeros((0, 3))
        self.angular_velocity = np.zeros((0, 3))
        self.stats = np.zeros((0, _pl.N_STATS))

    def ensure(self, capacity: int) -> None:
        """(Re)allocate to exactly ``capacity`` rows when it changed."""
        if capacity == self.capacity:
            return
        self.capacity = capacity
        self.position = np.zeros((capacity, 3))
        self.orientation = np.zeros((capacity, 4))
        self.orientation[:, 0] = 1.0
        self.velocity = np.zeros((capacity, 3))
        self.angular_velocity = np.zeros((capacity, 3))
        self.stats = np.zeros((capacity, _pl.N_STATS))


def _describe_status(status: int) -> str:
    parts = []
    if status & _pl.STATUS_BAD_INPUT:
        parts.append("its state was already non-finite")
    if status & _pl.STATUS_BAD_FORCE:
        parts.append("its force, torque or energy is non-finite (coincident particles?)")
    if status & _pl.STATUS_BAD_OUTPUT:
        parts.append("its new state would be non-finite")
    return "; ".join(parts) or "unknown"


def kernel_rest(rest: np.ndarray) -> np.ndarray:
    """The ``rest`` array of the kernels: the spacings, or an empty array when all are 1 (the
    kernels then skip the per-pair scale: uniform spacing costs nothing extra)."""
    if rest.size and np.all(rest == 1.0):
        return _NO_REST
    return np.ascontiguousarray(rest)


def integrate_step(
    state: ParticleState,
    coefficients: Coefficients,
    mode: int,
    neighbors: tuple[np.ndarray, np.ndarray],
    reference_position: np.ndarray,
    extras: tuple[np.ndarray, np.ndarray, np.ndarray],
    buffers: StepBuffers,
    *,
    parallel: bool,
    step_index: int = 0,
) -> StepResult:
    """Advance ``state`` by one fused force + integration step, in place.

    Parameters
    ----------
    state : ParticleState
        Updated in place (its dynamic buffers are swapped with ``buffers``).
    coefficients : Coefficients
        :func:`recon.forces.pack_coefficients` output (:class:`recon.params.Coefficients`).
    mode : int
        Weighting mode.
    neighbors : (offsets, indices)
        Full CSR list, radius ≥ cutoff, valid for the current positions.
    reference_position : (n, 3) float64
        Positions at the list build (for the skin test).
    extras : tuple of three (m, 3) float64
        Anchor points, anchor normals, external forces (:func:`recon.forces.kernel_extras`).
    buffers : StepBuffers
        Scratch buffers; resized to the state's capacity as needed.
    parallel : bool
        Use the threaded kernel.
    step_index : int
        Step number, for error messages.

    Returns
    -------
    StepResult

    Raises
    ------
    DivergenceError
        If any particle's state, force or new state is not finite; the state is unchanged.
    """
    n = state.n
    buffers.ensure(state.capacity)
    state_in = (state.position, state.orientation, state.velocity, state.angular_velocity)
    state_out = (
        buffers.position[:n],
        buffers.orientation[:n],
        buffers.velocity[:n],
        buffers.angular_velocity[:n],
    )
    try:
        with thread_limit(parallel):
            result = _pl.step_particles(
                coefficients,
                mode,
                True,
                state_in,
                state_out,
                (state.is_pinned, state.is_oriented),
                (state.mass, state.inertia, kernel_rest(state.rest)),
                neighbors,
                reference_position,
                extras,
                buffers.stats[:n],
            )
    except ZeroDivisionError:  # only without the JIT (NUMBA_DISABLE_JIT=1); compiled: inf/NaN
        raise DivergenceError(
            f"particle dynamics diverged at step {step_index}: a force is non-finite "
            "(coincident particles?). The state was left unchanged."
        ) from None
    potential, kinetic, kinetic_before, max_d2, max_v2, bad, status = result
    if bad >= 0:
        raise DivergenceError(
            f"particle dynamics diverged at step {step_index}: particle {bad} at "
            f"{state.position[bad].tolist()}: {_describe_status(status)}. "
            "The state was left unchanged; reduce dynamics.dt or check the input for "
            "duplicate points."
        )
    old = state.swap_dynamic(
        buffers.position, buffers.orientation, buffers.velocity, buffers.angular_velocity
    )
    buffers.position, buffers.orientation, buffers.velocity, buffers.angular_velocity = old
    return StepResult(
        float(potential), float(kinetic), float(kinetic_before), float(max_d2), float(max_v2)
    )
