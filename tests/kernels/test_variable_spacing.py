"""Adaptive spacing: per-particle rest spacings r_i, pair rest distance (r_i + r_j)/2.

With the spacings frozen during a step, the pair energy is E_ij(r; s) = E_ij(r / s; 1) with
s = (r_i + r_j)/2 (every length of the pair terms scales with s). Forces and torques are checked
against finite differences of that energy, pair by pair and for a whole system with uneven
spacings (which also checks that the neighbour list covers the largest cutoff).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from recon.forces import accumulate_forces, evaluate_pair
from recon.state import ParticleState
from tests.kernels.term_checks import MODES, term_params
from tests.reference import (
    numerical_gradients,
    pair_energy,
    relative_error,
    rotate,
    system_energy,
    unit,
)


def _params(weighting: str):
    p = term_params("w_lj", weighting, 1.0)
    return dataclasses.replace(p, w_lj=0.7, w_planarity=1.1, w_normality=0.9, w_circularity=0.6)


@pytest.mark.parametrize("weighting", list(MODES))
@pytest.mark.parametrize("scale", [0.6, 1.0, 1.7])
def test_scaled_pair_is_minus_gradient_of_the_scaled_energy(weighting, scale):
    params = _params(weighting)
    rng = np.random.default_rng(4)
    h = 1e-6 * scale

    def energy(x_i, x_j, n_i, n_j):
        return pair_energy(x_i / scale, x_j / scale, n_i, n_j, params, params.lj_sigma)

    for _ in range(30):
        x_i = rng.normal(size=3) * scale
        x_j = x_i + rng.uniform(0.55, 0.98 * params.cutoff) * scale * unit(rng.normal(size=3))
        n_i, n_j = unit(rng.normal(size=3)), unit(rng.normal(size=3))
        if abs(n_i @ n_j) < 0.05:  # FD rotations must not cross the opposed-sheet switch
            continue
        res = evaluate_pair(x_i, x_j, n_i, n_j, params, scale=scale)
        assert res.energy == pytest.approx(energy(x_i, x_j, n_i, n_j), rel=1e-9, abs=1e-12)
        f_num = np.zeros(3)
        t_num = np.zeros(3)
        for k in range(3):
            e = np.eye(3)[k] * h
            f_num[k] = -(energy(x_i + e, x_j, n_i, n_j) - energy(x_i - e, x_j, n_i, n_j)) / (2 * h)
            t_num[k] = (
                -(
                    energy(x_i, x_j, rotate(n_i, np.eye(3)[k], 1e-6), n_j)
                    - energy(x_i, x_j, rotate(n_i, np.eye(3)[k], -1e-6), n_j)
                )
                / 2e-6
            )
        ref = max(np.max(np.abs(f_num)) * scale, np.max(np.abs(t_num)), 1e-9)
        assert np.max(np.abs(res.force_i - f_num)) * scale / ref < 1e-5
        assert np.max(np.abs(res.torque_i - t_num)) / ref < 1e-5
        np.testing.assert_array_equal(res.force_j, -res.force_i)


def test_pair_scaling_moves_the_cutoff_and_the_rest_distance():
    params = _params("poly")
    n = np.array([0.0, 0.0, 1.0])
    x_j = np.array([1.5 * params.cutoff / 2.0 * 1.9, 0.0, 0.0])  # beyond r_c, within 1.5 r_c
    assert evaluate_pair(np.zeros(3), x_j, n, n, params).energy == 0.0
    assert evaluate_pair(np.zeros(3), x_j, n, n, params, scale=1.5).energy != 0.0
    # a pair at rest distance s·d has s-independent energy (pure scaling)
    d = np.array([1.1, 0.2, 0.05])
    e1 = evaluate_pair(np.zeros(3), d, n, n, params).energy
    e2 = evaluate_pair(np.zeros(3), 1.7 * d, n, n, params, scale=1.7).energy
    assert e2 == pytest.approx(e1, rel=1e-12)


@pytest.mark.parametrize("weighting", list(MODES))
def test_system_with_uneven_spacings_matches_the_reference_gradient(weighting):
    params = _params(weighting)
    rng = np.random.default_rng(8)
    grid = np.array([[i, j, 0.0] for i in range(4) for j in range(3)], dtype=float)
    rest = np.where(grid[:, 0] < 2, 0.7, 1.3) + rng.uniform(-0.05, 0.05, len(grid))
    position = grid * rest[:, None] + rng.normal(scale=0.1, size=grid.shape)
    normal = unit(np.array([0.0, 0.0, 1.0]) + rng.normal(scale=0.3, size=grid.shape))
    state = ParticleState.from_points(position, normal)
    state.rest = rest
    forces = accumulate_forces(state, params)

    def energy(pos, nrm):
        return system_energy(pos, nrm, params, params.lj_sigma, rest=rest)

    assert forces.energy == pytest.approx(energy(position, state.normal), rel=1e-12)
    f_num, t_num = numerical_gradients(energy, position, state.normal, h=1e-6)
    assert relative_error(forces.force, f_num) < 1e-5
    assert relative_error(forces.torque, t_num) < 1e-5
    # Newton's third law with r_ij = (r_i + r_j)/2: the net force vanishes
    assert np.max(np.abs(forces.force.sum(axis=0))) < 1e-10 * np.max(np.abs(forces.force))


def test_rest_spacings_must_be_positive():
    state = ParticleState.from_points(np.zeros((2, 3)) + [[0, 0, 0], [1, 0, 0]], None)
    with pytest.raises(ValueError, match="rest"):
        state.rest = [1.0, 0.0]
    state.rest = [0.5, 2.0]
    assert state.copy().rest.tolist() == [0.5, 2.0]
