"""The step kernel's pair terms in SIMD form (recon.kernels.pair_terms) against the reference."""

from __future__ import annotations

import dataclasses
import platform
import re

import numba
import numpy as np
import pytest
from numba import njit

from recon.config import ReconConfig
from recon.forces import pack_coefficients
from recon.kernels.options import JIT_OPTIONS
from recon.kernels.pair_loop import pair_interaction
from recon.kernels.pair_terms import isotropic_orientation_terms, polynomial_pair_terms
from recon.kernels.weights import WEIGHT_POLY
from recon.params import PhysicsParams
from tests.reference import unit

#: The kernels' options (fast-math flags, NumPy's error model), compiled here, not cached.
_OPTIONS = {**JIT_OPTIONS, "cache": False}


def test_isotropic_fast_path_equals_the_term_kernels():
    from recon.kernels.circularity import circularity_pair
    from recon.kernels.normality import normality_pair
    from recon.kernels.planarity import planarity_pair

    rng = np.random.default_rng(9)
    w_p, w_n, w_c, s2 = 1.1, 0.9, 0.6, 1 / 1.7**2
    for _ in range(50):
        r = rng.normal(size=3)
        ni, nj = unit(rng.normal(size=(2, 3)))
        psi, dpsi = rng.uniform(0, 1), rng.uniform(-1, 0)
        args = (*r, *ni, *nj, psi, dpsi, psi, dpsi, 0.0)
        expected = (
            w_p * np.array(planarity_pair(*args, s2))
            + w_n * np.array(normality_pair(*args))
            + w_c * np.array(circularity_pair(*args, s2))
        )
        fast = isotropic_orientation_terms(
            *r, *ni, *nj, ni @ r, nj @ r, psi, dpsi, w_p, w_n, w_c, s2
        )
        np.testing.assert_allclose(fast, expected, rtol=1e-12, atol=1e-14)


@njit(**_OPTIONS)
def _simd_loop(pr, po, coef, variable_rest, out):
    """The term loop as the step kernel runs it (contiguous rows, a constant ``variable_rest``)."""
    if variable_rest:
        for a in range(pr.shape[1]):
            t = polynomial_pair_terms(
                pr[0, a], pr[1, a], pr[2, a], pr[3, a], pr[4, a], pr[5, a], pr[6, a],
                pr[7, a], pr[8, a], po[a], coef, pr[9, a], True,
            )  # fmt: skip
            for k in range(7):
                out[k, a] = t[k]
    else:
        for a in range(pr.shape[1]):
            t = polynomial_pair_terms(
                pr[0, a], pr[1, a], pr[2, a], pr[3, a], pr[4, a], pr[5, a], pr[6, a],
                pr[7, a], pr[8, a], po[a], coef, pr[9, a], False,
            )  # fmt: skip
            for k in range(7):
                out[k, a] = t[k]


@njit(**_OPTIONS)
def _reference_loop(pr, po, coef, variable_rest, out):
    for a in range(pr.shape[1]):
        scale = pr[9, a] if variable_rest else 1.0
        t = pair_interaction(
            pr[0, a], pr[1, a], pr[2, a], pr[3, a], pr[4, a], pr[5, a], pr[6, a],
            pr[7, a], pr[8, a], po[a], coef, WEIGHT_POLY, scale,
        )  # fmt: skip
        for k in range(7):
            out[k, a] = t[k]


def _pairs(rng: np.random.Generator, n: int, cutoff: float) -> tuple[np.ndarray, np.ndarray]:
    """Rows r (3), n_i (3), n_j (3), s_ij of ``n`` pairs: every case of the reference's branches
    (beyond the cutoff, in the repulsive range, opposed normals, unoriented, coincident)."""
    pr = np.empty((10, n))
    d = rng.uniform(0.0, 1.3 * cutoff, n)
    pr[0:3] = (unit(rng.normal(size=(n, 3))) * d[:, None]).T
    if not numba.config.DISABLE_JIT:  # (in plain Python both raise ZeroDivisionError)
        pr[0:3, :5] = 0.0  # coincident particles: infinite spacing terms, as in the reference
    ni = unit(rng.normal(size=(n, 3)) + [0.0, 0.0, 1.5])
    nj = unit(rng.normal(size=(n, 3)) + [0.0, 0.0, 1.5])
    nj[::4] *= -1.0  # opposed sheets
    pr[3:6] = ni.T
    pr[6:9] = nj.T
    pr[9] = rng.uniform(0.6, 1.4, n)
    pr[9, ::3] = 1.0
    po = rng.uniform(size=n) < 0.8
    return pr, po


COEFFICIENT_VARIANTS = {
    "defaults": {},
    "no spacing term": {"w_lj": 0.0},
    "no orientation terms": {"w_planarity": 0.0, "w_normality": 0.0, "w_circularity": 0.0},
    "co-circularity on": {"w_circularity": 0.7},
    "opposed sheets not separated": {"separate_opposed": False},
}


@pytest.mark.parametrize("variant", sorted(COEFFICIENT_VARIANTS))
@pytest.mark.parametrize("variable_rest", [False, True])
def test_branch_free_terms_equal_the_reference_bit_for_bit(variant, variable_rest):
    base = PhysicsParams.from_config(ReconConfig(), 0.7)
    params = dataclasses.replace(base, **COEFFICIENT_VARIANTS[variant])
    coef = pack_coefficients(params)
    pr, po = _pairs(np.random.default_rng(3), 2003, params.cutoff)
    got = np.empty((7, pr.shape[1]))
    want = np.empty_like(got)
    _simd_loop(pr, po, coef, variable_rest, got)
    _reference_loop(pr, po, coef, variable_rest, want)
    np.testing.assert_array_equal(got.view(np.int64), want.view(np.int64))
    # every branch of the reference is exercised by these pairs
    within = np.sum(pr[0:3] ** 2, axis=0) < params.cutoff**2 * (pr[9] ** 2 if variable_rest else 1)
    assert (~within).any() and within[5:].any()
    assert (want[4:7, 5:] != 0.0).any() or variant == "no orientation terms"


def _host_has_avx2() -> bool:
    import llvmlite.binding as llvm

    try:
        features = llvm.get_host_cpu_features()
    except RuntimeError:
        return False
    return bool(features.get("avx2")) and not features.get("avx512f")


@pytest.mark.skipif(
    numba.config.DISABLE_JIT
    or platform.machine() not in ("x86_64", "AMD64")
    or not _host_has_avx2(),
    reason="checks the code LLVM emits for an AVX2 machine without AVX-512",
)
def test_the_term_loop_runs_in_simd_lanes_on_avx2():
    """The reason for the module: LLVM's cost model declined the branchy reference on AVX2.
    A branch added back to the term loop would make it scalar again (about 2.4x slower)."""
    coef = pack_coefficients(PhysicsParams.from_config(ReconConfig(), 1.0))
    pr, po = _pairs(np.random.default_rng(0), 64, coef.cutoff)
    out = np.empty((7, 64))
    _simd_loop(pr, po, coef, False, out)
    asm = next(iter(_simd_loop.inspect_asm().values()))
    packed = re.findall(r"vmulpd\s+[^\n]*ymm", asm)
    assert len(packed) >= 20, f"{len(packed)} packed multiplies on ymm registers"
