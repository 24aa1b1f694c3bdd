"""`oprecon remesh` end to end through click's runner."""

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from recon.cli.main import app

from recon.io import read_mesh, write_mesh
from recon.topology import mesh_topology

SAMPLE = Path("sample_data/lblock-gt.ply")


def _run(args):
    return CliRunner().invoke(app, args, catch_exceptions=False)


def test_remesh_sample_with_creases_writes_mesh_and_report(tmp_path):
    out = tmp_path / "clean.ply"
    res = _run(["remesh", str(SAMPLE), "-o", str(out), "--crease-angle", "40"])
    assert res.exit_code == 0, res.output
    assert "topology" in res.stderr and "preserved" in res.stderr
    assert "min angle mean" in res.stderr
    v, f = read_mesh(out)
    assert len(f) > 1000
    topo = mesh_topology(v, f)
    assert topo["watertight"] and topo["genus"] == 0
    report = json.loads((tmp_path / "clean.report.json").read_text())
    assert report["topology_preserved"] is True
    assert report["output"]["topology"]["n_faces"] == len(f)
    assert report["features"]["corners"] == 12
    # every crease kept: triangles never span one (patches are meshed on their own)
    assert report["features"]["deviation_max_relative"] < 5e-4
    assert report["distance"]["hausdorff95_relative"] < 1e-3
    q_in, q_out = report["input"]["triangle_quality"], report["output"]["triangle_quality"]
    assert q_out["min_angle_mean_deg"] > q_in["min_angle_mean_deg"]


def test_remesh_json_and_faces(tmp_path):
    out = tmp_path / "m.obj"
    res = _run(["remesh", str(SAMPLE), "-o", str(out), "--faces", "2000", "--json", "-q"])
    assert res.exit_code == 0, res.output
    report = json.loads(res.stdout)
    assert abs(report["output"]["topology"]["n_faces"] - 2000) <= 100
    assert res.stderr == ""


def test_point_cloud_input_is_refused(tmp_path):
    out = tmp_path / "o.ply"
    res = _run(["remesh", "sample_data/sphere-sparse.ply", "-o", str(out)])
    assert res.exit_code == 2
    assert "sphere-sparse.ply" in res.stderr and "no faces" in res.stderr
    assert "Traceback" not in res.output
    assert not out.exists() and not (tmp_path / "o.report.json").exists()


def test_non_manifold_input_is_refused_and_nothing_written(tmp_path):
    src = tmp_path / "nm.ply"
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1]], float)
    write_mesh(src, v, np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]]))
    out = tmp_path / "o.ply"
    res = _run(["remesh", str(src), "-o", str(out)])
    assert res.exit_code == 2
    assert "nm.ply" in res.stderr and "non-manifold" in res.stderr
    assert list(tmp_path.iterdir()) == [src]


def test_usage_errors(tmp_path):
    out = str(tmp_path / "o.ply")
    res = _run(["remesh", str(SAMPLE), "-o", out, "--spacing", "0.1", "--faces", "100"])
    assert res.exit_code == 2 and "exclusive" in res.output
    res = _run(["remesh", str(SAMPLE), "-o", out, "--min-spacing", "0.1"])
    assert res.exit_code == 2 and "--adaptive" in res.output
    res = _run(["remesh", str(tmp_path / "missing.ply"), "-o", out])
    assert res.exit_code == 2 and "missing.ply" in res.stderr
    res = _run(["remesh", str(SAMPLE), "-o", str(SAMPLE)])
    assert res.exit_code == 2


def test_help_lists_remesh():
    res = _run(["--help"])
    assert "oprecon remesh" in res.output


def test_output_format_is_checked_before_work(tmp_path):
    res = _run(["remesh", str(SAMPLE), "-o", str(tmp_path / "m.xyz")])
    assert res.exit_code == 2 and "m.xyz" in res.stderr and ".ply or .obj" in res.stderr


def test_changed_topology_is_written_and_exits_1(tmp_path, monkeypatch):
    import recon.remesh as remesh_pkg
    from recon.remesh.pipeline import remesh_file

    def changed(*args, **kwargs):
        result = remesh_file(*args, **kwargs)
        result.report["topology_preserved"] = False
        result.report["warnings"].append("topology changed: (test)")
        return result

    monkeypatch.setattr(remesh_pkg, "remesh_file", changed)
    out = tmp_path / "m.ply"
    res = _run(["remesh", str(SAMPLE), "-o", str(out), "--spacing", "0.1"])
    assert res.exit_code == 1
    assert out.exists() and "topology changed" in res.stderr


def test_a_spacing_too_small_is_refused_before_the_work(tmp_path):
    res = _run(["remesh", str(SAMPLE), "-o", str(tmp_path / "m.ply"), "--spacing", "1e-5"])
    assert res.exit_code == 2 and "particles" in res.stderr and "--spacing" in res.stderr
    assert not (tmp_path / "m.ply").exists()


def test_a_first_run_says_it_compiles_the_step_kernel_first(tmp_path, monkeypatch):
    import recon.remesh
    from recon.errors import OpreconError
    from recon.kernels import warm

    asked = []

    def uncached(names=warm.FIT_KERNELS):
        asked.append(tuple(names))
        return list(names)

    def stop(*args, **kwargs):
        raise OpreconError("stopped before the remesh")

    monkeypatch.setattr(warm, "uncached", uncached)
    monkeypatch.setattr(recon.remesh, "remesh_file", stop)
    res = _run(["remesh", str(SAMPLE), "-o", str(tmp_path / "m.ply")])
    assert res.exit_code == 2
    assert res.stderr.index("compiling the numba kernels first") < res.stderr.index("stopped")
    assert asked == [("pair_loop.step_particles",)]  # the kernels a remesh calls, not a fit's


def test_a_first_runs_summary_says_its_times_include_the_compile(tmp_path, monkeypatch):
    from recon.kernels import warm

    for uncached, extra, said in ((True, (), True), (False, (), False), (True, ("-q",), False)):
        monkeypatch.setattr(warm, "uncached", lambda names=(), u=uncached: list(names) * u)
        out = tmp_path / "m.ply"
        res = _run(["remesh", str(SAMPLE), "-o", str(out), "--faces", "2000", *extra])
        assert res.exit_code == 0, res.output
        assert ("compiling the numba kernels first" in res.stderr) is said
        assert ("include compiling the numba kernels" in res.stderr) is said


def _unit_cube(tmp_path: Path) -> Path:
    """The 12-triangle unit cube of open3d's ``create_box`` (a coarse CAD mesh)."""
    import open3d as o3d

    box = o3d.geometry.TriangleMesh.create_box()
    path = tmp_path / "cube.ply"
    write_mesh(path, np.asarray(box.vertices, dtype=np.float64), np.asarray(box.triangles))
    return path


def test_a_coarse_cad_cube_is_remeshed_at_the_defaults(tmp_path):
    """Regression: the 12-triangle unit cube failed at the default spacing, its mean edge
    length 1.14 ("the remeshed surface has no faces; the spacing 1.13807 is too large"). The
    default spacing is now at most a tenth of the bounding-box diagonal."""
    src, out = _unit_cube(tmp_path), tmp_path / "out.ply"
    res = _run(["remesh", str(src), "-o", str(out)])
    assert res.exit_code == 0, res.output
    v, f = read_mesh(out)
    topo = mesh_topology(v, f)
    assert topo["watertight"] and topo["components"] == 1 and topo["genus"] == 0
    assert len(f) > 300
    report = json.loads((tmp_path / "out.report.json").read_text())
    assert report["topology_preserved"] is True
    assert report["spacing"] == pytest.approx(0.1 * 3**0.5)
    assert report["distance"]["hausdorff_relative"] < 0.1
    # every vertex lies on the cube's surface (one coordinate at 0 or 1, all within [0, 1])
    assert np.abs(v - 0.5).max(axis=1) == pytest.approx(np.full(len(v), 0.5), abs=1e-9)
    # sharp edges and corners are kept with --crease-angle (not by default, as documented):
    # then at the same default spacing the 8 corners are exact
    res = _run(["remesh", str(src), "-o", str(out), "--crease-angle", "40"])
    assert res.exit_code == 0, res.output
    v, f = read_mesh(out)
    assert mesh_topology(v, f)["watertight"] and len(f) > 300
    corners = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], float)
    assert np.linalg.norm(v[None] - corners[:, None], axis=2).min(axis=1).max() < 1e-9


def test_an_explicit_spacing_too_coarse_for_the_mesh_is_still_refused(tmp_path):
    """Only the default spacing is bounded by the diagonal; a given one is the user's."""
    out = tmp_path / "out.ply"
    res = CliRunner().invoke(
        app, ["remesh", str(_unit_cube(tmp_path)), "-o", str(out), "--spacing", "2"]
    )
    assert res.exit_code == 2
    assert "the remeshed surface has no faces" in res.stderr and "Traceback" not in res.output
    assert not out.exists()


@pytest.mark.parametrize("option", [["--spacing", "0.05"], ["--faces", "5000"]])
def test_an_open_box_keeps_its_open_side(tmp_path, option):
    """Regression: the gap closing zipped every loop not made of the input's boundary
    particles alone; where the triangulation cut inside the rim, the rim's loop held a few
    other particles and was zipped into a lid (an open box came out closed, a fitted face
    scan grew a back sheet 0.11 of its diagonal away). A loop mostly on the rim is the rim."""
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0],
                  [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]], dtype=float)  # fmt: skip
    f = np.array([[0, 3, 2], [0, 2, 1], [0, 1, 5], [0, 5, 4], [1, 2, 6],
                  [1, 6, 5], [2, 3, 7], [2, 7, 6], [3, 0, 4], [3, 4, 7]])  # fmt: skip
    src = tmp_path / "openbox.ply"
    write_mesh(src, v, f)
    out = tmp_path / "r.ply"
    res = _run(["remesh", str(src), "-o", str(out), *option])
    assert res.exit_code == 0, res.output
    topo = mesh_topology(*read_mesh(out)[:2])
    assert topo["boundary_loops"] == 1 and topo["components"] == 1, topo


@pytest.mark.parametrize("spacing", ["0.1", "0.2"])
def test_two_disjoint_tetrahedra_stay_two(tmp_path, spacing):
    """Regression: two disjoint tetrahedra at --spacing 0.1 came out as 4 closed components
    (0.2: 5 and 2 loops), exit 1. Each component is a patch of its own; triangles over the
    sharp edges (no crease angle given) lie off the surface and were dropped as if they
    bridged a patch's reflex corner, and gap closing capped the torn pieces one by one."""
    from tests.mesh_shapes import tetrahedron

    v, f = tetrahedron()
    src = tmp_path / "two.ply"
    write_mesh(src, np.vstack([v, v + [3.0, 0.0, 0.0]]), np.vstack([f, f + 4]))
    out = tmp_path / "r.ply"
    res = _run(["remesh", str(src), "-o", str(out), "--spacing", spacing])
    assert res.exit_code == 0, res.output
    v2, f2 = read_mesh(out)[:2]
    topo = mesh_topology(v2, f2)
    assert topo["components"] == 2 and topo["watertight"] and topo["genus"] == 0, topo
    assert topo["euler_characteristic"] == 4
    # each tetrahedron is remeshed over its own surface
    left = v2[:, 0] < 1.5
    assert np.abs(v2[left].min(axis=0)).max() < 1e-9
    assert np.abs(v2[~left].min(axis=0) - [3.0, 0.0, 0.0]).max() < 1e-9
