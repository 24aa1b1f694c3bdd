"""Normality term: force and torque = −∇ of the energy, energy = NumPy reference."""

from __future__ import annotations

import zlib

import numpy as np
import pytest

from recon.forces import evaluate_pair
from tests.kernels.term_checks import FD_TOLERANCE, check_term, term_params


@pytest.mark.parametrize("weighting", ["poly", "gaussian", "anisotropic"])
@pytest.mark.parametrize("spacing", [1.0, 0.013])
def test_normality_matches_finite_differences(weighting, spacing):
    worst = check_term("w_normality", weighting, spacing, seed=zlib.crc32(b"normality") % 1000)
    assert worst["energy"] < 1e-12, worst
    for name in ("force_i", "force_j", "torque_i", "torque_j"):
        assert worst[name] < FD_TOLERANCE, (name, worst)


def test_normality_torque_turns_normals_together():
    # T-thesis eq. 4.15 has the opposite sign (DESIGN §2); the right torque aligns the normals
    params = term_params("w_normality", "poly")
    n_i = np.array([np.sin(0.3), 0.0, np.cos(0.3)])
    n_j = np.array([0.0, 0.0, 1.0])
    res = evaluate_pair(np.zeros(3), [1.0, 0.0, 0.0], n_i, n_j, params)
    # d n_i = tau_i x n_i must reduce the angle between n_i and n_j
    assert np.dot(np.cross(res.torque_i, n_i), n_j) > 0.0
    assert np.dot(np.cross(res.torque_j, n_j), n_i) > 0.0
    np.testing.assert_allclose(res.torque_i, -res.torque_j, atol=1e-15)
    np.testing.assert_allclose(res.torque_i, 2 * 1.3 * 0.75**2 * np.cross(n_i, n_j), rtol=1e-12)
