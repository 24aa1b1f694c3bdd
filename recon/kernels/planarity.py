r"""Co-planarity potential φ_P (S&T92 eq. 3, T-thesis eqs. 4.13 and §4.5 φ*_P).

The energy is small when each particle's neighbours lie in its tangent plane. We use the
symmetrised form of T-thesis §4.5 (DESIGN §1), each half weighted in the frame of the particle
whose normal it measures:

.. math::

    E^P_{ij} = \frac{(n_i\cdot r)^2\,\psi_i + (n_j\cdot r)^2\,\psi_j}{r_0^2},
    \qquad r = x_j - x_i

(ψ_i = ψ_j for the isotropic weights.) Division by r0² makes the energy dimensionless, so the
weight α_P means the same for any spacing (DESIGN §3: "α_P effectively scaled by 1/r0²").

Notes
-----
Deviations from the publications (DESIGN §2): S&T92 Appendix A's f_P and τ_P miss a factor 2 on
the main term (they are written for ½(n·r)²) and f_P has the sign of the force on j; T-thesis'
combination rule "+f_P(n_j, r_ji)" has the wrong sign. Everything here is derived from the one
energy above and checked against finite differences.

References
----------
.. [ST92] R. Szeliski, D. Tonnesen. "Surface Modeling with Oriented Particle Systems".
   SIGGRAPH '92, eq. 3 and Appendix A.
.. [T00] D. Tonnesen. PhD thesis, chapter 4, eq. 4.13 and §4.5.
"""

from __future__ import annotations

from numba import njit

from .options import JIT_OPTIONS


@njit(inline="always", **JIT_OPTIONS)
def planarity_pair(
    rx, ry, rz, nix, niy, niz, njx, njy, njz, psi_i, dpsi_i, psi_j, dpsi_j, kappa, inv_spacing2
):
    r"""Co-planarity energy, force on i and torques on i and j (S&T92 eq. 3, T-thesis 4.13).

    Parameters
    ----------
    rx, ry, rz : float64
        r = x_j − x_i [length].
    nix, niy, niz, njx, njy, njz : float64
        Unit normals n_i, n_j.
    psi_i, dpsi_i, psi_j, dpsi_j : float64
        Weights h(q_i), h′(q_i), h(q_j), h′(q_j) from
        :func:`recon.kernels.weights.pair_weights` [dimensionless, 1/length²].
    kappa : float64
        a² − 1 for the anisotropic weight (S&T92 eq. 7), else 0.
    inv_spacing2 : float64
        1/r0² [1/length²].

    Returns
    -------
    energy : float64
        E^P_ij [dimensionless], unscaled by α_P.
    fx, fy, fz : float64
        Force on i, f_i = −∂E/∂x_i = ∂E/∂r [1/length]; the force on j is −f_i.
    tix, tiy, tiz, tjx, tjy, tjz : float64
        Torques τ_i = −∂E/∂θ_i = −n_i × ∂E/∂n_i and τ_j [dimensionless].

    Notes
    -----
    With a = n_i·r, b = n_j·r, s = 1/r0², ∇ψ_i = h′_i(2r + 2κ a n_i):

    .. math::

        f_i &= s\,[2a\psi_i n_i + a^2\nabla\psi_i + 2b\psi_j n_j + b^2\nabla\psi_j] \\
        \tau_i &= -2s\,a\,(\psi_i + \kappa a^2 h'_i)\,(n_i \times r), \qquad
        \tau_j = -2s\,b\,(\psi_j + \kappa b^2 h'_j)\,(n_j \times r)

    For the isotropic weights (κ = 0) this is DESIGN §2's table, row "co-planarity", applied to
    both halves.
    """
    a = nix * rx + niy * ry + niz * rz
    b = njx * rx + njy * ry + njz * rz
    energy = inv_spacing2 * (a * a * psi_i + b * b * psi_j)
    # f_i = s [ (2 a psi_i + 2 kappa a^3 h'_i) n_i + (2 b psi_j + 2 kappa b^3 h'_j) n_j
    #           + 2 (a^2 h'_i + b^2 h'_j) r ]
    ci = 2.0 * inv_spacing2 * a * (psi_i + kappa * a * a * dpsi_i)
    cj = 2.0 * inv_spacing2 * b * (psi_j + kappa * b * b * dpsi_j)
    cr = 2.0 * inv_spacing2 * (a * a * dpsi_i + b * b * dpsi_j)
    fx = ci * nix + cj * njx + cr * rx
    fy = ci * niy + cj * njy + cr * ry
    fz = ci * niz + cj * njz + cr * rz
    # tau_i = -n_i x (ci r),  tau_j = -n_j x (cj r)
    tix = -ci * (niy * rz - niz * ry)
    tiy = -ci * (niz * rx - nix * rz)
    tiz = -ci * (nix * ry - niy * rx)
    tjx = -cj * (njy * rz - njz * ry)
    tjy = -cj * (njz * rx - njx * rz)
    tjz = -cj * (njx * ry - njy * rx)
    return energy, fx, fy, fz, tix, tiy, tiz, tjx, tjy, tjz
