"""recon.kernels.pca: neighbourhood scatter matrices, bit for bit those of the numpy code they
replaced (a gather, a mean over the neighbours, an einsum), in the point's frame and not, for
int32 views of a wider neighbour table and int64 tables, and far from the origin."""

from __future__ import annotations

import numpy as np
import pytest

from recon.kernels.pca import scatter_matrices


def numpy_scatter(points: np.ndarray, idx: np.ndarray, centre: np.ndarray, local: bool):
    """The numpy version (recon.normals._pca_normals and recon.creases._pca before the
    kernel)."""
    nb = points[idx]
    if local:
        nb -= centre[:, None, :]
    nb = nb - nb.mean(axis=1, keepdims=True)
    return np.einsum("nki,nkj->nij", nb, nb)


def _cloud(seed: int, n: int = 300, offset: float = 0.0):
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-1.0, 1.0, (n, 2))
    z = 0.3 * xy[:, 0] ** 2 + rng.normal(0.0, 0.01, n)
    return np.column_stack([xy, z]) + offset


@pytest.mark.parametrize("local", [True, False])
@pytest.mark.parametrize("offset", [0.0, 1e4])
@pytest.mark.parametrize("k", [3, 9, 20])
def test_scatter_is_the_numpy_scatter_bit_for_bit(k, offset, local):
    pts = _cloud(k, offset=offset)
    rng = np.random.default_rng(1)
    wide = rng.integers(0, len(pts), (len(pts), 24)).astype(np.int32)
    idx = wide[:, :k]  # a non-contiguous int32 view, as the fit's shared neighbour table
    want = numpy_scatter(pts, idx, pts, local)
    got = np.full((len(pts), 3, 3), np.nan)
    scatter_matrices(pts, idx, pts, local, got)
    np.testing.assert_array_equal(got, want)
    # int64 indices and a centre other than the points themselves
    idx64 = np.ascontiguousarray(idx, dtype=np.int64)[:50]
    centre = pts[::-1][:50].copy()
    got = np.empty((50, 3, 3))
    scatter_matrices(pts, idx64, centre, local, got)
    np.testing.assert_array_equal(got, numpy_scatter(pts, idx64, centre, local))


def test_scatter_of_a_plane_has_a_zero_normal_moment():
    g = np.stack(np.meshgrid(np.arange(4.0), np.arange(4.0), [2.0]), -1).reshape(-1, 3)
    idx = np.tile(np.arange(len(g)), (2, 1))
    out = np.empty((2, 3, 3))
    scatter_matrices(g, idx, g[:2], True, out)
    np.testing.assert_array_equal(out[:, 2, :], 0.0)
    np.testing.assert_array_equal(out[:, :, 2], 0.0)
    assert out[0, 0, 0] == 20.0  # 4 rows of x in 0..3 about 1.5: 4 * 5
