"""recon.fitting.scale: the point spacing of scan lines, and a fit of them (#11: LiDAR-like
rings 3.7x farther apart than their points fell apart into 131 components)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner
from scipy.spatial import cKDTree

import recon.fitting.scale as scale
from cli.main import app
from recon.config import ReconConfig, with_values
from recon.errors import InputError
from recon.fitting import reconstruct
from recon.fitting.scale import SURROUND_RATIO, choose_spacing, sampled_spacing
from recon.io import cloud_from_arrays, read_points, write_points


def scan_lines(n_lines: int = 24, per_line: int = 120, seed: int = 0) -> np.ndarray:
    """A gently curved 4 x 4 patch scanned in ``n_lines`` lines (0.17 apart) of ``per_line``
    random points each (0.033 apart on average, 0.011 to the nearest)."""
    rng = np.random.default_rng(seed)
    rows = []
    for y in np.linspace(0.0, 4.0, n_lines):
        x = np.sort(rng.uniform(0.0, 4.0, per_line))
        z = 0.3 * np.sin(0.8 * x) * np.cos(0.6 * y)
        rows.append(np.c_[x, np.full(per_line, y), z])
    return np.vstack(rows)


def random_patch(n: int = 3000, seed: int = 0) -> np.ndarray:
    xy = np.random.default_rng(seed).uniform(0.0, 4.0, (n, 2))
    return np.c_[xy, 0.3 * np.sin(0.8 * xy[:, 0]) * np.cos(0.6 * xy[:, 1])]


def test_random_samples_keep_the_nearest_neighbour_spacing_exactly():
    pts = random_patch()
    nearest = np.median(cKDTree(pts).query(pts, 2)[0][:, 1])
    notes: list[str] = []
    r0, spacing = choose_spacing(pts, ReconConfig(), notes=notes)
    assert spacing == nearest and notes == []


def test_scan_lines_get_the_spacing_across_them_and_say_so():
    pts = scan_lines()
    notes: list[str] = []
    r0, spacing = choose_spacing(pts, ReconConfig(), notes=notes)
    gap = 4.0 / 23
    assert spacing == pytest.approx(gap / SURROUND_RATIO, rel=0.05)
    assert len(notes) == 1 and "lines or clumps about 0.17" in notes[0], notes
    # a spacing the user gives is theirs: no note, but the point spacing (max_gap) is the same
    notes.clear()
    cfg = with_values(ReconConfig(), seeds={"spacing": 0.05})
    assert choose_spacing(pts, cfg, notes=notes) == (0.05, spacing) and notes == []


def test_repeated_points_are_still_refused_with_their_reason():
    assert sampled_spacing(0.0, 5.0) == 0.0
    pts = np.repeat(random_patch(500), 3, axis=0)
    with pytest.raises(InputError, match="exact duplicates"):
        choose_spacing(pts, ReconConfig())


def test_a_scan_line_patch_is_fitted_whole(monkeypatch):
    """One component, its one boundary the patch's rim, and a warning that says why r0 is
    what it is; from the spacing along the lines the fit made no triangle at all."""
    cloud = cloud_from_arrays(scan_lines())
    result = reconstruct(cloud, ReconConfig())
    topo = result.report.topology
    assert (topo.components, topo.boundary_loops, topo.non_manifold_edges) == (1, 1, 0)
    assert topo.largest_hole_perimeter == pytest.approx(16.0, rel=0.1)  # the 4 x 4 rim
    assert any("lines or clumps" in w for w in result.report.warnings)
    monkeypatch.setattr(scale, "SURROUND_RATIO", np.inf)  # the spacing along the lines
    with pytest.raises(InputError, match="no triangles"):
        reconstruct(cloud, ReconConfig())


def test_info_shows_the_spacing_between_scan_lines(tmp_path):
    path = tmp_path / "lines.ply"
    write_points(path, scan_lines())
    res = CliRunner().invoke(app, ["info", str(path), "--json"])
    assert res.exit_code == 0, res.output
    d = json.loads(res.stdout)
    assert d["spacing_surround"] == pytest.approx(4.0 / 23, rel=0.05)
    assert d["spacing"] == pytest.approx(d["spacing_surround"] / SURROUND_RATIO)
    table = CliRunner().invoke(app, ["info", str(path)]).output
    assert "in lines or clumps" in table
    write_points(path, random_patch())
    d = json.loads(CliRunner().invoke(app, ["info", str(path), "--json"]).stdout)
    assert d["spacing"] == d["spacing_median_nn"]


def test_a_small_change_of_the_spacing_is_not_announced():
    """Regression: a sphere with 1 point in 3 in jittered clumps took a spacing 1.06x its
    nearest-neighbour distance and warned "about 0.045 apart, 4 times their spacing"."""
    cfg = ReconConfig()
    assert scale.sampling_note(1.0, 1.2, 2.5, cfg) is None
    assert "5 times" in scale.sampling_note(1.0, 1.25, 2.5, cfg)


def test_info_measures_the_spacing_in_the_fits_order(tmp_path):
    """Regression: `oprecon info` sampled the points in the file's order, the fit in its
    Morton order: near the threshold one said lines and the other not. Now info gives the
    fit's spacing whatever the file's order (up to points tied in one Morton cell)."""
    from recon.cloud import spatial_order

    pts = np.random.default_rng(3).permutation(scan_lines())
    path = tmp_path / "lines.ply"
    write_points(path, pts)
    d = json.loads(CliRunner().invoke(app, ["info", str(path), "--json"]).stdout)
    read = read_points(path).points  # (as written)
    _, spacing = choose_spacing(read[spatial_order(read)], ReconConfig())
    assert d["spacing"] == pytest.approx(spacing, rel=1e-12)
