r"""The pair terms of the step kernel in forms that run in SIMD lanes.

:func:`recon.kernels.pair_loop.pair_interaction` is the reference for one pair: it returns
early for a pair beyond the cutoff, for opposed sheets and for unoriented particles. In the
step kernel's term loop (:func:`recon.kernels.pair_loop.step_particles`, pass 2) those
branches decide whether LLVM vectorises: with AVX-512 it predicates them and runs the loop
eight pairs wide, but on AVX2 machines (an AMD EPYC with znver3, for one) its cost model
declines, and every pair ran in scalar code, about 2.4 times slower per pair.

:func:`polynomial_pair_terms` computes every branch's values and selects among them at the
end, for the polynomial weight (the default; the Gaussian weights call ``exp``, whose vector
form would round differently). Each branch's values are computed by the same operations in
the same order as in the reference, and a selection is exact, so the result is the
reference's, bit for bit (``tests/kernels/test_pair_terms.py``), while LLVM vectorises the
loop on AVX2 as well.

References
----------
.. [ST92] R. Szeliski, D. Tonnesen. "Surface Modeling with Oriented Particle Systems".
   SIGGRAPH '92, eqs. 3-7.
.. [T00] D. Tonnesen. PhD thesis, chapter 4, eqs. 4.11-4.17.
"""

from __future__ import annotations

from numba import njit

from .lennard_jones import lj_pair
from .options import JIT_OPTIONS


@njit(inline="always", **JIT_OPTIONS)
def isotropic_orientation_terms(
    rx, ry, rz, nix, niy, niz, njx, njy, njz, a, b, psi, dpsi, w_p, w_n, w_c, s2
):
    r"""Weighted sum of the three orientation terms for an isotropic weight ψ(d) (fast path).

    Algebraically identical to α_P·:func:`~recon.kernels.planarity.planarity_pair` +
    α_N·:func:`~recon.kernels.normality.normality_pair` +
    α_C·:func:`~recon.kernels.circularity.circularity_pair` with ψ_i = ψ_j = ψ and κ = 0
    (S&T92 eqs. 3–5, T-thesis 4.13, 4.14, 4.17), sharing the common factors.

    Parameters
    ----------
    a, b : float64
        n_i·r and n_j·r [length].
    psi, dpsi : float64
        h(d²) and h′(d²) (:func:`recon.kernels.weights.weight_value`).
    w_p, w_n, w_c : float64
        α_P, α_N, α_C.
    s2 : float64
        1/r0².

    Returns
    -------
    tuple of 10 float64
        (E, f_i (3), τ_i (3), τ_j (3)).

    Notes
    -----
    With m = n_i + n_j, e = m·r = a + b, c = |n_i − n_j|² and
    Φ = α_P s (a² + b²) + α_N c + α_C s e²:

    .. math::

        E &= \Phi\,\psi \\
        f_i &= 2\psi\,[\alpha_P s\,(a n_i + b n_j) + \alpha_C s\, e\, m] + 2h'\Phi\, r \\
        \tau_i &= -2\psi s\,(\alpha_P a + \alpha_C e)(n_i \times r)
                  + 2\alpha_N\psi\,(n_i \times n_j) \\
        \tau_j &= -2\psi s\,(\alpha_P b + \alpha_C e)(n_j \times r)
                  - 2\alpha_N\psi\,(n_i \times n_j)
    """
    dx = nix - njx
    dy = niy - njy
    dz = niz - njz
    c = dx * dx + dy * dy + dz * dz
    e = a + b
    wps = w_p * s2
    wcs = w_c * s2
    phi = wps * (a * a + b * b) + w_n * c + wcs * e * e
    energy = phi * psi
    ci = 2.0 * psi * (wps * a + wcs * e)
    cj = 2.0 * psi * (wps * b + wcs * e)
    cr = 2.0 * dpsi * phi
    fx = ci * nix + cj * njx + cr * rx
    fy = ci * niy + cj * njy + cr * ry
    fz = ci * niz + cj * njz + cr * rz
    cn = 2.0 * w_n * psi
    cx = niy * njz - niz * njy
    cy = niz * njx - nix * njz
    cz = nix * njy - niy * njx
    tix = cn * cx - ci * (niy * rz - niz * ry)
    tiy = cn * cy - ci * (niz * rx - nix * rz)
    tiz = cn * cz - ci * (nix * ry - niy * rx)
    tjx = -cn * cx - cj * (njy * rz - njz * ry)
    tjy = -cn * cy - cj * (njz * rx - njx * rz)
    tjz = -cn * cz - cj * (njx * ry - njy * rx)
    return energy, fx, fy, fz, tix, tiy, tiz, tjx, tjy, tjz


@njit(inline="always", **JIT_OPTIONS)
def pair_lengths(coef, scale, scaled):
    """The lengths of a pair's terms (DESIGN §1, variable spacing): with ``scaled`` every
    packed length of ``coef`` times s_ij = ``scale`` (energies are dimensionless:
    unchanged), so that E_ij(r; s) = E_ij(r / s; 1); else the packed ones.

    Returns
    -------
    (r_c², r_c, σ², φ′(r_c), d_m², 1/r_c², 1/(2σ_w²), 1/r0²) for the pair.
    """
    if scaled:
        sc2 = scale * scale
        inv_sc2 = 1.0 / sc2
        return (
            coef.cutoff2 * sc2,
            coef.cutoff * scale,
            coef.lj_sigma2 * sc2,
            coef.lj_dphi_cutoff / scale,
            coef.lj_repulsive2 * sc2,
            coef.inv_cutoff2 * inv_sc2,
            coef.inv_2sigma2 * inv_sc2,
            coef.inv_spacing2 * inv_sc2,
        )
    return (
        coef.cutoff2,
        coef.cutoff,
        coef.lj_sigma2,
        coef.lj_dphi_cutoff,
        coef.lj_repulsive2,
        coef.inv_cutoff2,
        coef.inv_2sigma2,
        coef.inv_spacing2,
    )


@njit(inline="always", **JIT_OPTIONS)
def polynomial_pair_terms(
    rx, ry, rz, nix, niy, niz, njx, njy, njz, oriented, coef, scale, variable_rest
):
    r"""E_ij, f_i and τ_i of one pair for the polynomial weight, without branches (DESIGN §1
    pair energy; S&T92 eqs. 3-5 and 7, T-thesis eqs. 4.11-4.17).

    Parameters
    ----------
    rx, ry, rz, nix, niy, niz, njx, njy, njz, oriented, coef
        As :func:`recon.kernels.pair_loop.pair_interaction`.
    scale : float64
        s_ij, the pair's rest spacing relative to r0; read only when ``variable_rest``.
    variable_rest : bool
        With False every length is the packed one (s_ij = 1). The step kernel passes a
        run-time value; its term loop still runs in SIMD lanes on AVX2
        (``tests/kernels/test_pair_terms.py``).

    Returns
    -------
    tuple of 7 float64
        (E_ij, f_i (3), τ_i (3)): the first seven values of
        :func:`~recon.kernels.pair_loop.pair_interaction` with ``mode`` the polynomial weight.

    Notes
    -----
    With h(q) = (1 − q/r_c²)² for q < r_c² (:func:`recon.kernels.weights.weight_value`),
    the energy is α_LJ φ_sf(d) plus, for two oriented particles whose normals are not opposed,
    the isotropic orientation terms (:func:`isotropic_orientation_terms`); for opposed normals
    (``separate_opposed``) only the repulsive branch α_LJ [φ_sf(d) − φ_sf(d_m)], 0 from d_m on.
    Every pair is 0 from the cutoff on. Every candidate is computed (an unused one may be
    infinite or NaN, as for coincident particles; it is never selected) and the selection
    happens last. The comparisons are the reference's, negated (``not (d2 >= cut2)``, not
    ``d2 < cut2``), so that a NaN distance gives NaN terms, as there; a torque is ``0.0 + τ``,
    as the reference's sum is (+0 for −0 without the JIT; with ``nsz`` both reduce to τ).
    """
    d2 = rx * rx + ry * ry + rz * rz
    cut2, cut, sigma2, dphi_c, rep2, inv_cut2, _, s2 = pair_lengths(coef, scale, variable_rest)
    w_lj = coef.w_lj
    w_p = coef.w_planarity
    w_n = coef.w_normality
    w_c = coef.w_circularity
    has_lj = w_lj != 0.0
    opposed = oriented and coef.separate_opposed != 0.0 and nix * njx + niy * njy + niz * njz < 0.0
    # the spacing term
    phi, dphi_over_d = lj_pair(d2, sigma2, cut, coef.lj_phi_cutoff, dphi_c)
    c = w_lj * dphi_over_d
    e_lj = w_lj * phi if has_lj else 0.0
    fx_lj = c * rx if has_lj else 0.0
    fy_lj = c * ry if has_lj else 0.0
    fz_lj = c * rz if has_lj else 0.0
    # the orientation terms with the polynomial weight
    ri = nix * rx + niy * ry + niz * rz
    rj = njx * rx + njy * ry + njz * rz
    t = 1.0 - d2 * inv_cut2
    psi = 0.0 if t <= 0.0 else t * t
    dpsi = 0.0 if t <= 0.0 else -2.0 * t * inv_cut2
    e, fx, fy, fz, tx, ty, tz, _, _, _ = isotropic_orientation_terms(
        rx, ry, rz, nix, niy, niz, njx, njy, njz, ri, rj, psi, dpsi, w_p, w_n, w_c, s2
    )
    # the selection
    within = not (d2 >= cut2) and not (opposed and not (has_lj and not (d2 >= rep2)))
    turn = within and oriented and not opposed and not (w_p == 0.0 and w_n == 0.0 and w_c == 0.0)
    if opposed:
        e_lj = w_lj * (phi - coef.lj_phi_repulsive)
    return (
        (e_lj + e if turn else e_lj) if within else 0.0,
        (fx_lj + fx if turn else fx_lj) if within else 0.0,
        (fy_lj + fy if turn else fy_lj) if within else 0.0,
        (fz_lj + fz if turn else fz_lj) if within else 0.0,
        0.0 + tx if turn else 0.0,
        0.0 + ty if turn else 0.0,
        0.0 + tz if turn else 0.0,
    )
