"""Colours and attributes on the mesh (issue #14 part 3), and the memory estimate (part 4)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from plyfile import PlyData, PlyElement
from recon.cli.main import app

from recon.attributes import majority, transfer_attributes
from recon.config import ReconConfig, config_from_dict, parse_size
from recon.errors import ConfigError, InputError
from recon.fitting.memory import (
    BYTES_PER_PARTICLE,
    check_memory,
    estimate_peak_memory,
)
from recon.io import cloud_from_arrays, read_points, write_mesh

ROOT = Path(__file__).resolve().parent.parent
FAST = ["--set", "seeds.min_particles=0", "--set", "dynamics.max_steps=150"]

RED = (220, 30, 30)
BLUE = (20, 40, 230)


def two_coloured_sphere(tmp_path: Path) -> Path:
    """The bundled sparse sphere, red above z = 0 and blue below, as a PLY with colours."""
    pts = read_points(ROOT / "sample_data" / "sphere-sparse.ply").absolute_points()
    rgb = np.where(pts[:, 2:3] >= 0, RED, BLUE).astype(np.uint8)
    rows = np.zeros(
        len(pts),
        dtype=[(c, "f4") for c in "xyz"] + [(c, "u1") for c in ("red", "green", "blue")],
    )
    for j, c in enumerate("xyz"):
        rows[c] = pts[:, j]
    for j, c in enumerate(("red", "green", "blue")):
        rows[c] = rgb[:, j]
    path = tmp_path / "sphere-rgb.ply"
    PlyData([PlyElement.describe(rows, "vertex")]).write(str(path))
    return path


# --------------------------------------------------------------------------------------------
# the transfer itself


def test_majority_takes_the_most_frequent_class_and_breaks_ties_by_nearest():
    labels = np.array([[6, 2, 2, 6, 2], [6, 2, 5, 9, 1], [3, 3, 4, 4, 4], [7, 7, 1, 1, 5]])
    assert majority(labels).tolist() == [2, 6, 4, 7]


def test_colours_are_the_inverse_distance_weighted_mean():
    pts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=np.float64) + 5e6
    col = np.array([[1, 0, 0], [0, 0, 1], [0, 1, 0], [1, 1, 1]], dtype=np.float64)
    cloud = cloud_from_arrays(pts, colors=col)
    vertices = np.array([[0.25, 0, 0], [0, 0, 0]]) + 5e6
    out = transfer_attributes(cloud, vertices, r0=1.0, k=2)
    # vertex 0: neighbours at 0.25 (red) and 0.75 (blue), weights 1/0.251 and 1/0.751
    w = np.array([1 / (0.25 + 1e-3), 1 / (0.75 + 1e-3)])
    w /= w.sum()
    expected = np.rint(255 * (w[0] * col[0] + w[1] * col[1])).astype(np.uint8)
    assert out.colors[0].tolist() == expected.tolist()
    assert out.colors[1].tolist() == [255, 0, 0]  # on an input point: its colour (to 1/255)


def test_quality_is_the_distance_to_the_nearest_point_in_r0():
    pts = np.array([[0, 0, 0], [2, 0, 0], [0, 2, 0], [0, 0, 2]], dtype=np.float64)
    cloud = cloud_from_arrays(pts)
    out = transfer_attributes(cloud, np.array([[0, 0, 0.5], [2, 0, 0]]), r0=0.25, quality=True)
    assert out.colors is None
    assert out.properties["quality"].dtype == np.float32
    assert out.properties["quality"].tolist() == [2.0, 0.0]


def test_transfer_intensity_and_classification():
    rng = np.random.default_rng(0)
    pts = rng.uniform(0, 1, size=(500, 3))
    cls = np.where(pts[:, 0] < 0.5, 2, 6).astype(np.uint8)
    intensity = np.full(500, 1000.0)
    cloud = cloud_from_arrays(pts, attributes={"intensity": intensity, "classification": cls})
    verts = np.array([[0.1, 0.5, 0.5], [0.9, 0.5, 0.5]])
    out = transfer_attributes(cloud, verts, r0=0.05, transfer=["intensity", "classification"])
    assert out.properties["classification"].tolist() == [2, 6]
    assert out.properties["classification"].dtype == np.uint8
    assert np.allclose(out.properties["intensity"], 1000.0)
    assert list(out.properties) == ["intensity", "classification"]


def test_transfer_of_a_missing_attribute_is_refused():
    cloud = cloud_from_arrays(np.random.default_rng(0).uniform(size=(50, 3)))
    with pytest.raises(InputError, match="has no classification per point"):
        transfer_attributes(cloud, np.zeros((1, 3)), 1.0, transfer=["classification"])


# --------------------------------------------------------------------------------------------
# writing


def test_ply_vertex_colours_and_properties_round_trip(tmp_path):
    verts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=np.float64)
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    rgb = np.array([[255, 0, 0], [0, 255, 0], [0, 0, 255], [1, 2, 3]], dtype=np.uint8)
    props = {
        "intensity": np.array([1.5, 2.5, 3.5, 65535.0], dtype=np.float32),
        "classification": np.array([2, 6, 9, 255], dtype=np.uint8),
    }
    for ascii in (False, True):
        path = tmp_path / f"m{int(ascii)}.ply"
        write_mesh(path, verts, faces, colors=rgb, vertex_properties=props, ascii=ascii)
        v = PlyData.read(str(path))["vertex"]
        names = [p.name for p in v.properties]
        assert names == ["x", "y", "z", "red", "green", "blue", "intensity", "classification"]
        assert v["red"].dtype == np.uint8 and v["classification"].dtype == np.uint8
        assert np.array_equal(np.column_stack([v["red"], v["green"], v["blue"]]), rgb)
        assert np.array_equal(v["intensity"], props["intensity"])
        assert np.array_equal(v["classification"], props["classification"])
        # our own reader takes the colours back
        assert np.array_equal(np.rint(read_points(path).colors * 255), rgb)


def test_obj_vertex_colours_are_floats_after_the_coordinates(tmp_path):
    verts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=np.float64)
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    rgb = np.array([[255, 0, 0], [0, 255, 0], [0, 0, 255], [51, 102, 153]], dtype=np.uint8)
    path = tmp_path / "m.obj"
    write_mesh(path, verts, faces, colors=rgb)
    lines = [ln for ln in path.read_text().splitlines() if ln.startswith("v ")]
    assert lines[3] == "v 0 0 1 0.2 0.4 0.6"
    assert np.array_equal(np.rint(read_points(path).colors * 255), rgb)


def test_obj_refuses_vertex_properties(tmp_path):
    verts = np.eye(3)
    with pytest.raises(InputError, match="OBJ has no vertex properties"):
        write_mesh(tmp_path / "m.obj", verts, [[0, 1, 2]], vertex_properties={"q": np.ones(3)})


def test_no_colours_no_flags_write_the_same_bytes(tmp_path):
    verts = np.random.default_rng(0).uniform(size=(10, 3))
    faces = np.array([[0, 1, 2], [3, 4, 5]])
    for ext in (".ply", ".obj"):
        a, b = tmp_path / f"a{ext}", tmp_path / f"b{ext}"
        write_mesh(a, verts, faces, np.tile([0.0, 0.0, 1.0], (10, 1)))
        write_mesh(b, verts, faces, np.tile([0.0, 0.0, 1.0], (10, 1)), vertex_properties={})
        assert a.read_bytes() == b.read_bytes()
        assert b"red" not in a.read_bytes()


# --------------------------------------------------------------------------------------------
# through the CLI


def test_two_coloured_sphere_gives_red_top_and_blue_bottom(tmp_path):
    src = two_coloured_sphere(tmp_path)
    out = tmp_path / "mesh.ply"
    res = CliRunner().invoke(app, ["fit", str(src), "-o", str(out), "--quiet", "--quality"])
    assert res.exit_code == 0, res.output
    v = PlyData.read(str(out))["vertex"]
    rgb = np.column_stack([v["red"], v["green"], v["blue"]]).astype(int)
    z = np.asarray(v["z"])
    top, bottom = z > 0.4, z < -0.4  # farther from the seam than the 8 nearest points reach
    assert top.sum() > 50 and bottom.sum() > 50
    assert np.all(rgb[top] == RED)
    assert np.all(rgb[bottom] == BLUE)
    # near the equator the colours mix, but stay between the two
    lo, hi = np.minimum(RED, BLUE), np.maximum(RED, BLUE)
    assert np.all((rgb >= lo) & (rgb <= hi))
    # quality: the distance to the nearest input point in r0, checked independently
    from scipy.spatial import cKDTree

    r0 = json.loads((tmp_path / "mesh.report.json").read_text())["spacing"]
    data = read_points(src).absolute_points()
    xyz = np.column_stack([v["x"], v["y"], v["z"]]).astype(np.float64)
    expected = cKDTree(data).query(xyz)[0] / r0
    assert np.allclose(np.asarray(v["quality"]), expected, rtol=1e-5, atol=1e-5)


def test_obj_gets_colours_only_when_asked(tmp_path):
    src = two_coloured_sphere(tmp_path)
    plain, coloured = tmp_path / "plain.obj", tmp_path / "col.obj"
    for out, extra in ((plain, []), (coloured, ["--obj-colors"])):
        res = CliRunner().invoke(app, ["fit", str(src), "-o", str(out), "--quiet", *FAST, *extra])
        assert res.exit_code == 0, res.output
    first_v = next(ln for ln in plain.read_text().splitlines() if ln.startswith("v "))
    assert len(first_v.split()) == 4
    first_v = next(ln for ln in coloured.read_text().splitlines() if ln.startswith("v "))
    assert len(first_v.split()) == 7


def test_no_colors_flag_keeps_the_mesh_plain(tmp_path):
    src = two_coloured_sphere(tmp_path)
    out = tmp_path / "mesh.ply"
    res = CliRunner().invoke(
        app, ["fit", str(src), "-o", str(out), "--quiet", "--no-colors", *FAST]
    )
    assert res.exit_code == 0, res.output
    assert "red" not in [p.name for p in PlyData.read(str(out))["vertex"].properties]


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--transfer", "classification"], "has no classification per point"),
        (["--transfer", "colour"], "expected a comma-separated list of intensity"),
        (["--quality", "-o", "OUT.obj"], "OBJ has no vertex properties for quality"),
    ],
)
def test_attribute_errors_exit_2_before_fitting(tmp_path, args, message):
    src = two_coloured_sphere(tmp_path)
    out = tmp_path / "out"
    out.mkdir()
    args = [a.replace("OUT", str(out / "m")) for a in args]
    if "-o" not in args:
        args += ["-o", str(out / "m.ply")]
    res = CliRunner().invoke(app, ["fit", str(src), *args])
    assert res.exit_code == 2
    assert message in res.output and "Traceback" not in res.output
    assert list(out.iterdir()) == []


# --------------------------------------------------------------------------------------------
# memory


def test_parse_size():
    assert parse_size("8G") == 8 * 2**30
    assert parse_size("512 MiB") == 512 * 2**20
    assert parse_size("1.5k") == 1536
    for bad in ("", "8X", "-1G", "0"):
        with pytest.raises(ConfigError):
            parse_size(bad, "io.max_memory")


def test_config_checks_max_memory():
    with pytest.raises(ConfigError, match="io.max_memory: 'lots' is not a size"):
        config_from_dict({"io": {"max_memory": "lots"}})
    assert config_from_dict({"io": {"max_memory": "8G"}}).io.max_memory == "8G"
    assert ReconConfig().io.max_memory is None


def test_estimate_grows_with_points_and_shrinks_with_spacing():
    a = estimate_peak_memory(100_000, 1.0, 1.0)
    b = estimate_peak_memory(200_000, 1.0, 1.0)
    c = estimate_peak_memory(100_000, 2.0, 1.0)
    assert b.peak_bytes > a.peak_bytes > c.peak_bytes
    assert a.particles == pytest.approx(4 * c.particles, rel=1e-5)
    assert b.particles == pytest.approx(2 * a.particles, rel=1e-5)


def test_estimate_respects_the_particle_cap():
    free = estimate_peak_memory(1_000_000, 1.0, 1.0)
    capped = estimate_peak_memory(1_000_000, 1.0, 1.0, max_particles=100_000)
    assert capped.particles == 100_000 < free.particles
    assert capped.peak_bytes < free.peak_bytes


def test_refusal_suggests_a_spacing_that_fits():
    est = estimate_peak_memory(2_000_000, 0.1, 0.1)
    cap = est.peak_bytes // 2
    with pytest.raises(InputError, match=r"use a larger --spacing \(at least ([0-9.]+)") as err:
        check_memory(est, cap, 0.1)
    suggested = float(err.value.args[0].split("at least ")[1].split(",")[0])
    assert suggested > 0.1
    assert estimate_peak_memory(2_000_000, suggested, 0.1).peak_bytes <= cap
    check_memory(est, est.peak_bytes, 0.1)  # at the limit: accepted
    assert BYTES_PER_PARTICLE > 0


def test_cli_max_memory_refuses_with_exit_2_and_writes_nothing(tmp_path):
    src = two_coloured_sphere(tmp_path)
    out = tmp_path / "out"
    out.mkdir()
    res = CliRunner().invoke(app, ["fit", str(src), "-o", str(out / "m.ply"), "--max-memory", "1M"])
    assert res.exit_code == 2
    assert "estimated" in res.output and "--max-memory" in res.output
    assert "Traceback" not in res.output
    assert list(out.iterdir()) == []


def test_report_carries_the_memory_estimate(tmp_path):
    src = two_coloured_sphere(tmp_path)
    out = tmp_path / "m.ply"
    res = CliRunner().invoke(app, ["fit", str(src), "-o", str(out), *FAST, "--max-memory", "64G"])
    assert res.exit_code == 0, res.output
    assert "memory (estimate)" in res.output
    rep = json.loads((tmp_path / "m.report.json").read_text())
    mem = rep["input"]["memory_estimate"]
    assert mem["points"] == rep["input"]["points"]
    assert mem["peak_bytes"] > 0 and mem["particles"] > 0


def test_every_mesh_file_of_a_fit_carries_the_attributes(tmp_path):
    """Regression: batch wrote its second mesh format after the fit with a plain
    ``write_mesh``, dropping the colours and vertex properties (and outside the all-or-nothing
    set of outputs)."""
    from recon.batch.worker import run_item
    from recon.config import config_to_dict

    src = two_coloured_sphere(tmp_path)
    cfg = config_from_dict(
        {"seeds": {"min_particles": 0}, "dynamics": {"max_steps": 150}, "output": {"quality": True}}
    )
    meshes = [tmp_path / "a.ply", tmp_path / "b.ply"]
    spec = {"input": str(src), "meshes": [str(m) for m in meshes], "config": config_to_dict(cfg)}
    run_item(spec)
    first, second = (PlyData.read(str(m))["vertex"] for m in meshes)
    for element in (first, second):
        names = {p.name for p in element.properties}
        assert {"red", "green", "blue", "quality"} <= names, names
    assert np.array_equal(first["red"], second["red"])
