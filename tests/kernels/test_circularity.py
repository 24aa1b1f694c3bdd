"""Circularity term: force and torque = −∇ of the energy, energy = NumPy reference."""

from __future__ import annotations

import zlib

import numpy as np
import pytest

from recon.forces import evaluate_pair
from tests.kernels.term_checks import FD_TOLERANCE, check_term, term_params


@pytest.mark.parametrize("weighting", ["poly", "gaussian", "anisotropic"])
@pytest.mark.parametrize("spacing", [1.0, 0.013])
def test_circularity_matches_finite_differences(weighting, spacing):
    worst = check_term("w_circularity", weighting, spacing, seed=zlib.crc32(b"circularity") % 1000)
    assert worst["energy"] < 1e-12, worst
    for name in ("force_i", "force_j", "torque_i", "torque_j"):
        assert worst[name] < FD_TOLERANCE, (name, worst)


def test_circularity_vanishes_on_a_sphere():
    params = term_params("w_circularity", "poly")
    rng = np.random.default_rng(5)
    for _ in range(20):
        a, b = rng.normal(size=(2, 3))
        a, b = a / np.linalg.norm(a), b / np.linalg.norm(b)
        radius = 1.0 / np.linalg.norm(a - b) * rng.uniform(0.6, 1.8)
        res = evaluate_pair(radius * a, radius * b, a, b, params)
        assert abs(res.energy) < 1e-24
        assert np.max(np.abs(res.force_i)) < 1e-12 and np.max(np.abs(res.torque_i)) < 1e-12


def test_circularity_uses_the_sum_of_the_normals():
    # S&T92 Appendix A's f_C uses n_i where it needs n_i + n_j (DESIGN §2)
    params = term_params("w_circularity", "poly")
    n_i = np.array([0.0, 0.0, 1.0])
    n_j = np.array([0.0, 1.0, 0.0])
    r = np.array([0.6, 0.5, 0.5])
    res = evaluate_pair(np.zeros(3), r, n_i, n_j, params)
    m = n_i + n_j
    psi = (1 - r @ r / 4.0) ** 2
    dpsi_r = 2 * (1 - r @ r / 4.0) * (-2 / 4.0) * r  # grad of psi with respect to r
    expected = 1.3 * (2 * (m @ r) * psi * m + (m @ r) ** 2 * dpsi_r)
    np.testing.assert_allclose(res.force_i, expected, rtol=1e-12)
