"""recon.io.xyz: text point files whose extension, separators, comments or bad rows were misread.

Each test is the regression test of one defect found by a tester: the extension that says what
columns 4-6 hold (.xyzn, .xyzrgb), semicolon-separated decimal commas, trailing ``#`` comments,
file line numbers in messages, and pipes given as input files.
"""

from __future__ import annotations

import os
import threading
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from recon.cli.main import app

from recon.errors import InputError
from recon.io import files, read_points


def sphere(n: int = 300, seed: int = 0) -> np.ndarray:
    """Points on a unit sphere (spanning 3-D), which are also their own unit normals."""
    d = np.random.default_rng(seed).normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def bad(path: Path, *needles: str) -> str:
    """The message of the InputError reading ``path``; it names the file and every needle."""
    with pytest.raises(InputError) as e:
        read_points(path)
    msg = str(e.value)
    assert msg.startswith(f"{path}: "), msg
    problem = msg[len(f"{path}: ") :]  # the folder of tmp_path holds the test's name
    for needle in needles:
        assert needle in problem, msg
    return problem


# ------------------------------------------------------------------ 1. the extension says


def test_xyzrgb_with_unit_length_label_colours_is_read_as_colours(tmp_path):
    """Open3D writes .xyzrgb colours as 0-1 floats; pure labels (1,0,0) have unit length and
    were taken for normals."""
    p = sphere()
    rgb = np.eye(3)[np.arange(len(p)) % 3]
    path = tmp_path / "labels.xyzrgb"
    np.savetxt(path, np.hstack([p, rgb]), fmt="%.10f")
    c = read_points(path)
    assert c.normals is None
    np.testing.assert_array_equal(c.colors, rgb)
    assert c.info["properties"] == ["x", "y", "z", "red", "green", "blue"]


def test_xyzrgb_with_0_255_colours(tmp_path):
    p = sphere()
    rgb = np.random.default_rng(1).integers(0, 256, p.shape)
    rgb[0] = 255  # the file is 0-255 even where a row stays <= 1
    path = tmp_path / "c.xyzrgb"
    np.savetxt(path, np.hstack([p, rgb]), fmt="%.10g")
    np.testing.assert_allclose(read_points(path).colors, rgb / 255.0)


def test_xyzrgb_with_values_that_are_not_colours_is_refused(tmp_path):
    p = sphere()
    path = tmp_path / "c.xyzrgb"
    np.savetxt(path, np.hstack([p, -3.0 * p]), fmt="%.10g")
    bad(path, "columns 4-6", "colours", ".xyzrgb")


def test_xyzn_normals_not_of_unit_length_are_normalised(tmp_path):
    """.xyzn normals of length 5 were dropped as 'neither unit normals nor colours'."""
    p = sphere()
    path = tmp_path / "scaled.xyzn"
    np.savetxt(path, np.hstack([p, 5.0 * p]), fmt="%.17g")
    c = read_points(path)
    np.testing.assert_allclose(c.normals, p, atol=1e-12)
    assert c.colors is None
    assert c.info["properties"] == ["x", "y", "z", "nx", "ny", "nz"]


def test_xyzn_normals_that_look_like_colours_are_normals(tmp_path):
    """Short normals in the positive octant (values in [0, 1]) were read as colours."""
    p = np.abs(sphere())
    path = tmp_path / "octant.xyzn"
    np.savetxt(path, np.hstack([p, 0.5 * p]), fmt="%.17g")
    c = read_points(path)
    assert c.colors is None
    np.testing.assert_allclose(c.normals, p, atol=1e-9)


def test_xyzn_zero_normal_is_dropped_for_its_row_only(tmp_path):
    p = sphere()
    n = 3.0 * p
    n[7] = 0.0
    path = tmp_path / "zero.xyzn"
    np.savetxt(path, np.hstack([p, n]), fmt="%.17g")
    c = read_points(path)
    assert np.isnan(c.normals[7]).all()  # re-estimated later, like other invalid normals
    keep = np.arange(len(p)) != 7
    np.testing.assert_allclose(c.normals[keep], p[keep], atol=1e-12)


def test_xyzn_without_normal_columns_is_refused(tmp_path):
    path = tmp_path / "short.xyzn"
    np.savetxt(path, sphere(), fmt="%.17g")
    bad(path, ".xyzn", "nx ny nz", "3 columns")


def test_pts_count_line_intensity_and_colours_still_read(tmp_path):
    p = sphere()
    rgb = np.random.default_rng(2).integers(0, 256, p.shape)
    intensity = np.arange(len(p)) - 100
    path = tmp_path / "s.pts"
    body = np.hstack([p, intensity[:, None], rgb])
    np.savetxt(path, body, fmt=["%.17g"] * 3 + ["%d"] * 4, header=str(len(p)), comments="")
    c = read_points(path)
    assert c.format == "pts"
    np.testing.assert_array_equal(c.absolute_points(), p)
    np.testing.assert_allclose(c.colors, rgb / 255.0)
    assert c.info["properties"] == ["x", "y", "z", "intensity", "red", "green", "blue"]


def test_xyz_still_guesses_normals_and_colours(tmp_path):
    p = sphere()
    rgb = np.random.default_rng(3).integers(0, 256, p.shape)
    path = tmp_path / "g.xyz"
    np.savetxt(path, np.hstack([p, p, rgb]), fmt="%.17g")
    c = read_points(path)
    np.testing.assert_allclose(c.normals, p, atol=1e-12)
    np.testing.assert_allclose(c.colors, rgb / 255.0)


# ------------------------------------------------------------------ 2. decimal commas


def _euro(p: np.ndarray, sep: str) -> str:
    return "".join(sep.join(f"{v:.3f}" for v in row).replace(".", ",") + "\n" for row in p)


def test_semicolons_with_decimal_commas(tmp_path):
    """'109,4;90,1;148,1' was read as six columns with invented colours."""
    p = np.round(sphere() * 50 + 100, 3)
    path = tmp_path / "euro.txt"
    path.write_text(_euro(p, ";"))
    c = read_points(path)
    np.testing.assert_allclose(c.absolute_points(), p, atol=1e-9)
    assert c.colors is None and c.normals is None
    assert c.info["properties"] == ["x", "y", "z"]


def test_semicolons_with_decimal_commas_and_a_header(tmp_path):
    p = np.round(sphere(), 3)
    path = tmp_path / "euro.csv"
    path.write_text("x;y;z\n" + _euro(p, ";"))
    np.testing.assert_allclose(read_points(path).absolute_points(), p, atol=1e-9)


def test_tabs_with_decimal_commas(tmp_path):
    p = np.round(sphere(), 3)
    path = tmp_path / "euro.xyz"
    path.write_text(_euro(p, "\t"))
    c = read_points(path)
    np.testing.assert_allclose(c.absolute_points(), p, atol=1e-9)
    assert c.colors is None


def test_semicolons_with_decimal_points(tmp_path):
    p = sphere()
    path = tmp_path / "semi.txt"
    path.write_text("".join(";".join(repr(v) for v in row) + "\n" for row in p.tolist()))
    np.testing.assert_array_equal(read_points(path).absolute_points(), p)


def test_semicolons_with_both_decimal_marks_are_refused(tmp_path):
    path = tmp_path / "thousands.txt"
    path.write_text("1.234,5;2,0;3,0\n" * 5)
    bad(path, "';'", "decimal", "',' and '.'")


# ------------------------------------------------------------------ 3. trailing comments


@pytest.mark.parametrize("mark", ["#", "//"])
def test_trailing_comments_are_stripped(tmp_path, mark):
    """A trailing '# note' was kept and read as two more columns."""
    p = sphere(50)
    rows = [f"{a!r} {b!r} {c!r}" for a, b, c in p.tolist()]
    rows = [r + (f"  {mark} note 1 2" if i >= 20 else "") for i, r in enumerate(rows)]
    path = tmp_path / "trail.xyz"
    path.write_text(f"{mark} whole-line comment\n\n" + "\n".join(rows) + "\n")
    np.testing.assert_array_equal(read_points(path).absolute_points(), p)


# ------------------------------------------------------------------ 4. line numbers


_HEAD = "# c\n# c\n\n0 0 0\n1 0 0\n"
_TAIL = "0 0 1\n1 1 1\n"


def test_a_bad_token_is_named_by_its_line(tmp_path):
    """Line 6 was reported as 'row 2' (numpy's 0-based count of data rows)."""
    path = tmp_path / "bad.xyz"
    path.write_text(_HEAD + "0 y 1\n" + _TAIL)
    msg = bad(path, "line 6:", "'y'")
    assert "row 2" not in msg, msg


def test_a_ragged_row_is_named_by_its_line(tmp_path):
    """Line 6 was reported as 'row 3' (numpy's count of data rows)."""
    path = tmp_path / "rag.xyz"
    path.write_text(_HEAD + "0 1\n" + _TAIL)
    bad(path, "line 6:", "2 columns", "the rows before it have 3")


def test_line_numbers_count_the_header_and_pts_count_lines(tmp_path):
    csv = tmp_path / "h.csv"
    csv.write_text("// made by hand\nx,y,z\n0,0,0\n1,0,0\n0,1,q\n0,0,1\n")
    bad(csv, "line 5:", "'q'")
    pts = tmp_path / "c.pts"
    pts.write_text("4\n0 0 0\n\n1 0 0\n0 1 0 5\n0 0 1\n")
    bad(pts, "line 5:", "4 columns")


def test_the_cli_names_the_line_in_one_line(tmp_path):
    path = tmp_path / "bad.xyz"
    path.write_text(_HEAD + "0 y 1\n" + _TAIL)
    r = CliRunner().invoke(app, ["info", str(path)])
    assert r.exit_code == 2, r.output
    assert "line 6" in r.output and "Traceback" not in r.output, r.output


# ------------------------------------------------------------------ 5. pipes


@pytest.fixture
def fifo(tmp_path):
    """A named pipe with a writer, so that a reader that opens it does not hang."""
    if not hasattr(os, "mkfifo"):
        pytest.skip("no named pipes on this platform")
    path = tmp_path / "s.xyz"
    os.mkfifo(path)
    data = "".join(f"{a!r} {b!r} {c!r}\n" for a, b, c in sphere(50).tolist()).encode()

    def write() -> None:
        fd = os.open(path, os.O_WRONLY)  # blocks until a reader opens the pipe
        try:
            os.write(fd, data)
        except OSError:
            pass
        finally:
            os.close(fd)

    threading.Thread(target=write, daemon=True).start()
    return path


def test_a_pipe_is_refused_by_the_input_check(fifo):
    with pytest.raises(InputError) as e:
        files.check_regular_file(fifo)
    msg = str(e.value)
    assert msg.startswith(f"{fifo}: "), msg
    problem = msg[len(f"{fifo}: ") :]
    assert "pipe" in problem and "save" in problem, msg


def test_a_regular_file_passes_the_input_check(tmp_path):
    path = tmp_path / "s.xyz"
    np.savetxt(path, sphere(10))
    files.check_regular_file(path)


def test_reading_a_pipe_says_pipes_are_not_supported(fifo):
    """'oprecon info <(cat s.xyz)' said '/dev/fd/63: file is empty'."""
    bad(fifo, "pipe")


@pytest.mark.parametrize(
    ("name", "text"),
    [
        ("s.pts", "4\n0 0 0 -10 1 2 3\n1 0 0 20 1 2 3\n0 1 0 30 1 2 3\n0 0 1 40 1 2 3\n"),
        ("s.pts", "0 0 0 -10\n1 0 0 20\n0 1 0 30\n0 0 1 40\n"),
        ("s.xyz", "0 0 0 -10\n1 0 0 20\n0 1 0 30\n0 0 1 40\n"),
        ("s.csv", "x,y,z,intensity\n0,0,0,-10\n1,0,0,20\n0,1,0,30\n0,0,1,40\n"),
    ],
)
def test_an_intensity_column_is_read_for_the_transfer(tmp_path, name, text):
    """Regression: ``info`` listed a PTS file's intensity, but ``fit --transfer intensity``
    said the input had none: text readers kept no intensity."""
    path = tmp_path / name
    path.write_text(text)
    cloud = read_points(path)
    assert "intensity" in cloud.info["properties"]
    np.testing.assert_array_equal(cloud.attributes["intensity"], [-10, 20, 30, 40])
