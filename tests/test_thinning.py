"""recon.thinning: points denser than the surface needs are thinned before the fit (#11):
clumps (a sphere with 100 of its points repeated 50 times at 1e-6 jitter came out with bumps
of 8 r0) and scan lines far denser along than across (an airborne strip in 28 pieces)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

import recon.thinning as thinning
from recon.config import ReconConfig, with_values
from recon.fitting import reconstruct
from recon.io import cloud_from_arrays
from recon.thinning import clump_rows, line_rows, thinned_cloud, thinning_notes


def _grid(n: int = 10) -> np.ndarray:
    return np.stack(np.meshgrid(np.arange(float(n)), np.arange(float(n)), [0.0]), -1).reshape(-1, 3)


def test_a_clump_is_thinned_to_one_point_per_tenth_of_a_spacing():
    grid = _grid()
    rng = np.random.default_rng(0)
    clump = grid[55] + rng.normal(size=(30, 3)) * 1e-4
    pts = np.vstack([grid, clump])
    keep = clump_rows(pts, cKDTree(pts))
    assert keep.tolist() == list(range(len(grid)))  # the clump goes: its grid point stays
    wide = np.vstack([grid, grid[55] + rng.normal(size=(60, 3)) * 0.05])
    kept = clump_rows(wide, cKDTree(wide))
    assert kept[: len(grid)].tolist() == list(range(len(grid)))
    assert len(grid) + 3 < len(kept) < len(wide) - 30  # thinned, not to one point
    assert np.sort(cKDTree(wide[kept]).query(wide[kept], 2)[0][:, 1])[0] >= 0.1
    again = pts[keep]
    assert clump_rows(again, cKDTree(again)) is None
    # given neighbours are used as queried
    tree = cKDTree(pts)
    assert np.array_equal(clump_rows(pts, tree, tree.query(pts, 8)), keep)


def test_pairs_and_triples_are_chance_not_clumps():
    """Four others within 0.1 spacings are not a clump; five are."""
    grid = _grid()
    for extra, clumped in ((4, False), (5, True)):
        pts = np.vstack([grid, grid[55] + 1e-3 * np.arange(1, extra + 1)[:, None] * [1, 0, 0]])
        keep = clump_rows(pts, cKDTree(pts))
        assert (keep is not None) == clumped
        if clumped:
            assert len(keep) == len(grid)


def test_the_thinned_cloud_keeps_its_rows_aligned_and_says_why():
    pts = np.array([[0, 0, 0], [1, 0, 0], [1, 1e-9, 0], [0, 1, 0], [1, 1, 0]], dtype=float)
    cloud = cloud_from_arrays(pts, colors=np.linspace(0, 1, 15).reshape(5, 3))
    cloud.attributes["intensity"] = np.arange(5.0)
    out = thinned_cloud(cloud, np.array([0, 1, 3, 4]), {"kind": "clumps"})
    assert out.attributes["intensity"].tolist() == [0, 1, 3, 4]
    np.testing.assert_array_equal(out.colors, cloud.colors[[0, 1, 3, 4]])
    assert out.info["thinned"] == [{"kind": "clumps", "removed": 1, "before": 5}]
    assert "thinned" not in cloud.info
    cfg = ReconConfig()
    assert "1 points lay in clumps (5 or more others" in thinning_notes(out.info, cfg)[0]
    assert thinning_notes(cloud.info, cfg) == []
    lines = {"kind": "lines", "gap": 2.0, "nearest": 0.1, "radius": 0.5}
    twice = thinned_cloud(out, np.array([0, 1]), lines)
    notes = thinning_notes(twice.info, cfg)
    assert len(notes) == 2 and "about 2 apart, 20 times" in notes[1]
    assert "(2 of 4 went)" in notes[1] and "r0 follows the gaps" in notes[1]
    given = with_values(cfg, seeds={"spacing": 0.3})  # r0 the user's: the thinning is said
    notes = thinning_notes(twice.info, given)
    assert len(notes) == 2 and "r0 follows" not in notes[1] and "(2 of 4 went)" in notes[1]


def test_scan_lines_are_thinned_to_one_point_per_spacing_and_random_samples_are_not():
    x, y = np.meshgrid(np.arange(0.0, 20.0, 0.05), np.arange(0.0, 20.0, 2.0))
    lines = np.c_[x.ravel(), y.ravel(), np.zeros(x.size)]
    kept = line_rows(lines, 0.5, 0.05)
    assert len(kept) == 10 * 40  # one per 0.5 along each of the 10 lines
    tree = cKDTree(lines[kept])
    assert tree.query(lines[kept], 2)[0][:, 1].min() >= 0.5
    assert line_rows(lines, 0.0624, 0.05) is None  # under 1.25 x the nearest distance
    rng = np.random.default_rng(0)
    flat = np.c_[rng.uniform(0, 10, (3000, 2)), np.zeros(3000)]
    assert thinning.thinned_rows(flat, cKDTree(flat), None, 0.1) is None


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
    monkeypatch.setattr(thinning, "NEAR_DUPLICATE", 0.0)
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
    assert clump_rows(pts, cKDTree(pts)) is None


def _plate_in_lines(gap: float = 0.04, along: float = 0.004) -> np.ndarray:
    """A 1 x 1 plate 0.02 thick scanned on both faces in lines ``gap`` apart, random points
    ``along`` apart on average along them."""
    rng = np.random.default_rng(9)
    faces = []
    for z in (0.01, -0.01):
        for y in np.arange(0.0, 1.0, gap):
            x = rng.uniform(0.0, 1.0, int(1.0 / along))
            faces.append(np.c_[x, np.full(len(x), y), np.full(len(x), z)])
    return np.vstack(faces)


def test_a_plate_scanned_in_lines_is_one_closed_piece(monkeypatch):
    """A tester's plate scanned in lines (ratio 29) came out as 11 ribbons (16 here): each
    point's 20 nearest lay on its own line. Thinned along the lines, it is one watertight
    piece."""
    cloud = cloud_from_arrays(_plate_in_lines())
    result = reconstruct(cloud, ReconConfig())
    topo = result.report.topology
    assert (topo.components, topo.watertight, topo.genus) == (1, True, 0)
    assert any("thinned to one point per" in w for w in result.report.warnings)
    monkeypatch.setattr(thinning, "LINE_RATIO", np.inf)  # no thinning: ribbons
    ribbons = reconstruct(cloud, ReconConfig()).report.topology
    assert ribbons.components > 3 or not ribbons.watertight


def test_a_few_lines_are_thinned_once_and_said_once(monkeypatch):
    """Regression: 6 lines of 8 points were thinned to 28 points, measured again (the few
    left farther apart) and thinned again to 10, with two notes that disagreed on the gap."""
    rng = np.random.default_rng(0)
    pts = np.vstack(
        [np.c_[rng.uniform(0, 1, 8), np.full(8, y), np.zeros(8)] for y in np.linspace(0, 1, 6)]
    )
    result = reconstruct(cloud_from_arrays(pts), ReconConfig())
    lines = [w for w in result.report.warnings if "lines or clumps" in w]
    assert len(lines) == 1 and "about 0.2199 apart" in lines[0]  # 0.2 apart
    went = int(lines[0].split("(")[1].split(" of 48 went")[0])
    assert result.report.input.points == 48 - went


def test_a_strip_two_rows_wide_is_not_taken_for_scan_lines():
    """Regression: every point of a strip two rows wide is on a border, never surrounded;
    with a lower bound for its surround distance the strip read as lines 5 spacings apart,
    was thinned, and made no triangle. 4cd19ed fitted it (602 faces)."""
    rng = np.random.default_rng(0)
    x, y = np.meshgrid(np.arange(300) * 0.01, np.arange(2) * 0.01)
    pts = np.c_[x.ravel(), y.ravel(), np.zeros(x.size)] + rng.normal(0, 1e-4, (x.size, 3))
    result = reconstruct(cloud_from_arrays(pts), ReconConfig())
    assert result.report.input.points == 600 and len(result.mesh.faces) > 500
    assert not any("lines or clumps" in w for w in result.report.warnings)


def test_repeats_kept_with_a_spacing_given_are_fitted():
    """Regression: with io.merge_duplicates off, most points repeated and --spacing given
    (as the refusal without it advises), the lines' thinning got a spacing of 0 and raised
    ValueError (radius must be > 0)."""
    rng = np.random.default_rng(0)
    v = rng.normal(size=(2000, 3))
    v /= np.linalg.norm(v, axis=1)[:, None]
    cfg = with_values(ReconConfig(), io={"merge_duplicates": False}, seeds={"spacing": 0.1})
    cloud = cloud_from_arrays(np.repeat(v, 3, axis=0), merge_duplicates=False)
    result = reconstruct(cloud, cfg)
    assert result.report.input.points == 6000 and len(result.mesh.faces) > 1000
