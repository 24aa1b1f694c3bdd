"""The growing rule's kernel (recon.kernels.growth_rules)."""

import numba
import numpy as np
import pytest

from recon.kernels.growth_rules import MAX_PER_PARTICLE, grow_kernel
from recon.neighbors import build_neighbor_list


def _grow(pos, nrm, radius=1.5, min_nb=0, max_nb=6, gap_deg=60.0, step_deg=60.0):
    off, idx = build_neighbor_list(pos, radius)
    out = np.zeros((len(pos), MAX_PER_PARTICLE, 3))
    count = np.zeros(len(pos), dtype=np.int64)
    grow_kernel(
        pos, nrm, off, idx, min_nb, max_nb, np.deg2rad(gap_deg), np.deg2rad(step_deg), out, count
    )
    return out, count


def test_an_isolated_particle_grows_a_hexagon_in_its_tangent_plane():
    n = np.array([[0.0, 0.6, 0.8]])
    out, count = _grow(np.array([[1.0, 2.0, 3.0]]), n)
    assert count.tolist() == [MAX_PER_PARTICLE]
    d = out[0] - [1.0, 2.0, 3.0]
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(d @ n[0], 0.0, atol=1e-12)
    # neighbours of the hexagon are one unit apart
    np.testing.assert_allclose(np.linalg.norm(d - np.roll(d, 1, axis=0), axis=1), 1.0, atol=1e-12)


def test_a_particle_with_one_neighbour_grows_into_the_open_side_only():
    pos = np.array([[0.0, 0, 0], [1.0, 0, 0]])
    nrm = np.tile([0.0, 0.0, 1.0], (2, 1))
    out, count = _grow(pos, nrm)
    assert count.tolist() == [5, 5]  # a 360 deg gap of six 60 deg steps: five candidates
    d = out[0, :5]
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
    assert np.all(np.linalg.norm(d - pos[1], axis=1) > 0.99)  # none onto the neighbour


@pytest.mark.skipif(numba.config.DISABLE_JIT, reason="thread counts need the JIT")
def test_candidates_are_the_same_for_any_thread_count():
    rng = np.random.default_rng(8)
    pos = rng.uniform(0, 20, (6000, 3))
    pos[:, 2] *= 0.05
    nrm = rng.normal(scale=0.1, size=(6000, 3)) + [0.0, 0.0, 1.0]
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    before = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        one = _grow(pos, nrm)
        numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
        many = _grow(pos, nrm)
    finally:
        numba.set_num_threads(before)
    assert np.array_equal(one[0], many[0]) and np.array_equal(one[1], many[1])
