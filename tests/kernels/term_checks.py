"""Shared finite-difference checks for the per-term kernel tests (not a test module)."""

from __future__ import annotations

import dataclasses

import numpy as np

from recon.config import ReconConfig
from recon.forces import evaluate_pair
from recon.params import PhysicsParams
from tests.reference import pair_gradient_errors, random_pairs

TERMS = ("w_lj", "w_planarity", "w_normality", "w_circularity")
MODES = {"poly": 0, "gaussian": 1, "anisotropic": 2}
FD_TOLERANCE = 1e-5


def term_params(term: str, weighting: str, spacing: float = 1.0, **extra) -> PhysicsParams:
    """Default params at ``spacing`` with only ``term`` switched on (weight 1.3)."""
    base = PhysicsParams.from_config(ReconConfig(), spacing)
    weights = dict.fromkeys(TERMS, 0.0)
    weights[term] = 1.3
    return dataclasses.replace(base, weighting=MODES[weighting], anisotropy=2.5, **weights, **extra)


def check_term(term: str, weighting: str, spacing: float, seed: int = 0, n_pairs: int = 40):
    """Worst FD errors of the pair kernel with only ``term`` active."""
    params = term_params(term, weighting, spacing)
    pairs = random_pairs(np.random.default_rng(seed), n_pairs, spacing, params.cutoff)

    def evaluate(x_i, x_j, n_i, n_j):
        return evaluate_pair(x_i, x_j, n_i, n_j, params)

    return pair_gradient_errors(evaluate, params, params.lj_sigma, pairs)
