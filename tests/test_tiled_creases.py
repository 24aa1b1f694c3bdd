"""Creases in tiled fits: what a tiled fit does with the sharp features an untiled fit detects,
keeps sharp, reports and writes.

Each tile detects and fits the creases of its core and halo, so the mesh keeps the edges its
tiles found sharp; the detection reads the points beyond the halo (``creases.reach``), so a
crease near a seam is found by both tiles; the scan's crease statistics (length, corners,
detected points) are not measured (null, said so), crease particles are counted, a crease one
tile found and its neighbour missed is warned of, ``creases.split_ply`` is refused and an
OBJ's unsplit normals are warned of (a tiled mesh is streamed into its file with one normal
per vertex).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from recon.cli.fit import format_tiled_summary
from recon.cli.main import app

from recon.config import ReconConfig, with_values
from recon.io import read_mesh
from recon.tiling import TileGrid, fit_tiled

#: The L-block (1 x 0.8 x 0.5 with a 0.6 x 0.4 notch), 4,000 points: at tiles of 0.5 the halo
#: (4 r0 = 0.067) is narrower than the crease detection's neighbourhood (48 points, 0.10
#: across here); detecting on the core and halo alone, the tile of x >= 0.5, y < 0.5 missed
#: the two lines along y = 0 that its neighbour (x < 0.5) found.
LBLOCK = Path(__file__).resolve().parent.parent / "sample_data" / "lblock-sparse.ply"


def _run(args):
    return CliRunner().invoke(app, args, catch_exceptions=False)


def _edge_turns(vertices, faces, a, b, reach):
    """The largest turn [deg] between the two faces of a mesh edge within ``reach`` of each of
    20 points on the segment a-b (its ends left out)."""
    from scipy.spatial import cKDTree

    v, f = np.asarray(vertices, float), np.asarray(faces, np.int64)
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    fn /= np.linalg.norm(fn, axis=1, keepdims=True)
    e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    owner = np.tile(np.arange(len(f)), 3)
    order = np.lexsort((e[:, 1], e[:, 0]))
    e, owner = e[order], owner[order]
    pair = np.flatnonzero(np.all(e[1:] == e[:-1], axis=1))
    cos = np.einsum("ij,ij->i", fn[owner[pair]], fn[owner[pair + 1]])
    turn = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
    tree = cKDTree(v[e[pair]].mean(axis=1))
    t = np.linspace(0.1, 0.9, 20)[:, None]
    near = tree.query_ball_point(np.asarray(a) + t * (np.asarray(b) - np.asarray(a)), reach)
    return np.array([turn[k].max() if k else 0.0 for k in near])


@pytest.fixture(scope="module")
def tiled(tmp_path_factory):
    """The L-block fitted in 0.5 tiles (3 of them) into an OBJ (60 steps: 10 s, not 15)."""
    d = tmp_path_factory.mktemp("tiled_creases")
    cfg = with_values(ReconConfig(), tiling={"size": 0.5}, dynamics={"max_steps": 60})
    result = fit_tiled(LBLOCK, d / "m.obj", cfg, jobs=2)
    return d, result.report


def test_a_tiled_report_says_its_crease_statistics_are_not_measured(tiled):
    """Regression: the tiled report had no ``creases`` section (an untiled report then means
    creases.enabled is off) and its summary no line on them."""
    _, report = tiled
    cr = report["creases"]
    assert cr["angle_deg"] == 50.0
    for key in ("length", "length_relative", "corners", "crease_points", "corner_points"):
        assert cr[key] is None, key  # not measured, not a wrong number
    assert "not measured" in cr["note"]
    per_tile = report["tiles"]["per_tile"]
    # the crease particles of the mesh, each counted once (by the tile whose core holds it)
    assert 0 < cr["crease_particles"] <= sum(t["crease_particles"] for t in per_tile)
    summary = format_tiled_summary(report)
    line = next(s for s in summary.splitlines() if "sharp features" in s)
    assert f"{cr['crease_particles']:,} crease particles" in line
    assert "not measured" in line


def test_the_tiled_summary_says_what_the_fit_did_with_the_creases(tiled):
    _, report = tiled
    config = report["config"]

    def line(**changes):
        summary = format_tiled_summary({**report, **changes})
        return next((s for s in summary.splitlines() if "sharp features" in s), None)

    assert "kept sharp" in line()
    off = {**config, "creases": {**config["creases"], "fit": False}}
    assert "creases.fit is off, the mesh rounds them" in line(config=off)
    none = {**report["creases"], "crease_particles": 0}
    assert "none fitted at 50 deg" in line(creases=none)
    assert line(creases=None) is None  # detection off: no line, as an untiled fit's summary


def test_a_crease_near_a_seam_stays_sharp_in_both_tiles_at_the_default_halo(tiled):
    """Regression: the tile of x >= 0.5 detected the creases on its core and halo (4 r0)
    alone, missed the lines along y = 0 that its neighbour found, and its fit rounded them
    past the seam (45 and 70 deg; 7 crease particles unmatched, a warning to raise the halo
    to 19 r0). Its detection now reads the points within the crease reach, its fit the
    halo's."""
    d, report = tiled
    v, f = read_mesh(d / "m.obj")
    r0 = report["spacing"]
    for z in (0.0, 0.5):  # the bottom and top lines along y = 0, on both sides of x = 0.5
        left = _edge_turns(v, f, [0.0, 0, z], [0.45, 0, z], r0)
        right = _edge_turns(v, f, [0.55, 0, z], [1.0, 0, z], r0)
        assert np.median(left) > 80.0 and np.median(right) > 80.0, (z, left, right)
    cr = report["creases"]
    assert cr["unmatched_at_seams"] == 0
    assert not [w for w in report["warnings"] if "crease" in w and "seam" in w]
    assert report["tiles"]["halo"] == pytest.approx(4 * r0)  # the fit's halo did not grow
    assert cr["reach"] > 3 * report["tiles"]["halo"]


def _lblock_grid():
    """The L-block sample as a tiled fit in 0.5 tiles sees it: its points, the configuration
    (``normals.k`` resolved for the whole scan), the grid (halo 4 r0) and the crease reach."""
    from scipy.spatial import cKDTree

    from recon.fitting.scale import choose_spacing, with_neighborhood_size
    from recon.io import read_points
    from recon.tiling.run import crease_reach

    cloud = read_points(LBLOCK)
    pts = cloud.absolute_points()
    cfg = with_neighborhood_size(cloud.points, ReconConfig())
    r0, _ = choose_spacing(cloud.points, cfg)
    d6 = float(np.median(cKDTree(pts).query(pts, 7)[0][:, -1]))  # as the tiled fit's
    grid = TileGrid.cover(pts.min(axis=0), pts.max(axis=0), 0.5, cfg.tiling.halo * r0)
    return pts, cfg, r0, grid, crease_reach(cfg, d6, r0)


def test_a_tiles_crease_detection_labels_its_core_and_halo_as_the_untiled_one():
    """The tile of x >= 0.5, y < 0.5: on its core and halo alone the detection labelled 80 of
    its 1,661 points otherwise than the untiled detection (the lines along y = 0 near the
    seam); on the points within the crease reach, none."""
    from recon.creases import SMOOTH
    from recon.fitting.wide_creases import creases_around, detect_fit_creases
    from recon.io import cloud_from_arrays

    pts, cfg, r0, grid, reach = _lblock_grid()
    tile = int(grid.cell_of(np.array([[0.75, 0.25, 0.25]]))[0])
    fit, wide = grid.in_halo_box(tile, pts), grid.in_halo_box(tile, pts, reach)
    assert reach > 4 * grid.halo and wide.sum() > 1.5 * fit.sum()
    untiled = detect_fit_creases(cloud_from_arrays(pts), cfg).labels[fit] != SMOOTH
    here = cloud_from_arrays(pts[fit])
    alone = detect_fit_creases(here, cfg).labels != SMOOTH
    lo, hi = grid.core(tile)
    box = (lo - grid.halo, hi + grid.halo)
    found = creases_around(here, cloud_from_arrays(pts[wide]), cfg, box)
    assert np.count_nonzero(alone != untiled) > 50
    assert np.array_equal(found.labels != SMOOTH, untiled)
    # feet and corners in the tile cloud's coordinates: on the block's edges (two of their
    # coordinates on the faces' planes), the corners in the core and halo
    faces = [np.array([0.0, 0.4, 1.0]), np.array([0.0, 0.4, 0.8]), np.array([0.0, 0.5])]
    for p in (found.foot[found.labels == 1], found.corners):
        p = p + here.origin
        on = sum(np.abs(p[:, [j]] - faces[j]).min(axis=1) < r0 for j in range(3))
        assert len(p) and np.all(on >= 2), p[on < 2]
    corners = found.corners + here.origin
    assert np.all((corners >= box[0]) & (corners < box[1]))


def test_creases_given_to_a_particle_fit_are_those_it_detects_itself():
    """``fit_particles(creases=...)`` (a tile's wider detection) takes the creases in the
    cloud's rows: given its own detection, the particle sheet is the same to the bit."""
    from recon.fitting.pipeline import fit_particles
    from recon.fitting.wide_creases import detect_fit_creases
    from recon.io import cloud_from_arrays

    pts, cfg, r0, grid, _ = _lblock_grid()
    cfg = with_values(cfg, seeds={"spacing": r0}, dynamics={"max_steps": 30})
    tile = int(grid.cell_of(np.array([[0.75, 0.25, 0.25]]))[0])
    rows = np.flatnonzero(grid.in_halo_box(tile, pts))
    rows = rows[np.random.default_rng(0).permutation(len(rows))]  # any row order
    here = cloud_from_arrays(pts[rows])
    own = fit_particles(here, cfg)
    given = fit_particles(here, cfg, creases=detect_fit_creases(here, cfg))
    assert own.crease.sum() > 50
    assert np.array_equal(own.positions, given.positions)
    assert np.array_equal(own.crease, given.crease)


def test_a_crease_one_tile_found_and_its_neighbour_missed_is_warned_of(tmp_path):
    """The safety net: unmatched crease particles at the seams are counted in the report's
    section and warned of, with the halo that would keep them."""
    from recon.tiling.records import TileRecords
    from recon.tiling.run import _crease_section

    grid = TileGrid.cover(np.zeros(3), np.ones(3), 0.5, 0.067)
    cfg = ReconConfig()
    section, warnings = _crease_section(cfg, TileRecords(grid), 7, 0.036, 0.0167, False)
    assert section["unmatched_at_seams"] == 7
    warning = next(w for w in warnings if "crease" in w and "seam" in w)
    assert warning.startswith("7 crease particles") and "--set tiling.halo=19" in warning
    assert f"reads {section['reach']:.3g} around a tile" in warning
    assert _crease_section(cfg, TileRecords(grid), 0, 0.036, 0.0167, False)[1] == []


def test_a_tiled_obj_warns_that_its_normals_are_not_split_at_the_creases(tiled):
    """An untiled OBJ gets one normal per face corner, split at the creases; the tiled writer
    writes one per vertex (averaged across the crease)."""
    d, report = tiled
    assert any("OBJ" in w and "normals" in w for w in report["warnings"])
    text = (d / "m.obj").read_text().splitlines()
    assert sum(s.startswith("vn ") for s in text) == sum(s.startswith("v ") for s in text)


def test_split_ply_is_refused_by_a_tiled_fit_before_any_work(tmp_path):
    """Regression: ``creases.split_ply`` was ignored silently (a welded PLY, no word of it)."""
    out = tmp_path / "m.ply"
    res = _run(["fit", str(LBLOCK), "-o", str(out), "--tile-size", "0.5",
                "--set", "creases.split_ply=true"])  # fmt: skip
    assert res.exit_code == 2, res.output
    assert "creases.split_ply" in res.stderr and "tile" in res.stderr
    assert list(tmp_path.iterdir()) == []


def test_split_ply_is_not_refused_where_it_does_not_apply(tmp_path):
    cfg = with_values(ReconConfig(), tiling={"auto": True}, creases={"split_ply": True})
    # --tiles auto that finds one fit enough: the untiled fit splits the PLY
    assert fit_tiled(LBLOCK, tmp_path / "m.ply", cfg) is None
    # an OBJ (corner normals, no split) or crease detection off: nothing to refuse
    for over in ({"split_ply": True}, {"split_ply": True, "enabled": False}):
        cfg = with_values(ReconConfig(), tiling={"size": 0.5}, creases=over)
        out = "m.obj" if "enabled" not in over else "n.ply"
        from recon.tiling import run

        run._check_crease_outputs(tmp_path / out, cfg)  # no error


def test_unmatched_crease_particles_compare_both_sides_of_a_seam():
    """Two tiles side by side (x < 1 and x >= 1), r0 0.1: a crease line along x at y = z = 0.
    Tile 0 found it (crease particles up to its halo), tile 1 found it only where asked."""
    from recon.tiling.stitch import unmatched_crease_particles

    grid = TileGrid.cover(np.zeros(3), np.array([2.0, 1.0, 1.0]), 1.0, 0.2)
    r0 = 0.1
    line = np.column_stack([np.arange(0.0, 2.0, r0), np.zeros(20), np.zeros(20)])

    def border(tile, found_by_1):
        own = grid.in_core(tile, line)
        near = grid.in_halo_box(tile, line, 1.5 * r0)
        crease = np.ones(len(line), bool) if tile == 0 or found_by_1 else np.zeros(len(line), bool)
        return {
            "in": (line[own], crease[own]),
            "out": (line[near & ~own], crease[near & ~own]),
        }

    for found_by_1, expected in ((True, 0), (False, 2)):
        b = {t: border(t, found_by_1) for t in (0, 1)}
        n = unmatched_crease_particles(
            grid, {t: b[t]["in"] for t in b}, {t: b[t]["out"] for t in b}, r0, depth=2.25
        )
        # missed by tile 1: tile 0's halo particles at x = 1.0 and 1.1 have no counterpart
        assert n == expected


def test_the_tiled_report_is_json_with_the_creases_section(tiled):
    d, report = tiled
    on_disk = json.loads((d / "m.report.json").read_text())
    assert on_disk["creases"] == report["creases"]
