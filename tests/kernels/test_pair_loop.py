"""The per-particle loop: whole-system forces/torques against the NumPy reference energy."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from recon.forces import Anchors, accumulate_forces, evaluate_pair
from recon.state import ParticleState
from tests.kernels.term_checks import MODES, term_params
from tests.reference import numerical_gradients, relative_error, system_energy, unit


def _cluster(seed: int, n: int = 9, spacing: float = 1.0):
    rng = np.random.default_rng(seed)
    grid = np.array([[i, j, 0.0] for i in range(3) for j in range(3)])[:n] * 0.95
    position = (grid + rng.normal(scale=0.25, size=(n, 3))) * spacing
    normal = unit(np.array([0.0, 0.0, 1.0]) + rng.normal(scale=0.5, size=(n, 3)))
    return position, normal


def _params(weighting: str, spacing: float = 1.0, **weights):
    p = term_params("w_lj", weighting, spacing)
    w = {"w_lj": 0.7, "w_planarity": 1.1, "w_normality": 0.9, "w_circularity": 0.6}
    w.update(weights)
    return dataclasses.replace(p, **w)


@pytest.mark.parametrize("weighting", list(MODES))
@pytest.mark.parametrize("spacing", [1.0, 2.9])
def test_system_forces_are_minus_gradient_of_reference_energy(weighting, spacing):
    params = _params(weighting, spacing)
    position, normal = _cluster(1, spacing=spacing)
    oriented = np.ones(len(position), dtype=bool)
    oriented[4] = False
    rng = np.random.default_rng(2)
    anchor_points = position + rng.normal(scale=0.3 * spacing, size=position.shape)
    anchor_normals = unit(rng.normal(size=position.shape))
    anchors = Anchors.create(anchor_points, anchor_normals, len(position), 0.8, 0.3)

    def energy(pos, nrm):
        return system_energy(
            pos,
            nrm,
            params,
            params.lj_sigma,
            oriented,
            (anchors.points, anchors.normals, 0.8, 0.3),
        )

    state = ParticleState.from_points(position, normal)
    state.set_oriented(oriented)
    forces = accumulate_forces(state, params, anchors=anchors)
    assert forces.energy == pytest.approx(energy(position, state.normal), rel=1e-12)
    f_num, t_num = numerical_gradients(energy, position, state.normal, h=1e-6 * spacing)
    assert relative_error(forces.force, f_num) < 1e-5
    assert relative_error(forces.torque, t_num) < 1e-5
    assert np.all(forces.torque[4] == 0.0)


@pytest.mark.parametrize("weighting", list(MODES))
def test_energy_invariant_under_rigid_motion_and_net_force_torque_vanish(weighting):
    params = _params(weighting)
    position, normal = _cluster(3)
    state = ParticleState.from_points(position, normal)
    base = accumulate_forces(state, params)

    rot = Rotation.from_rotvec([0.4, -1.1, 0.7])
    shift = np.array([3.0, -2.0, 5.5])
    moved = ParticleState.from_points(rot.apply(position) + shift, rot.apply(state.normal))
    other = accumulate_forces(moved, params)
    assert other.energy == pytest.approx(base.energy, rel=1e-12)
    # forces and torques rotate with the system
    np.testing.assert_allclose(other.force, rot.apply(base.force), atol=1e-11)
    np.testing.assert_allclose(other.torque, rot.apply(base.torque), atol=1e-11)

    scale = np.max(np.abs(base.force))
    assert np.max(np.abs(base.force.sum(axis=0))) < 1e-12 * max(scale, 1.0)
    net_torque = base.torque.sum(axis=0) + np.cross(position, base.force).sum(axis=0)
    assert np.max(np.abs(net_torque)) < 1e-12 * max(scale, 1.0) * 10


def test_unoriented_particles_feel_only_spacing_forces():
    params = _params("poly")
    lj_only = dataclasses.replace(params, w_planarity=0.0, w_normality=0.0, w_circularity=0.0)
    position, normal = _cluster(4)
    state = ParticleState.from_points(position, normal)
    state.set_oriented(False)
    full = accumulate_forces(state, params)
    spacing_only = accumulate_forces(state, lj_only)
    np.testing.assert_array_equal(full.force, spacing_only.force)
    assert full.energy == spacing_only.energy
    assert np.all(full.torque == 0.0)
    # one unoriented particle among oriented ones: its force is the LJ force alone
    state.set_oriented(np.arange(len(position)) != 4)
    mixed = accumulate_forces(state, params)
    np.testing.assert_allclose(mixed.force[4], spacing_only.force[4], rtol=1e-14, atol=1e-15)
    assert np.all(mixed.torque[4] == 0.0)


@pytest.mark.parametrize("parallel", [False, True])
def test_rows_in_several_blocks_sum_their_own_pairs(parallel):
    """600 particles (three blocks of rows in the step kernel), unoriented ones and variable
    rest spacing: every particle's force, torque and energy share are the sums of
    :func:`evaluate_pair` over its pairs within the cutoff (a wrong row range or scratch
    offset in a later block would take another row's pairs)."""
    params = _params("poly")
    rng = np.random.default_rng(11)
    n = 600
    position = rng.uniform([0.0, 0.0, 0.0], [20.0, 20.0, 1.5], size=(n, 3))
    normal = unit(np.array([0.0, 0.0, 1.0]) + rng.normal(scale=0.3, size=(n, 3)))
    oriented = rng.random(n) > 0.2
    rest = rng.uniform(0.8, 1.2, n)
    state = ParticleState.from_points(position, normal)
    state.set_oriented(oriented)
    state.rest = rest
    got = accumulate_forces(state, params, parallel=parallel)
    force = np.zeros((n, 3))
    torque = np.zeros((n, 3))
    energy = np.zeros(n)
    nrm = state.normal
    for i, j in cKDTree(position).query_pairs(params.cutoff * rest.max()):
        s = 0.5 * (rest[i] + rest[j])
        if np.linalg.norm(position[j] - position[i]) >= params.cutoff * s:
            continue
        both = bool(oriented[i] and oriented[j])
        pair = evaluate_pair(
            position[i], position[j], nrm[i], nrm[j], params, oriented=both, scale=s
        )
        force[i] += pair.force_i
        force[j] += pair.force_j
        torque[i] += pair.torque_i if oriented[i] else 0.0
        torque[j] += pair.torque_j if oriented[j] else 0.0
        energy[[i, j]] += 0.5 * pair.energy
    scale = np.max(np.abs(force))
    np.testing.assert_allclose(got.force, force, rtol=0, atol=1e-10 * scale)
    np.testing.assert_allclose(
        got.torque, torque, rtol=0, atol=1e-10 * max(np.max(np.abs(torque)), 1.0)
    )
    np.testing.assert_allclose(
        got.energy_per_particle, energy, rtol=0, atol=1e-10 * np.max(np.abs(energy))
    )
    assert np.count_nonzero(np.any(force != 0.0, axis=1)) > 0.9 * n  # the pairs are there


def test_serial_and_parallel_kernels_agree_bitwise():
    params = _params("anisotropic")
    rng = np.random.default_rng(8)
    position = rng.uniform(0, 6, size=(300, 3))
    normal = unit(rng.normal(size=(300, 3)))
    state = ParticleState.from_points(position, normal)
    a = accumulate_forces(state, params, parallel=False)
    b = accumulate_forces(state, params, parallel=True)
    np.testing.assert_array_equal(a.force, b.force)
    np.testing.assert_array_equal(a.torque, b.torque)
    np.testing.assert_array_equal(a.energy_per_particle, b.energy_per_particle)
