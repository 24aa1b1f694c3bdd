"""The fit report's warnings about a poor mesh (recon.fitting.mesh_warnings)."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
from click.testing import CliRunner
from mesh_shapes import icosphere
from recon.cli.fit import format_summary
from recon.cli.main import app

import recon
import recon.thinning
from recon.fitting.mesh_warnings import (
    FAR_DATA_R0,
    FRAGMENT_COMPONENTS,
    MIN_LARGEST_SHARE,
    MIN_ON_DATA,
    MIN_VERTEX_SHARE,
    PIECES_COMPONENTS,
    crossing_warning,
    facing_warning,
    far_data_warning,
    fit_warnings,
    fragment_warning,
    largest_component_faces,
    mesh_warnings,
    off_data_warning,
)
from recon.fitting.report import (
    Fidelity,
    FitReport,
    MeshMeasures,
    MeshToInput,
    Topology,
    TriangleQuality,
    TriangulationStats,
)
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


def mesh_to_input(within_reach: float, reach: float = 0.01) -> MeshToInput:
    return MeshToInput(
        n=1000,
        mean=reach / 3,
        rms=reach / 2,
        p95=reach,
        max=2 * reach,
        mean_relative=reach / 3,
        rms_relative=reach / 2,
        p95_relative=reach,
        max_relative=2 * reach,
        within_r0=within_reach,
        reach=reach,
        within_reach=within_reach,
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
    # two objects, and ten, each with thousands of faces: not debris (ten of a tenth each are
    # warned about once their largest is counted: test_pieces_warning_...)
    assert fragment_warning(2, 30_000, 15_000, 15_000) is None
    assert fragment_warning(10, 10 * 2_000, 10 * 1_002, 10 * 1_002) is None


def test_pieces_warning_at_the_largest_components_share():
    n, faces = PIECES_COMPONENTS, 30_000
    at = int(np.ceil(MIN_LARGEST_SHARE * faces))  # the largest holds exactly the share: quiet
    assert fragment_warning(n, faces, faces // 2, faces // 2, at) is None
    w = fragment_warning(n, faces, faces // 2, faces // 2, at - 1)
    assert w is not None and f"falls apart into {n} components, the largest holding only 67%" in w
    assert "separate objects" in w and "--max-gap" in w
    assert "on average" not in w  # its pieces are not debris
    # fewer components: maybe as many separate objects, whatever their shares
    assert fragment_warning(n - 1, faces, faces // 2, faces // 2, faces // n) is None
    # the largest component not counted: that rule skipped
    assert fragment_warning(n, faces, faces // 2, faces // 2, None) is None


def test_pieces_and_debris_in_one_sentence():
    # 35 pieces of 628 faces on average (above the debris size), the largest 23.5 % of them
    w = fragment_warning(35, 21_993, 12_000, 12_000, 5_178)
    assert w is not None and "35 components, the largest holding only 24% of the faces" in w
    # 100 pieces of debris, the largest 10 %: both said once
    w = fragment_warning(100, 4_000, 3_000, 3_000, 400)
    assert w is not None and w.count("falls apart") == 1 and w.count("--spacing") == 1
    assert "100 components of 40 faces on average" in w and "the largest holding only 10%" in w


def test_a_few_separate_objects_are_not_pieces():
    # three objects of a third each, four of a quarter: legitimate components
    assert fragment_warning(3, 30_000, 15_000, 15_000, 10_000) is None
    assert fragment_warning(4, 40_000, 20_000, 20_000, 10_000) is None
    # a main part with small non-debris pieces beside it that hold less than a third
    assert fragment_warning(40, 30_000, 15_000, 15_000, 20_001) is None


def test_largest_component_faces_counts_faces_through_shared_vertices():
    # a strip of 3 faces, a bow-tie of 2 (joined at vertex 8) and a lone face
    f = [[0, 1, 2], [1, 2, 3], [2, 3, 4], [5, 6, 8], [8, 9, 10], [11, 12, 13]]
    assert largest_component_faces(f) == 3
    assert largest_component_faces(np.asarray(f)[3:]) == 2
    assert largest_component_faces(np.zeros((0, 3), dtype=np.int64)) == 0


def test_off_data_warning_at_its_share():
    r0 = 0.01
    assert off_data_warning(MIN_ON_DATA, r0, r0) is None
    w = off_data_warning(0.587, 0.02, r0)
    assert w is not None and "only 58.7% of the mesh surface lies within reach (0.02, 2.0 r0)" in w
    assert "--max-gap" in w and "bridges gaps" in w
    w = off_data_warning(np.nextafter(MIN_ON_DATA, 0.0), r0, r0)
    assert w is not None and "only 66.7%" in w
    assert off_data_warning(None, None, r0) is None  # not measured


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


def test_mesh_warnings_reads_the_mesh_on_the_data_and_the_largest_component():
    topo, r0 = topology(components=PIECES_COMPONENTS, faces=30_000), 0.01
    kw = {"particles": 15_000, "r0": r0, "fidelity": fidelity(0.005)}
    assert (
        mesh_warnings(topo, stats(), mesh_to_input=mesh_to_input(0.99), largest=29_000, **kw) == ()
    )
    both = mesh_warnings(topo, stats(), mesh_to_input=mesh_to_input(0.6), largest=9_000, **kw)
    assert len(both) == 2
    assert "the largest holding only 30%" in both[0] and "only 60.0% of the mesh" in both[1]
    plain = mesh_warnings(
        topo.to_dict(), {}, mesh_to_input=mesh_to_input(0.6).to_dict(), largest=9_000, **kw
    )
    assert plain == both


def measures(components: int, faces: int, within_reach: float) -> MeshMeasures:
    quality = TriangleQuality(1, *[1.0] * 9)
    topo = topology(components=components, faces=faces, vertices=faces)
    return MeshMeasures(topo, quality, 1.0, fidelity(0.001), mesh_to_input(within_reach))


def strip(n: int, first: int) -> list[list[int]]:
    """A strip of ``n`` triangles on the vertices ``first .. first + n + 1``."""
    return [[first + i, first + i + 1, first + i + 2] for i in range(n)]


def test_fit_warnings_counts_the_largest_component_from_the_faces():
    # a main strip of 120 faces and 5 strips of 60 (above the debris size): 6 components, the
    # largest 120 / 420 of the faces
    faces = np.array(strip(120, 0) + sum((strip(60, 200 + 100 * i) for i in range(5)), []))
    m = measures(6, len(faces), 0.99)
    tri = SimpleNamespace(stats={}, faces=faces, vertices=np.zeros((800, 3)))
    w = fit_warnings(m, tri, 420, 0.01)
    assert len(w) == 1 and "6 components, the largest holding only 29%" in w[0]
    # fewer components than the rule needs: the faces are not even counted
    assert fit_warnings(measures(4, len(faces), 0.99), tri, 420, 0.01) == ()
    off = fit_warnings(measures(1, len(faces), 0.5), tri, 420, 0.01)
    assert len(off) == 1 and "only 50.0% of the mesh surface" in off[0]


def _valley(n: int = 30) -> tuple[np.ndarray, np.ndarray]:
    """A grid over [-1, 1]^2 lifted to z = x^2, wound to face down (its convex side)."""
    x, y = np.meshgrid(np.linspace(-1, 1, n), np.linspace(-1, 1, n), indexing="ij")
    v = np.column_stack([x.ravel(), y.ravel(), x.ravel() ** 2])
    i = np.arange(n - 1)[:, None] * n + np.arange(n - 1)[None, :]
    i = i.ravel()
    up = np.vstack([np.column_stack([i, i + n, i + 1]), np.column_stack([i + 1, i + n, i + n + 1])])
    return v, up[:, ::-1]


def test_facing_warning_names_an_open_mesh_the_outward_vote_turned_down():
    v, down = _valley()
    outward = {"orientation": "auto", "component_methods": {"outward": 1}}
    w = facing_warning(v, down, 1, outward)
    assert w is not None and "faces down" in w and "--viewpoint" in w
    assert facing_warning(v, down[:, ::-1], 1, outward) is None  # facing up
    assert facing_warning(v, down, 0, outward) is None  # closed: outward is right
    for other in (
        {"orientation": "auto", "component_methods": {"up": 1}},
        {"orientation": "auto", "component_methods": {"viewpoint": 1}},
        {"orientation": "outward", "component_methods": {"outward": 1}},  # asked for
        {},
    ):
        assert facing_warning(v, down, 1, other) is None


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


def test_a_fit_that_falls_apart_says_so_in_report_and_summary(monkeypatch):
    # rings 0.19 apart, a spacing of 0.03 and gaps of at most 4 r0: the sheet cannot join the
    # rings, the mesh is a scatter of small pieces far from most of the data (with the lines
    # thinned as by default it makes no triangle at all: exit 2)
    monkeypatch.setattr(recon.thinning, "LINE_RATIO", np.inf)
    res = recon.fit(scan_lines(16, 125, seed=2), {"seeds.spacing": 0.03, "growth.max_gap": 4.0})
    rep = res.report
    assert rep.topology.components >= FRAGMENT_COMPONENTS
    falls_apart = [w for w in rep.warnings if w.startswith("the mesh falls apart")]
    far = [w for w in rep.warnings if "input points lie farther than" in w]
    assert len(falls_apart) == 1 and len(far) == 1
    summary = format_summary(rep)
    assert f"  warning: {falls_apart[0]}" in summary and f"  warning: {far[0]}" in summary
    assert FitReport.from_dict(rep.to_dict()).warnings == rep.warnings


def test_a_fit_of_many_pieces_says_so_in_the_report():
    # six unit spheres far apart at one spacing: six components of about a sixth of the faces
    # each (more separate objects than the rule lets by), the largest well under 2/3
    rng = np.random.default_rng(1)
    clouds = []
    for i, n in enumerate([1200, 600, 600, 600, 600, 600]):
        p = rng.normal(size=(n, 3))
        clouds.append(p / np.linalg.norm(p, axis=1, keepdims=True) + [5.0 * i, 0.0, 0.0])
    rep = recon.fit(np.vstack(clouds), {"seeds.spacing": 0.1}).report
    assert rep.topology.components == 6
    pieces = [w for w in rep.warnings if "the largest holding only" in w]
    assert len(pieces) == 1 and "6 components" in pieces[0]
    assert not any("falls apart" in w for w in rep.warnings if w not in pieces)


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
            mesh_to_input=rep.mesh_to_input,
            largest=rep.topology.n_faces,
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


def test_a_valley_turned_down_by_the_outward_vote_says_so():
    """A valley (z = x^2, its convex side below) from bare points is signed by the outward
    vote and faces down: the fit says so and names --viewpoint; with a viewpoint above it
    faces up and says nothing."""
    rng = np.random.default_rng(0)
    xy = rng.uniform(-1.0, 1.0, (3000, 2))
    pts = np.column_stack([xy, xy[:, 0] ** 2])
    rep = recon.fit(pts).report
    assert rep.input.normals["component_methods"] == {"outward": 1}
    assert sum("the open mesh faces down" in w for w in rep.warnings) == 1
    rep = recon.fit(pts, {"normals.viewpoint": [0.0, 0.0, 10.0]}).report
    assert not any("faces down" in w for w in rep.warnings)
