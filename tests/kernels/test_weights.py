"""Weighting functions ψ: values, derivatives, compact support, anisotropy (S&T92 eq. 7)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from recon.kernels.weights import (
    WEIGHT_ANISOTROPIC,
    WEIGHT_GAUSSIAN,
    WEIGHT_POLY,
    pair_weights,
    weight_value,
)

RC = 2.0
SIGMA = 1.0


def _h(q, mode):
    return weight_value(q, mode, 1.0 / RC**2, 1.0 / (2.0 * SIGMA**2))


@pytest.mark.parametrize("mode", [WEIGHT_POLY, WEIGHT_GAUSSIAN, WEIGHT_ANISOTROPIC])
def test_derivative_matches_finite_difference(mode):
    for q in np.linspace(0.05, 3.95, 40):
        h = 1e-6
        numeric = (_h(q + h, mode)[0] - _h(q - h, mode)[0]) / (2 * h)
        assert abs(_h(q, mode)[1] - numeric) < 1e-8


@pytest.mark.parametrize("mode", [WEIGHT_POLY, WEIGHT_GAUSSIAN, WEIGHT_ANISOTROPIC])
def test_compact_and_continuous_at_cutoff(mode):
    assert _h(RC**2, mode) == (0.0, 0.0)
    assert _h(RC**2 * 1.5, mode) == (0.0, 0.0)
    value, slope = _h(RC**2 * (1 - 1e-9), mode)
    assert value < 1e-16 and abs(slope) < 1e-8


def test_hand_values():
    assert _h(0.0, WEIGHT_POLY)[0] == 1.0
    assert _h(1.0, WEIGHT_POLY)[0] == pytest.approx(0.75**2)
    assert _h(1.0, WEIGHT_GAUSSIAN)[0] == pytest.approx(math.exp(-0.5) * 0.75**2)


def test_anisotropic_weight_is_smaller_along_the_normal():
    kappa = 2.0**2 - 1.0
    inv_c2, inv_s2 = 1.0 / RC**2, 1.0 / (2.0 * SIGMA**2)
    # same distance, one neighbour in the tangent plane of i, one along n_i
    in_plane = pair_weights(1.0, 0.0, 0.0, WEIGHT_ANISOTROPIC, inv_c2, inv_s2, kappa)
    along = pair_weights(1.0, 1.0, 0.0, WEIGHT_ANISOTROPIC, inv_c2, inv_s2, kappa)
    assert along[0] < in_plane[0]
    assert along[2] == in_plane[2]  # psi_j only sees n_j . r = 0
    iso = pair_weights(1.0, 1.0, 0.0, WEIGHT_GAUSSIAN, inv_c2, inv_s2, kappa)
    assert iso[0] == iso[2] == in_plane[0]
