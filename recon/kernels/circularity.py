r"""Co-circularity potential φ_C (S&T92 eq. 5, T-thesis eq. 4.17).

The energy is small when two particles lie on a common sphere whose normals they share, i.e.
when the sum of the normals is perpendicular to the chord:

.. math::

    E^C_{ij} = \frac{\bigl((n_i + n_j)\cdot r\bigr)^2}{r_0^2}\,\bar\psi,
    \qquad \bar\psi = \tfrac12(\psi_i + \psi_j)

Division by r0² makes the energy dimensionless (as for co-planarity).

Notes
-----
Deviations from the publications (DESIGN §2): S&T92 Appendix A's f_C uses n_i where it needs
m = n_i + n_j; T-thesis eqs. 4.18–4.19 give the co-circularity torques with the wrong sign
(§4.5 has them right). Everything here is derived from the energy above.

References
----------
.. [ST92] R. Szeliski, D. Tonnesen. "Surface Modeling with Oriented Particle Systems".
   SIGGRAPH '92, eq. 5 and Appendix A.
.. [T00] D. Tonnesen. PhD thesis, chapter 4, eqs. 4.17–4.19 and §4.5.
"""

from __future__ import annotations

from numba import njit

from .options import JIT_OPTIONS


@njit(inline="always", **JIT_OPTIONS)
def circularity_pair(
    rx, ry, rz, nix, niy, niz, njx, njy, njz, psi_i, dpsi_i, psi_j, dpsi_j, kappa, inv_spacing2
):
    r"""Co-circularity energy, force on i and torques on i and j (S&T92 eq. 5, T-thesis 4.17).

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
    inv_spacing2 : float64
        1/r0² [1/length²].

    Returns
    -------
    energy : float64
        E^C_ij [dimensionless], unscaled by α_C.
    fx, fy, fz : float64
        Force on i [1/length]; the force on j is its negative.
    tix, tiy, tiz, tjx, tjy, tjz : float64
        Torques on i and j [dimensionless].

    Notes
    -----
    With m = n_i + n_j, e = m·r, a = n_i·r, b = n_j·r, s = 1/r0²:

    .. math::

        f_i &= s\,\bigl[2e\bar\psi\,m + \tfrac{e^2}{2}
               \bigl(h'_i(2r + 2\kappa a n_i) + h'_j(2r + 2\kappa b n_j)\bigr)\bigr] \\
        \tau_i &= -s\,(2e\bar\psi + \kappa e^2 a h'_i)\,(n_i \times r), \qquad
        \tau_j = -s\,(2e\bar\psi + \kappa e^2 b h'_j)\,(n_j \times r)

    For κ = 0 this is DESIGN §2's row "co-circularity".
    """
    mx = nix + njx
    my = niy + njy
    mz = niz + njz
    e = mx * rx + my * ry + mz * rz
    psi = 0.5 * (psi_i + psi_j)
    energy = inv_spacing2 * e * e * psi
    a = nix * rx + niy * ry + niz * rz
    b = njx * rx + njy * ry + njz * rz
    cm = 2.0 * inv_spacing2 * e * psi
    cr = inv_spacing2 * e * e * (dpsi_i + dpsi_j)
    ci = inv_spacing2 * e * e * kappa * a * dpsi_i
    cj = inv_spacing2 * e * e * kappa * b * dpsi_j
    fx = cm * mx + cr * rx + ci * nix + cj * njx
    fy = cm * my + cr * ry + ci * niy + cj * njy
    fz = cm * mz + cr * rz + ci * niz + cj * njz
    ti = cm + inv_spacing2 * kappa * e * e * a * dpsi_i
    tj = cm + inv_spacing2 * kappa * e * e * b * dpsi_j
    tix = -ti * (niy * rz - niz * ry)
    tiy = -ti * (niz * rx - nix * rz)
    tiz = -ti * (nix * ry - niy * rx)
    tjx = -tj * (njy * rz - njz * ry)
    tjy = -tj * (njz * rx - njx * rz)
    tjz = -tj * (njx * ry - njy * rx)
    return energy, fx, fy, fz, tix, tiy, tiz, tjx, tjy, tjz
