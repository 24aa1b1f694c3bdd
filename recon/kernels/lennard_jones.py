r"""Spacing potential: soft 4-2 Lennard-Jones with shifted-force truncation.

S&T92 §4 (the Lennard-Jones potential φ_LJ(r) = B/r^n − A/r^m, before eq. 3) and T-thesis §4.4
use a Lennard-Jones-type potential to keep particles at a rest spacing. We use the soft
exponents n = 4, m = 2 (DESIGN §3: 12-6 was too stiff to converge at any usable time step),
written with the position σ of the minimum of the untruncated potential (B = σ⁴, A = 2σ²,
well depth 1):

.. math::

    \phi(d) = (\sigma/d)^4 - 2(\sigma/d)^2

and truncated at the cutoff r_c by the shifted-force rule, so that energy and force both vanish
continuously at r_c:

.. math::

    \phi_\mathrm{sf}(d) = \phi(d) - \phi(r_c) - (d - r_c)\,\phi'(r_c) \quad (d < r_c),
    \qquad \phi_\mathrm{sf} = 0 \quad (d \ge r_c)

Notes
-----
The truncation and the second neighbour shell move the equilibrium of a lattice away from σ
(DESIGN §3 measured 1.15 r0, 0.99 r0 and 0.87 r0 for r_c = 1.6, 2.0 and 2.5 r0 with σ = r0; for
this shifted-force form the stress-free infinite hexagonal lattice has spacing 1.127, 1.025 and
0.912 σ). :func:`calibrate_lj_minimum` therefore chooses σ so that the flat hexagonal lattice
with nearest-neighbour distance r0 is stress-free for the given cutoff (σ = 0.914, 0.983 and
1.067 r0); "equilibrium at r0" then holds for the sheet the particles are meant to form, for any
cutoff. A pair on its own rests at a distance slightly different from r0.

S&T92 Appendix A writes the LJ force on j where it labels the force on i; here every force is
derived from the energy, f_i = +φ′_sf(d) r̂ with r = x_j − x_i (DESIGN §2).

References
----------
.. [ST92] R. Szeliski, D. Tonnesen. "Surface Modeling with Oriented Particle Systems".
   SIGGRAPH '92, §4 and Appendix A.
.. [T00] D. Tonnesen. PhD thesis, chapter 4, §4.4.
.. [AT87] M. P. Allen, D. J. Tildesley. "Computer Simulation of Liquids", §5.2.3
   (shifted-force potential).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .options import JIT_OPTIONS


@njit(inline="always", **JIT_OPTIONS)
def lj_pair(d2, sigma2, cutoff, phi_cutoff, dphi_cutoff):
    r"""Shifted-force 4-2 energy φ_sf(d) and φ′_sf(d)/d.

    Parameters
    ----------
    d2 : float64
        Squared separation d² [length²], 0 < d < r_c.
    sigma2 : float64
        σ², the squared minimum position of the untruncated potential [length²].
    cutoff : float64
        r_c [length].
    phi_cutoff, dphi_cutoff : float64
        φ(r_c) [dimensionless] and φ′(r_c) [1/length] (see :func:`lj_cutoff_values`).

    Returns
    -------
    energy : float64
        φ_sf(d) [dimensionless].
    dphi_over_d : float64
        φ′_sf(d)/d [1/length²]. The force on i is ``dphi_over_d * r`` (r = x_j − x_i), and
        the force on j is its negative.

    Notes
    -----
    .. math::

        u = \sigma^2/d^2,\quad \phi = u^2 - 2u,\quad
        \frac{\phi'(d)}{d} = \frac{4u - 4u^2}{d^2},\quad
        \frac{\phi'_\mathrm{sf}(d)}{d} = \frac{\phi'(d) - \phi'(r_c)}{d}
    """
    inv_d = 1.0 / math.sqrt(d2)
    inv_d2 = inv_d * inv_d
    u = sigma2 * inv_d2
    energy = u * u - 2.0 * u - phi_cutoff - (d2 * inv_d - cutoff) * dphi_cutoff
    dphi_over_d = (4.0 * u - 4.0 * u * u) * inv_d2 - dphi_cutoff * inv_d
    return energy, dphi_over_d


def lj_cutoff_values(sigma: float, cutoff: float) -> tuple[float, float]:
    """φ(r_c) and φ′(r_c) of the untruncated 4-2 potential.

    Parameters
    ----------
    sigma : float
        Minimum position σ [length].
    cutoff : float
        r_c [length].

    Returns
    -------
    phi, dphi : float
        φ(r_c) [dimensionless], φ′(r_c) [1/length].
    """
    u = (sigma / cutoff) ** 2
    return u * u - 2.0 * u, (4.0 * u - 4.0 * u * u) / cutoff


def lj_repulsive_range(sigma: float, cutoff: float) -> tuple[float, float]:
    r"""Minimum d_m of the shifted-force 4-2 potential and φ_sf(d_m): the repulsive branch.

    The repulsive part used between opposed sheets
    (:func:`recon.kernels.pair_loop.pair_interaction`) is φ_sf(d) − φ_sf(d_m) for d < d_m and
    0 beyond (the Weeks-Chandler-Andersen split): continuous with its derivative at d_m, never
    attractive.

    Parameters
    ----------
    sigma, cutoff : float
        σ and r_c [length], σ < r_c.

    Returns
    -------
    d_m : float
        Where φ′_sf(d_m) = 0 [length] (σ ≤ d_m < r_c).
    phi_m : float
        φ_sf(d_m) [dimensionless], ≤ 0.
    """
    phi_c, dphi_c = lj_cutoff_values(sigma, cutoff)

    def dphi_sf(d: float) -> float:
        u = (sigma / d) ** 2
        return (4.0 * u - 4.0 * u * u) / d - dphi_c

    # φ'(d) - φ'(r_c) < 0 at d = σ (φ'(σ) = 0 and φ'(r_c) > 0) and = 0 at r_c with the sign
    # change at d_m in between: bisection on [σ, r_c)
    lo, hi = sigma, cutoff
    if dphi_sf(lo) >= 0.0:
        d_m = lo
    else:
        for _ in range(200):
            mid = 0.5 * (lo + hi)
            if dphi_sf(mid) < 0.0:
                lo = mid
            else:
                hi = mid
            if hi - lo < 1e-15 * cutoff:
                break
        d_m = 0.5 * (lo + hi)
    u = (sigma / d_m) ** 2
    phi_m = u * u - 2.0 * u - phi_c - (d_m - cutoff) * dphi_c
    return float(d_m), float(phi_m)


def _hex_shells(radius: float) -> np.ndarray:
    """Distances (in lattice constants) of all hexagonal-lattice sites closer than ``radius``."""
    m = int(math.ceil(radius)) + 2
    i, j = np.meshgrid(np.arange(-m, m + 1), np.arange(-m, m + 1), indexing="ij")
    x = i + 0.5 * j
    y = (math.sqrt(3.0) / 2.0) * j
    d = np.sqrt(x * x + y * y).ravel()
    return d[(d > 0.0) & (d < radius)]


def hex_lattice_pressure(sigma: float, spacing: float, cutoff: float) -> float:
    """d/da of the energy per particle of a flat hexagonal lattice, at a = ``spacing``.

    Zero when the lattice with nearest-neighbour distance ``spacing`` is stress-free.

    Parameters
    ----------
    sigma, spacing, cutoff : float
        σ, the lattice constant a and r_c [length].

    Returns
    -------
    float
        ½ Σ_k c_k φ′_sf(a c_k) over lattice sites at distance a c_k < r_c [1/length].
    """
    shells = _hex_shells(cutoff / spacing)
    _, dphi_c = lj_cutoff_values(sigma, cutoff)
    d = spacing * shells
    u = (sigma / d) ** 2
    dphi = (4.0 * u - 4.0 * u * u) / d - dphi_c
    return float(0.5 * np.sum(shells * dphi))


def calibrate_lj_minimum(spacing: float, cutoff: float) -> float:
    """σ such that the flat hexagonal lattice of spacing r0 is stress-free (shifted force).

    Parameters
    ----------
    spacing : float
        Rest spacing r0 [length], > 0.
    cutoff : float
        Cutoff r_c [length], > 0.

    Returns
    -------
    float
        σ [length]; σ ≈ 0.983 r0 for r_c = 2 r0.

    Raises
    ------
    ValueError
        If the cutoff is not above r0 (no neighbour would interact).
    """
    if not (spacing > 0.0 and cutoff > spacing):
        raise ValueError(
            f"LJ calibration needs 0 < spacing < cutoff, got spacing={spacing}, cutoff={cutoff}"
        )
    lo, hi = 0.2 * spacing, 3.0 * spacing
    # the pressure is positive (attractive) for small sigma and negative for large sigma
    f_lo = hex_lattice_pressure(lo, spacing, cutoff)
    f_hi = hex_lattice_pressure(hi, spacing, cutoff)
    if not (f_lo > 0.0 > f_hi):
        raise ValueError(
            f"LJ calibration failed to bracket sigma for cutoff/spacing={cutoff / spacing}"
        )
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if hex_lattice_pressure(mid, spacing, cutoff) > 0.0:
            lo = mid
        else:
            hi = mid
        if hi - lo < 1e-15 * spacing:
            break
    return 0.5 * (lo + hi)
