r"""The per-particle loop: pair forces and torques, anchors, damping and the integration step.

Total energy (DESIGN §1), summed over unordered pairs within the cutoff r_c plus anchors:

.. math::

    E = \sum_{i<j} \Bigl[\alpha_{LJ}\phi_\mathrm{sf}(d)
        + \alpha_P \frac{(n_i\cdot r)^2\psi_i + (n_j\cdot r)^2\psi_j}{r_0^2}
        + \alpha_N |n_i - n_j|^2 \bar\psi
        + \alpha_C \frac{((n_i + n_j)\cdot r)^2}{r_0^2} \bar\psi\Bigr]
      + \sum_i E^A_i

(S&T92 eqs. 3–5 and 7, T-thesis eqs. 4.11–4.17; the orientation terms are skipped for pairs with
an unoriented particle, and pairs with opposed normals keep only the repulsive branch of φ_sf:
:func:`pair_interaction`.) Neighbour lists are *full*: each pair appears in both rows, and row i
accumulates only the force and torque on i. The ``prange`` runs over blocks of rows; each row
is evaluated by one thread, writes only its own row (no races) and sums in a fixed order, so
results are bit-identical from run to run and for any thread count.

The fused step :func:`step_particles` reads the state from one set of buffers and writes the new
state to another, so forces and integration share one parallel region per step (DESIGN §3: a
region costs milliseconds on a loaded machine); small systems run it in the calling thread
(:func:`recon.kernels.options.thread_limit`), with the same compiled code. Equations of motion,
in reduced units (lengths in r0, DESIGN §3), semi-implicit Euler:

.. math::

    m\dot v_i &= r_0^2 f_i - \beta_0 v_i - \beta_1\sum_j (v_i - v_j), \qquad
    I\dot\omega_i = \tau_i - \beta_2\omega_i - \beta_3\sum_j(\omega_i - \omega_j) \\
    v_i' &= \frac{v_i + \Delta t\,(r_0^2 f_i - \beta_1\sum_j(v_i - v_j))/m}
                 {1 + \Delta t\,\beta_0/m},\qquad x_i' = x_i + \Delta t\,v_i' \\
    q_i' &= \exp(\tfrac12\omega_i'\Delta t) \otimes q_i\ \text{(renormalised)}

(T-thesis eqs. 4.9–4.10). The factor r0² on the force makes the dynamics of x/r0 independent of
r0; the linear and angular damping are treated implicitly (unconditionally stable), the relative
damping explicitly. Per-step displacement and rotation are capped; the velocity is scaled with
the step, so a capped particle does not keep a velocity its position did not follow. Pinned
particles keep position and frame and have zero velocities; unoriented particles keep their
frame.

Notes
-----
Deviation from T-thesis eqs. 4.37–4.38: relative damping there is −β₁Σ(v_j − v_i), which adds
energy (DESIGN §2); we use −β₁Σ(v_i − v_j) as in eq. 4.10. Sums over j run over neighbours within
r_c (oriented pairs only for the angular term).

References
----------
.. [ST92] R. Szeliski, D. Tonnesen. "Surface Modeling with Oriented Particle Systems".
   SIGGRAPH '92, §4 and eqs. 3–7.
.. [T00] D. Tonnesen. PhD thesis, chapter 4, eqs. 4.9–4.19 and §4.5.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from .anchor import anchor_interaction
from .circularity import circularity_pair
from .lennard_jones import lj_pair
from .normality import normality_pair
from .options import JIT_OPTIONS
from .pair_terms import isotropic_orientation_terms, pair_lengths, polynomial_pair_terms
from .planarity import planarity_pair
from .quaternion import quaternion_normal, rotate_quaternion
from .weights import WEIGHT_ANISOTROPIC, WEIGHT_POLY, pair_weights

# Columns of the per-particle output array of :func:`step_particles`.
S_POTENTIAL = 0
S_KINETIC = 1
S_KINETIC_BEFORE = 2
S_DISPLACEMENT2 = 3
S_SPEED2 = 4
S_STATUS = 5
S_FORCE = 6  # 6, 7, 8
S_TORQUE = 9  # 9, 10, 11
N_STATS = 12

# Bits of the status column.
STATUS_BAD_INPUT = 1
STATUS_BAD_FORCE = 2
STATUS_BAD_OUTPUT = 4

_JIT = JIT_OPTIONS
#: Rows per scratch block of :func:`step_particles`.
_BLOCK = 256


@njit(inline="always", **_JIT)
def _add_scaled(acc, w, t):
    return (
        acc[0] + w * t[0],
        acc[1] + w * t[1],
        acc[2] + w * t[2],
        acc[3] + w * t[3],
        acc[4] + w * t[4],
        acc[5] + w * t[5],
        acc[6] + w * t[6],
        acc[7] + w * t[7],
        acc[8] + w * t[8],
        acc[9] + w * t[9],
    )


@njit(inline="always", **_JIT)
def pair_interaction(rx, ry, rz, nix, niy, niz, njx, njy, njz, oriented, coef, mode, scale):
    r"""Energy, force on i and torques on i and j of one pair (DESIGN §1 pair energy).

    Parameters
    ----------
    rx, ry, rz : float64
        r = x_j − x_i [length].
    nix, niy, niz, njx, njy, njz : float64
        Unit normals n_i, n_j (ignored unless ``oriented``).
    oriented : bool
        Both particles are oriented; otherwise only the spacing term acts (creases). When both
        are oriented, their normals are opposed (n_i · n_j < 0) and ``coef.separate_opposed`` is
        set, only the repulsive branch of the spacing term acts (see Notes).
    coef : recon.params.Coefficients
        Packed parameters, a named tuple of floats (:func:`recon.forces.pack_coefficients`).
    mode : int
        Weighting mode (:mod:`recon.kernels.weights`).
    scale : float64
        s_ij = (r_i + r_j) / 2, the pair's rest spacing relative to r0 (1 for uniform
        spacing): every length of the pair terms (LJ σ and r_c, the weight widths, the r0 of
        the orientation terms) is multiplied by s_ij, so that E_ij(r; s) = E_ij(r / s; 1).
        It is held fixed during a step (not differentiated).

    Returns
    -------
    tuple of 10 float64
        (E_ij, f_i (3), τ_i (3), τ_j (3)); f_j = −f_i. E_ij is dimensionless, forces are in
        1/length, torques dimensionless.

    Notes
    -----
    .. math::

        E_{ij} = \alpha_{LJ}\phi_\mathrm{sf}(d) + \alpha_P E^P_{ij}
                 + \alpha_N E^N_{ij} + \alpha_C E^C_{ij}

    with the terms of :mod:`~recon.kernels.lennard_jones` (S&T92 §4),
    :mod:`~recon.kernels.planarity` (eq. 3), :mod:`~recon.kernels.normality` (eq. 4) and
    :mod:`~recon.kernels.circularity` (eq. 5), weighted by :mod:`~recon.kernels.weights`
    (eq. 7 for the anisotropic form). For the isotropic weights the three orientation terms are
    evaluated together by
    :func:`~recon.kernels.pair_terms.isotropic_orientation_terms` (same values, fewer operations).

    Opposed sheets (n_i · n_j < 0, both oriented, ``separate_opposed``; DESIGN §8): the two
    sides of a thin part must neither attract nor align, so the pair keeps only the repulsive
    (Weeks-Chandler-Andersen) branch of the spacing potential,

    .. math::

        E_{ij} = \alpha_{LJ}\,[\phi_\mathrm{sf}(d) - \phi_\mathrm{sf}(d_m)]\ (d < d_m),
        \qquad E_{ij} = 0\ (d \ge d_m)

    with d_m the minimum of φ_sf (:func:`~recon.kernels.lennard_jones.lj_repulsive_range`).
    The switch depends on the normals only through the sign of n_i · n_j: forces and torques
    are the exact gradient of this energy on either side of the switch (torques vanish).
    """
    acc = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    d2 = rx * rx + ry * ry + rz * rz
    # the packed lengths for uniform spacing (s_ij = 1), else every length times s_ij
    cut2, cut, sigma2, dphi_c, rep2, inv_cut2, inv_2sigma2, s2 = pair_lengths(
        coef, scale, scale != 1.0
    )
    if d2 >= cut2:
        return acc
    w_lj = coef.w_lj
    if oriented and coef.separate_opposed != 0.0 and nix * njx + niy * njy + niz * njz < 0.0:
        # opposed sheets: the repulsive branch only, no orientation terms
        if w_lj == 0.0 or d2 >= rep2:
            return acc
        phi, dphi_over_d = lj_pair(d2, sigma2, cut, coef.lj_phi_cutoff, dphi_c)
        c = w_lj * dphi_over_d
        return (
            w_lj * (phi - coef.lj_phi_repulsive),
            c * rx,
            c * ry,
            c * rz,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
        )
    if w_lj != 0.0:
        phi, dphi_over_d = lj_pair(d2, sigma2, cut, coef.lj_phi_cutoff, dphi_c)
        c = w_lj * dphi_over_d
        acc = (w_lj * phi, c * rx, c * ry, c * rz, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    if not oriented:
        return acc
    w_p = coef.w_planarity
    w_n = coef.w_normality
    w_c = coef.w_circularity
    if w_p == 0.0 and w_n == 0.0 and w_c == 0.0:
        return acc
    kappa = coef.kappa
    ri = nix * rx + niy * ry + niz * rz
    rj = njx * rx + njy * ry + njz * rz
    psi_i, dpsi_i, psi_j, dpsi_j = pair_weights(d2, ri, rj, mode, inv_cut2, inv_2sigma2, kappa)
    if mode != WEIGHT_ANISOTROPIC:
        t = isotropic_orientation_terms(
            rx, ry, rz, nix, niy, niz, njx, njy, njz, ri, rj, psi_i, dpsi_i, w_p, w_n, w_c, s2
        )
        return _add_scaled(acc, 1.0, t)
    if w_p != 0.0:
        t = planarity_pair(
            rx, ry, rz, nix, niy, niz, njx, njy, njz, psi_i, dpsi_i, psi_j, dpsi_j, kappa, s2
        )
        acc = _add_scaled(acc, w_p, t)
    if w_n != 0.0:
        t = normality_pair(
            rx, ry, rz, nix, niy, niz, njx, njy, njz, psi_i, dpsi_i, psi_j, dpsi_j, kappa
        )
        acc = _add_scaled(acc, w_n, t)
    if w_c != 0.0:
        t = circularity_pair(
            rx, ry, rz, nix, niy, niz, njx, njy, njz, psi_i, dpsi_i, psi_j, dpsi_j, kappa, s2
        )
        acc = _add_scaled(acc, w_c, t)
    return acc


@njit(inline="always", **_JIT)
def _store_terms(pt, a, e, fx, fy, fz, tx, ty, tz):
    """Column ``a`` of the scratch ``pt``: E_ij, f_i (3), τ_i (3) of one pair."""
    pt[0, a] = e
    pt[1, a] = fx
    pt[2, a] = fy
    pt[3, a] = fz
    pt[4, a] = tx
    pt[5, a] = ty
    pt[6, a] = tz


@njit(inline="always", **_JIT)
def _poly_pair_terms(pr, po, pt, count, coef, variable_rest):
    """Pass 2 of :func:`step_particles` for the polynomial weight: the terms of
    :func:`pair_interaction` (S&T92 eqs. 3-7) for ``count`` gathered pairs (``pr`` rows r (3),
    s_ij, n_j (3), n_i (3); ``po`` oriented) into ``pt`` rows E_ij, f_i (3), τ_i (3), by the
    branch-free :func:`~recon.kernels.pair_terms.polynomial_pair_terms`.

    Inlined, at one call site (numba copies an inlined function's IR per site: a second copy,
    one per value of ``variable_rest``, took about 17 s of the step kernel's compile and ran no
    faster: 17.8 ns per pair for uniform spacing with the flag a constant or a run-time
    value, 18.6 with the run-time flag for per-particle spacing). The loop reads and writes
    only contiguous scratch rows, and LLVM vectorises it with the flag a run-time value too
    (4 lanes with AVX2, up to 8 with AVX-512; packed multiplies on AVX2 are checked by
    ``tests/kernels/test_pair_terms.py``).
    A SIMD lane performs the scalar operations (add, multiply, divide, square root: exactly
    rounded; no ``contract`` or ``reassoc``), so the terms are bit-identical. The loop calls
    nothing that is not inlined (a call in it would keep LLVM from vectorising it)."""
    for a in range(count):
        rx, ry, rz, s_ij = pr[0, a], pr[1, a], pr[2, a], pr[3, a]
        njx, njy, njz = pr[4, a], pr[5, a], pr[6, a]
        nix, niy, niz = pr[7, a], pr[8, a], pr[9, a]
        e, fx, fy, fz, tx, ty, tz = polynomial_pair_terms(
            rx, ry, rz, nix, niy, niz, njx, njy, njz, po[a], coef, s_ij, variable_rest
        )
        _store_terms(pt, a, e, fx, fy, fz, tx, ty, tz)


@njit(**_JIT)
def _other_pair_terms(pr, po, pt, count, coef, mode, variable_rest):
    """Pass 2 of :func:`step_particles` for the Gaussian and anisotropic weights: as
    :func:`_poly_pair_terms`, by :func:`pair_interaction`. Not inlined: it is called once per
    block of rows, so its array arguments cost a few reference counts per block, and the step
    kernel compiles without a third copy of the pair terms (numba copies the IR of every
    inlined call; with this copy, and the general terms in the polynomial copies' untaken
    branches, the kernel's first call took 70 s against 56 s, 2026-11-30). These weights call
    ``exp``, which would differ in a vector math library: the loop keeps the scalar reference."""
    for a in range(count):
        rx, ry, rz, s_ij = pr[0, a], pr[1, a], pr[2, a], pr[3, a]
        njx, njy, njz = pr[4, a], pr[5, a], pr[6, a]
        nix, niy, niz = pr[7, a], pr[8, a], pr[9, a]
        scale = s_ij if variable_rest else 1.0
        e, fx, fy, fz, tx, ty, tz, _, _, _ = pair_interaction(
            rx, ry, rz, nix, niy, niz, njx, njy, njz, po[a], coef, mode, scale
        )
        _store_terms(pt, a, e, fx, fy, fz, tx, ty, tz)


@njit(**_JIT)
def _reduce_stats(stats, n):
    """Serial, fixed-order reduction of the per-particle statistics (deterministic)."""
    potential = 0.0
    kinetic = 0.0
    kinetic_before = 0.0
    max_displacement2 = 0.0
    max_speed2 = 0.0
    first_bad = -1
    bad_status = 0
    for i in range(n):
        potential += stats[i, S_POTENTIAL]
        kinetic += stats[i, S_KINETIC]
        kinetic_before += stats[i, S_KINETIC_BEFORE]
        if stats[i, S_DISPLACEMENT2] > max_displacement2:
            max_displacement2 = stats[i, S_DISPLACEMENT2]
        if stats[i, S_SPEED2] > max_speed2:
            max_speed2 = stats[i, S_SPEED2]
        if stats[i, S_STATUS] != 0.0 and first_bad < 0:
            first_bad = i
            bad_status = int(stats[i, S_STATUS])
    return (
        potential,
        kinetic,
        kinetic_before,
        max_displacement2,
        max_speed2,
        first_bad,
        bad_status,
    )


@njit(parallel=True, **_JIT)
def step_particles(
    coef,
    mode,
    integrate,
    state_in,
    state_out,
    flags,
    inertial,
    neighbors,
    reference_position,
    extras,
    stats,
):
    r"""Forces, torques and (optionally) one integration step for every particle.

    The per-row work is written out in full (no helper called per row or per pair receives
    arrays): passing arrays to a non-inlined numba function costs atomic reference-count
    updates per call, which threads contend for. The one exception is
    :func:`_other_pair_terms`, called once per block of rows. Run it single-threaded with
    :func:`recon.kernels.options.thread_limit`.

    Rows are taken in blocks of ``_BLOCK``, each with its own scratch arrays (allocated once
    per block, not per particle), in three passes: (1) the list entries within the cutoff are
    gathered branch-free, with r = x_j − x_i, s_ij, n_j, n_i and whether both are oriented
    (every normal is computed from its quaternion once per call, not once per pair);
    (2) the pair terms of the whole block are computed into the scratch
    (:func:`_poly_pair_terms`, vectorised, for the polynomial weight;
    :func:`_other_pair_terms` for the others); (3) per row, the terms are
    summed in list order, then the anchors and the step. Each pair's arithmetic (no
    ``contract`` or ``reassoc``: a SIMD lane computes what the scalar code does) and the order
    of every sum are those of a single loop over the row, so the results are bit-identical to
    it; the split avoids a mispredicted skip branch per list entry (about 40 % of the Verlet
    list lies beyond r_c) and lets the term loop run in SIMD lanes.

    Parameters
    ----------
    coef : recon.params.Coefficients
        Packed parameters, a named tuple of floats (:func:`recon.forces.pack_coefficients`).
    mode : int
        Weighting mode (:mod:`recon.kernels.weights`).
    integrate : bool
        Advance the state into ``state_out``; if False only forces, torques and energies are
        written to ``stats`` (``state_out`` is not touched and may be ``state_in``).
    state_in, state_out : tuple of four 2-D float64 arrays
        (position (n, 3) [length], orientation (n, 4) (w, x, y, z), velocity (n, 3)
        [length/time], angular_velocity (n, 3) [rad/time]). Must not share memory when
        ``integrate``.
    flags : tuple of two (n,) bool
        (is_pinned, is_oriented).
    inertial : tuple of three float64 arrays
        (mass (n,), inertia (n,), rest): rest spacings relative to r0, (n,) or empty for all
        ones (uniform spacing); a pair uses (rest_i + rest_j)/2 (:func:`pair_interaction`).
    neighbors : (offsets (n + 1,) int64, indices (nnz,) int32)
        Full CSR neighbour list, radius ≥ r_c · max(rest).
    reference_position : (n, 3) float64
        Positions at the last list build (for the skin test) [length].
    extras : tuple of three (m, 3) float64
        Anchor points, anchor normals, external forces (m = n when enabled in ``coef``).
    stats : (n, N_STATS) float64
        Per-particle output (written): energy share ½Σ_j E_ij + E^A_i, kinetic energy after and
        before, squared displacement since the list build, squared speed, status bits, force
        (3) [1/length] and torque (3). With ``integrate``, pinned particles skip their pair and
        anchor terms (they do not move): their energy share, force and torque are 0.

    Returns
    -------
    tuple
        (potential, kinetic after, kinetic before, max displacement², max speed², first
        particle with a non-finite input/force/output or −1, its status bits).

    Notes
    -----
    Per particle i (T-thesis eqs. 4.9–4.10, reduced units):

    .. math::

        v_i' = \frac{v_i + \Delta t\,(r_0^2 f_i - \beta_1\sum_j (v_i - v_j))/m_i}
                    {1 + \Delta t\,\beta_0/m_i},\quad
        \omega_i' = \frac{\omega_i + \Delta t\,(\tau_i - \beta_3\sum_j
                    (\omega_i - \omega_j))/I_i}{1 + \Delta t\,\beta_2/I_i}

    then the caps, x_i' = x_i + Δt v_i' and q_i' = exp(½ω_i'Δt) ⊗ q_i.
    """
    position, orientation, velocity, angular_velocity = state_in
    position_out, orientation_out, velocity_out, angular_velocity_out = state_out
    is_pinned, is_oriented = flags
    mass, inertia, rest = inertial
    variable_rest = rest.shape[0] > 0
    offsets, indices = neighbors
    anchor_point, anchor_normal, external = extras
    n = position.shape[0]
    cutoff2 = coef.cutoff2
    inv_s2 = coef.inv_spacing2
    spacing2 = coef.spacing * coef.spacing
    dt = coef.dt
    beta0 = coef.damping_linear
    beta1 = coef.damping_relative_linear
    beta2 = coef.damping_angular
    beta3 = coef.damping_relative_angular
    max_step = coef.max_displacement
    max_turn = coef.max_rotation
    has_anchors = coef.has_anchors != 0.0
    has_external = coef.has_external_force != 0.0
    # every particle's normal once per call (serial: a few flops per particle), so that the
    # pairs gather n_j instead of computing it from q_j in every row that lists j
    normal = np.empty((n, 3))
    for i in range(n):
        normal[i, 0], normal[i, 1], normal[i, 2] = quaternion_normal(
            orientation[i, 0], orientation[i, 1], orientation[i, 2], orientation[i, 3]
        )
    # rows in blocks: one set of scratch rows per block (no allocation per particle)
    nblocks = (n + _BLOCK - 1) // _BLOCK
    for b in prange(nblocks):
        lo = b * _BLOCK
        hi = min(n, lo + _BLOCK)
        cap = offsets[hi] - offsets[lo]
        pj = np.empty(cap, dtype=np.int64)
        pr = np.empty((10, cap))
        pt = np.empty((7, cap))
        po = np.empty(cap, dtype=np.bool_)
        start = np.empty(hi - lo + 1, dtype=np.int64)
        # pass 1: the list entries within the cutoff, branch-free (about 60 % of the list
        # are: a skip branch would mispredict); pj, pr[0:4] = j, (r, s_ij)
        count = 0
        for i in range(lo, hi):
            start[i - lo] = count
            x0 = position[i, 0]
            x1 = position[i, 1]
            x2 = position[i, 2]
            rest_i = rest[i] if variable_rest else 1.0
            # a pinned particle does not move: its pair and anchor terms are not needed when
            # stepping (its energy share counts as 0; force-only calls evaluate every particle)
            active = not (integrate and is_pinned[i])
            row_end = offsets[i + 1] if active else offsets[i]
            for k in range(offsets[i], row_end):
                j = indices[k]
                rx = position[j, 0] - x0
                ry = position[j, 1] - x1
                rz = position[j, 2] - x2
                scale = 0.5 * (rest_i + rest[j]) if variable_rest else 1.0
                pj[count] = j
                pr[0, count] = rx
                pr[1, count] = ry
                pr[2, count] = rz
                pr[3, count] = scale
                count += not (rx * rx + ry * ry + rz * rz >= cutoff2 * (scale * scale))
        start[hi - lo] = count
        # the normals of those pairs (pr[4:7] = n_j, pr[7:10] = n_i, po = both oriented; in a
        # pair that is not both oriented n_j is +z, unread), so that pass 2 reads the scratch
        # only
        for i in range(lo, hi):
            nix = normal[i, 0]
            niy = normal[i, 1]
            niz = normal[i, 2]
            oriented_i = is_oriented[i]
            for a in range(start[i - lo], start[i - lo + 1]):
                j = pj[a]
                oriented = oriented_i and is_oriented[j]
                pr[4, a] = normal[j, 0] if oriented else 0.0
                pr[5, a] = normal[j, 1] if oriented else 0.0
                pr[6, a] = normal[j, 2] if oriented else 1.0
                pr[7, a] = nix
                pr[8, a] = niy
                pr[9, a] = niz
                po[a] = oriented
        # pass 2: the pair terms (S&T92 eqs. 3-7) of the whole block into pt
        if mode == WEIGHT_POLY:
            _poly_pair_terms(pr, po, pt, count, coef, variable_rest)
        else:
            # the count read back from the int64 array: typed int64 from the start (the
            # running `count` is first typed as the literal 0, which would compile this
            # function twice)
            _other_pair_terms(pr, po, pt, start[hi - lo], coef, mode, variable_rest)
        for i in range(lo, hi):
            status = 0
            x0 = position[i, 0]
            x1 = position[i, 1]
            x2 = position[i, 2]
            qw = orientation[i, 0]
            qx = orientation[i, 1]
            qy = orientation[i, 2]
            qz = orientation[i, 3]
            v0 = velocity[i, 0]
            v1 = velocity[i, 1]
            v2 = velocity[i, 2]
            w0 = angular_velocity[i, 0]
            w1 = angular_velocity[i, 1]
            w2 = angular_velocity[i, 2]
            if not (
                math.isfinite(x0 + x1 + x2)
                and math.isfinite(qw + qx + qy + qz)
                and math.isfinite(v0 + v1 + v2)
                and math.isfinite(w0 + w1 + w2)
            ):
                status |= STATUS_BAD_INPUT
            nix = normal[i, 0]
            niy = normal[i, 1]
            niz = normal[i, 2]
            oriented_i = is_oriented[i]
            active = not (integrate and is_pinned[i])

            # ---- pair forces and torques (S&T92 eqs. 3-7) and relative velocity sums
            energy = 0.0
            fx = 0.0
            fy = 0.0
            fz = 0.0
            tx = 0.0
            ty = 0.0
            tz = 0.0
            sv0 = 0.0
            sv1 = 0.0
            sv2 = 0.0
            sw0 = 0.0
            sw1 = 0.0
            sw2 = 0.0
            # pass 3: the sums, in list order
            for a in range(start[i - lo], start[i - lo + 1]):
                j = pj[a]
                energy += 0.5 * pt[0, a]
                fx += pt[1, a]
                fy += pt[2, a]
                fz += pt[3, a]
                tx += pt[4, a]
                ty += pt[5, a]
                tz += pt[6, a]
                if beta1 != 0.0:
                    sv0 += v0 - velocity[j, 0]
                    sv1 += v1 - velocity[j, 1]
                    sv2 += v2 - velocity[j, 2]
                if beta3 != 0.0 and po[a]:
                    if nix * pr[4, a] + niy * pr[5, a] + niz * pr[6, a] >= 0.0:
                        sw0 += w0 - angular_velocity[j, 0]
                        sw1 += w1 - angular_velocity[j, 1]
                        sw2 += w2 - angular_velocity[j, 2]

            # ---- anchors (data pull) and external force
            if has_anchors and active:
                a = anchor_interaction(
                    x0,
                    x1,
                    x2,
                    anchor_point[i, 0],
                    anchor_point[i, 1],
                    anchor_point[i, 2],
                    anchor_normal[i, 0],
                    anchor_normal[i, 1],
                    anchor_normal[i, 2],
                    nix,
                    niy,
                    niz,
                    coef.anchor_stiffness,
                    coef.anchor_normal_stiffness if oriented_i else 0.0,
                    inv_s2,
                )
                energy += a[0]
                fx += a[1]
                fy += a[2]
                fz += a[3]
                tx += a[4]
                ty += a[5]
                tz += a[6]
            if has_external:
                fx += external[i, 0]
                fy += external[i, 1]
                fz += external[i, 2]
            if not oriented_i:
                tx = 0.0
                ty = 0.0
                tz = 0.0
            if not math.isfinite(energy + fx + fy + fz + tx + ty + tz):
                status |= STATUS_BAD_FORCE
            stats[i, S_POTENTIAL] = energy
            stats[i, S_FORCE] = fx
            stats[i, S_FORCE + 1] = fy
            stats[i, S_FORCE + 2] = fz
            stats[i, S_TORQUE] = tx
            stats[i, S_TORQUE + 1] = ty
            stats[i, S_TORQUE + 2] = tz

            # ---- damped semi-implicit Euler step (T-thesis eqs. 4.9-4.10)
            m = mass[i]
            inertia_i = inertia[i]
            kinetic_before = 0.5 * m * (v0 * v0 + v1 * v1 + v2 * v2) * inv_s2 + 0.5 * inertia_i * (
                w0 * w0 + w1 * w1 + w2 * w2
            )
            stats[i, S_KINETIC_BEFORE] = kinetic_before
            if not integrate:
                stats[i, S_KINETIC] = kinetic_before
                stats[i, S_DISPLACEMENT2] = 0.0
                stats[i, S_SPEED2] = v0 * v0 + v1 * v1 + v2 * v2
                stats[i, S_STATUS] = status
                continue
            if is_pinned[i]:
                v0 = 0.0
                v1 = 0.0
                v2 = 0.0
                w0 = 0.0
                w1 = 0.0
                w2 = 0.0
            else:
                damp = 1.0 / (1.0 + dt * beta0 / m)
                v0 = (v0 + dt * (spacing2 * fx - beta1 * sv0) / m) * damp
                v1 = (v1 + dt * (spacing2 * fy - beta1 * sv1) / m) * damp
                v2 = (v2 + dt * (spacing2 * fz - beta1 * sv2) / m) * damp
                step2 = dt * dt * (v0 * v0 + v1 * v1 + v2 * v2)
                if step2 > max_step * max_step:
                    scale = max_step / math.sqrt(step2)
                    v0 *= scale
                    v1 *= scale
                    v2 *= scale
                x0 += dt * v0
                x1 += dt * v1
                x2 += dt * v2
                if oriented_i:
                    damp = 1.0 / (1.0 + dt * beta2 / inertia_i)
                    w0 = (w0 + dt * (tx - beta3 * sw0) / inertia_i) * damp
                    w1 = (w1 + dt * (ty - beta3 * sw1) / inertia_i) * damp
                    w2 = (w2 + dt * (tz - beta3 * sw2) / inertia_i) * damp
                    turn2 = dt * dt * (w0 * w0 + w1 * w1 + w2 * w2)
                    if turn2 > max_turn * max_turn:
                        scale = max_turn / math.sqrt(turn2)
                        w0 *= scale
                        w1 *= scale
                        w2 *= scale
                    qw, qx, qy, qz = rotate_quaternion(qw, qx, qy, qz, dt * w0, dt * w1, dt * w2)
                else:
                    w0 = 0.0
                    w1 = 0.0
                    w2 = 0.0
            position_out[i, 0] = x0
            position_out[i, 1] = x1
            position_out[i, 2] = x2
            orientation_out[i, 0] = qw
            orientation_out[i, 1] = qx
            orientation_out[i, 2] = qy
            orientation_out[i, 3] = qz
            velocity_out[i, 0] = v0
            velocity_out[i, 1] = v1
            velocity_out[i, 2] = v2
            angular_velocity_out[i, 0] = w0
            angular_velocity_out[i, 1] = w1
            angular_velocity_out[i, 2] = w2
            speed2 = v0 * v0 + v1 * v1 + v2 * v2
            kinetic = 0.5 * m * speed2 * inv_s2 + 0.5 * inertia_i * (w0 * w0 + w1 * w1 + w2 * w2)
            if not math.isfinite(kinetic + x0 + x1 + x2 + qw + qx + qy + qz):
                status |= STATUS_BAD_OUTPUT
            d0 = x0 - reference_position[i, 0]
            d1 = x1 - reference_position[i, 1]
            d2 = x2 - reference_position[i, 2]
            stats[i, S_KINETIC] = kinetic
            stats[i, S_DISPLACEMENT2] = d0 * d0 + d1 * d1 + d2 * d2
            stats[i, S_SPEED2] = speed2
            stats[i, S_STATUS] = status
    return _reduce_stats(stats, n)
