"""recon.kernels.signs: the certified screen of consistent_normals. Whenever it says "all
agree", numpy's reflected dot products are all >= 0 (all_agree); it says so on a clean sphere,
and not where one normal is flipped, nor on an edge whose value is 0 (no margin)."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from recon.kernels.signs import surely_agree
from recon.particle_signs import all_agree, reflected_dots

MARGIN = 1e-9


def _sphere(n: int, seed: int):
    rng = np.random.default_rng(seed)
    p = rng.normal(size=(n, 3))
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    return p


def _numpy_agree(pos, nrm, idx):
    n, kk = idx.shape
    rows, cols = np.repeat(np.arange(n), kk - 1), idx[:, 1:].ravel()
    keep = rows != cols
    return all_agree(reflected_dots(pos, nrm, rows[keep], cols[keep]))


def test_clean_sphere_surely_agrees_and_a_flip_does_not():
    p = _sphere(500, 0)
    idx = cKDTree(p).query(p, 7)[1]
    nrm = p.copy()
    assert surely_agree(p, nrm, idx, MARGIN) and _numpy_agree(p, nrm, idx)
    nrm[17] *= -1.0
    assert not surely_agree(p, nrm, idx, MARGIN)
    assert not _numpy_agree(p, nrm, idx)


def test_screen_never_claims_what_numpy_denies():
    """Noisy normals (some edges near 0, some negative): a True is always numpy's True."""
    claimed = 0
    for seed in range(40):
        p = _sphere(200, seed)
        rng = np.random.default_rng(100 + seed)
        nrm = p + rng.normal(0.0, 0.01 * seed, p.shape)
        nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
        idx = cKDTree(p).query(p, 7)[1]
        sure = surely_agree(p, nrm, idx, MARGIN)
        assert not sure or _numpy_agree(p, nrm, idx)
        claimed += sure
    assert 0 < claimed < 40  # the screen answers on some of them, not all


def test_an_edge_at_zero_is_not_sure():
    """Perpendicular normals on one flat sheet read exactly 0: numpy's all_agree holds, but
    the screen has no margin there and leaves it to numpy."""
    p = np.array([[0.0, 0, 0], [1.0, 0, 0]])
    nrm = np.array([[0.0, 0, 1], [0.0, 1, 0]])
    idx = np.array([[0, 1], [1, 0]])
    assert _numpy_agree(p, nrm, idx)
    assert not surely_agree(p, nrm, idx, MARGIN)
    dup = np.array([[0.0, 0, 0], [0.0, 0, 0]])  # duplicate positions: u = 0, r = n_i . n_j
    same = np.array([[0.0, 0, 1], [0.0, 0, 1]])
    assert surely_agree(dup, same, idx, MARGIN)


def test_within_covers_every_edge_a_query_could_hold():
    """From a wider table: every point within the (k+1)-th distance counts, whichever of the
    tied ones a query picks. A grid (many exact ties) with one normal flipped just outside
    the k nearest but tied with the last of them is caught; rows whose ties may run past the
    table are not claimed."""
    from recon.kernels.signs import surely_agree_within

    g = np.stack(np.meshgrid(np.arange(9.0), np.arange(9.0), [0.0]), -1).reshape(-1, 3)
    nrm = np.tile([0.0, 0.0, 1.0], (len(g), 1))
    tree = cKDTree(g)
    dist, idx = tree.query(g, 13)
    assert surely_agree_within(g, nrm, dist, idx, 6, MARGIN)
    # the centre's 4 neighbours at 1 and 4 at sqrt(2): the 7th distance (sqrt 2) ties with
    # the 8th; a flipped diagonal neighbour is some query's 7-nearest, whatever the order
    centre = 4 * 9 + 4
    diagonal = np.flatnonzero(np.isclose(np.linalg.norm(g - g[centre], axis=1), np.sqrt(2)))
    flipped = nrm.copy()
    flipped[diagonal[-1]] *= -1.0
    assert not surely_agree_within(g, flipped, dist, idx, 6, MARGIN)
    # a table no wider than the ties: not claimed
    assert not surely_agree_within(g, nrm, dist[:, :8], idx[:, :8], 6, MARGIN)
