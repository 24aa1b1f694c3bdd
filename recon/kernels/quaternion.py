"""Unit quaternions (w, x, y, z) for particle frames.

A particle's frame R_i is stored as a unit quaternion q = (w, x, y, z); its normal n_i is the
third column of R_i (S&T92 §3: the local z axis). Angular velocities are world-frame vectors, so
a rotation by the vector θ = ω Δt acts from the left, q ← exp(θ/2) ⊗ q, and rotates the normal
by δn = δθ × n to first order (DESIGN §1).

References
----------
.. [ST92] R. Szeliski, D. Tonnesen. "Surface Modeling with Oriented Particle Systems".
   SIGGRAPH '92, §3 (particle state, orientation as a rotation matrix / quaternion).
.. [T00] D. Tonnesen. PhD thesis, chapter 4, §4.3 (orientation dynamics).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .options import JIT_OPTIONS


@njit(inline="always", **JIT_OPTIONS)
def quaternion_normal(qw, qx, qy, qz):
    r"""Normal n = R(q) e_z, the third column of the rotation matrix of a unit quaternion.

    Parameters
    ----------
    qw, qx, qy, qz : float64
        Unit quaternion (w, x, y, z).

    Returns
    -------
    nx, ny, nz : float64
        The particle normal [unit vector].

    Notes
    -----
    .. math::

        n = \bigl(2(xz + wy),\; 2(yz - wx),\; 1 - 2(x^2 + y^2)\bigr)
    """
    return (
        2.0 * (qx * qz + qw * qy),
        2.0 * (qy * qz - qw * qx),
        1.0 - 2.0 * (qx * qx + qy * qy),
    )


@njit(inline="always", **JIT_OPTIONS)
def quaternion_multiply(aw, ax, ay, az, bw, bx, by, bz):
    r"""Hamilton product a ⊗ b of two quaternions.

    .. math::

        a \otimes b = (a_w b_w - \mathbf a\cdot\mathbf b,\;
                        a_w \mathbf b + b_w \mathbf a + \mathbf a \times \mathbf b)

    Returns
    -------
    w, x, y, z : float64
    """
    return (
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + bw * ax + ay * bz - az * by,
        aw * by + bw * ay + az * bx - ax * bz,
        aw * bz + bw * az + ax * by - ay * bx,
    )


@njit(inline="always", **JIT_OPTIONS)
def rotate_quaternion(qw, qx, qy, qz, tx, ty, tz):
    r"""Rotate a frame by the world-frame rotation vector θ and renormalise.

    Parameters
    ----------
    qw, qx, qy, qz : float64
        Unit quaternion of the frame.
    tx, ty, tz : float64
        Rotation vector θ = ω Δt [radians]: axis θ/|θ|, angle |θ|.

    Returns
    -------
    w, x, y, z : float64
        exp(θ/2) ⊗ q, renormalised to unit length.

    Notes
    -----
    The exponential map (Rodrigues) of T-thesis §4.3, applied from the left because ω is a
    world-frame vector:

    .. math::

        q' = \Bigl(\cos\tfrac{|\theta|}{2},\;
             \tfrac{\sin(|\theta|/2)}{|\theta|}\,\theta\Bigr) \otimes q,
        \qquad q' \leftarrow q' / |q'|
    """
    angle = math.sqrt(tx * tx + ty * ty + tz * tz)
    if angle < 1e-8:
        # sin(a/2)/a = 1/2 - a^2/48 + O(a^4)
        s = 0.5 - angle * angle / 48.0
    else:
        s = math.sin(0.5 * angle) / angle
    c = math.cos(0.5 * angle)
    w, x, y, z = quaternion_multiply(c, s * tx, s * ty, s * tz, qw, qx, qy, qz)
    inv = 1.0 / math.sqrt(w * w + x * x + y * y + z * z)
    return w * inv, x * inv, y * inv, z * inv


def normals_from_quaternions(orientation: np.ndarray) -> np.ndarray:
    """Normals (third columns of R) of many unit quaternions.

    Parameters
    ----------
    orientation : (n, 4) float64
        Unit quaternions (w, x, y, z).

    Returns
    -------
    (n, 3) float64
        Unit normals.
    """
    q = np.asarray(orientation, dtype=np.float64)
    w, x, y, z = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    out = np.zeros((q.shape[0], 3))
    out[:, 0] = 2.0 * (x * z + w * y)
    out[:, 1] = 2.0 * (y * z - w * x)
    out[:, 2] = 1.0 - 2.0 * (x * x + y * y)
    return out


def quaternions_from_normals(normals: np.ndarray) -> np.ndarray:
    r"""Frames whose third axis is the given normal (deterministic tangent choice).

    The frame is the minimal rotation taking e_z to n. Near n = −e_z, where that rotation is
    ill-conditioned, it is the minimal rotation taking −e_z to n composed with a half-turn about
    the x axis. The tangent directions are therefore a deterministic, continuous-almost-everywhere
    function of n; no physics depends on them except the anisotropic weight, which is symmetric
    about the normal.

    Parameters
    ----------
    normals : (n, 3) float64
        Normals; they are normalised here (zero vectors are rejected).

    Returns
    -------
    (n, 4) float64
        Unit quaternions (w, x, y, z).

    Raises
    ------
    ValueError
        If a normal has zero or non-finite length.

    Notes
    -----
    .. math::

        q = \frac{(1 + n_z,\; -n_y,\; n_x,\; 0)}{\sqrt{2(1 + n_z)}} \quad (n_z \ge 0),
        \qquad
        q = \frac{(-n_y,\; 1 - n_z,\; 0,\; n_x)}{\sqrt{2(1 - n_z)}} \quad (n_z < 0)
    """
    n = np.asarray(normals, dtype=np.float64)
    if n.ndim != 2 or n.shape[1] != 3:
        raise ValueError(f"normals: expected shape (n, 3), got {n.shape}")
    length = np.linalg.norm(n, axis=1)
    bad = ~np.isfinite(length) | (length == 0.0)
    if np.any(bad):
        first = int(np.flatnonzero(bad)[0])
        raise ValueError(f"normals: row {first} has zero or non-finite length ({n[first]})")
    n = n / length[:, None]
    q = np.zeros((n.shape[0], 4))
    up = n[:, 2] >= 0.0
    nu = n[up]
    q[up, 0] = 1.0 + nu[:, 2]
    q[up, 1] = -nu[:, 1]
    q[up, 2] = nu[:, 0]
    nd = n[~up]
    q[~up, 0] = -nd[:, 1]
    q[~up, 1] = 1.0 - nd[:, 2]
    q[~up, 3] = nd[:, 0]
    q /= np.linalg.norm(q, axis=1)[:, None]
    return q
