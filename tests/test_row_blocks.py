"""Per-point numpy work in row blocks over the fit's threads (:mod:`recon.row_blocks`): the
same result, bit for bit, whatever the threads and blocks."""

from __future__ import annotations

import threading

import numba
import numpy as np
import pytest
from scipy.spatial import cKDTree

from recon.creases import _pca
from recon.kernels.options import thread_count
from recon.row_blocks import MIN_ROWS, for_row_blocks, row_blocks

needs_two = pytest.mark.skipif(
    int(numba.config.NUMBA_NUM_THREADS) < 2, reason="numba has fewer than 2 threads here"
)


@pytest.mark.parametrize(("n", "block", "parts"), [(0, 5, 2), (1, 5, 2), (10, 3, 1), (10, 100, 3)])
def test_row_blocks_cover_the_rows_in_order(n, block, parts):
    blocks = row_blocks(n, block, parts)
    assert np.array_equal(np.concatenate([np.arange(n)[b] for b in blocks] or [[]]), np.arange(n))
    assert all(b.stop - b.start <= block for b in blocks)
    assert len(blocks) >= min(parts, n)


@needs_two
def test_blocks_run_in_the_fits_threads_only():
    n = 3 * MIN_ROWS
    for threads, many in ((1, False), (2, True)):
        seen: set[str] = set()
        out = np.zeros(n)

        def fn(b: slice, seen=seen, out=out) -> None:
            seen.add(threading.current_thread().name)
            out[b] = np.arange(n)[b] * 2.0

        with thread_count(threads):
            for_row_blocks(fn, n, n)
        assert np.array_equal(out, np.arange(n) * 2.0)
        if many:  # a pool of two (which of its threads takes a block is up to the pool)
            assert all(name.startswith("oprecon-rows") for name in seen), seen
        else:
            assert seen == {threading.current_thread().name}


def test_an_error_in_a_block_propagates():
    def fn(b: slice) -> None:
        raise ValueError("bad block")

    with thread_count(2), pytest.raises(ValueError, match="bad block"):
        for_row_blocks(fn, 3 * MIN_ROWS, 10**6)


def _flat_cloud(seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """9,000 points of a thin slab, their 24 nearest (distances, int32 indices)."""
    pts = np.random.default_rng(seed).normal(size=(9000, 3)) * [1.0, 1.0, 0.05]
    dist, idx = cKDTree(pts).query(pts, 24)
    return pts, dist, idx.astype(np.int32)


def _count_block_calls(monkeypatch, module) -> list[int]:
    """The row counts of every ``for_row_blocks`` call made by ``module``."""
    calls: list[int] = []
    real = module.for_row_blocks
    monkeypatch.setattr(
        module, "for_row_blocks", lambda fn, n, b: calls.append(n) or real(fn, n, b)
    )
    return calls


@needs_two
def test_crease_pca_is_bit_identical_with_one_and_two_threads_and_any_block(monkeypatch):
    import recon.creases

    pts, _, idx = _flat_cloud(5)
    tree = cKDTree(pts)
    calls = _count_block_calls(monkeypatch, recon.creases)
    results = []
    for threads, block in ((1, 65536), (2, 65536), (2, 1000), (1, 777)):
        monkeypatch.setattr(recon.creases, "BLOCK", block)
        with thread_count(threads):
            results.append(_pca(pts, tree, 20, idx))
    assert calls == [len(pts)] * 4  # the shared neighbours' rows go through the blocks
    for normals, variation in results[1:]:
        assert np.array_equal(normals, results[0][0])
        assert np.array_equal(variation, results[0][1])
    # and the k-d tree path (no shared neighbours) gives the same rows
    with thread_count(2):
        normals, variation = _pca(pts, tree, 20, None)
    assert np.array_equal(variation, results[0][1])


@needs_two
@pytest.mark.parametrize("radius", [None, 0.3])
def test_normal_estimate_is_bit_identical_with_one_and_two_threads_and_any_block(
    radius, monkeypatch
):
    import recon.normals
    from recon.normals import estimate_normals

    pts, dist, idx = _flat_cloud(6)
    shared = (dist, idx)
    calls = _count_block_calls(monkeypatch, recon.normals)
    results = []
    for threads, chunk in ((1, 16384), (2, 16384), (2, 1000), (1, 777)):
        monkeypatch.setattr(recon.normals, "_CHUNK", chunk)
        with thread_count(threads):
            results.append(estimate_normals(pts, k=20, radius=radius, neighbors=shared))
    assert calls == [len(pts)] * 4
    with thread_count(2):  # the k-d tree path
        results.append(estimate_normals(pts, k=20, radius=radius))
    for normals in results[1:]:
        assert np.array_equal(normals, results[0])
