"""The fit report's warnings about a poor mesh (recon.fitting.mesh_warnings)."""

from __future__ import annotations

import json

import numpy as np
from click.testing import CliRunner
from mesh_shapes import icosphere
from recon.cli.fit import format_summary
from recon.cli.main import app

import recon
from recon.fitting.mesh_warnings import (
    FAR_DATA_R0,
    FRAGMENT_COMPONENTS,
    MIN_VERTEX_SHARE,
    crossing_warning,
    far_data_warning,
    fragment_warning,
    mesh_warnings,
)
from recon.fitting.report import Fidelity, FitReport, Topology, TriangulationStats
from recon.io import write_mesh
from recon.winding import MIN_COMPONENT_FACES


def topology(components: int = 1, faces: int = 20_000, vertices: int = 10_002) -> Topology:
    return Topology(
        n_vertices=vertices,
        n_faces=faces,
        n_edges=faces * 3 // 2,
        components=components,
        boundary_edges=0,
        boundary_loops=0,
        non_manifold_edges=0,
        non_manifold_vertices=0,
        watertight=True,
        orientable=True,
        consistently_oriented=True,
        euler_characteristic=2 * components,
        genus=0,
        degenerate_faces=0,
        duplicate_faces=0,
        unreferenced_vertices=0,
    )


def fidelity(p95: float, within_r0: float = 1.0) -> Fidelity:
    return Fidelity(
        diag=1.0,
        n=1000,
        mean=p95 / 3,
        rms=p95 / 2,
        p95=p95,
        max=2 * p95,
        mean_relative=p95 / 3,
        rms_relative=p95 / 2,
        p95_relative=p95,
        max_relative=2 * p95,
        within_r0=within_r0,
    )


def stats(left: int = 0, found: int = 0) -> TriangulationStats:
    return TriangulationStats(
        method="ball_pivot",
        faces_raw=20_000,
        faces_manifold=20_000,
        holes_filled=0,
        small_components_removed=0,
        self_intersections_found=found,
        self_intersections_left=left,
    )


# --------------------------------------------------------------------------------------------
# one rule at a time, at its boundary


def test_crossing_warning_fires_on_one_pair_left_and_names_the_counts():
    assert crossing_warning(0, 12) is None
    w = crossing_warning(1, 12)
    assert w is not None and "has 1 self-crossing face pair left after untangling (12 found)" in w
    assert "CGAL" in w and "--spacing" in w
    assert "has 3 self-crossing face pairs:" in crossing_warning(3)
    assert "untangling" not in crossing_warning(3)  # found unknown: not named
    assert crossing_warning(3, hint="repair it").endswith("reject it; repair it")


def test_fragment_warning_at_the_mean_component_size_of_debris():
    n = FRAGMENT_COMPONENTS
    limit = MIN_COMPONENT_FACES * n  # mean component of exactly the debris size: quiet
    assert fragment_warning(n, limit, limit, limit) is None
    w = fragment_warning(n, limit - 1, limit, limit)
    assert w is not None and f"falls apart into {n} components" in w and "--max-gap" in w
    # fewer components than "many": a small mesh, not a fragmented one
    assert fragment_warning(n - 1, 10, 10, 10) is None


def test_fragment_warning_at_the_share_of_particles_meshed():
    particles = 1000
    at = int(MIN_VERTEX_SHARE * particles)
    assert fragment_warning(1, 20_000, at, particles) is None
    w = fragment_warning(1, 20_000, at - 1, particles)
    assert w is not None and f"{at - 1} vertices from 1,000 fitted particles" in w
    assert fragment_warning(1, 20_000, 10, 0) is None  # particles unknown: not judged


def test_fragment_warning_names_both_defects_in_one_sentence():
    w = fragment_warning(100, 400, 500, 8000)
    assert w is not None and w.count("--spacing") == 1
    assert "100 components of 4 faces" in w and "500 vertices from 8,000" in w


def test_separate_objects_with_real_shares_are_not_fragments():
    # two objects, and ten, each with thousands of faces: legitimate components
    assert fragment_warning(2, 30_000, 15_000, 15_000) is None
    assert fragment_warning(10, 10 * 2_000, 10 * 1_002, 10 * 1_002) is None


def test_far_data_warning_at_its_distance():
    r0 = 0.01
    assert far_data_warning(FAR_DATA_R0 * r0, 0.9, r0) is None
    w = far_data_warning(FAR_DATA_R0 * r0 * 1.01, 0.42, r0)
    assert w is not None and "farther than 3.0 r0" in w and "only 42% lie within r0" in w
    assert "remove outliers" in w
    assert far_data_warning(None, None, r0) is None  # not measured


def test_mesh_warnings_reads_sections_and_plain_dicts_alike():
    good = mesh_warnings(topology(), stats(), particles=10_000, r0=0.01, fidelity=fidelity(0.005))
    assert good == ()
    bad_args = (topology(components=30, faces=300, vertices=400), stats(left=7, found=40))
    bad = mesh_warnings(*bad_args, particles=5000, r0=0.01, fidelity=fidelity(0.2, 0.1))
    assert len(bad) == 3
    assert "7 self-crossing" in bad[0] and "falls apart" in bad[1] and "20.0 r0" in bad[2]
    plain = mesh_warnings(
        bad_args[0].to_dict(),
        bad_args[1].to_dict(),
        particles=5000,
        r0=0.01,
        fidelity=fidelity(0.2, 0.1).to_dict(),
    )
    assert plain == bad
    # no fidelity measured: that rule skipped
    no_fidelity = mesh_warnings(
        bad_args[0].to_dict(), bad_args[1].to_dict(), particles=5000, r0=0.01
    )
    assert no_fidelity == bad[:2]
    # a tiled fit: no crossing counts either (the tiles' include their halos)
    assert mesh_warnings(bad_args[0].to_dict(), {}, particles=5000, r0=0.01) == bad[1:2]


# --------------------------------------------------------------------------------------------
# end to end


def scan_lines(rings: int, per_ring: int, seed: int) -> np.ndarray:
    """LiDAR-like rings of points on the unit sphere, random longitudes on each."""
    rng = np.random.default_rng(seed)
    rows = []
    for lat in np.linspace(-1.4, 1.4, rings):
        lon = rng.uniform(0.0, 2.0 * np.pi, per_ring)
        rows.append(
            np.c_[
                np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.full(per_ring, np.sin(lat))
            ]
        )
    return np.vstack(rows)


def test_a_fit_that_falls_apart_says_so_in_report_and_summary():
    # rings 0.19 apart, a spacing of 0.03 and gaps of at most 4 r0: the sheet cannot join the
    # rings, the mesh is a scatter of small pieces far from most of the data
    res = recon.fit(scan_lines(16, 125, seed=2), {"seeds.spacing": 0.03, "growth.max_gap": 4.0})
    rep = res.report
    assert rep.topology.components >= FRAGMENT_COMPONENTS
    falls_apart = [w for w in rep.warnings if w.startswith("the mesh falls apart")]
    far = [w for w in rep.warnings if "input points lie farther than" in w]
    assert len(falls_apart) == 1 and len(far) == 1
    summary = format_summary(rep)
    assert f"  warning: {falls_apart[0]}" in summary and f"  warning: {far[0]}" in summary
    assert FitReport.from_dict(rep.to_dict()).warnings == rep.warnings


def test_a_sound_fit_has_no_mesh_warnings():
    rng = np.random.default_rng(0)
    p = rng.normal(size=(2000, 3))
    res = recon.fit(p / np.linalg.norm(p, axis=1, keepdims=True))
    rep = res.report
    assert rep.topology.components == 1
    assert (
        mesh_warnings(
            rep.topology,
            rep.triangulation,
            particles=rep.particles,
            r0=rep.spacing,
            fidelity=rep.fidelity,
        )
        == ()
    )


def test_report_command_warns_about_crossings(tmp_path):
    v, f = icosphere(2)
    sound, crossing = tmp_path / "sound.ply", tmp_path / "crossing.ply"
    write_mesh(sound, v, f)
    # a second sphere through the first: face pairs crossing on their common circle
    write_mesh(crossing, np.vstack([v, v + [1.0, 0, 0]]), np.vstack([f, f + len(v)]))
    r = CliRunner().invoke(app, ["report", str(sound)])
    assert r.exit_code == 0, r.output
    assert "warning" not in r.output
    r = CliRunner().invoke(app, ["report", str(crossing)])
    assert r.exit_code == 0, r.output
    lines = [x for x in r.stdout.splitlines() if x.startswith("  warning: the mesh has")]
    assert len(lines) == 1 and "self-crossing face pairs" in lines[0] and "repair" in lines[0]
    r = CliRunner().invoke(app, ["report", str(crossing), "--json"])
    assert r.exit_code == 0, r.output
    n = json.loads(r.stdout)["self_intersections"]
    assert f"the mesh has {n:,} self-crossing face pairs" in r.stderr
