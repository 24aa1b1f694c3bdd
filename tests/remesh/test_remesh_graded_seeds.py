"""Graded seeds for --adaptive: Poisson-disk thinning with a radius per point.

The graded seeds must follow the density 1/rest² (not evened out) and be as evenly spread as
the uniform ones (no clumps of a random draw)."""

import numpy as np
from scipy.spatial import cKDTree

from recon.geometry import poisson_disk_thin, poisson_disk_thin_graded
from recon.remesh.pipeline import ADAPTIVE_MAX, ADAPTIVE_MIN, spacing_field
from recon.remesh.relax import SEED_THINNING, Particles, seed
from recon.remesh.surface import MeshSurface
from tests.mesh_shapes import icosphere


def _graded_plane(n=6000, seed=0):
    rng = np.random.default_rng(seed)
    p = rng.uniform(0, 20, size=(n, 3))
    p[:, 2] = 0.0
    r = 0.4 + 0.1 * p[:, 0]  # 0.4 .. 2.4 across the plane
    return p, r


def test_graded_kept_pairs_respect_the_mean_radius():
    p, r = _graded_plane()
    keep = poisson_disk_thin_graded(p, r, np.random.default_rng(1).permutation(len(p)))
    idx = np.flatnonzero(keep)
    pairs = cKDTree(p[idx]).query_pairs(r.max(), output_type="ndarray")
    i, j = idx[pairs[:, 0]], idx[pairs[:, 1]]
    d = np.linalg.norm(p[i] - p[j], axis=1)
    assert np.all(d >= 0.5 * (r[i] + r[j]))


def test_graded_thinning_is_maximal():
    p, r = _graded_plane()
    keep = poisson_disk_thin_graded(p, r)
    idx = np.flatnonzero(keep)
    tree = cKDTree(p[idx])
    for k in np.flatnonzero(~keep):
        near = idx[tree.query_ball_point(p[k], r.max())]
        assert np.any(np.linalg.norm(p[near] - p[k], axis=1) < 0.5 * (r[near] + r[k]))


def test_graded_density_follows_one_over_radius_squared():
    p, r = _graded_plane(20000)
    keep = poisson_disk_thin_graded(p, r)
    fine = np.sum(keep & (p[:, 0] < 5)) / 5.0  # r ~ 0.65 on average
    coarse = np.sum(keep & (p[:, 0] > 15)) / 5.0  # r ~ 2.15
    expected = (2.15 / 0.65) ** 2
    assert 0.7 * expected < fine / coarse < 1.3 * expected


def test_constant_radius_matches_the_scalar_thinning():
    p, _ = _graded_plane()
    order = np.random.default_rng(3).permutation(len(p))
    a = poisson_disk_thin(p, 1.0, order, keep_first=5)
    b = poisson_disk_thin_graded(p, np.ones(len(p)), order, keep_first=5)
    assert np.array_equal(a, b)


def test_graded_keep_first_and_bad_radius():
    p = np.array([[0.0, 0, 0], [0.1, 0, 0], [5.0, 0, 0], [5.2, 0, 0]])
    keep = poisson_disk_thin_graded(p, np.ones(4), np.arange(4), keep_first=2)
    assert keep.tolist() == [True, True, True, False]
    for bad in (np.ones(3), np.array([1.0, 0.0, 1.0, 1.0])):
        try:
            poisson_disk_thin_graded(p, bad)
        except ValueError:
            continue
        raise AssertionError(f"radius {bad} accepted")


def test_adaptive_seeds_follow_the_field_and_are_evenly_spread():
    # a disc-like spheroid: fine spacing on the rim, coarse on the flat faces
    v, f = icosphere(4)
    v = v * [1.0, 1.0, 0.2] / 0.06  # normalised by the spacing, as the pipeline does
    surface = MeshSurface(v, f)
    field = spacing_field(surface, 1.0, ADAPTIVE_MIN, ADAPTIVE_MAX)
    faces = surface.faces

    def rest_at(points, face):
        return field[faces[face]].mean(axis=1)

    rest_f = rest_at(None, np.arange(len(faces)))
    n = int(round(np.sum(surface.face_area / (np.sqrt(3) / 2 * rest_f**2))))
    empty = Particles(
        np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), np.zeros(0, np.int8), np.zeros(0, int)
    )
    p = seed(surface, empty, n, rest_at, np.random.default_rng(0))
    assert p.n == n
    d, _ = cKDTree(p.position).query(p.position, k=2)
    ratio = d[:, 1] / p.rest
    # evenly spread: no seed has a neighbour much closer than the thinning radius (a random
    # draw of density 1/rest^2 has a 1st percentile near 0.1)
    assert np.percentile(ratio, 1) > 0.6 * SEED_THINNING, np.percentile(ratio, 1)
    # density follows the field at both ends: nearest-neighbour distance over rest alike
    lo, hi = np.percentile(p.rest, [20, 80])
    assert hi > 1.8 * lo
    fine, coarse = np.median(ratio[p.rest <= lo]), np.median(ratio[p.rest >= hi])
    assert 0.85 < fine / coarse < 1.15, (fine, coarse)
