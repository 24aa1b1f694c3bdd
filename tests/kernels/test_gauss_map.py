"""recon.kernels.gauss_map: the axial Lloyd iterations and the per-cluster planes.

The Lloyd iterations stop at a fixed point; checked bit for bit against all ``_ITERATIONS``
rounds, run one per call. The cluster planes, fitted only where a pair of
clusters separates, are the PCA normals of the members signed like their centres.
"""

from __future__ import annotations

import numpy as np
import pytest

from recon.kernels import gauss_map
from recon.kernels.gauss_map import _clusters, _lloyd, _planes


def plain_lloyd(
    nb: np.ndarray, centres: np.ndarray, m: int, monkeypatch: pytest.MonkeyPatch
) -> tuple[np.ndarray, np.ndarray]:
    """Every one of the ``_ITERATIONS`` rounds: the kernel's Python source run one round per
    call (so no early stop), as many times."""
    centres = centres.copy()
    assign = np.zeros(len(nb), dtype=np.int64)
    rounds = gauss_map._ITERATIONS
    monkeypatch.setattr(gauss_map, "_ITERATIONS", 1)
    for _ in range(rounds):
        getattr(_lloyd, "py_func", _lloyd)(nb, centres, m, assign)  # plain without the JIT
    monkeypatch.undo()
    return centres, assign


def _normals(kind: str, rng: np.random.Generator, kk: int = 24) -> np.ndarray:
    """Unit normals of one neighbourhood: one face, two faces, three faces, a smooth arc."""
    if kind == "arc":
        t = rng.uniform(-0.6, 0.6, kk)
        n = np.stack([np.sin(t), np.zeros(kk), np.cos(t)], axis=1)
    else:
        faces = {"one": 1, "two": 2, "three": 3}[kind]
        axes = np.eye(3)[:faces]
        n = axes[rng.integers(0, faces, kk)] * rng.choice([-1.0, 1.0], (kk, 1))
    n = n + rng.normal(scale=0.05, size=n.shape)
    return n / np.linalg.norm(n, axis=1, keepdims=True)


@pytest.mark.parametrize("kind", ["one", "two", "three", "arc"])
@pytest.mark.parametrize("m", [2, 3])
def test_lloyd_stops_at_a_fixed_point_with_the_result_of_every_round(kind, m, monkeypatch):
    rng = np.random.default_rng(7)
    for _ in range(20):
        nb = _normals(kind, rng)
        start = nb[rng.choice(len(nb), 3, replace=False)].copy()
        want_centres, want_assign = plain_lloyd(nb, start, m, monkeypatch)
        centres = start.copy()
        assign = np.zeros(len(nb), dtype=np.int64)
        _lloyd(nb, centres, m, assign)
        np.testing.assert_array_equal(centres[:m], want_centres[:m])
        np.testing.assert_array_equal(assign, want_assign)


def test_cluster_planes_are_the_members_pca_normals_signed_like_the_centres():
    rng = np.random.default_rng(3)
    kk = 24
    pts = rng.normal(size=(kk, 3)) * [1.0, 1.0, 0.01]  # a flat patch, normal +-z
    nb = np.tile([0.0, 0.0, 1.0], (kk, 1))
    assign = np.zeros(kk, dtype=np.int64)
    assign[:2] = 1  # cluster 1: two members, too few for a plane
    centres = np.array([[0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    share, spread = np.zeros(3), np.zeros(3)
    centroid, plane = np.zeros((3, 3)), np.zeros((3, 3))
    _clusters(nb, pts, centres, 2, assign, share, spread, centroid, plane)
    np.testing.assert_array_equal(plane[:2], centres[:2])  # the centres until fitted
    _planes(pts, centres, 2, assign, centroid, plane)
    members = pts[assign == 0]
    _, vec = np.linalg.eigh(np.cov((members - members.mean(axis=0)).T))
    want = vec[:, 0] * np.sign(vec[:, 0] @ centres[0])
    np.testing.assert_allclose(plane[0], want, atol=1e-9)
    assert plane[0] @ centres[0] > 0.99
    np.testing.assert_array_equal(plane[1], centres[1])
    np.testing.assert_allclose(centroid[0], members.mean(axis=0), atol=1e-12)
    assert share[0] == pytest.approx((kk - 2) / kk)
