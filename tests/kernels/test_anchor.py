"""Anchor (data pull) term: energy, force and torque signs by finite differences."""

from __future__ import annotations

import numpy as np
import pytest

from recon.kernels.anchor import anchor_interaction
from tests.reference import anchor_energy, relative_error, rotate, unit


@pytest.mark.parametrize("spacing", [1.0, 3.7])
def test_anchor_matches_finite_differences(spacing):
    rng = np.random.default_rng(11)
    k_d, k_n = 0.8, 0.45
    worst = 0.0
    for _ in range(30):
        x, a = rng.normal(size=(2, 3)) * spacing
        m, n = unit(rng.normal(size=(2, 3)))
        e, fx, fy, fz, tx, ty, tz = anchor_interaction(*x, *a, *m, *n, k_d, k_n, 1 / spacing**2)
        assert e == pytest.approx(anchor_energy(x, n, a, m, k_d, k_n, spacing), rel=1e-13)
        h = 1e-6 * spacing
        f_num = np.zeros(3)
        t_num = np.zeros(3)
        for k in range(3):
            d = np.eye(3)[k] * h
            f_num[k] = -(
                anchor_energy(x + d, n, a, m, k_d, k_n, spacing)
                - anchor_energy(x - d, n, a, m, k_d, k_n, spacing)
            ) / (2 * h)
            ax = np.eye(3)[k]
            t_num[k] = (
                -(
                    anchor_energy(x, rotate(n, ax, 1e-6), a, m, k_d, k_n, spacing)
                    - anchor_energy(x, rotate(n, ax, -1e-6), a, m, k_d, k_n, spacing)
                )
                / 2e-6
            )
        worst = max(worst, relative_error([fx, fy, fz], f_num), relative_error([tx, ty, tz], t_num))
    assert worst < 1e-5


def test_anchor_torque_is_k_n_times_n_cross_m():
    n = np.array([0.0, 0.0, 1.0])
    m = unit([0.0, 0.3, 1.0])
    out = anchor_interaction(0, 0, 0, 0, 0, 0, *m, *n, 0.0, 2.0, 1.0)
    np.testing.assert_allclose(out[4:], 2.0 * np.cross(n, m), rtol=1e-14)
    # and it turns n toward m
    assert np.dot(np.cross(out[4:], n), m) > 0.0


def test_anchor_force_is_along_the_anchor_normal_only():
    m = np.array([0.0, 0.0, 1.0])
    out = anchor_interaction(0.3, -0.2, 0.5, 0, 0, 0, *m, *m, 2.0, 0.0, 1.0)
    np.testing.assert_allclose(out[1:4], [0.0, 0.0, -1.0], atol=1e-15)
    assert out[0] == pytest.approx(0.25)
