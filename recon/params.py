"""Physical parameters of the particle engine and the coefficient layout the kernels read.

:class:`PhysicsParams` gathers everything the kernels need in absolute units;
:meth:`PhysicsParams.from_config` converts the ``dynamics`` and ``potentials`` sections of a
validated :class:`~recon.config.ReconConfig` (lengths in units of r0) for a given spacing r0.
Its fields are checked by the same machinery as the configuration (:mod:`recon.schema`), so a
bad value raises :class:`~recon.errors.ConfigError` naming the field however it is built.

:class:`Coefficients` is the layout of the packed parameters passed to
:mod:`recon.kernels.pair_loop` (a ``NamedTuple`` of floats: numba reads its fields by name as
cheaply as a plain tuple by index). :func:`recon.forces.pack_coefficients` fills it.

References
----------
.. [ST92] R. Szeliski, D. Tonnesen. "Surface Modeling with Oriented Particle Systems".
   SIGGRAPH '92.
.. [T00] D. Tonnesen. PhD thesis, chapter 4.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, NamedTuple

from .errors import ConfigError, did_you_mean
from .kernels.lennard_jones import calibrate_lj_minimum
from .kernels.weights import WEIGHT_MODES
from .schema import Schema, option

if TYPE_CHECKING:
    from .config import ReconConfig

__all__ = ["Coefficients", "PhysicsParams", "lj_minimum"]


class Coefficients(NamedTuple):
    """Packed parameters of the kernels, all lengths absolute (field order is the layout)."""

    spacing: float
    """r0 [length]."""
    inv_spacing2: float
    """1 / r0²."""
    cutoff: float
    """r_c [length]."""
    cutoff2: float
    """r_c²."""
    inv_cutoff2: float
    """1 / r_c²."""
    lj_sigma2: float
    """σ² of the 4-2 potential."""
    lj_phi_cutoff: float
    """φ(r_c) (shifted-force truncation)."""
    lj_dphi_cutoff: float
    """φ'(r_c)."""
    w_lj: float
    """α_LJ."""
    w_planarity: float
    """α_P."""
    w_normality: float
    """α_N."""
    w_circularity: float
    """α_C."""
    inv_2sigma2: float
    """1 / (2 σ_ψ²) of the Gaussian weights."""
    kappa: float
    """a² − 1 of the anisotropic weight (0 otherwise)."""
    dt: float
    """Time step."""
    damping_linear: float
    """β0."""
    damping_relative_linear: float
    """β1."""
    damping_angular: float
    """β2."""
    damping_relative_angular: float
    """β3."""
    max_displacement: float
    """Per-step displacement cap [length]."""
    max_rotation: float
    """Per-step rotation cap [rad]."""
    anchor_stiffness: float
    """k_d of the anchor pull."""
    anchor_normal_stiffness: float
    """k_n of the anchor normal torque."""
    has_anchors: float
    """1.0 when the anchor term is on."""
    has_external_force: float
    """1.0 when an external force is added."""
    separate_opposed: float
    """1.0: pairs with n_i · n_j < 0 keep only the repulsive LJ branch (opposed sheets)."""
    lj_repulsive2: float
    """d_m², the squared minimum of φ_sf: the repulsive branch is d < d_m."""
    lj_phi_repulsive: float
    """φ_sf(d_m), subtracted from the repulsive branch so that it vanishes at d_m."""


@functools.lru_cache(maxsize=64)
def _lj_minimum_ratio(cutoff_ratio: float) -> float:
    return calibrate_lj_minimum(1.0, cutoff_ratio)


def lj_minimum(params: PhysicsParams) -> float:
    """σ of the 4-2 potential: ``params.lj_minimum`` or the hexagonal-lattice calibration.

    Parameters
    ----------
    params : PhysicsParams

    Returns
    -------
    float
        σ [length] (≈ 0.983 · spacing for cutoff = 2 · spacing).
    """
    if params.lj_minimum is not None:
        return float(params.lj_minimum)
    return params.spacing * _lj_minimum_ratio(params.cutoff / params.spacing)


_POSITIVE = {"lo": 0.0, "lo_open": True}
_NONNEGATIVE = {"lo": 0.0}


@dataclass(frozen=True)
class PhysicsParams(Schema):
    """Everything the kernels need, in absolute units.

    Build it with :meth:`from_config`; defaults live in :mod:`recon.config` only. Every field is
    checked on construction (also by ``dataclasses.replace``); errors are
    :class:`~recon.errors.ConfigError` naming the field.

    Attributes
    ----------
    spacing : float
        Rest spacing r0 [length].
    cutoff : float
        Interaction cutoff r_c of all terms [length].
    w_lj, w_planarity, w_normality, w_circularity : float
        α_LJ, α_P, α_N, α_C [dimensionless].
    weighting : int
        ψ: 0 poly, 1 Gaussian, 2 anisotropic (:mod:`recon.kernels.weights`); a config name
        ("poly", ...) is accepted and converted.
    influence_radius : float
        σ of the Gaussian weights [length].
    anisotropy : float
        a ≥ 1: σ along the normal is σ/a (anisotropic weight only).
    dt : float
        Time step [model time].
    damping_linear, damping_angular : float
        β0, β2 [1/time, with m = I = 1].
    damping_relative_linear, damping_relative_angular : float
        β1, β3 (relative damping between neighbours within the cutoff).
    max_displacement : float
        Per-step displacement cap [length].
    max_rotation : float
        Per-step rotation cap [radians].
    skin : float
        Neighbour-list skin [length].
    lj_minimum : float or None
        σ of the 4-2 potential [length]; None (default) calibrates it so that the flat
        hexagonal lattice rests at ``spacing`` (:func:`recon.kernels.calibrate_lj_minimum`).
    separate_opposed : bool
        Pairs of oriented particles with opposed normals (n_i · n_j < 0: two sides of a thin
        part) feel only the repulsive branch of the spacing potential and no orientation
        terms, so opposite sheets never attract or align.
    """

    spacing: float = option(doc="Rest spacing r0 [length].", **_POSITIVE)
    cutoff: float = option(doc="Interaction cutoff [length].", **_POSITIVE)
    w_lj: float = option(doc="alpha_LJ.", **_NONNEGATIVE)
    w_planarity: float = option(doc="alpha_P.", **_NONNEGATIVE)
    w_normality: float = option(doc="alpha_N.", **_NONNEGATIVE)
    w_circularity: float = option(doc="alpha_C.", **_NONNEGATIVE)
    weighting: int = option(doc="psi mode.", choices=tuple(sorted(WEIGHT_MODES.values())))
    influence_radius: float = option(doc="sigma of the Gaussian weights [length].", **_POSITIVE)
    anisotropy: float = option(doc="Anisotropic weight divisor.", lo=1.0)
    dt: float = option(doc="Time step.", **_POSITIVE)
    damping_linear: float = option(doc="beta_0.", **_NONNEGATIVE)
    damping_angular: float = option(doc="beta_2.", **_NONNEGATIVE)
    damping_relative_linear: float = option(doc="beta_1.", **_NONNEGATIVE)
    damping_relative_angular: float = option(doc="beta_3.", **_NONNEGATIVE)
    max_displacement: float = option(doc="Per-step displacement cap [length].", **_POSITIVE)
    max_rotation: float = option(doc="Per-step rotation cap [rad].", hi=math.pi, **_POSITIVE)
    skin: float = option(doc="Neighbour-list skin [length].", **_POSITIVE)
    lj_minimum: float | None = option(None, "sigma of the 4-2 potential [length].", **_POSITIVE)
    separate_opposed: bool = option(True, "Opposed pairs: repulsion only.")

    def __post_init__(self) -> None:
        if isinstance(self.weighting, str):
            if self.weighting not in WEIGHT_MODES:
                raise ConfigError(
                    f"weighting: {self.weighting!r} is not one of: {', '.join(WEIGHT_MODES)}"
                    f"{did_you_mean(self.weighting, list(WEIGHT_MODES))}"
                )
            object.__setattr__(self, "weighting", WEIGHT_MODES[self.weighting])
        super().__post_init__()

    def check(self, prefix: str) -> None:
        if self.lj_minimum is None:
            if not self.cutoff > self.spacing:
                raise ConfigError(
                    f"{prefix}cutoff ({self.cutoff}) must exceed {prefix}spacing "
                    f"({self.spacing}) for the LJ calibration"
                )
        elif not self.lj_minimum < self.cutoff:
            raise ConfigError(
                f"{prefix}lj_minimum: expected 0 < value < cutoff, got {self.lj_minimum}"
            )

    @classmethod
    def from_config(cls, cfg: ReconConfig, spacing: float) -> PhysicsParams:
        """Absolute parameters from the ``dynamics`` and ``potentials`` config sections.

        Parameters
        ----------
        cfg : ReconConfig
            Configuration; its lengths are in units of r0, angles in degrees.
        spacing : float
            r0 [length] (1.0 when positions are already divided by r0).

        Returns
        -------
        PhysicsParams
        """
        d = cfg.dynamics
        p = cfg.potentials
        return cls(
            spacing=float(spacing),
            cutoff=p.cutoff * spacing,
            w_lj=p.w_lj,
            w_planarity=p.w_planarity,
            w_normality=p.w_normality,
            w_circularity=p.w_circularity,
            weighting=WEIGHT_MODES[p.weighting],
            influence_radius=p.influence_radius * spacing,
            anisotropy=p.anisotropy,
            dt=d.dt,
            damping_linear=d.damping_linear,
            damping_angular=d.damping_angular,
            damping_relative_linear=d.damping_relative_linear,
            damping_relative_angular=d.damping_relative_angular,
            max_displacement=d.max_displacement * spacing,
            max_rotation=math.radians(d.max_rotation_deg),
            skin=d.skin * spacing,
            separate_opposed=p.separate_opposed,
        )

    @property
    def lj_sigma(self) -> float:
        """σ actually used by the spacing potential [length]."""
        return lj_minimum(self)
