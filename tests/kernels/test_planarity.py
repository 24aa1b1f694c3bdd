"""Planarity term: force and torque = −∇ of the energy, energy = NumPy reference."""

from __future__ import annotations

import zlib

import numpy as np
import pytest

from recon.forces import evaluate_pair
from tests.kernels.term_checks import FD_TOLERANCE, check_term, term_params


@pytest.mark.parametrize("weighting", ["poly", "gaussian", "anisotropic"])
@pytest.mark.parametrize("spacing", [1.0, 0.013])
def test_planarity_matches_finite_differences(weighting, spacing):
    worst = check_term("w_planarity", weighting, spacing, seed=zlib.crc32(b"planarity") % 1000)
    assert worst["energy"] < 1e-12, worst
    for name in ("force_i", "force_j", "torque_i", "torque_j"):
        assert worst[name] < FD_TOLERANCE, (name, worst)


def test_planarity_hand_cases():
    params = term_params("w_planarity", "poly")
    up = np.array([0.0, 0.0, 1.0])
    # neighbour in the tangent plane: zero energy, force and torque
    res = evaluate_pair(np.zeros(3), [1.0, 0.0, 0.0], up, up, params)
    assert res.energy == 0.0
    assert np.all(res.force_i == 0.0) and np.all(res.torque_i == 0.0)
    # neighbour straight above: (n_i.r)^2 + (n_j.r)^2 = 2, psi(1) = 0.75^2; pushed back to the plane
    res = evaluate_pair(np.zeros(3), [0.0, 0.0, 1.0], up, up, params)
    assert res.energy == pytest.approx(1.3 * 2 * 0.75**2)
    assert res.force_j[2] < 0.0 < res.force_i[2]
    # tilted normal with the neighbour in the plane: the torque turns n_i back toward e_z
    tilted = np.array([np.sin(0.2), 0.0, np.cos(0.2)])
    res = evaluate_pair(np.zeros(3), [1.0, 0.0, 0.0], tilted, up, params)
    assert np.dot(np.cross(res.torque_i, tilted), up) > 0.0
