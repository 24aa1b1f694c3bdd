r"""FIRE relaxation (Bitzek et al. 2006): the integration half of a step, after the forces.

FIRE ("fast inertial relaxation engine") minimises the potential energy by undamped inertial
dynamics whose velocity is steered toward the force, with an adaptive time step. Per step, with
the forces F(x) and velocities v of every free particle stacked into single vectors (reduced
units: u = v/r0, g = r0 f for the linear part, ω and τ for the angular part, m = I = 1 by
default; Bitzek et al. 2006, PRL 97 170201, eqs. 1-2 and the rules below them):

.. math::

    P = F\cdot v, \qquad
    v \leftarrow (1-\alpha)\,v + \alpha\,|v|\,\hat F \quad (P > 0), \qquad
    v \leftarrow 0 \quad (P \le 0),

    v' = v + \Delta t\,F/m, \qquad x' = x + \Delta t\,v' \quad\text{(semi-implicit Euler)}

and the adaptation: after more than N_min steps with P > 0, Δt ← min(f_inc Δt, Δt_max) and
α ← f_α α; when P ≤ 0, Δt ← f_dec Δt, α ← α_start. The adaptation and the global sums are done
by the caller (:func:`fire_power` gives P, |F|², |v|²); :func:`fire_update` applies the mixing
and the Euler step to every particle, with the engine's per-step displacement and rotation caps.

The sums of :func:`fire_power` run serially in particle order, and :func:`fire_update` writes
only its own particle's rows, so the result is bit-identical for any thread count.

References
----------
.. [BBFG06] E. Bitzek, P. Koskinen, F. Gähler, M. Moseler, P. Gumbsch. "Structural Relaxation
   Made Simple". Phys. Rev. Lett. 97, 170201 (2006).
.. [GNP20] J. Guénolé et al. "Assessment and optimization of the fast inertial relaxation
   engine (FIRE) for energy minimization in atomistic simulations and its implementation in
   LAMMPS". Comput. Mater. Sci. 175, 109584 (2020) (semi-implicit Euler as the MD step).
"""

from __future__ import annotations

import math

from numba import njit, prange

from .options import JIT_OPTIONS
from .pair_loop import (
    S_DISPLACEMENT2,
    S_FORCE,
    S_KINETIC,
    S_SPEED2,
    S_STATUS,
    S_TORQUE,
    STATUS_BAD_OUTPUT,
)
from .quaternion import rotate_quaternion

_JIT = JIT_OPTIONS


@njit(**_JIT)
def fire_power(stats, velocity, angular_velocity, is_pinned, is_oriented, spacing):
    """Global sums of FIRE (Bitzek et al. 2006, eq. 2): P = F·v, |F|², |v|² over free particles.

    Reduced units: the linear part is u = v/r0 and g = r0 f (``stats`` holds f), the angular
    part ω and τ. Serial, in particle order (deterministic).

    Returns
    -------
    (power, force2, speed2) : three floats
    """
    n = velocity.shape[0]
    inv_s = 1.0 / spacing
    power = 0.0
    force2 = 0.0
    speed2 = 0.0
    for i in range(n):
        if is_pinned[i]:
            continue
        for a in range(3):
            g = spacing * stats[i, S_FORCE + a]
            u = velocity[i, a] * inv_s
            power += g * u
            force2 += g * g
            speed2 += u * u
        if is_oriented[i]:
            for a in range(3):
                t = stats[i, S_TORQUE + a]
                w = angular_velocity[i, a]
                power += t * w
                force2 += t * t
                speed2 += w * w
    return power, force2, speed2


@njit(parallel=True, **_JIT)
def fire_update(state_in, state_out, flags, inertial, reference_position, stats, spacing, control):
    r"""Velocity mixing and one semi-implicit Euler step of FIRE for every particle.

    Bitzek et al. 2006, eq. 2 and the MD step: v ← keep·v + mix·F (keep = 1 − α and
    mix = α|v|/|F|, or keep = mix = 0 after an uphill step), then v' = v + Δt F/m,
    x' = x + Δt v', q' = exp(½ω'Δt) ⊗ q, with |Δt v'| ≤ ``max_step`` and |Δt ω'| ≤ ``max_turn``
    (the velocity is scaled with the step). Pinned particles keep their state and get zero
    velocities; unoriented particles keep their frame.

    Parameters
    ----------
    state_in, state_out : tuple of four 2-D float64 arrays
        (position, orientation, velocity, angular_velocity), as in
        :func:`recon.kernels.pair_loop.step_particles`; must not share memory.
    flags : (is_pinned, is_oriented)
    inertial : (mass (n,), inertia (n,))
    reference_position : (n, 3) float64
        Positions at the last neighbour-list build (for the skin test).
    stats : (n, N_STATS) float64
        Forces and torques from ``step_particles(integrate=False)``; the kinetic energy after
        the step, the squared displacement since the list build, the squared speed and the
        status are written.
    spacing : float
        r0 [length].
    control : (dt, keep, mix, max_step, max_turn) floats
        Time step, mixing factors, caps [length] and [rad].
    """
    position, orientation, velocity, angular_velocity = state_in
    position_out, orientation_out, velocity_out, angular_velocity_out = state_out
    is_pinned, is_oriented = flags
    mass, inertia = inertial
    dt, keep, mix, max_step, max_turn = control
    inv_s2 = 1.0 / (spacing * spacing)
    spacing2 = spacing * spacing
    n = position.shape[0]
    for i in prange(n):
        x0 = position[i, 0]
        x1 = position[i, 1]
        x2 = position[i, 2]
        qw = orientation[i, 0]
        qx = orientation[i, 1]
        qy = orientation[i, 2]
        qz = orientation[i, 3]
        v0 = 0.0
        v1 = 0.0
        v2 = 0.0
        w0 = 0.0
        w1 = 0.0
        w2 = 0.0
        m = mass[i]
        inertia_i = inertia[i]
        if not is_pinned[i]:
            # mixing in reduced units (u = v/r0, g = r0 f): u <- keep u + mix g, i.e.
            # v <- keep v + mix r0^2 f
            v0 = keep * velocity[i, 0] + mix * spacing2 * stats[i, S_FORCE]
            v1 = keep * velocity[i, 1] + mix * spacing2 * stats[i, S_FORCE + 1]
            v2 = keep * velocity[i, 2] + mix * spacing2 * stats[i, S_FORCE + 2]
            v0 += dt * spacing2 * stats[i, S_FORCE] / m
            v1 += dt * spacing2 * stats[i, S_FORCE + 1] / m
            v2 += dt * spacing2 * stats[i, S_FORCE + 2] / m
            step2 = dt * dt * (v0 * v0 + v1 * v1 + v2 * v2)
            if step2 > max_step * max_step:
                scale = max_step / math.sqrt(step2)
                v0 *= scale
                v1 *= scale
                v2 *= scale
            x0 += dt * v0
            x1 += dt * v1
            x2 += dt * v2
            if is_oriented[i]:
                w0 = keep * angular_velocity[i, 0] + mix * stats[i, S_TORQUE]
                w1 = keep * angular_velocity[i, 1] + mix * stats[i, S_TORQUE + 1]
                w2 = keep * angular_velocity[i, 2] + mix * stats[i, S_TORQUE + 2]
                w0 += dt * stats[i, S_TORQUE] / inertia_i
                w1 += dt * stats[i, S_TORQUE + 1] / inertia_i
                w2 += dt * stats[i, S_TORQUE + 2] / inertia_i
                turn2 = dt * dt * (w0 * w0 + w1 * w1 + w2 * w2)
                if turn2 > max_turn * max_turn:
                    scale = max_turn / math.sqrt(turn2)
                    w0 *= scale
                    w1 *= scale
                    w2 *= scale
                qw, qx, qy, qz = rotate_quaternion(qw, qx, qy, qz, dt * w0, dt * w1, dt * w2)
        position_out[i, 0] = x0
        position_out[i, 1] = x1
        position_out[i, 2] = x2
        orientation_out[i, 0] = qw
        orientation_out[i, 1] = qx
        orientation_out[i, 2] = qy
        orientation_out[i, 3] = qz
        velocity_out[i, 0] = v0
        velocity_out[i, 1] = v1
        velocity_out[i, 2] = v2
        angular_velocity_out[i, 0] = w0
        angular_velocity_out[i, 1] = w1
        angular_velocity_out[i, 2] = w2
        speed2 = v0 * v0 + v1 * v1 + v2 * v2
        kinetic = 0.5 * m * speed2 * inv_s2 + 0.5 * inertia_i * (w0 * w0 + w1 * w1 + w2 * w2)
        status = stats[i, S_STATUS]
        if not math.isfinite(kinetic + x0 + x1 + x2 + qw + qx + qy + qz):
            status = float(int(status) | STATUS_BAD_OUTPUT)
        d0 = x0 - reference_position[i, 0]
        d1 = x1 - reference_position[i, 1]
        d2 = x2 - reference_position[i, 2]
        stats[i, S_KINETIC] = kinetic
        stats[i, S_DISPLACEMENT2] = d0 * d0 + d1 * d1 + d2 * d2
        stats[i, S_SPEED2] = speed2
        stats[i, S_STATUS] = status
