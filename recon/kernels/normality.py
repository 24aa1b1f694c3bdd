r"""Co-normality potential φ_N (S&T92 eq. 4, T-thesis eq. 4.14).

The energy is small when neighbouring normals agree:

.. math::

    E^N_{ij} = |n_i - n_j|^2\,\bar\psi, \qquad \bar\psi = \tfrac12(\psi_i + \psi_j)

(ψ̄ = ψ for the isotropic weights; with the anisotropic weight of S&T92 eq. 7 each particle
weighs the pair in its own frame and the two views are averaged.)

Notes
-----
Deviations from the publications (DESIGN §2): T-thesis eq. 4.15 gives the co-normality torque
with the wrong sign (it turns normals apart); §4.5's −2(n_j × n_i)w is right, but §4.5's force
uses r where it needs r̂. Here the torque on i is +2ψ̄ (n_i × n_j), derived from the energy.

References
----------
.. [ST92] R. Szeliski, D. Tonnesen. "Surface Modeling with Oriented Particle Systems".
   SIGGRAPH '92, eq. 4.
.. [T00] D. Tonnesen. PhD thesis, chapter 4, eqs. 4.14–4.15 and §4.5.
"""

from __future__ import annotations

from numba import njit

from .options import JIT_OPTIONS


@njit(inline="always", **JIT_OPTIONS)
def normality_pair(rx, ry, rz, nix, niy, niz, njx, njy, njz, psi_i, dpsi_i, psi_j, dpsi_j, kappa):
    r"""Co-normality energy, force on i and torques on i and j (S&T92 eq. 4, T-thesis 4.14).

    Parameters
    ----------
    rx, ry, rz : float64
        r = x_j − x_i [length].
    nix, niy, niz, njx, njy, njz : float64
        Unit normals n_i, n_j.
    psi_i, dpsi_i, psi_j, dpsi_j : float64
        Weights h(q_i), h′(q_i), h(q_j), h′(q_j) [dimensionless, 1/length²].
    kappa : float64
        a² − 1 for the anisotropic weight (S&T92 eq. 7), else 0.

    Returns
    -------
    energy : float64
        E^N_ij [dimensionless], unscaled by α_N.
    fx, fy, fz : float64
        Force on i [1/length]; the force on j is its negative.
    tix, tiy, tiz, tjx, tjy, tjz : float64
        Torques on i and j [dimensionless].

    Notes
    -----
    With c = |n_i − n_j|², a = n_i·r, b = n_j·r:

    .. math::

        f_i &= \tfrac{c}{2}\,[h'_i(2r + 2\kappa a n_i) + h'_j(2r + 2\kappa b n_j)] \\
        \tau_i &= 2\bar\psi\,(n_i \times n_j) - c\,\kappa\,a\,h'_i\,(n_i \times r) \\
        \tau_j &= -2\bar\psi\,(n_i \times n_j) - c\,\kappa\,b\,h'_j\,(n_j \times r)

    For κ = 0 this is DESIGN §2's row "co-normality" (f_i = c ψ′ r̂).
    """
    dx = nix - njx
    dy = niy - njy
    dz = niz - njz
    c = dx * dx + dy * dy + dz * dz
    psi = 0.5 * (psi_i + psi_j)
    energy = c * psi
    a = nix * rx + niy * ry + niz * rz
    b = njx * rx + njy * ry + njz * rz
    cr = c * (dpsi_i + dpsi_j)
    ci = c * kappa * a * dpsi_i
    cj = c * kappa * b * dpsi_j
    fx = cr * rx + ci * nix + cj * njx
    fy = cr * ry + ci * niy + cj * njy
    fz = cr * rz + ci * niz + cj * njz
    # n_i x n_j
    cx = niy * njz - niz * njy
    cy = niz * njx - nix * njz
    cz = nix * njy - niy * njx
    two_psi = 2.0 * psi
    tix = two_psi * cx - ci * (niy * rz - niz * ry)
    tiy = two_psi * cy - ci * (niz * rx - nix * rz)
    tiz = two_psi * cz - ci * (nix * ry - niy * rx)
    tjx = -two_psi * cx - cj * (njy * rz - njz * ry)
    tjy = -two_psi * cy - cj * (njz * rx - njx * rz)
    tjz = -two_psi * cz - cj * (njx * ry - njy * rx)
    return energy, fx, fy, fz, tix, tiy, tiz, tjx, tjy, tjz
