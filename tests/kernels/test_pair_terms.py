"""The step kernel's pair terms in SIMD form (recon.kernels.pair_terms) against the reference."""

from __future__ import annotations

import dataclasses
import os
import platform
import re

import numba
import numpy as np
import pytest
from numba import njit

from recon.config import ReconConfig
from recon.forces import pack_coefficients
from recon.kernels.options import JIT_OPTIONS
from recon.kernels.pair_loop import _other_pair_terms, _poly_pair_terms, pair_interaction
from recon.kernels.pair_terms import isotropic_orientation_terms
from recon.kernels.weights import WEIGHT_ANISOTROPIC, WEIGHT_GAUSSIAN, WEIGHT_POLY
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
def _pass_two_uniform(pr, po, pt, count, coef):
    """The step kernel's pass 2 as ``step_particles`` inlines it (scratch rows r (3), s_ij,
    n_j (3), n_i (3); constant flags), for uniform spacing ..."""
    _poly_pair_terms(pr, po, pt, count, coef, False)


@njit(**_OPTIONS)
def _pass_two_variable(pr, po, pt, count, coef):
    """... and for per-particle rest spacings."""
    _poly_pair_terms(pr, po, pt, count, coef, True)


@njit(**_OPTIONS)
def _pass_two_either(pr, po, pt, count, coef, variable_rest):
    """... and as ``step_particles`` calls it: the flag a run-time value."""
    _poly_pair_terms(pr, po, pt, count, coef, variable_rest)


@njit(**_OPTIONS)
def _reference_any(pr, po, coef, mode, variable_rest, out):
    for a in range(pr.shape[1]):
        scale = pr[9, a] if variable_rest else 1.0
        t = pair_interaction(
            pr[0, a], pr[1, a], pr[2, a], pr[3, a], pr[4, a], pr[5, a], pr[6, a],
            pr[7, a], pr[8, a], po[a], coef, mode, scale,
        )  # fmt: skip
        for k in range(7):
            out[k, a] = t[k]


def _reference_loop(pr, po, coef, variable_rest, out):
    _reference_any(pr, po, coef, WEIGHT_POLY, variable_rest, out)


#: Rows of :func:`_pairs` with a special case: coincident particles (with the JIT only), NaN
#: separations, axis-aligned pairs (zero torque components of either sign); the rest random.
COINCIDENT, NAN_ROWS, AXIS_ROWS, RANDOM_FROM = slice(0, 5), slice(5, 8), slice(8, 24), 24


def _pairs(rng: np.random.Generator, n: int, cutoff: float) -> tuple[np.ndarray, np.ndarray]:
    """Rows r (3), n_i (3), n_j (3), s_ij of ``n`` pairs: every case of the reference's branches
    (beyond the cutoff, in the repulsive range, opposed normals, unoriented, coincident, NaN)."""
    pr = np.empty((10, n))
    d = rng.uniform(0.0, 1.3 * cutoff, n)
    pr[0:3] = (unit(rng.normal(size=(n, 3))) * d[:, None]).T
    ni = unit(rng.normal(size=(n, 3)) + [0.0, 0.0, 1.5])
    nj = unit(rng.normal(size=(n, 3)) + [0.0, 0.0, 1.5])
    nj[::4] *= -1.0  # opposed sheets
    po = rng.uniform(size=n) < 0.8
    if not numba.config.DISABLE_JIT:  # (in plain Python both raise ZeroDivisionError)
        pr[0:3, COINCIDENT] = 0.0  # infinite spacing terms, as in the reference
    pr[0, NAN_ROWS] = np.nan  # a NaN separation: NaN terms, as in the reference
    ni[NAN_ROWS] = nj[NAN_ROWS] = [0.0, 0.0, 1.0]
    nj[NAN_ROWS.start] = [0.0, 0.0, -1.0]  # and opposed: the repulsive branch's NaN
    po[NAN_ROWS] = True
    k = np.arange(AXIS_ROWS.stop - AXIS_ROWS.start)
    pr[0:3, AXIS_ROWS] = 0.0
    pr[k % 3, AXIS_ROWS.start + k] = np.where(k % 2, 0.9, -0.9) * cutoff
    ni[AXIS_ROWS] = [0.0, 0.0, 1.0]
    nj[AXIS_ROWS] = [0.0, 0.0, 1.0]
    nj[AXIS_ROWS.start + 1 :: 4][: len(k) // 4] = [0.0, 0.0, -1.0]
    po[AXIS_ROWS] = True
    pr[3:6] = ni.T
    pr[6:9] = nj.T
    pr[9] = rng.uniform(0.6, 1.4, n)
    pr[9, ::3] = 1.0
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
    pass_two = _pass_two_variable if variable_rest else _pass_two_uniform
    scratch = np.ascontiguousarray(pr[[0, 1, 2, 9, 6, 7, 8, 3, 4, 5]])  # the kernel's rows
    pass_two(scratch, po, got, pr.shape[1], coef)
    _reference_loop(pr, po, coef, variable_rest, want)
    np.testing.assert_array_equal(got.view(np.int64), want.view(np.int64))
    either = np.empty_like(got)  # the flag as a run-time value, as the step kernel passes it
    _pass_two_either(scratch, po, either, pr.shape[1], coef, variable_rest)
    np.testing.assert_array_equal(either.view(np.int64), want.view(np.int64))
    # every branch of the reference is exercised by these pairs
    scale2 = pr[9] ** 2 if variable_rest else np.ones(pr.shape[1])
    d2 = np.sum(pr[0:3] ** 2, axis=0)
    within = d2 < coef.cutoff2 * scale2
    repulsive = d2 < coef.lj_repulsive2 * scale2
    opposed = po & (np.einsum("ij,ij->j", pr[3:6], pr[6:9]) < 0.0)
    rest = slice(RANDOM_FROM, None)
    assert (~within[rest]).any() and (~po[rest] & within[rest]).any()
    assert (opposed & within & repulsive)[rest].any()
    assert (opposed & within & ~repulsive)[rest].any()
    nan_rows = want[0:4, NAN_ROWS]  # energy and force NaN (opposed: unless w_lj = 0, then 0)
    assert np.isnan(nan_rows[:, 1:]).all()
    assert np.isnan(nan_rows[:, 0]).all() or variant == "no spacing term"
    assert (want[4:7, rest] != 0.0).any() or variant == "no orientation terms"


@pytest.mark.parametrize("mode", [WEIGHT_GAUSSIAN, WEIGHT_ANISOTROPIC])
@pytest.mark.parametrize("variable_rest", [False, True])
def test_the_other_weights_pass_two_is_the_reference_per_pair(mode, variable_rest):
    """The step kernel's pass 2 for the Gaussian and anisotropic weights (a function of its
    own, called once per block) gives each pair's :func:`pair_interaction`, bit for bit."""
    params = dataclasses.replace(PhysicsParams.from_config(ReconConfig(), 0.7), anisotropy=2.5)
    coef = pack_coefficients(params)
    pr, po = _pairs(np.random.default_rng(5), 503, params.cutoff)
    got = np.empty((7, pr.shape[1]))
    want = np.empty_like(got)
    scratch = np.ascontiguousarray(pr[[0, 1, 2, 9, 6, 7, 8, 3, 4, 5]])  # the kernel's rows
    _other_pair_terms(scratch, po, got, pr.shape[1], coef, mode, variable_rest)
    _reference_any(pr, po, coef, mode, variable_rest, want)
    np.testing.assert_array_equal(got.view(np.int64), want.view(np.int64))
    assert np.count_nonzero(want[4:7, RANDOM_FROM:]) > 100  # torques: the pairs interact


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
    or not _host_has_avx2()
    or bool(os.environ.get("NUMBA_CPU_NAME") or os.environ.get("NUMBA_CPU_FEATURES")),
    reason="checks the code LLVM emits for this AVX2 host (no AVX-512, no other target set)",
)
@pytest.mark.parametrize("pass_two", [_pass_two_uniform, _pass_two_variable, _pass_two_either])
def test_the_step_kernels_term_loop_runs_in_simd_lanes_on_avx2(pass_two):
    """The reason for the module: LLVM's cost model declined the branchy reference on AVX2
    (znver3). A branch added back to the step kernel's pass 2 (:func:`_poly_pair_terms`, inlined
    into ``step_particles`` as here) would make it scalar again (about 2.4x slower)."""
    coef = pack_coefficients(PhysicsParams.from_config(ReconConfig(), 1.0))
    pr = np.zeros((10, 64))
    pr[3] = pr[6] = pr[9] = 1.0
    flag = (False,) if pass_two is _pass_two_either else ()  # an argument: a run-time value
    pass_two(pr, np.ones(64, dtype=np.bool_), np.empty((7, 64)), 64, coef, *flag)
    asm = next(iter(pass_two.inspect_asm().values()))
    packed = re.findall(r"vmulpd\s+[^\n]*ymm", asm)
    assert len(packed) >= 20, f"{len(packed)} packed multiplies on ymm registers"
