"""``oprecon info`` and ``oprecon normals`` through click's CliRunner."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from recon.cli.main import app

from recon.io import read_points, write_points

SAMPLES = Path(__file__).resolve().parent.parent / "sample_data"
BUNNY = SAMPLES / "bunny-sparse.ply"


def run(*args):
    return CliRunner().invoke(app, [str(a) for a in args])


def sphere(n: int = 1500) -> np.ndarray:
    d = np.random.default_rng(0).normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


# ------------------------------------------------------------------------------ info


def test_info_table():
    r = run("info", BUNNY)
    assert r.exit_code == 0, r.output
    out = r.stdout
    for needle in (
        "ply-binary_little_endian",
        "2,000",
        "bbox min",
        "bbox diagonal",
        "spacing",
        "normals",
        "no",
    ):
        assert needle in out, out


def test_info_json(tmp_path):
    path = tmp_path / "geo.ply"
    p = sphere() * 10 + [5e6, 4e6, 0.0]
    write_points(path, p, sphere())
    r = run("info", path, "--json")
    assert r.exit_code == 0, r.output
    d = json.loads(r.stdout)
    assert d["points"] == 1500 and d["has_normals"] and not d["has_colors"]
    assert d["bbox_min"][0] == pytest.approx(p[:, 0].min())
    assert d["bbox_diagonal"] == pytest.approx(np.linalg.norm(p.max(0) - p.min(0)))
    assert d["spacing_median_nn"] > 0
    assert d["elements"] == {"vertex": 1500}
    assert d["origin"][0] != 0


def test_info_counts_cleaning(tmp_path):
    path = tmp_path / "dirty.xyz"
    p = sphere(100)
    rows = np.vstack([p, p[:7], [[np.nan, 1, 2]]])
    np.savetxt(path, rows, fmt="%.17g")
    d = json.loads(run("info", path, "--json").stdout)
    assert (d["points"], d["points_read"], d["duplicates_merged"], d["nonfinite_dropped"]) == (
        100,
        108,
        7,
        1,
    )


# ------------------------------------------------------------------------------ normals


def test_normals_writes_oriented_cloud(tmp_path):
    out = tmp_path / "o.ply"
    r = run("normals", BUNNY, "-o", out)
    assert r.exit_code == 0, r.output
    assert "2,000 points" in r.stderr and "oriented" in r.stderr
    c = read_points(out)
    src = read_points(BUNNY)
    np.testing.assert_array_equal(c.absolute_points(), src.absolute_points())
    np.testing.assert_allclose(np.linalg.norm(c.normals, axis=1), 1.0, atol=1e-6)


def test_normals_absolute_coordinates_and_viewpoint(tmp_path):
    rng = np.random.default_rng(0)
    p = np.column_stack([rng.uniform(0, 100, (2000, 2)), np.zeros(2000)]) + [5e6, 4e6, 250.0]
    inp = tmp_path / "scan.ply"
    write_points(inp, p)
    out = tmp_path / "scan-n.ply"
    r = run("normals", inp, "-o", out, "--viewpoint", "5000050,4000050,200", "-q")
    assert r.exit_code == 0, r.output
    assert r.stderr == ""
    c = read_points(out)
    np.testing.assert_array_equal(c.absolute_points(), p)
    assert np.all(c.normals[:, 2] < -0.999)  # toward the scanner below


def test_normals_options_override_config(tmp_path):
    cfg = tmp_path / "c.yaml"
    cfg.write_text("normals:\n  k: 3\n  orientation: none\nio:\n  ascii: false\n")
    out = tmp_path / "o.ply"
    r = run(
        "normals",
        BUNNY,
        "-o",
        out,
        "--config",
        cfg,
        "--k",
        "12",
        "--orientation",
        "outward",
        "--ascii",
    )
    assert r.exit_code == 0, r.output
    assert "k=12" in r.stderr and "outward" in r.stderr
    assert read_points(out).format == "ply-ascii"
    r = run("normals", BUNNY, "-o", out, "--config", cfg, "--set", "normals.k=9")
    assert r.exit_code == 0 and "k=9" in r.stderr and "oriented none" in r.stderr


def test_normals_input_mode(tmp_path):
    r = run("normals", BUNNY, "-o", tmp_path / "x.ply", "--normals", "input")
    assert r.exit_code == 2
    assert "no normals" in r.stderr and str(BUNNY) in r.stderr
    src = tmp_path / "with.ply"
    write_points(src, sphere(), -sphere())
    r = run("normals", src, "-o", tmp_path / "y.ply", "--normals", "input")
    assert r.exit_code == 0 and "kept the file's normals" in r.stderr
    np.testing.assert_allclose(read_points(tmp_path / "y.ply").normals, -sphere(), atol=1e-6)


def test_normals_output_checks(tmp_path):
    src = tmp_path / "in.ply"
    write_points(src, sphere())
    r = run("normals", src, "-o", src)
    assert r.exit_code == 2 and "overwrite an input" in r.stderr
    r = run("normals", src, "-o", tmp_path / "new" / "o.ply")
    assert r.exit_code == 2 and "--mkdir" in r.stderr
    r = run("normals", src, "-o", tmp_path / "new" / "o.ply", "--mkdir")
    assert r.exit_code == 0 and (tmp_path / "new" / "o.ply").is_file()


@pytest.mark.parametrize("value", ["1,2", "a,b,c"])
def test_normals_bad_viewpoint_is_usage_error(tmp_path, value):
    r = run("normals", BUNNY, "-o", tmp_path / "o.ply", "--viewpoint", value)
    assert r.exit_code == 2 and "viewpoint" in r.stderr
    assert not (tmp_path / "o.ply").exists()


def test_help_has_examples():
    for cmd in ("info", "normals"):
        r = run(cmd, "--help")
        assert r.exit_code == 0 and "Examples:" in r.stdout


# ------------------------------------------------------------------------------ bad inputs


def _ply_header(n: int, fmt: str = "binary_little_endian") -> bytes:
    props = "".join(f"property float {c}\n" for c in "xyz")
    return f"ply\nformat {fmt} 1.0\nelement vertex {n}\n{props}end_header\n".encode()


def _make_bad(tmp_path: Path, kind: str) -> tuple[Path, str]:
    path = tmp_path / f"{kind}.ply"
    if kind == "empty":
        path.write_bytes(b"")
        return path, "empty"
    if kind == "truncated":
        path.write_bytes(_ply_header(1000) + b"\x00" * 100)
        return path, "truncated"
    if kind == "magic":
        path.write_bytes(b"\x89PNG\r\n\x1a\n" + b"\x00" * 64)
        return path, "magic"
    if kind == "token":
        path.write_bytes(_ply_header(4, "ascii") + b"0 0 0\n1 0 0\n0 1 oops\n0 0 1\n")
        return path, "oops"
    if kind == "directory":
        path.mkdir()
        return path, "directory"
    if kind == "missing":
        return path, "no such file"
    raise AssertionError(kind)


KINDS = ["empty", "truncated", "magic", "token", "directory", "missing"]


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("command", ["info", "normals"])
def test_bad_input_exit_2_one_line(tmp_path, kind, command):
    path, problem = _make_bad(tmp_path, kind)
    out = tmp_path / "out" / "o.ply"
    out.parent.mkdir()
    args = [command, path] + (["-o", out] if command == "normals" else [])
    r = run(*args)
    assert r.exit_code == 2, (r.exit_code, r.output)
    err = r.stderr
    assert err.startswith("oprecon: error: ") and err.count("\n") == 1, err
    assert str(path) in err and problem in err, err
    assert "Traceback" not in r.output
    assert r.stdout == ""
    assert list(out.parent.iterdir()) == []  # no output, no temporary file


def test_bad_input_subprocess_no_traceback(tmp_path):
    import subprocess
    import sys

    path, _ = _make_bad(tmp_path, "truncated")
    out = tmp_path / "o.ply"
    root = Path(__file__).resolve().parent.parent
    proc = subprocess.run(
        [sys.executable, "-m", "recon.cli.main", "normals", str(path), "-o", str(out)],
        cwd=root,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr and str(path) in proc.stderr
    assert not out.exists()


def test_the_normals_summary_gives_the_k_it_used(tmp_path):
    """Regression: the summary printed the configured k (20) where the noise rule raised it
    (80 on the noisy bunny sample)."""
    out = tmp_path / "n.ply"
    r = run("normals", SAMPLES / "bunny-noise1.ply", "-o", out)
    assert r.exit_code == 0, r.output
    assert "estimated (k=80)" in r.stderr, r.stderr


def test_normals_keep_the_files_colours_and_scalars(tmp_path):
    """Regression: ``oprecon normals`` wrote points and normals only; a coloured scan lost its
    colours on the way to ``fit``."""
    from plyfile import PlyData

    from recon.io import read_points

    rng = np.random.default_rng(0)
    p = rng.normal(size=(500, 3))
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    rgb = rng.integers(0, 256, size=(500, 3)).astype(np.uint8)
    src = tmp_path / "c.pts"  # x y z intensity r g b
    np.savetxt(src, np.column_stack([p, np.arange(500.0), rgb]), fmt="%.8f")
    out = tmp_path / "n.ply"
    r = run("normals", src, "-o", out)
    assert r.exit_code == 0, r.output
    back = read_points(out)
    assert back.normals is not None
    np.testing.assert_array_equal(np.round(255 * back.colors).astype(np.uint8), rgb)
    np.testing.assert_array_equal(PlyData.read(str(out))["vertex"]["intensity"], np.arange(500))


def test_normals_keep_every_ply_vertex_property_and_classes_past_255(tmp_path):
    """Regression: ``normals`` dropped PLY vertex properties other than intensity and
    classification (``quality`` was gone) and wrote every class above 255 as 255."""
    from plyfile import PlyData, PlyElement

    p = sphere(400).astype(np.float32)
    quality = np.random.default_rng(1).uniform(size=400).astype(np.float32)
    classes = (300 + np.arange(400) % 3).astype(np.int32)
    rows = np.zeros(
        400,
        dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("quality", "f4"), ("classification", "i4")],
    )
    for j, c in enumerate("xyz"):
        rows[c] = p[:, j]
    rows["quality"], rows["classification"] = quality, classes
    src = tmp_path / "cls.ply"
    PlyData([PlyElement.describe(rows, "vertex")]).write(str(src))
    for extra in ((), ("--ascii",)):
        out = tmp_path / "out.ply"
        r = run("normals", src, "-o", out, *extra)
        assert r.exit_code == 0, r.output
        v = PlyData.read(str(out))["vertex"]
        names = [q.name for q in v.properties]
        assert names == ["x", "y", "z", "nx", "ny", "nz", "quality", "classification"]
        np.testing.assert_array_equal(v["quality"], quality)
        assert v["quality"].dtype == np.float32
        np.testing.assert_array_equal(v["classification"], classes)


def test_normals_an_explicit_k_is_used_as_given(tmp_path):
    """Regression: ``--k 500`` on a 1000-point sphere printed ``k=1000`` and ``--k 200`` on a
    noisy cloud ``k=400``: the noise rule raised an explicit k past its range. An explicit
    ``--k`` turns the rule off; a configured k is raised at most to 500, and the summary
    says from what."""
    src = tmp_path / "s.ply"
    write_points(src, sphere(1000))
    out = tmp_path / "o.ply"
    r = run("normals", src, "-o", out, "--k", "500", "--set", "normals.per_point_scale=false")
    assert r.exit_code == 0, r.output
    assert "estimated (k=500)" in r.stderr, r.stderr
    noisy = tmp_path / "noisy.ply"
    rng = np.random.default_rng(0)
    write_points(noisy, sphere(1000) + rng.normal(scale=0.15, size=(1000, 3)))
    r = run("normals", noisy, "-o", out, "--k", "60")
    assert r.exit_code == 0, r.output
    assert "estimated (k=60)" in r.stderr, r.stderr
    r = run("normals", noisy, "-o", out, "--set", "normals.k=60")
    assert r.exit_code == 0, r.output
    assert "raised from normals.k=60" in r.stderr, r.stderr


def test_normals_radius_is_refused_or_reported(tmp_path):
    """Regression: ``--radius 1e-9`` and ``--radius 1e9`` gave the default normals and the
    summary said nothing of the radius. A radius that leaves most points fewer than 3
    neighbours is refused (exit 2, with a radius that works); one that trims nothing is
    said to."""
    src = tmp_path / "s.ply"
    write_points(src, sphere(1000))
    out = tmp_path / "o.ply"
    r = run("normals", src, "-o", out, "--radius", "1e-9")
    assert r.exit_code == 2, r.output
    assert str(src) in r.stderr and "normals.radius = 1e-09" in r.stderr
    assert "at least" in r.stderr and not out.exists()
    r = run("normals", src, "-o", out, "--radius", "1e9")
    assert r.exit_code == 0, r.output
    assert "radius 1e+09" in r.stderr and "trims none" in r.stderr, r.stderr
    r = run("normals", src, "-o", out, "--radius", "0.1")
    assert r.exit_code == 0, r.output
    assert "within radius 0.1" in r.stderr and "fewer of their 20 nearest" in r.stderr, r.stderr


def test_normals_help_says_what_k_and_radius_do():
    r = run("normals", "--help")
    text = " ".join(r.output.split())
    assert "auto_scale" in text and "per_point_scale" in text
    assert "fewer than 3" in text
