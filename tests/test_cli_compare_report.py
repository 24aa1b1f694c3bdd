"""``oprecon compare`` and ``oprecon report`` through click's CliRunner: exit codes 0/1/2, JSON."""

from __future__ import annotations

import json

import matplotlib.image as mpimg
import numpy as np
import pytest
from click.testing import CliRunner
from mesh_shapes import icosphere, open_cylinder, torus
from recon.cli.main import app

from recon.io import write_mesh, write_points

FAST = ["--samples", "5000"]


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("meshes")
    v, f = icosphere(3)
    paths = {
        "sphere": d / "sphere.ply",
        "sphere_obj": d / "sphere.obj",
        "big": d / "big.ply",
        "torus": d / "torus.ply",
        "tube": d / "tube.ply",
        "cloud": d / "cloud.ply",
        "garbage": d / "garbage.ply",
    }
    write_mesh(paths["sphere"], v, f)
    write_mesh(paths["sphere_obj"], v, f)
    write_mesh(paths["big"], v * 1.02, f)
    write_mesh(paths["torus"], *torus(24, 12))
    write_mesh(paths["tube"], *open_cylinder(24, 5))
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(3000, 3))
    pts /= np.linalg.norm(pts, axis=1, keepdims=True)
    write_points(paths["cloud"], pts, pts)
    paths["garbage"].write_bytes(b"ply\nformat nonsense\nend_header\n\x00\x01")
    return paths


def run(*args):
    return CliRunner().invoke(app, [str(a) for a in args])


def one_line_error(result, *needles):
    assert result.exit_code == 2, result.output
    assert "Traceback" not in result.output
    err = result.stderr.strip()
    assert err.startswith("oprecon: error:") or err.startswith("Usage:"), err
    for needle in needles:
        assert needle in result.stderr, result.stderr


# ---------------------------------------------------------------------------- compare


def test_compare_identical_meshes_passes(files):
    r = run("compare", files["sphere"], files["sphere_obj"], *FAST, "--max-chamfer", "1e-6")
    assert r.exit_code == 0, r.output
    assert "Chamfer-L1" in r.stdout and "F-score" in r.stdout
    assert "result: PASS" in r.stdout


def test_compare_json(files):
    r = run("compare", files["sphere"], files["big"], *FAST, "--json")
    assert r.exit_code == 0, r.output
    data = json.loads(r.stdout)
    assert data["reference_kind"] == "mesh"
    assert data["chamfer_l1"] == pytest.approx(0.02, rel=0.02)
    assert data["checks"] == [] and data["passed"] is True
    assert data["n_samples"] == {"mesh": 5000, "reference": 5000}
    assert data["topology"]["mesh"]["genus"] == 0 == data["topology"]["reference"]["genus"]


def test_compare_outside_tolerance_exits_1_with_a_table(files):
    r = run(
        "compare", files["sphere"], files["big"], *FAST,
        "--max-chamfer", "1e-3", "--min-fscore", "0.5", "--max-hausdorff95", "0.5",
    )  # fmt: skip
    assert r.exit_code == 1, r.output
    lines = r.stdout.splitlines()
    failed = [ln for ln in lines if "FAIL" in ln and "chamfer_l1_relative" in ln]
    assert len(failed) == 1 and "--max-chamfer" in failed[0] and "% over" in failed[0]
    assert any("hausdorff95_relative" in ln and " ok" in ln for ln in lines)
    assert "result: FAIL (1 of 3 checks outside tolerance)" in r.stdout


@pytest.mark.parametrize("option", ["--max-chamfer", "--max-chamfer-abs", "--max-hausdorff95"])
def test_a_limit_of_zero_fails_with_the_table_not_a_traceback(files, option):
    """Regression: a check failing against a limit of 0 raised ZeroDivisionError (the
    percentage over the limit) with a traceback and no verdict."""
    r = run("compare", files["sphere"], files["big"], *FAST, option, "0")
    assert r.exit_code == 1, r.output
    assert r.exception is None or isinstance(r.exception, SystemExit), r.exception
    failed = [ln for ln in r.stdout.splitlines() if "FAIL" in ln and option in ln]
    assert len(failed) == 1 and "% over" not in failed[0], r.stdout
    assert "result: FAIL (1 of 1 checks outside tolerance)" in r.stdout


def test_compare_failure_in_json_still_exits_1(files):
    r = run("compare", files["sphere"], files["big"], *FAST, "--max-chamfer-abs", "0.001", "--json")
    assert r.exit_code == 1
    data = json.loads(r.stdout)
    assert data["passed"] is False
    (check,) = data["checks"]
    assert check["metric"] == "chamfer_l1" and check["passed"] is False
    assert check["excess"] == pytest.approx(data["chamfer_l1"] - 0.001)


def test_compare_fscore_with_absolute_tau(files):
    r = run(
        "compare", files["sphere"], files["big"], *FAST, "--tau", "0.05", "--min-fscore", "0.99"
    )
    assert r.exit_code == 0, r.output
    r = run(
        "compare", files["sphere"], files["big"], *FAST, "--tau", "0.01", "--min-fscore", "0.99"
    )
    assert r.exit_code == 1
    assert any("fscore" in ln and "FAIL" in ln and "% under" in ln for ln in r.stdout.splitlines())


def test_compare_same_topology(files):
    r = run("compare", files["sphere"], files["big"], *FAST, "--same-topology")
    assert r.exit_code == 0, r.output
    r = run("compare", files["torus"], files["sphere"], *FAST, "--same-topology", "--json")
    assert r.exit_code == 1
    failed = {c["metric"] for c in json.loads(r.stdout)["checks"] if not c["passed"]}
    assert failed == {"topology.genus"}
    r = run("compare", files["tube"], files["sphere"], *FAST, "--same-topology")
    assert r.exit_code == 1
    assert "topology.boundary_loops" in r.stdout and "topology.watertight" in r.stdout


def test_compare_tolerance_file(files, tmp_path):
    tol = tmp_path / "tol.yaml"
    tol.write_text("max-chamfer: 0.001\nmin_fscore: 0.5\nsamples: 3000\n")
    r = run("compare", files["sphere"], files["big"], "--tolerances", tol, "--json")
    assert r.exit_code == 1
    data = json.loads(r.stdout)
    assert data["n_samples"]["mesh"] == 3000
    assert {c["metric"] for c in data["checks"]} == {"chamfer_l1_relative", "fscore"}
    # the command line wins over the file
    r = run("compare", files["sphere"], files["big"], "--tolerances", tol, "--max-chamfer", "0.1")
    assert r.exit_code == 0, r.output


def test_compare_tolerance_file_errors(files, tmp_path):
    tol = tmp_path / "tol.yaml"
    tol.write_text("max_chamfer: 0.001\nmax_champher: 2\n")
    r = run("compare", files["sphere"], files["big"], *FAST, "--tolerances", tol)
    one_line_error(r, "max_champher", str(tol))
    tol.write_text("min_fscore: high\n")
    one_line_error(run("compare", files["sphere"], files["big"], "--tolerances", tol), "min_fscore")
    tol.write_text("samples: 0\n")
    one_line_error(run("compare", files["sphere"], files["big"], "--tolerances", tol), "samples")
    tol.write_text("seed: -1\n")
    one_line_error(run("compare", files["sphere"], files["big"], "--tolerances", tol), "seed")
    tol.write_text("max_chamfer: [1\n")
    one_line_error(run("compare", files["sphere"], files["big"], "--tolerances", tol), "YAML")
    tol.write_text("max_chamfer: 0.001\nmax_chamfer: 0.1\n")  # regression: the last won
    one_line_error(
        run("compare", files["sphere"], files["big"], "--tolerances", tol),
        "line 2: max_chamfer: duplicate key",
    )
    tol.write_text("- 1\n- 2\n")
    one_line_error(run("compare", files["sphere"], files["big"], "--tolerances", tol), "mapping")
    one_line_error(
        run("compare", files["sphere"], files["big"], "--tolerances", tmp_path / "none.yaml"),
        "none.yaml",
    )


def test_compare_point_cloud_reference(files):
    r = run("compare", files["sphere"], files["cloud"], *FAST)
    assert r.exit_code == 0, r.output
    assert "only point-based metrics apply" in r.stdout
    assert "point cloud" in r.stdout
    r = run("compare", files["sphere"], files["cloud"], *FAST, "--json")
    data = json.loads(r.stdout)
    assert data["reference_kind"] == "points" and data["topology"]["reference"] is None
    assert data["normal_consistency"] > 0.9
    one_line_error(
        run("compare", files["sphere"], files["cloud"], *FAST, "--same-topology"),
        "point cloud",
        "cloud.ply",
    )
    r = run("compare", files["sphere"], files["big"], *FAST, "--reference-points", "--json")
    assert json.loads(r.stdout)["reference_kind"] == "points"


def test_compare_bad_inputs_exit_2(files, tmp_path):
    one_line_error(run("compare", tmp_path / "missing.ply", files["sphere"]), "missing.ply")
    one_line_error(run("compare", files["sphere"], tmp_path / "nope.ply"), "nope.ply")
    one_line_error(run("compare", files["cloud"], files["sphere"]), "cloud.ply", "no faces")
    one_line_error(run("compare", files["garbage"], files["sphere"]), "garbage.ply")
    r = run("compare", files["sphere"], files["big"], "--tau", "0.1", "--tau-relative", "0.1")
    one_line_error(r, "exclusive")
    assert run("compare", files["sphere"], files["big"], "--samples", "0").exit_code == 2
    assert run("compare", files["sphere"], files["big"], "--seed", "-1").exit_code == 2


@pytest.mark.parametrize("flat_is_reference", [False, True])
def test_compare_names_the_mesh_that_has_zero_area(files, tmp_path, flat_is_reference):
    """Regression: a mesh of one degenerate triangle against a sphere said "A against B: mesh
    has zero surface area", without saying which of the two meshes it was."""
    flat = tmp_path / "flat.ply"
    write_mesh(flat, np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0]]), np.array([[0, 1, 2]]))
    pair = (files["sphere"], flat) if flat_is_reference else (flat, files["sphere"])
    r = run("compare", *pair, *FAST)
    one_line_error(r, "zero surface area", f"comparing {pair[0]} against {pair[1]}")
    assert r.stderr.startswith(f"oprecon: error: {flat}: "), r.stderr


# ---------------------------------------------------------------------------- report


def test_report_table(files):
    r = run("report", files["tube"])
    assert r.exit_code == 0, r.output
    assert "boundary loops" in r.stdout and "min angle" in r.stdout
    assert "fidelity" not in r.stdout


def test_report_json_with_input(files):
    r = run("report", files["sphere"], "--input", files["cloud"], "--json")
    assert r.exit_code == 0, r.output
    data = json.loads(r.stdout)
    assert data["topology"]["watertight"] is True and data["topology"]["genus"] == 0
    assert data["triangle_quality"]["min_angle_mean_deg"] > 40
    fid = data["fidelity"]
    assert fid["n"] == 3000
    assert 0 < fid["mean"] < 0.01  # unit-sphere points vs the inscribed icosphere
    assert fid["mean_relative"] == pytest.approx(fid["mean"] / fid["diag"])
    assert data["fit_report"] is None and data["png"] is None


def test_report_counts_self_intersections(files, tmp_path):
    r = run("report", files["sphere"], "--json")
    assert json.loads(r.stdout)["self_intersections"] == 0
    # a second sphere through the first: every face pair crossing on their common circle
    v, f = icosphere(2)
    crossing = tmp_path / "crossing.ply"
    write_mesh(crossing, np.vstack([v, v + [1.0, 0, 0]]), np.vstack([f, f + len(v)]))
    r = run("report", crossing, "--json")
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["self_intersections"] > 10
    r = run("report", crossing)
    assert "self-intersections" in r.stdout


def test_report_png_with_fit_history(files, tmp_path):
    mesh = tmp_path / "fitted.ply"
    write_mesh(mesh, *icosphere(2))
    history = {
        "step": [0, 15, 30, 130],
        "particles": [10, 50, 80, 80],
        "kinetic": [1.0, 0.1, 0.01, 0.001],
        "coverage": [0.2, 0.7, 0.99, 0.99],
        "phase": ["grow", "grow", "grow", "release"],
    }
    (tmp_path / "fitted.report.json").write_text(json.dumps({"history": history}))
    png = tmp_path / "fitted.png"
    r = run("report", mesh, "--png", png, "--json")
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["fit_report"].endswith("fitted.report.json")
    image = mpimg.imread(png)
    assert image.shape[:2] == (500, 1500) and image[..., :3].std() > 0.05


def test_report_png_of_a_mesh_with_unreferenced_vertices(tmp_path):
    # regression: a traceback (IndexError) instead of the picture
    v, f = open_cylinder(16, 3)
    mesh = tmp_path / "loose.ply"
    write_mesh(mesh, np.vstack([[[9.0, 9.0, 9.0]], v]), f + 1)
    r = run("report", mesh, "--png", tmp_path / "loose.png")
    assert r.exit_code == 0, r.output
    assert "unreferenced vertices   1" in r.stdout
    assert mpimg.imread(tmp_path / "loose.png")[..., :3].std() > 0.05


def test_report_png_survives_a_broken_fit_report(files, tmp_path):
    mesh = tmp_path / "m.ply"
    write_mesh(mesh, *icosphere(1))
    (tmp_path / "m.report.json").write_text("{not json")
    r = run("report", mesh, "--png", tmp_path / "m.png")
    assert r.exit_code == 0, r.output
    assert "warning" in r.stderr and (tmp_path / "m.png").is_file()
    (tmp_path / "m.report.json").write_text(
        json.dumps({"history": {"step": [1, 2], "kinetic": [1]}})
    )
    r = run("report", mesh, "--png", tmp_path / "m.png")
    assert r.exit_code == 0, r.output
    assert "history not drawn" in r.stderr


def test_report_bad_inputs_exit_2(files, tmp_path):
    one_line_error(run("report", tmp_path / "missing.ply"), "missing.ply")
    one_line_error(run("report", files["cloud"]), "cloud.ply", "no faces")
    one_line_error(run("report", files["garbage"]), "garbage.ply")
    one_line_error(run("report", files["sphere"], "--input", tmp_path / "pts.xyz"), "pts.xyz")
    one_line_error(run("report", files["sphere"], "--png", files["sphere"]), "input file")


def test_help_has_examples():
    for name in ("compare", "report"):
        r = run(name, "--help")
        assert r.exit_code == 0 and "Examples:" in r.output
    assert "reference's bounding-box diagonal" in run("compare", "--help").output


def test_compare_tolerances_share_the_config_machinery(tmp_path):
    from recon.cli.compare import CompareTolerances, load_tolerances

    from recon.errors import ConfigError

    with pytest.raises(ConfigError, match=r"^samples: 0 is out of range, allowed \[1, inf\)"):
        CompareTolerances(samples=0)
    tol = tmp_path / "tol.yaml"
    tol.write_text("max_champher: 2\n")
    with pytest.raises(ConfigError, match=r"unknown key 'max_champher' \(did you mean"):
        load_tolerances(tol)
    tol.write_text("max-chamfer: 1\nseed: 3\n")
    assert load_tolerances(tol) == {"max_chamfer": 1.0, "seed": 3}


@pytest.mark.parametrize("command", ["report", "remesh", "compare"])
def test_a_mesh_with_coordinates_past_1e100_is_refused_by_name(tmp_path, command):
    """Regression: the mesh commands did not check the coordinates' range as the point
    commands do (remesh: a ValueError traceback; report: overflow warnings and nan angles)."""
    v, f = icosphere(1)
    mesh = tmp_path / "huge.ply"
    write_mesh(mesh, v * 1e300, f)
    args = {"report": [mesh], "remesh": [mesh, "-o", tmp_path / "r.ply"]}.get(command)
    if args is None:
        ref = tmp_path / "unit.ply"
        write_mesh(ref, v, f)
        args = [ref, mesh]
    r = run(command, *args)
    one_line_error(r, str(mesh), "too large")
    assert not (tmp_path / "r.ply").exists()


@pytest.mark.parametrize("swap", [False, True])
def test_surfaces_far_apart_are_compared_in_any_units(tmp_path, swap):
    """Regression: a sphere of radius 1e12 against a unit sphere: Embree's float32 closest-point
    query returned its invalid face id, and compare died with an IndexError traceback (then
    was refused by name). The query now runs at the mesh's own scale (a power of two) and
    measures the distance: about 1e12 each way."""
    v, f = icosphere(1)
    big, unit = tmp_path / "big.ply", tmp_path / "unit.ply"
    write_mesh(big, v * 1e12, f)
    write_mesh(unit, v, f)
    pair = (unit, big) if swap else (big, unit)
    r = run("compare", *pair, "--json", *FAST)
    assert r.exit_code == 0, r.output
    data = json.loads(r.stdout)
    assert 0.8e12 < data["chamfer_l1"] < 1e12 and 0.9e12 < data["hausdorff"] <= 1e12, data


def test_remesh_of_a_mesh_1e20_across_works(tmp_path):
    """Regression: remesh of a sphere of radius 1e20 died with an IndexError traceback (then
    was refused by name): its distance check now runs at the mesh's scale."""
    v, f = icosphere(2)
    mesh = tmp_path / "far.ply"
    write_mesh(mesh, v * 1e20, f)
    r = run("remesh", mesh, "-o", tmp_path / "r.ply")
    assert r.exit_code == 0, r.output
    assert "topology           preserved" in r.stderr
