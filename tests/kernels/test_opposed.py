"""Opposed sheets (n_i · n_j < 0): only the repulsive branch of the spacing potential acts.

Forces and torques of the switched pair are checked against finite differences of the
reference energy (with the switch frozen: FD steps never cross n_i · n_j = 0), and the switched
energy is checked to be repulsive, continuous at its range and zero beyond it.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from recon.forces import accumulate_forces, evaluate_pair
from recon.kernels.lennard_jones import lj_repulsive_range
from recon.state import ParticleState
from tests.kernels.term_checks import MODES, term_params
from tests.reference import (
    lj_energy,
    numerical_gradients,
    pair_gradient_errors,
    relative_error,
    system_energy,
    unit,
)


def _all_terms(weighting: str, spacing: float = 1.0, **extra):
    p = term_params("w_lj", weighting, spacing)
    return dataclasses.replace(
        p, w_lj=0.7, w_planarity=1.1, w_normality=0.9, w_circularity=0.6, **extra
    )


def _opposed_pairs(rng, n_pairs: int, spacing: float, cutoff: float, reach: float):
    """Random pairs with n_i · n_j < −0.05 at 0.55 r0 < d < ``reach``."""
    out = []
    while len(out) < n_pairs:
        x_i = rng.normal(size=3) * spacing
        d = rng.uniform(0.55 * spacing, reach)
        x_j = x_i + d * unit(rng.normal(size=3))
        n_i, n_j = unit(rng.normal(size=3)), unit(rng.normal(size=3))
        if n_i @ n_j < -0.05:
            out.append((x_i, x_j, n_i, n_j))
    return out


def test_repulsive_range_is_the_minimum_of_the_shifted_force_potential():
    sigma, rc = 0.983, 2.0
    d_m, phi_m = lj_repulsive_range(sigma, rc)
    assert sigma < d_m < rc
    d = np.linspace(0.6, 1.99, 2000)
    e = np.array([lj_energy(x, sigma, rc) for x in d])
    assert phi_m == pytest.approx(e.min(), abs=1e-6)
    assert d_m == pytest.approx(d[np.argmin(e)], abs=2e-3)


@pytest.mark.parametrize("weighting", list(MODES))
@pytest.mark.parametrize("spacing", [1.0, 0.013])
def test_switched_pair_forces_and_torques_are_minus_gradient(weighting, spacing):
    params = _all_terms(weighting, spacing)
    d_m, _ = lj_repulsive_range(params.lj_sigma, params.cutoff)
    pairs = _opposed_pairs(np.random.default_rng(5), 40, spacing, params.cutoff, 0.999 * d_m)
    worst = pair_gradient_errors(
        lambda a, b, c, d: evaluate_pair(a, b, c, d, params), params, params.lj_sigma, pairs
    )
    assert worst["energy"] < 1e-9, worst
    for name in ("force_i", "force_j", "torque_i", "torque_j"):
        assert worst[name] < 1e-5, (name, worst)


@pytest.mark.parametrize("weighting", list(MODES))
def test_opposed_pair_is_never_attractive_and_has_no_torque(weighting):
    params = _all_terms(weighting)
    d_m, _ = lj_repulsive_range(params.lj_sigma, params.cutoff)
    n_i = np.array([0.0, 0.0, 1.0])
    n_j = unit(np.array([0.3, 0.0, -1.0]))
    previous = None
    for d in np.linspace(0.6, 0.999 * params.cutoff, 60):
        x_j = d * unit(np.array([1.0, 0.4, 0.2]))
        res = evaluate_pair(np.zeros(3), x_j, n_i, n_j, params)
        assert res.energy >= 0.0
        assert res.force_i @ x_j <= 0.0  # pushes i away from j
        assert np.all(res.torque_i == 0.0) and np.all(res.torque_j == 0.0)
        if d >= d_m:
            assert res.energy == 0.0 and np.all(res.force_i == 0.0)
        if previous is not None:
            assert res.energy <= previous  # monotone: continuous down to 0 at d_m
        previous = res.energy
    # the same pair with agreeing normals attracts beyond d_m
    x_j = 1.5 * unit(np.array([1.0, 0.4, 0.2]))
    res = evaluate_pair(np.zeros(3), x_j, n_i, -n_j, dataclasses.replace(params, w_planarity=0))
    assert res.force_i @ x_j > 0.0


def test_switch_off_restores_the_full_pair_energy():
    params = _all_terms("poly", separate_opposed=False)
    n_i = np.array([0.0, 0.0, 1.0])
    n_j = unit(np.array([0.3, 0.0, -1.0]))
    x_j = np.array([1.2, 0.3, 0.1])
    res = evaluate_pair(np.zeros(3), x_j, n_i, n_j, params)
    switched = evaluate_pair(np.zeros(3), x_j, n_i, n_j, _all_terms("poly"))
    assert res.energy > 0.5  # normality |n_i - n_j|^2 ~ 4 dominates
    assert switched.energy == 0.0  # beyond d_m


@pytest.mark.parametrize("weighting", list(MODES))
def test_two_opposed_sheets_in_the_fused_loop_match_the_reference_gradient(weighting):
    """A folded pair of sheets (a thin part): system forces/torques = −∇E with the switch."""
    params = _all_terms(weighting)
    rng = np.random.default_rng(11)
    grid = np.array([[i, j, 0.0] for i in range(3) for j in range(3)], dtype=float)
    top = grid + rng.normal(scale=0.08, size=grid.shape)
    bottom = grid + np.array([0.4, 0.3, -0.9]) + rng.normal(scale=0.08, size=grid.shape)
    position = np.vstack([top, bottom])
    normal = np.vstack(
        [
            unit(np.array([0.0, 0.0, 1.0]) + rng.normal(scale=0.2, size=(9, 3))),
            unit(np.array([0.0, 0.0, -1.0]) + rng.normal(scale=0.2, size=(9, 3))),
        ]
    )
    state = ParticleState.from_points(position, normal)
    forces = accumulate_forces(state, params)

    def energy(pos, nrm):
        return system_energy(pos, nrm, params, params.lj_sigma)

    assert forces.energy == pytest.approx(energy(position, state.normal), rel=1e-12)
    f_num, t_num = numerical_gradients(energy, position, state.normal, h=1e-6)
    assert relative_error(forces.force, f_num) < 1e-5
    assert relative_error(forces.torque, t_num) < 1e-5
