"""Slow NumPy reference implementations for the engine tests (stumpy's ``naive.py`` habit).

Everything here is written from the formulas of DESIGN §1–2 with plain NumPy loops, without
importing the kernels, so the kernels can be checked against an independent implementation:
pair and system energies, brute-force neighbour lists, finite-difference gradients (positions,
and small rotations δn = δθ × n with τ = −∂E/∂θ), and test geometries (hexagonal sheet, sphere).

References
----------
.. [ST92] R. Szeliski, D. Tonnesen. "Surface Modeling with Oriented Particle Systems".
   SIGGRAPH '92, eqs. 3–7.
.. [T00] D. Tonnesen. PhD thesis, chapter 4, eqs. 4.11–4.19.
"""

from __future__ import annotations

import math

import numpy as np

# ----------------------------------------------------------------------------- energies


def lj_energy(d: float, sigma: float, cutoff: float) -> float:
    """Shifted-force 4-2 Lennard-Jones energy."""
    if d >= cutoff:
        return 0.0

    def phi(x):
        return (sigma / x) ** 4 - 2.0 * (sigma / x) ** 2

    def dphi(x):
        return -4.0 * sigma**4 / x**5 + 4.0 * sigma**2 / x**3

    return phi(d) - phi(cutoff) - (d - cutoff) * dphi(cutoff)


def lj_repulsive_energy(d: float, sigma: float, cutoff: float) -> float:
    """Repulsive (WCA) branch of the shifted-force potential: φ_sf(d) − min φ_sf, 0 past it."""
    from scipy.optimize import minimize_scalar

    res = minimize_scalar(
        lambda x: lj_energy(x, sigma, cutoff),
        bounds=(0.5 * sigma, cutoff),
        method="bounded",
        options={"xatol": 1e-13},
    )
    d_m, e_m = float(res.x), float(res.fun)
    if d >= d_m:
        return 0.0
    return lj_energy(d, sigma, cutoff) - e_m


def weight(q: float, mode: int, cutoff: float, sigma: float) -> float:
    """ψ as a function of the squared (possibly anisotropic) distance q."""
    t = 1.0 - q / cutoff**2
    if t <= 0.0:
        return 0.0
    if mode == 0:
        return t * t
    return math.exp(-q / (2.0 * sigma**2)) * t * t


def directed_weight(r, n, params) -> float:
    """ψ of the pair seen from the particle with normal n (S&T92 eq. 7 for mode 2)."""
    mode = params.weighting
    if mode == 2:
        # q = |R^T r|^2 in the metric diag(1, 1, a^2): build an explicit frame to stay independent
        t1 = np.cross(n, [1.0, 0.0, 0.0])
        if np.linalg.norm(t1) < 0.5:
            t1 = np.cross(n, [0.0, 1.0, 0.0])
        t1 /= np.linalg.norm(t1)
        t2 = np.cross(n, t1)
        u = np.array([t1 @ r, t2 @ r, n @ r])
        q = u[0] ** 2 + u[1] ** 2 + (params.anisotropy * u[2]) ** 2
    else:
        q = float(r @ r)
    return weight(q, mode, params.cutoff, params.influence_radius)


def pair_energy(x_i, x_j, n_i, n_j, params, sigma: float, oriented: bool = True) -> float:
    """E_ij of DESIGN §1 with the directed (anisotropic) weights.

    With ``params.separate_opposed`` a pair of opposed normals (n_i · n_j < 0) keeps only the
    repulsive branch of the spacing term (DESIGN §8).
    """
    r = np.asarray(x_j, dtype=float) - np.asarray(x_i, dtype=float)
    d = float(np.linalg.norm(r))
    if d >= params.cutoff:
        return 0.0
    if oriented and getattr(params, "separate_opposed", False) and float(n_i @ n_j) < 0.0:
        # opposed sheets: the repulsive branch of the spacing term only
        return params.w_lj * lj_repulsive_energy(d, sigma, params.cutoff)
    e = params.w_lj * lj_energy(d, sigma, params.cutoff)
    if not oriented:
        return e
    s2 = 1.0 / params.spacing**2
    psi_i = directed_weight(r, n_i, params)
    psi_j = directed_weight(r, n_j, params)
    psi = 0.5 * (psi_i + psi_j)
    e += params.w_planarity * s2 * ((n_i @ r) ** 2 * psi_i + (n_j @ r) ** 2 * psi_j)
    e += params.w_normality * float(np.sum((n_i - n_j) ** 2)) * psi
    e += params.w_circularity * s2 * float(((n_i + n_j) @ r) ** 2) * psi
    return float(e)


def anchor_energy(x, n, a, m, k_d, k_n, spacing, oriented=True) -> float:
    """E^A = k_d/2 (m·(x − a))²/r0² + k_n/2 |n − m|²."""
    h = float(m @ (x - a))
    e = 0.5 * k_d * h * h / spacing**2
    if oriented:
        e += 0.5 * k_n * float(np.sum((n - m) ** 2))
    return e


def system_energy(position, normal, params, sigma, oriented=None, anchors=None, rest=None) -> float:
    """Total energy by brute force over all pairs (O(n²)).

    ``rest`` (optional, (n,)): rest spacings relative to r0. A pair with s = (rest_i + rest_j)/2
    has the energy of the pair scaled down by s (every length of the pair terms is s times
    longer): E_ij(x_i, x_j; s) = E_ij(x_i / s, x_j / s; 1).
    """
    n = position.shape[0]
    if oriented is None:
        oriented = np.ones(n, dtype=bool)
    if rest is None:
        rest = np.ones(n)
    total = 0.0
    for i in range(n):
        for j in range(i + 1, n):
            s = 0.5 * (rest[i] + rest[j])
            total += pair_energy(
                position[i] / s,
                position[j] / s,
                normal[i],
                normal[j],
                params,
                sigma,
                bool(oriented[i] and oriented[j]),
            )
    if anchors is not None:
        a, m, k_d, k_n = anchors
        for i in range(n):
            total += anchor_energy(
                position[i], normal[i], a[i], m[i], k_d, k_n, params.spacing, bool(oriented[i])
            )
    return total


# ----------------------------------------------------------------------------- geometry helpers


def rotate(v, axis, angle):
    """Rodrigues rotation of v about ``axis`` by ``angle``."""
    axis = np.asarray(axis, dtype=float)
    axis = axis / np.linalg.norm(axis)
    c, s = math.cos(angle), math.sin(angle)
    return v * c + np.cross(axis, v) * s + axis * (axis @ v) * (1.0 - c)


def unit(v):
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def numerical_gradients(energy, position, normal, h=1e-6):
    """Central-difference force −∂E/∂x and torque −∂E/∂θ of every particle.

    ``energy(position, normal)`` returns a float; rotations act on the normals, δn = δθ × n.
    """
    n = position.shape[0]
    force = np.zeros((n, 3))
    torque = np.zeros((n, 3))
    for i in range(n):
        for k in range(3):
            p = position.copy()
            p[i, k] += h
            ep = energy(p, normal)
            p[i, k] -= 2 * h
            em = energy(p, normal)
            force[i, k] = -(ep - em) / (2 * h)
            axis = np.eye(3)[k]
            q = normal.copy()
            q[i] = rotate(normal[i], axis, h)
            ep = energy(position, q)
            q[i] = rotate(normal[i], axis, -h)
            em = energy(position, q)
            torque[i, k] = -(ep - em) / (2 * h)
    return force, torque


def relative_error(analytic, numeric) -> float:
    """max |a − b| / max |b| (with a floor to avoid 0/0)."""
    analytic = np.asarray(analytic, dtype=float)
    numeric = np.asarray(numeric, dtype=float)
    scale = max(float(np.max(np.abs(numeric))), 1e-12)
    return float(np.max(np.abs(analytic - numeric))) / scale


def brute_force_neighbors(position, radius):
    """Rows of all j ≠ i with |x_j − x_i| < radius (sorted)."""
    d2 = np.sum((position[:, None, :] - position[None, :, :]) ** 2, axis=-1)
    np.fill_diagonal(d2, np.inf)
    return [np.flatnonzero(row < radius * radius) for row in d2]


def hex_sheet(n_x: int, n_y: int, spacing: float = 1.0) -> np.ndarray:
    """(n_x·n_y, 3) hexagonal lattice in the z = 0 plane, nearest-neighbour distance ``spacing``."""
    i, j = np.meshgrid(np.arange(n_x), np.arange(n_y), indexing="xy")
    x = (i + 0.5 * (j % 2)) * spacing
    y = j * spacing * math.sqrt(3.0) / 2.0
    return np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])


def fibonacci_sphere(n: int, radius: float) -> np.ndarray:
    """n nearly uniform points on a sphere (golden-angle spiral)."""
    k = np.arange(n) + 0.5
    z = 1.0 - 2.0 * k / n
    rho = np.sqrt(1.0 - z * z)
    phi = k * math.pi * (3.0 - math.sqrt(5.0))
    return radius * np.column_stack([rho * np.cos(phi), rho * np.sin(phi), z])


def nearest_neighbor_distance(position) -> np.ndarray:
    from scipy.spatial import cKDTree

    d, _ = cKDTree(position).query(position, k=2)
    return d[:, 1]


# ----------------------------------------------------------------------------- pair FD checks


def random_pairs(rng, n_pairs: int, spacing: float, cutoff: float):
    """Random pairs inside the cutoff (0.55 r0 < d < 0.98 r_c) with random unit normals."""
    out = []
    for _ in range(n_pairs):
        x_i = rng.normal(size=3) * spacing
        d = rng.uniform(0.55 * spacing, 0.98 * cutoff)
        x_j = x_i + d * unit(rng.normal(size=3))
        out.append((x_i, x_j, unit(rng.normal(size=3)), unit(rng.normal(size=3))))
    return out


def pair_gradient_errors(evaluate, params, sigma, pairs, h=None):
    """Worst relative errors of a pair kernel against finite differences of the reference energy.

    ``evaluate(x_i, x_j, n_i, n_j)`` returns an object with ``energy``, ``force_i``,
    ``force_j``, ``torque_i``, ``torque_j``. Returns a dict of worst relative errors for the
    energy (against :func:`pair_energy`) and each derivative.
    """
    h = 1e-6 * params.spacing if h is None else h
    worst = dict.fromkeys(("energy", "force_i", "force_j", "torque_i", "torque_j"), 0.0)

    def energy(x_i, x_j, n_i, n_j):
        return pair_energy(x_i, x_j, n_i, n_j, params, sigma)

    for x_i, x_j, n_i, n_j in pairs:
        res = evaluate(x_i, x_j, n_i, n_j)
        e_ref = energy(x_i, x_j, n_i, n_j)
        worst["energy"] = max(worst["energy"], abs(res.energy - e_ref) / max(abs(e_ref), 1e-12))
        f_i, f_j, t_i, t_j = (np.zeros(3) for _ in range(4))
        for k in range(3):
            e = np.eye(3)[k] * h
            f_i[k] = -(energy(x_i + e, x_j, n_i, n_j) - energy(x_i - e, x_j, n_i, n_j)) / (2 * h)
            f_j[k] = -(energy(x_i, x_j + e, n_i, n_j) - energy(x_i, x_j - e, n_i, n_j)) / (2 * h)
            a = np.eye(3)[k]
            t_i[k] = (
                -(
                    energy(x_i, x_j, rotate(n_i, a, 1e-6), n_j)
                    - energy(x_i, x_j, rotate(n_i, a, -1e-6), n_j)
                )
                / 2e-6
            )
            t_j[k] = (
                -(
                    energy(x_i, x_j, n_i, rotate(n_j, a, 1e-6))
                    - energy(x_i, x_j, n_i, rotate(n_j, a, -1e-6))
                )
                / 2e-6
            )
        # one scale per pair: a component that vanishes analytically is compared to the
        # pair's largest derivative, not to its own rounding noise
        scale = max(np.max(np.abs(v)) for v in (f_i * params.spacing, t_i, t_j))
        scale = max(scale, 1e-9)
        for name, analytic, numeric, unit_ in (
            ("force_i", res.force_i, f_i, params.spacing),
            ("force_j", res.force_j, f_j, params.spacing),
            ("torque_i", res.torque_i, t_i, 1.0),
            ("torque_j", res.torque_j, t_j, 1.0),
        ):
            err = float(np.max(np.abs(analytic - numeric))) * unit_ / scale
            worst[name] = max(worst[name], err)
    return worst
