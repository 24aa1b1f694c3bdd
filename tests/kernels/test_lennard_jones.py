"""Soft 4-2 Lennard-Jones with shifted-force truncation and its lattice calibration."""

from __future__ import annotations

import numpy as np
import pytest

from recon.kernels.lennard_jones import (
    calibrate_lj_minimum,
    hex_lattice_pressure,
    lj_cutoff_values,
    lj_pair,
)
from tests.reference import lj_energy


def _lj(d, sigma, rc):
    phi_c, dphi_c = lj_cutoff_values(sigma, rc)
    return lj_pair(d * d, sigma * sigma, rc, phi_c, dphi_c)


@pytest.mark.parametrize("sigma, rc", [(1.0, 2.0), (1.3, 2.6), (0.7, 1.1)])
def test_energy_matches_reference_and_force_is_minus_gradient(sigma, rc):
    for d in np.linspace(0.6 * sigma, rc * 0.999, 25):
        e, dphi_over_d = _lj(d, sigma, rc)
        assert e == pytest.approx(lj_energy(d, sigma, rc), rel=1e-12, abs=1e-14)
        h = 1e-6 * sigma
        numeric = (lj_energy(d + h, sigma, rc) - lj_energy(d - h, sigma, rc)) / (2 * h)
        assert dphi_over_d * d == pytest.approx(numeric, rel=1e-6, abs=1e-9)


def test_energy_and_force_vanish_at_cutoff():
    e, f = _lj(2.0 * (1 - 1e-12), 1.0, 2.0)
    assert abs(e) < 1e-10 and abs(f) < 1e-10


def test_untruncated_minimum_is_sigma():
    # with a very large cutoff the shift is negligible and phi'(sigma) = 0
    e, dphi_over_d = _lj(1.0, 1.0, 1e6)
    assert abs(dphi_over_d) < 1e-5
    assert e == pytest.approx(-1.0, abs=1e-5)


@pytest.mark.parametrize("ratio", [1.2, 1.6, 2.0, 2.5, 5.0])
def test_calibration_makes_the_hexagonal_lattice_stress_free(ratio):
    spacing = 0.37
    sigma = calibrate_lj_minimum(spacing, ratio * spacing)
    assert abs(hex_lattice_pressure(sigma, spacing, ratio * spacing)) < 1e-9
    # scale invariance of the calibration
    assert sigma / spacing == pytest.approx(calibrate_lj_minimum(1.0, ratio), rel=1e-12)


def test_calibration_for_default_cutoff_is_close_to_spacing():
    # the shifted force subtracts phi'(r_c) > 0 from every slope (more repulsive), so sigma is
    # slightly below r0; with the second shell at sqrt(3) r0 inside the cutoff it is ~0.98 r0
    sigma = calibrate_lj_minimum(1.0, 2.0)
    assert 0.97 < sigma < 1.0


def test_calibration_rejects_cutoff_below_spacing():
    with pytest.raises(ValueError, match="spacing < cutoff"):
        calibrate_lj_minimum(1.0, 0.9)
