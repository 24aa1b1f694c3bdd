"""recon.near_duplicates: one place sampled many times is merged before the fit (#11: a
sphere with 100 of its points repeated 50 times at 1e-6 jitter came out with bumps of 8 r0)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

import recon.near_duplicates as near
from recon.config import ReconConfig
from recon.fitting import reconstruct
from recon.io import cloud_from_arrays
from recon.near_duplicates import merged_cloud, near_duplicate_notes, near_duplicate_rows


def _grid(n: int = 10) -> np.ndarray:
    return np.stack(np.meshgrid(np.arange(float(n)), np.arange(float(n)), [0.0]), -1).reshape(-1, 3)


def test_a_clump_is_thinned_to_one_point_per_tenth_of_a_spacing():
    grid = _grid()
    rng = np.random.default_rng(0)
    clump = grid[55] + rng.normal(size=(30, 3)) * 1e-4
    pts = np.vstack([grid, clump])
    keep = near_duplicate_rows(pts, cKDTree(pts))
    assert keep.tolist() == list(range(len(grid)))  # the clump goes: its grid point stays
    wide = np.vstack([grid, grid[55] + rng.normal(size=(60, 3)) * 0.05])
    kept = near_duplicate_rows(wide, cKDTree(wide))
    assert kept[: len(grid)].tolist() == list(range(len(grid)))
    assert len(grid) + 3 < len(kept) < len(wide) - 30  # thinned, not to one point
    assert np.sort(cKDTree(wide[kept]).query(wide[kept], 2)[0][:, 1])[0] >= 0.1
    again = pts[keep]
    assert near_duplicate_rows(again, cKDTree(again)) is None
    # given neighbours are used as queried
    tree = cKDTree(pts)
    assert np.array_equal(near_duplicate_rows(pts, tree, tree.query(pts, 8)), keep)


def test_pairs_and_triples_are_chance_not_clumps():
    """Four others within 0.1 spacings are not a clump; five are."""
    grid = _grid()
    for extra, clumped in ((4, False), (5, True)):
        pts = np.vstack([grid, grid[55] + 1e-3 * np.arange(1, extra + 1)[:, None] * [1, 0, 0]])
        keep = near_duplicate_rows(pts, cKDTree(pts))
        assert (keep is not None) == clumped
        if clumped:
            assert len(keep) == len(grid)


def test_the_merged_cloud_keeps_its_rows_aligned_and_counts_them():
    pts = np.array([[0, 0, 0], [1, 0, 0], [1, 1e-9, 0], [0, 1, 0], [1, 1, 0]], dtype=float)
    cloud = cloud_from_arrays(pts, colors=np.linspace(0, 1, 15).reshape(5, 3))
    cloud.attributes["intensity"] = np.arange(5.0)
    out = merged_cloud(cloud, np.array([0, 1, 3, 4]))
    assert out.attributes["intensity"].tolist() == [0, 1, 3, 4]
    np.testing.assert_array_equal(out.colors, cloud.colors[[0, 1, 3, 4]])
    assert (
        out.info["n_near_duplicates_merged"] == 1 and "n_near_duplicates_merged" not in cloud.info
    )
    assert "1 points lay in clumps (5 or more others" in near_duplicate_notes(out.info)[0]
    assert near_duplicate_notes(cloud.info) == []


def _sphere_with_copies() -> np.ndarray:
    rng = np.random.default_rng(0)
    v = rng.normal(size=(3000, 3))
    v /= np.linalg.norm(v, axis=1)[:, None]
    idx = rng.choice(3000, 30, replace=False)
    return np.vstack([v, np.repeat(v[idx], 40, axis=0) + rng.normal(size=(1200, 3)) * 1e-7])


def test_a_sphere_with_points_repeated_at_tiny_jitter_stays_a_sphere(monkeypatch):
    """30 points repeated 40 times at 1e-7: the copies merged, the mesh within 1e-4 of the
    sphere; fitted with the copies, it had bumps of 0.15 (5 r0) where their local quadrics
    curved at 1e4 / r0 (at 1e-3 jitter, 0.1 and not watertight; now 0.0015, watertight)."""
    cloud = cloud_from_arrays(_sphere_with_copies())
    result = reconstruct(cloud, ReconConfig())
    off = np.abs(np.linalg.norm(result.mesh.vertices, axis=1) - 1.0)
    assert off.max() < 1e-3, off.max()
    assert 2990 < result.report.input.points <= 3000 and result.report.topology.watertight
    assert any("points lay in clumps" in w for w in result.report.warnings)
    assert result.report.timings.normals > 0
    monkeypatch.setattr(near, "NEAR_DUPLICATE", 0.0)
    kept = reconstruct(cloud, ReconConfig())
    assert np.abs(np.linalg.norm(kept.mesh.vertices, axis=1) - 1.0).max() > 0.05


def test_a_tiles_given_creases_follow_the_merged_rows():
    """fit_particles with a tile's creases (rows of the cloud as given): the creases are taken
    on the rows the merge keeps, so the fit of the L-block with copies finds its creases."""
    from recon.fitting.pipeline import fit_particles
    from recon.fitting.wide_creases import detect_fit_creases
    from recon.io import read_points
    from tests.test_tiled_creases import LBLOCK

    pts = read_points(LBLOCK).points
    rng = np.random.default_rng(1)
    idx = rng.choice(len(pts), 20, replace=False)
    both = np.vstack([pts, np.repeat(pts[idx], 30, axis=0) + rng.normal(size=(600, 3)) * 1e-8])
    cloud = cloud_from_arrays(both)
    fit = fit_particles(cloud, ReconConfig(), creases=detect_fit_creases(cloud, ReconConfig()))
    assert fit.crease is not None and fit.crease.sum() > 50
    assert "points lay in clumps" in fit.warnings[0]


@pytest.mark.parametrize("n", [0, 1])
def test_no_clump_no_merge(n):
    rng = np.random.default_rng(n)
    pts = rng.uniform(0, 1, (500, 3))
    assert near_duplicate_rows(pts, cKDTree(pts)) is None
