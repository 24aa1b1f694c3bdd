"""Re-signing estimated data normals where both faces of a thin part share a neighbourhood
(:mod:`recon.normal_signs`)."""

from pathlib import Path

import numpy as np

from recon.config import ReconConfig
from recon.fitting import reconstruct
from recon.geometry import median_variation
from recon.io import read_points
from recon.normal_signs import CLEAN_VARIATION, THIN_SCAN_SHARE, outward_across, resign_thin_parts

SAMPLE = Path(__file__).resolve().parent.parent / "sample_data"


def _sphere(n=2000, noise=0.0, seed=0):
    i = np.arange(n) + 0.5
    z = 1 - 2 * i / n
    phi = np.pi * (1 + 5**0.5) * i
    u = np.stack([np.sqrt(1 - z * z) * np.cos(phi), np.sqrt(1 - z * z) * np.sin(phi), z], 1)
    r = 10.0 + np.random.default_rng(seed).normal(scale=noise, size=n)
    return u * r[:, None], u


def test_a_wrong_patch_on_clean_data_is_re_signed():
    p, u = _sphere()
    n = u.copy()
    patch = u @ np.array([0.0, 0.6, 0.8]) > 0.95
    n[patch] *= -1
    assert patch.sum() > 30 and median_variation(p, 20) < CLEAN_VARIATION
    out, flipped = resign_thin_parts(p, n, 20)
    assert flipped == patch.sum()
    assert np.all(np.einsum("ij,ij->i", out, u) > 0.99)


def test_noisy_data_keeps_its_signs():
    """Offsets along the normals are noise there, not geometry: nothing is re-signed."""
    p, u = _sphere(noise=0.5)
    n = u.copy()
    n[u @ np.array([0.0, 0.6, 0.8]) > 0.95] *= -1
    assert median_variation(p, 20) >= CLEAN_VARIATION
    out, flipped = resign_thin_parts(p, n, 20)
    assert flipped == 0 and out is n


def test_sparse_bunny_ear_tips_close_further():
    """bunny-sparse (2,000 points): 78 data normals of the wrong sign at the ear tips and the
    bottom (a sparse neighbourhood holds both faces of the ear) left 3 slits; re-signed with
    reflected dot products, 9 are wrong and one ear tip closes (3 -> 2 loops)."""
    res = reconstruct(read_points(SAMPLE / "bunny-sparse.ply"), ReconConfig())
    topo = res.report.topology
    assert topo.components == 1 and topo.boundary_loops <= 2


def _plate(n=6000, thickness=1.0, seed=0):
    """Two faces of a plate (+-thickness/2 in z) over a 60 x 20 rectangle, spacing ~0.45,
    with their outward normals: the other face lies about two spacings behind each."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform([0, 0], [60, 20], (n, 2))
    side = rng.choice([-1.0, 1.0], n)
    points = np.column_stack([xy, 0.5 * thickness * side])
    normals = np.zeros((n, 3))
    normals[:, 2] = side
    return points, normals


def test_a_thin_part_signed_inside_out_is_turned_outward():
    points, outward = _plate()
    out, turned = outward_across(points, -outward)
    assert turned
    assert np.array_equal(out, outward)


def test_a_thin_part_signed_outward_stays():
    points, outward = _plate()
    out, turned = outward_across(points, outward)
    assert not turned and out is outward


def test_split_votes_change_nothing():
    """Half the plate outward and half inside out (a sign left inconsistent): no majority."""
    points, outward = _plate()
    mixed = np.where((points[:, 0] < 30)[:, None], outward, -outward)
    _, turned = outward_across(points, mixed)
    assert not turned


def test_a_scan_without_thin_parts_has_no_vote():
    p, u = _sphere()
    out, turned = outward_across(p, -u)  # inside out, but no neighbourhood spans two faces
    assert not turned and np.array_equal(out, -u)


def test_the_vote_needs_enough_two_sided_points():
    """A thick body with a few points of a thin fin: fewer than THIN_SCAN_SHARE vote."""
    p, u = _sphere(n=4000)
    fin_p, fin_n = _plate(n=150, thickness=0.4)
    fin_p = fin_p * [0.05, 0.05, 1.0] + [12.0, 0.0, 0.0]  # a small dense fin beside it
    points = np.concatenate([p, fin_p])
    normals = np.concatenate([u, -fin_n])  # the fin inside out
    _, turned = outward_across(points, normals)
    assert not turned
    assert 150 < THIN_SCAN_SHARE * len(points)
