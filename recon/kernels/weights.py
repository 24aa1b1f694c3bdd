r"""Weighting functions ψ of the orientation potentials.

The co-planarity, co-normality and co-circularity energies are weighted by a function ψ of the
pair separation that vanishes at the interaction cutoff r_c (S&T92 §4, T-thesis eq. 4.11).
Three forms are selectable by an integer mode (kernels never take jitted functions as
arguments, which would defeat ``cache=True``):

``WEIGHT_POLY`` (0, default)
    ψ(d) = (1 − d²/r_c²)² for d < r_c: smooth, compact, cheap.
``WEIGHT_GAUSSIAN`` (1)
    ψ(d) = exp(−d²/(2σ²)) · (1 − d²/r_c²)²: the Gaussian weight of S&T92 §4 times the compact
    taper.
``WEIGHT_ANISOTROPIC`` (2)
    The Gaussian of mode 1 evaluated in the frame of the owning particle, S&T92 eq. 7
    (T-thesis eq. 4.11): with u = R_iᵀ r and σ_n = σ/a along the normal,
    q_i = u_x² + u_y² + a² u_z² = d² + (a² − 1)(n_i·r)², ψ_i = exp(−q_i/(2σ²))·(1 − q_i/r_c²)².
    Because the frame only enters through n_i, ψ_i depends on R_i only via the normal.

Every form is written as a function h(q) of a squared length q (q = d² for the isotropic forms),
so the kernels need h and h′ = dh/dq only: ∇_r ψ_i = h′(q_i)·(2r + 2κ(n_i·r)n_i) and
∂ψ_i/∂n_i = h′(q_i)·2κ(n_i·r) r with κ = a² − 1 (κ = 0 for the isotropic forms).

Notes
-----
Deviation from the publications: the pure Gaussian does not vanish at the cutoff (at r_c = 2σ
it is still 13.5 % of its peak), so a pair crossing r_c would change the energy by a jump and
the force by a delta. We multiply it by the compact taper (1 − q/r_c²)², which makes energy and
force continuous; inside ~σ the shape is the Gaussian's.

References
----------
.. [ST92] R. Szeliski, D. Tonnesen. "Surface Modeling with Oriented Particle Systems".
   SIGGRAPH '92, §4 and eq. 7.
.. [T00] D. Tonnesen. PhD thesis, chapter 4, eq. 4.11.
"""

from __future__ import annotations

import math

from numba import njit

from .options import JIT_OPTIONS

WEIGHT_POLY = 0
WEIGHT_GAUSSIAN = 1
WEIGHT_ANISOTROPIC = 2
WEIGHT_MODES: dict[str, int] = {
    "poly": WEIGHT_POLY,
    "gaussian": WEIGHT_GAUSSIAN,
    "anisotropic": WEIGHT_ANISOTROPIC,
}
"""Config name (``potentials.weighting``) → integer mode passed to the kernels."""


@njit(inline="always", **JIT_OPTIONS)
def weight_value(q, mode, inv_cutoff2, inv_2sigma2):
    r"""Weight h(q) and its derivative dh/dq (S&T92 §4 and eq. 7, T-thesis eq. 4.11).

    Parameters
    ----------
    q : float64
        Squared (possibly anisotropic) separation [length²].
    mode : int
        ``WEIGHT_POLY``, ``WEIGHT_GAUSSIAN`` or ``WEIGHT_ANISOTROPIC``.
    inv_cutoff2 : float64
        1 / r_c² [1/length²].
    inv_2sigma2 : float64
        1 / (2σ²) of the Gaussian forms [1/length²]; unused by the polynomial.

    Returns
    -------
    h, dh_dq : float64
        Weight [dimensionless] and its derivative with respect to q [1/length²]; both zero for
        q ≥ r_c².

    Notes
    -----
    .. math::

        t = 1 - q / r_c^2,\qquad
        h_\mathrm{poly} = t^2,\qquad
        h_\mathrm{gauss} = e^{-q/(2\sigma^2)}\, t^2
    """
    t = 1.0 - q * inv_cutoff2
    if t <= 0.0:
        return 0.0, 0.0
    taper = t * t
    dtaper = -2.0 * t * inv_cutoff2
    if mode == WEIGHT_POLY:
        return taper, dtaper
    g = math.exp(-q * inv_2sigma2)
    return g * taper, g * (dtaper - inv_2sigma2 * taper)


@njit(inline="always", **JIT_OPTIONS)
def pair_weights(d2, ri, rj, mode, inv_cutoff2, inv_2sigma2, kappa):
    r"""Weights of a pair seen from both particles: ψ_i, h′_i, ψ_j, h′_j.

    Parameters
    ----------
    d2 : float64
        |r|², r = x_j − x_i [length²].
    ri, rj : float64
        n_i·r and n_j·r [length].
    mode : int
        Weighting mode; only ``WEIGHT_ANISOTROPIC`` makes ψ_i and ψ_j differ.
    inv_cutoff2, inv_2sigma2 : float64
        See :func:`weight_value`.
    kappa : float64
        κ = a² − 1, a = ``anisotropy`` (used by ``WEIGHT_ANISOTROPIC`` only).

    Returns
    -------
    psi_i, dpsi_i, psi_j, dpsi_j : float64
        h(q_i), h′(q_i), h(q_j), h′(q_j).

    Notes
    -----
    S&T92 eq. 7 / T-thesis eq. 4.11 in the frame of the owning particle:

    .. math::

        q_i = |R_i^\top r|^2_{\mathrm{diag}(1,1,a^2)} = d^2 + \kappa (n_i\cdot r)^2
    """
    if mode == WEIGHT_ANISOTROPIC:
        psi_i, dpsi_i = weight_value(d2 + kappa * ri * ri, mode, inv_cutoff2, inv_2sigma2)
        psi_j, dpsi_j = weight_value(d2 + kappa * rj * rj, mode, inv_cutoff2, inv_2sigma2)
        return psi_i, dpsi_i, psi_j, dpsi_j
    psi, dpsi = weight_value(d2, mode, inv_cutoff2, inv_2sigma2)
    return psi, dpsi, psi, dpsi
