r"""Anchor potential: a weak point-to-plane pull toward the data (the fit stage's fidelity term).

Each particle i may be tied to an anchor point a_i with unit anchor normal m_i (the nearest data
point and its normal, refreshed by the caller every few steps). The energy is a point-to-plane
spring plus a normal-alignment spring:

.. math::

    E^A_i = \frac{k_d}{2}\,\frac{\bigl(m_i\cdot(x_i - a_i)\bigr)^2}{r_0^2}
            + \frac{k_n}{2}\,|n_i - m_i|^2

Distances are measured in units of r0 so that k_d means the same at every scale (with positions
normalised to r0 = 1 this is exactly k_d/2·(m_i·(x_i − a_i))²).

Notes
-----
Not part of S&T92's particle interactions: their fitting (§7) attracts particles to the data
with a spring; DESIGN §4.5 found a point-to-plane pull (k_d ≈ 1) necessary during growth and
after the seeds are released, because pure smoothing shrinks closed shapes.

References
----------
.. [ST92] R. Szeliski, D. Tonnesen. "Surface Modeling with Oriented Particle Systems".
   SIGGRAPH '92, §7 (fitting to data).
.. [CM92] Y. Chen, G. Medioni. "Object modelling by registration of multiple range images".
   Image and Vision Computing 10(3), 1992 (point-to-plane distance).
"""

from __future__ import annotations

from numba import njit

from .options import JIT_OPTIONS


@njit(inline="always", **JIT_OPTIONS)
def anchor_interaction(
    xx, xy, xz, ax, ay, az, mx, my, mz, nx, ny, nz, stiffness, normal_stiffness, inv_spacing2
):
    r"""Anchor energy, force and torque on one particle.

    Parameters
    ----------
    xx, xy, xz : float64
        Particle position x_i [length].
    ax, ay, az : float64
        Anchor point a_i [length].
    mx, my, mz : float64
        Unit anchor normal m_i.
    nx, ny, nz : float64
        Particle normal n_i (ignored when ``normal_stiffness`` is 0).
    stiffness : float64
        k_d [dimensionless energy per r0²].
    normal_stiffness : float64
        k_n [dimensionless]; pass 0 for unoriented particles.
    inv_spacing2 : float64
        1/r0² [1/length²].

    Returns
    -------
    energy : float64
        E^A_i [dimensionless].
    fx, fy, fz : float64
        Force −∂E/∂x_i [1/length].
    tx, ty, tz : float64
        Torque −∂E/∂θ_i [dimensionless].

    Notes
    -----
    .. math::

        h = m_i\cdot(x_i - a_i),\qquad
        f_i = -\frac{k_d}{r_0^2}\,h\,m_i,\qquad
        \tau_i = -n_i \times k_n (n_i - m_i) = k_n\,(n_i \times m_i)
    """
    h = mx * (xx - ax) + my * (xy - ay) + mz * (xz - az)
    k = stiffness * inv_spacing2
    dx = nx - mx
    dy = ny - my
    dz = nz - mz
    energy = 0.5 * k * h * h + 0.5 * normal_stiffness * (dx * dx + dy * dy + dz * dz)
    c = -k * h
    tx = normal_stiffness * (ny * mz - nz * my)
    ty = normal_stiffness * (nz * mx - nx * mz)
    tz = normal_stiffness * (nx * my - ny * mx)
    return energy, c * mx, c * my, c * mz, tx, ty, tz
