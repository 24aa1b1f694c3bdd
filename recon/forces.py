r"""Parameters to kernel coefficients; force, torque and energy evaluation without integration.

:func:`pack_coefficients` turns :class:`recon.params.PhysicsParams` (absolute units) into the
:class:`recon.params.Coefficients` the kernels read. :func:`accumulate_forces` evaluates the
forces, torques and energy of a whole state (used by tests and diagnostics; the simulation
itself uses the fused step in :mod:`recon.integrate`). :func:`evaluate_pair` exposes the
per-pair kernel with the force and torque on both particles.

Energy (DESIGN §1, S&T92 eqs. 3–5 and 7, T-thesis 4.11–4.17), summed over unordered pairs with
d < r_c, plus anchors (see :mod:`recon.kernels.anchor`):

.. math::

    E = \sum_{i<j} \bigl[\alpha_{LJ}\phi_\mathrm{sf} + \alpha_P E^P_{ij}
        + \alpha_N E^N_{ij} + \alpha_C E^C_{ij}\bigr] + \sum_i E^A_i

Forces are f = −∂E/∂x [1/length] and torques τ = −∂E/∂θ (δn = δθ × n) [dimensionless].

References
----------
.. [ST92] R. Szeliski, D. Tonnesen. "Surface Modeling with Oriented Particle Systems".
   SIGGRAPH '92, §4, eqs. 3–7, Appendix A.
.. [T00] D. Tonnesen. PhD thesis, chapter 4, eqs. 4.11–4.19.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .integrate import kernel_rest
from .kernels import pair_loop as _pl
from .kernels.lennard_jones import lj_cutoff_values, lj_repulsive_range
from .kernels.options import thread_limit
from .kernels.weights import WEIGHT_ANISOTROPIC
from .neighbors import PARALLEL_MIN_PARTICLES, build_neighbor_list
from .params import Coefficients, PhysicsParams, lj_minimum

if TYPE_CHECKING:
    from .state import ParticleState

_EMPTY3 = np.zeros((0, 3))


@dataclass(frozen=True)
class Anchors:
    """Per-particle anchors for the point-to-plane data pull (:mod:`recon.kernels.anchor`).

    Attributes
    ----------
    points : (n, 3) float64
        Anchor points a_i [length].
    normals : (n, 3) float64
        Unit anchor normals m_i.
    stiffness : float
        k_d [dimensionless energy per r0²].
    normal_stiffness : float
        k_n [dimensionless].
    """

    points: np.ndarray
    normals: np.ndarray
    stiffness: float
    normal_stiffness: float

    @classmethod
    def create(cls, points, normals, n: int, stiffness: float, normal_stiffness: float) -> Anchors:
        """Validate shapes and values, normalise the normals, copy the arrays."""
        for name, value in (("stiffness", stiffness), ("normal_stiffness", normal_stiffness)):
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"{name}: expected a finite number >= 0, got {value}")
        p = np.array(points, dtype=np.float64, order="C", copy=True)
        m = np.array(normals, dtype=np.float64, order="C", copy=True)
        for name, arr in (("points", p), ("normals", m)):
            if arr.shape != (n, 3):
                raise ValueError(f"anchor {name}: expected shape ({n}, 3), got {arr.shape}")
            if not np.all(np.isfinite(arr)):
                raise ValueError(f"anchor {name}: contains non-finite values")
        length = np.linalg.norm(m, axis=1)
        if np.any(length == 0.0):
            first = int(np.flatnonzero(length == 0.0)[0])
            raise ValueError(f"anchor normals: row {first} has zero length")
        m /= length[:, None]
        return cls(p, m, float(stiffness), float(normal_stiffness))


@functools.lru_cache(maxsize=64)
def _repulsive_range(sigma: float, cutoff: float) -> tuple[float, float]:
    return lj_repulsive_range(sigma, cutoff)


def pack_coefficients(
    params: PhysicsParams,
    *,
    anchors: Anchors | None = None,
    has_external_force: bool = False,
) -> Coefficients:
    """The packed coefficients read by :mod:`recon.kernels.pair_loop`.

    Parameters
    ----------
    params : PhysicsParams
        Physical parameters in absolute units.
    anchors : Anchors, optional
        Enables the anchor term with its stiffnesses.
    has_external_force : bool
        Enables the per-particle external force.

    Returns
    -------
    Coefficients
    """
    sigma = lj_minimum(params)
    phi_c, dphi_c = lj_cutoff_values(sigma, params.cutoff)
    d_m, phi_m = _repulsive_range(float(sigma), float(params.cutoff))
    anchored = anchors is not None
    return Coefficients(
        spacing=float(params.spacing),
        inv_spacing2=float(1.0 / params.spacing**2),
        cutoff=float(params.cutoff),
        cutoff2=float(params.cutoff**2),
        inv_cutoff2=float(1.0 / params.cutoff**2),
        lj_sigma2=float(sigma * sigma),
        lj_phi_cutoff=float(phi_c),
        lj_dphi_cutoff=float(dphi_c),
        w_lj=float(params.w_lj),
        w_planarity=float(params.w_planarity),
        w_normality=float(params.w_normality),
        w_circularity=float(params.w_circularity),
        inv_2sigma2=float(1.0 / (2.0 * params.influence_radius**2)),
        kappa=float(params.anisotropy**2 - 1.0 if params.weighting == WEIGHT_ANISOTROPIC else 0.0),
        dt=float(params.dt),
        damping_linear=float(params.damping_linear),
        damping_relative_linear=float(params.damping_relative_linear),
        damping_angular=float(params.damping_angular),
        damping_relative_angular=float(params.damping_relative_angular),
        max_displacement=float(params.max_displacement),
        max_rotation=float(params.max_rotation),
        anchor_stiffness=float(anchors.stiffness) if anchored else 0.0,
        anchor_normal_stiffness=float(anchors.normal_stiffness) if anchored else 0.0,
        has_anchors=1.0 if anchored else 0.0,
        has_external_force=1.0 if has_external_force else 0.0,
        separate_opposed=1.0 if params.separate_opposed else 0.0,
        lj_repulsive2=float(d_m * d_m),
        lj_phi_repulsive=float(phi_m),
    )


def kernel_extras(
    anchors: Anchors | None, external_force: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The ``extras`` tuple of the kernels: anchor points, anchor normals, external force."""
    if anchors is None:
        a, m = _EMPTY3, _EMPTY3
    else:
        a, m = anchors.points, anchors.normals
    f = _EMPTY3 if external_force is None else external_force
    return a, m, f


@dataclass(frozen=True)
class Forces:
    """Forces, torques and energy of a state.

    Attributes
    ----------
    force : (n, 3) float64
        f_i = −∂E/∂x_i plus any external force [1/length].
    torque : (n, 3) float64
        τ_i = −∂E/∂θ_i [dimensionless]; zero for unoriented particles.
    energy : float
        Total potential energy E [dimensionless].
    energy_per_particle : (n,) float64
        ½ Σ_j E_ij + E^A_i; sums to ``energy``.
    """

    force: np.ndarray
    torque: np.ndarray
    energy: float
    energy_per_particle: np.ndarray


def accumulate_forces(
    state: ParticleState,
    params: PhysicsParams,
    *,
    neighbors: tuple[np.ndarray, np.ndarray] | None = None,
    anchors: Anchors | None = None,
    external_force: np.ndarray | None = None,
    parallel: bool | None = None,
) -> Forces:
    """Evaluate forces, torques and energy of ``state`` (no integration).

    Parameters
    ----------
    state : ParticleState
    params : PhysicsParams
    neighbors : (offsets, indices), optional
        A full CSR list with radius ≥ ``params.cutoff · max(state.rest)``; built here when
        omitted.
    anchors : Anchors, optional
        Anchor term (:mod:`recon.kernels.anchor`).
    external_force : (n, 3) float64, optional
        Added to the force (not to the energy).
    parallel : bool, optional
        Threaded kernel; default when n ≥ ``PARALLEL_MIN_PARTICLES``.

    Returns
    -------
    Forces
    """
    n = state.n
    position = np.ascontiguousarray(state.position)
    if neighbors is None:
        largest = float(np.max(state.rest)) if n else 1.0
        neighbors = build_neighbor_list(position, params.cutoff * max(largest, 1.0))
    offsets, indices = neighbors
    if offsets.shape != (n + 1,):
        raise ValueError(f"neighbors: expected {n + 1} offsets, got {offsets.shape[0]}")
    ext = None
    if external_force is not None:
        ext = np.ascontiguousarray(external_force, dtype=np.float64)
        if ext.shape != (n, 3):
            raise ValueError(f"external_force: expected shape ({n}, 3), got {ext.shape}")
    if anchors is not None and anchors.points.shape[0] != n:
        raise ValueError(f"anchors: expected {n} rows, got {anchors.points.shape[0]}")
    coef = pack_coefficients(params, anchors=anchors, has_external_force=ext is not None)
    if parallel is None:
        parallel = n >= PARALLEL_MIN_PARTICLES
    state_in = (
        position,
        np.ascontiguousarray(state.orientation),
        np.ascontiguousarray(state.velocity),
        np.ascontiguousarray(state.angular_velocity),
    )
    out = np.zeros((n, _pl.N_STATS))
    with thread_limit(parallel):
        _pl.step_particles(
            coef,
            int(params.weighting),
            False,
            state_in,
            state_in,
            (np.ascontiguousarray(state.is_pinned), np.ascontiguousarray(state.is_oriented)),
            (
                np.ascontiguousarray(state.mass),
                np.ascontiguousarray(state.inertia),
                kernel_rest(state.rest),
            ),
            (offsets, indices),
            position,
            kernel_extras(anchors, ext),
            out,
        )
    force = np.ascontiguousarray(out[:, _pl.S_FORCE : _pl.S_FORCE + 3])
    torque = np.ascontiguousarray(out[:, _pl.S_TORQUE : _pl.S_TORQUE + 3])
    energy = np.ascontiguousarray(out[:, _pl.S_POTENTIAL])
    return Forces(force, torque, float(np.sum(energy)), energy)


@dataclass(frozen=True)
class PairInteraction:
    """Energy, forces and torques of one pair (:func:`evaluate_pair`).

    Attributes
    ----------
    energy : float
        E_ij [dimensionless].
    force_i, force_j : (3,) float64
        −∂E/∂x_i and −∂E/∂x_j = −force_i [1/length].
    torque_i, torque_j : (3,) float64
        −∂E/∂θ_i and −∂E/∂θ_j [dimensionless].
    """

    energy: float
    force_i: np.ndarray
    force_j: np.ndarray
    torque_i: np.ndarray
    torque_j: np.ndarray


def evaluate_pair(
    position_i: np.ndarray,
    position_j: np.ndarray,
    normal_i: np.ndarray,
    normal_j: np.ndarray,
    params: PhysicsParams,
    *,
    oriented: bool = True,
    scale: float = 1.0,
) -> PairInteraction:
    """The pair kernel :func:`recon.kernels.pair_loop.pair_interaction` for one pair.

    Parameters
    ----------
    position_i, position_j : (3,) float64
        Positions [length].
    normal_i, normal_j : (3,) float64
        Unit normals.
    params : PhysicsParams
        Weights select the terms (set the others to 0 to isolate one potential).
    oriented : bool
        Both particles oriented (False: spacing only).
    scale : float
        The pair's rest spacing relative to ``params.spacing``, (r_i + r_j)/2 (adaptive
        spacing: every length of the pair terms is multiplied by it).

    Returns
    -------
    PairInteraction
    """
    coef = pack_coefficients(params)
    r = np.asarray(position_j, dtype=np.float64) - np.asarray(position_i, dtype=np.float64)
    ni = np.asarray(normal_i, dtype=np.float64)
    nj = np.asarray(normal_j, dtype=np.float64)
    t = _pl.pair_interaction(
        r[0],
        r[1],
        r[2],
        ni[0],
        ni[1],
        ni[2],
        nj[0],
        nj[1],
        nj[2],
        bool(oriented),
        coef,
        int(params.weighting),
        float(scale),
    )
    f = np.array(t[1:4])
    return PairInteraction(float(t[0]), f, -f, np.array(t[4:7]), np.array(t[7:10]))
