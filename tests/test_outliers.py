"""Statistical outlier removal (``io.outliers``, ``--remove-outliers``) and the fit's warning when
a scan looks outlier-ridden (:mod:`recon.io.outliers`)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from recon.cli.main import app

import recon
from recon.config import load_config
from recon.errors import ConfigError
from recon.io import cloud_from_arrays, read_points, write_points
from recon.io.outliers import (
    LOCAL_RATIO,
    WARN_FRACTION,
    far_fraction,
    local_ratio,
    mean_knn_distance,
    outlier_removal,
    outlier_summary,
    outlier_warnings,
    statistical_outliers,
)

FAST = ["--set", "seeds.min_particles=0"]


def _sphere(n: int, seed: int = 0) -> np.ndarray:
    p = np.random.default_rng(seed).normal(size=(n, 3))
    return p / np.linalg.norm(p, axis=1, keepdims=True)


def _with_box_outliers(n: int, n_out: int, seed: int = 0, half: float = 1.5) -> np.ndarray:
    """``n`` points on the unit sphere, then ``n_out`` uniform in [-half, half]^3."""
    rng = np.random.default_rng(seed + 1)
    return np.vstack([_sphere(n, seed), rng.uniform(-half, half, size=(n_out, 3))])


def _run(args):
    return CliRunner().invoke(app, args, catch_exceptions=False)


def test_statistical_outliers_removes_far_points_and_keeps_the_surface():
    p = _with_box_outliers(2000, 200)
    drop = statistical_outliers(p, 20, 3.0)
    off_surface = np.abs(np.linalg.norm(p, axis=1) - 1.0)
    assert not drop[:2000].any()  # every sphere point kept
    # every outlier off the surface by more than a quarter of the radius (3 point spacings) is
    # removed; those closer have the sphere's points as neighbours and some are under the
    # floor (2x the median mean distance): they stay
    far = off_surface > 0.25
    assert far[2000:].sum() > 120 and drop[far].all()
    assert drop[2000:].sum() >= 0.7 * 200


def test_statistical_outliers_is_deterministic_and_thread_independent():
    p = _with_box_outliers(1500, 100, seed=4)
    a = statistical_outliers(p, 20, 3.0, workers=1)
    b = statistical_outliers(p, 20, 3.0, workers=2)
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(a, statistical_outliers(p.copy(), 20, 3.0))
    # the same points in another order: the same points removed
    order = np.random.default_rng(0).permutation(len(p))
    np.testing.assert_array_equal(statistical_outliers(p[order], 20, 3.0), a[order])


def _grid(n: int, spacing: float = 1.0) -> np.ndarray:
    g = np.stack(np.meshgrid(np.arange(n) * spacing, np.arange(n) * spacing, [0.0]), -1)
    return g.reshape(-1, 3)


def test_statistical_outliers_on_a_regular_grid_keeps_every_point():
    """A structured-light grid: most distances alike (MAD 0, a tiny std fallback), its border
    and corner points 1.2-1.7x the median. The floor (2x the median) keeps them: the rule
    removed the two outer rows before, with or without jitter, and 16 of 40 points of a
    4 x 10 layout at k=1."""
    g = _grid(60)
    for k in (8, 20):
        assert not statistical_outliers(g, k, 3.0).any()
    rng = np.random.default_rng(0)
    for jitter in (1e-9, 1e-4, 1e-2):
        assert not statistical_outliers(g + rng.normal(0, jitter, g.shape), 20, 3.0).any()
    x, y = np.tile(np.linspace(0, 1, 10), 4), np.repeat([0, 0.3, 0.6, 0.9], 10)
    tiny = np.column_stack([x, y, 0.01 * np.sin(7 * x)])
    assert not statistical_outliers(tiny, 1, 3.0).any()


def test_statistical_outliers_floor_still_removes_stray_points_over_a_grid():
    """Uniform stray points over a grid: those more than 3 grid spacings off it are over
    twice its median distance, and go; those closer have the grid as neighbours."""
    g = _grid(80, 0.0125)
    rng = np.random.default_rng(5)
    stray = rng.uniform([0, 0, -0.3], [1, 1, 0.3], (200, 3))
    drop = statistical_outliers(np.vstack([g, stray]), 20, 3.0)
    assert not drop[: len(g)].any()
    assert drop[len(g) :][np.abs(stray[:, 2]) > 3 * 0.0125].all()


def test_smaller_std_ratio_removes_more():
    """Above the floor (2x the median, which std_ratio 5 stays under here) the robust
    threshold decides: a larger ratio keeps more."""
    p = _with_box_outliers(1500, 100, seed=2)
    counts = [int(statistical_outliers(p, 20, r).sum()) for r in (1.0, 5.0, 20.0)]
    assert counts[0] == counts[1] > counts[2] > 0


def test_mean_knn_distance_leaves_the_point_itself_out():
    p = np.array([[0.0, 0, 0], [1.0, 0, 0], [3.0, 0, 0], [0.0, 2, 0]])
    np.testing.assert_allclose(mean_knn_distance(p, 1), [1.0, 1.0, 2.0, 2.0])


def test_read_points_removes_outliers_with_their_rows(tmp_path: Path):
    """Normals, colours and attributes stay with their points: each row encodes its index."""
    p = _with_box_outliers(1200, 100)
    index = np.arange(len(p))
    normals = np.column_stack([np.cos(index), np.sin(index), np.zeros(len(p))])
    colors = np.column_stack([index % 256, index // 256, np.full(len(p), 7)]).astype(np.uint8)
    path = tmp_path / "scan.ply"
    write_points(
        path, p, normals, colors=colors, vertex_properties={"intensity": index.astype(float)}
    )
    expected = ~statistical_outliers(p, 20, 3.0)
    cloud = read_points(path, merge_duplicates=False, outliers=(20, 3.0))
    assert cloud.info["n_outliers_removed"] == int((~expected).sum()) > 60
    assert len(cloud) == int(expected.sum())
    kept = cloud.attributes["intensity"].astype(int)
    np.testing.assert_array_equal(kept, index[expected])
    np.testing.assert_allclose(cloud.absolute_points(), p[expected], atol=1e-6)
    np.testing.assert_allclose(cloud.normals, normals[expected], atol=1e-6)
    back = np.round(cloud.colors * 255).astype(int)
    np.testing.assert_array_equal(back[:, 0] + 256 * back[:, 1], kept)
    again = read_points(path, merge_duplicates=False, outliers=(20, 3.0))
    np.testing.assert_array_equal(again.points, cloud.points)


def test_cloud_from_arrays_keeps_every_point_unless_asked():
    p = _with_box_outliers(800, 80)
    assert len(cloud_from_arrays(p)) == len(p)
    cleaned = cloud_from_arrays(p, outliers=(20, 3.0))
    assert cleaned.info["n_outliers_removed"] > 45
    assert len(cleaned) == len(p) - cleaned.info["n_outliers_removed"]


def test_outlier_config_keys():
    cfg = load_config()
    assert cfg.io.outliers == "none" and outlier_removal(cfg.io) is None
    cfg = load_config(overrides={"io.outliers": "statistical", "io.outlier_std_ratio": 2.5})
    assert outlier_removal(cfg.io) == (20, 2.5)
    with pytest.raises(ConfigError, match="io.outliers"):
        load_config(overrides={"io.outliers": "radius"})
    with pytest.raises(ConfigError, match="io.outlier_std_ratio"):
        load_config(overrides={"io.outlier_std_ratio": 0})


def test_warning_fires_on_outliers_and_not_on_a_clean_scan():
    """Far points: over 2x the median mean distance of their neighbours. On a sphere of 3,000
    points, 20 % uniform outliers in its box are 6 % far; 5 % in a box 8 radii wide 3 %."""
    cases = ((3000, 0, 1.5, False), (3000, 750, 1.5, True), (1500, 79, 4.0, True))
    for n, n_out, half, fires in cases:
        p = _with_box_outliers(n, n_out, half=half)
        summary = outlier_summary({}, p, 20)
        assert (summary["far_fraction"] > WARN_FRACTION) is fires
        assert summary["statistical"] is False
        warnings = outlier_warnings({"outliers": summary})
        assert len(warnings) == int(fires)
        if fires:
            assert "--remove-outliers" in warnings[0] and "% of the input points" in warnings[0]


def _tls_ground(step_deg: float = 1.5) -> np.ndarray:
    """A terrestrial scanner 1.5 m above flat ground: rings every ``step_deg`` of elevation,
    a point every 1.2 degrees of azimuth, so the density falls with range (a ring at 15 m is
    50x farther from the next than one at 1.5 m)."""
    az = np.deg2rad(np.arange(0.0, 360.0, 1.2))
    rings = []
    for el in np.deg2rad(np.arange(-60.0, -4.0, step_deg)):
        r = 1.5 / np.tan(-el)
        rings.append(np.column_stack([r * np.cos(az), r * np.sin(az), np.zeros_like(az)]))
    p = np.vstack(rings)
    p[:, 2] += np.random.default_rng(4).normal(0, 0.003, len(p))
    return p


def test_warning_is_local_a_density_falling_with_range_is_not_outliers():
    """Over 10 % of a clean terrestrial scan's points are more than 4x the median point's
    distance from their neighbours (the global rule warned), none more than 2x their
    neighbours'; a few stray points among the dense near range still stand out."""
    p = _tls_ground()
    mean = mean_knn_distance(p, 20)
    assert np.mean(mean > 4 * np.median(mean)) > 0.1
    summary = outlier_summary({}, p, 20)
    assert summary["far_fraction"] <= WARN_FRACTION and not outlier_warnings({"outliers": summary})
    stray = np.random.default_rng(1).uniform([-2, -2, 0.2], [2, 2, 1.0], (40, 3))
    both = np.vstack([p, stray])
    from scipy.spatial import cKDTree

    dist, idx = cKDTree(both).query(both, 21)
    ratio = local_ratio(dist[:, 1:].mean(axis=1), idx[:, 1:])
    assert (ratio[len(p) :] > LOCAL_RATIO).mean() > 0.9 and (ratio[: len(p)] <= LOCAL_RATIO).all()


def test_no_warning_once_the_outliers_were_removed():
    """With io.outliers: statistical the summary's input line counts what went: the warning
    no longer names the flag that is on, however many far points are left."""
    p = _with_box_outliers(3000, 750)
    summary = outlier_summary({"n_outliers_removed": 0}, p, 20)
    assert summary["statistical"] is True and summary["far_fraction"] > WARN_FRACTION
    assert outlier_warnings({"outliers": summary}) == []
    assert outlier_warnings({"outliers": {**summary, "statistical": False}})


def test_warning_reuses_a_wider_neighbour_query():
    from scipy.spatial import cKDTree

    p = _with_box_outliers(1000, 100)
    knn = cKDTree(p).query(p, 41)
    assert outlier_summary({}, p, 20, knn) == outlier_summary({}, p, 20)
    # the last point is 5x its three neighbours, which are 1.25x theirs
    mean = np.array([1.0, 1.0, 1.0, 5.0])
    idx = np.array([[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]])
    np.testing.assert_allclose(local_ratio(mean, idx), [1.0, 1.0, 1.0, 5.0])
    assert far_fraction(mean, idx) == 0.25


def test_library_fit_removes_outliers_and_reports_them():
    p = _with_box_outliers(1500, 150)
    res = recon.fit(p, {"seeds.min_particles": 0, "io.outliers": "statistical"})
    outliers = res.report.input.normals["outliers"]
    assert outliers["removed"] >= 100
    assert res.report.input.points == len(p) - outliers["removed"]
    assert not any("outlier-ridden" in w for w in res.report.warnings)


def test_cli_fit_warns_then_removes_outliers(tmp_path: Path):
    src = tmp_path / "scan.ply"
    write_points(src, _with_box_outliers(1500, 79, half=4.0))  # 5 % stray points
    out = tmp_path / "plain.ply"
    res = _run(["fit", str(src), "-o", str(out), *FAST])
    assert res.exit_code == 0, res.output
    report = json.loads(out.with_suffix(".report.json").read_text())
    assert any("--remove-outliers" in w for w in report["warnings"])
    assert report["input"]["normals"]["outliers"]["removed"] == 0
    assert "outlier-ridden" in res.output

    out = tmp_path / "clean.ply"
    res = _run(["fit", str(src), "-o", str(out), "--remove-outliers", *FAST])
    assert res.exit_code == 0, res.output
    report = json.loads(out.with_suffix(".report.json").read_text())
    removed = report["input"]["normals"]["outliers"]["removed"]
    assert removed >= 75 and report["input"]["points"] == 1579 - removed
    assert report["config"]["io"]["outliers"] == "statistical"
    assert not any("outlier-ridden" in w for w in report["warnings"])
    assert f"({removed:,} statistical outliers removed: io.outliers)" in res.output
    assert report["topology"]["components"] == 1


def test_cli_fit_help_teaches_the_flag():
    res = _run(["fit", "--help"])
    text = " ".join(res.output.split())
    assert "--remove-outliers" in text and "io.outlier_k" in text
    assert "io.outlier_std_ratio" in text


def test_cli_normals_removes_outliers(tmp_path: Path):
    src = tmp_path / "scan.ply"
    write_points(src, _with_box_outliers(1000, 100))
    out = tmp_path / "n.ply"
    res = _run(["normals", str(src), "-o", str(out), "--remove-outliers"])
    assert res.exit_code == 0, res.output
    n = len(read_points(out, merge_duplicates=False))
    assert 1000 <= n <= 1040 and f"({1100 - n:,} statistical outliers removed)" in res.output


def test_tiled_fit_refuses_outlier_removal(tmp_path: Path):
    src = tmp_path / "scan.ply"
    write_points(src, _with_box_outliers(1000, 50))
    out = tmp_path / "m.ply"
    res = CliRunner().invoke(
        app, ["fit", str(src), "-o", str(out), "--tile-size", "1", "--remove-outliers"]
    )
    assert res.exit_code == 2, res.output
    assert str(src) in res.output and "not available in tiled fits" in res.output
    assert "Traceback" not in res.output and not out.exists()


def test_tiles_auto_refuses_outlier_removal_only_when_it_tiles(tmp_path: Path):
    """--tiles auto: refused once the budget makes it tile (2,500 points need ~376 MiB by the
    estimate: a 360 MiB budget tiles), not checked when one fit will do."""
    xy = np.random.default_rng(3).uniform(0, 8, (2500, 2))
    src = tmp_path / "sheet.ply"
    write_points(src, np.column_stack([xy, 0.4 * np.sin(xy[:, 0] / 1.3)]))
    out = tmp_path / "m.ply"
    args = ["fit", str(src), "-o", str(out), "--tiles", "auto", "--remove-outliers"]
    res = CliRunner().invoke(app, [*args, "--max-memory", "360M"])
    assert res.exit_code == 2, res.output
    assert "not available in tiled fits" in res.output and not out.exists()
    res = CliRunner().invoke(app, [*args, "--set", "dynamics.max_steps=300"])
    assert res.exit_code == 0, res.output
    assert "not tiling" in res.output and out.exists()
