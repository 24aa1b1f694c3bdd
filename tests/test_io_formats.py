"""recon.io readers: corrupt LAS/LAZ headers, colour scales, OBJ normals, PCD rgb, PLY messages.

Every input is built here in ``tmp_path``. Readers that could hang on a corrupt header run in a
child process with a memory limit and a timeout, so that a regression fails instead of hanging.
"""

from __future__ import annotations

import logging
import resource
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from plyfile import PlyData, PlyElement

from recon.errors import InputError
from recon.io import obj, read_mesh, read_points

ROOT = Path(__file__).resolve().parent.parent


def sphere(n: int = 300, seed: int = 0) -> np.ndarray:
    """Points on a unit sphere (float32-exact values)."""
    rng = np.random.default_rng(seed)
    p = rng.normal(size=(n, 3))
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    return p.astype(np.float32).astype(np.float64)


def write_ply(path: Path, fields: dict[str, np.ndarray], *, text: bool = False) -> Path:
    """A vertex element written with plyfile, an independent writer."""
    n = len(next(iter(fields.values())))
    arr = np.zeros(n, dtype=[(k, v.dtype.str) for k, v in fields.items()])
    for k, v in fields.items():
        arr[k] = v
    PlyData([PlyElement.describe(arr, "vertex")], text=text).write(str(path))
    return path


def xyz_fields(p: np.ndarray) -> dict[str, np.ndarray]:
    return {c: p[:, i].astype(np.float32) for i, c in enumerate("xyz")}


# ------------------------------------------------------------------------ LAS/LAZ headers


def _limit_memory() -> None:
    """In the child: a runaway reader fails with MemoryError instead of eating the machine."""
    resource.setrlimit(resource.RLIMIT_AS, (3 << 30, 3 << 30))


def cli_info(
    path: Path, timeout: float = 60.0, command: tuple[str, ...] = ("info",)
) -> subprocess.CompletedProcess:
    """``oprecon info path`` (or another ``command``) in a child process; a hang fails the
    test after ``timeout``."""
    return subprocess.run(
        [sys.executable, "-m", "recon.cli.main", command[0], str(path), *command[1:]],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=timeout,
        preexec_fn=_limit_memory,
    )


def write_las(path: Path, n: int = 300, version: str = "1.2") -> Path:
    laspy = pytest.importorskip("laspy")
    header = laspy.LasHeader(point_format=3, version=version)
    header.scales = np.array([1e-4] * 3)
    header.offsets = np.zeros(3)
    las = laspy.LasData(header)
    p = sphere(n)
    las.x, las.y, las.z = p[:, 0], p[:, 1], p[:, 2]
    las.write(str(path))
    return path


def patch(path: Path, offset: int, fmt: str, *values: int) -> Path:
    raw = bytearray(path.read_bytes())
    struct.pack_into(fmt, raw, offset, *values)
    path.write_bytes(bytes(raw))
    return path


@pytest.mark.parametrize("suffix", [".las", ".laz"])
def test_las_corrupt_vlr_count_stops_with_one_line(tmp_path, suffix):
    """0xEB000000 VLRs made laspy create empty VLRs for hours, memory growing 43 MB/s."""
    if suffix == ".laz":
        pytest.importorskip("lazrs")
    path = patch(write_las(tmp_path / f"vlrcount{suffix}"), 100, "<I", 0xEB000000)
    proc = cli_info(path)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in proc.stderr
    assert str(path) in lines[0] and "number of VLRs (bytes 100-103)" in lines[0]
    assert "3942645760" in lines[0]


def test_a_tiled_fit_of_a_las_with_a_corrupt_vlr_count_stops_with_one_line(tmp_path):
    """The tiled fit reads the LAS header itself (recon.tiling.source.scan_header) before any
    reader: it hung on the same count."""
    path = patch(write_las(tmp_path / "vlrcount.las"), 100, "<I", 0xEB000000)
    out = tmp_path / "out.ply"
    proc = cli_info(path, command=("fit", "-o", str(out), "--tile-size", "1"))
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "number of VLRs (bytes 100-103)" in lines[0], lines
    assert not out.exists()


def test_las_vlr_count_that_does_not_fit_is_refused(tmp_path):
    """1000 VLRs in no room at all: laspy read them from nothing and went on."""
    path = patch(write_las(tmp_path / "vlr1000.las"), 100, "<I", 1000)
    with pytest.raises(InputError, match=r"vlr1000\.las: .*number of VLRs .* is 1000"):
        read_points(path)


def test_las_header_size_beyond_point_data_is_refused(tmp_path):
    path = patch(write_las(tmp_path / "hdr.las"), 94, "<H", 65535)
    with pytest.raises(InputError, match=r"hdr\.las: .*header size \(bytes 94-95\) is 65535"):
        read_points(path)


def test_las_point_data_offset_beyond_the_file_is_refused(tmp_path):
    path = patch(write_las(tmp_path / "off.las"), 96, "<I", 4294967040)
    with pytest.raises(InputError, match=r"off\.las: .*offset to point data .* beyond the end"):
        read_points(path)


def test_las14_corrupt_evlr_count_stops_with_one_line(tmp_path):
    """The EVLRs are read the same way from the end of the file: the same endless loop."""
    path = write_las(tmp_path / "evlr.las", version="1.4")
    size = path.stat().st_size
    patch(path, 235, "<QI", size, 0xEB000000)
    proc = cli_info(path)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and str(path) in lines[0] and "EVLRs" in lines[0]


@pytest.mark.parametrize("suffix", [".las", ".laz"])
def test_las_valid_files_with_vlrs_and_evlrs_still_read(tmp_path, suffix):
    laspy = pytest.importorskip("laspy")
    if suffix == ".laz":
        pytest.importorskip("lazrs")
    las = laspy.read(str(write_las(tmp_path / "src.las", version="1.4")))
    las.header.vlrs.append(laspy.vlrs.known.WktCoordinateSystemVlr('LOCAL_CS["here"]'))
    las.evlrs = laspy.vlrs.vlrlist.VLRList([laspy.VLR("oprecon", 1, "test", b"x" * 1000)])
    path = tmp_path / f"ok{suffix}"
    las.write(str(path))
    cloud = read_points(path)
    assert len(cloud.points) == 300 and cloud.info["crs"] == 'LOCAL_CS["here"]'


# ------------------------------------------------------------------------------- colours


@pytest.mark.parametrize("text", [False, True])
def test_ply_16bit_colors_are_scaled_by_their_range(tmp_path, text):
    """ushort colours were divided by 255 and came out white."""
    p = sphere()
    rgb8 = np.random.default_rng(1).integers(0, 256, size=(len(p), 3))
    fields = xyz_fields(p) | {
        c: (rgb8[:, j] * 257).astype(np.uint16) for j, c in enumerate(("red", "green", "blue"))
    }
    cloud = read_points(write_ply(tmp_path / "c16.ply", fields, text=text))
    assert np.array_equal(np.round(cloud.colors * 255), rgb8)


def test_ply_float_colors_on_0_255_are_one_decision_for_all_channels(tmp_path):
    """A 0-255 blue channel that never exceeds 1 was taken as 0-1: full blue."""
    p = sphere()
    blue = np.where(np.arange(len(p)) % 2 == 0, 0.0, 1.0).astype(np.float32)
    fields = xyz_fields(p) | {
        "red": np.full(len(p), 200.0, dtype=np.float32),
        "green": np.full(len(p), 100.0, dtype=np.float32),
        "blue": blue,
    }
    cloud = read_points(write_ply(tmp_path / "f255.ply", fields))
    expected = np.column_stack([np.full(len(p), 200.0), np.full(len(p), 100.0), blue]) / 255
    assert np.allclose(cloud.colors, expected)


def test_ply_float_colors_on_0_1_are_kept(tmp_path):
    p = sphere()
    rgb = np.random.default_rng(2).random((len(p), 3)).astype(np.float32)
    fields = xyz_fields(p) | {c: rgb[:, j] for j, c in enumerate(("red", "green", "blue"))}
    cloud = read_points(write_ply(tmp_path / "f01.ply", fields))
    assert np.allclose(cloud.colors, rgb)


@pytest.mark.parametrize(
    ("dtype", "stored", "expected"),
    [
        (np.uint8, [0, 128, 255, 7], [0, 128, 255, 7]),
        (np.int8, [0, -56, -1, 7], [0, 200, 255, 7]),  # byte colours written as signed chars
        (np.int16, [0, 128, 255, 7], [0, 128, 255, 7]),
        (np.int32, [0, 128, 255, 7], [0, 128, 255, 7]),
        (np.uint32, [0, 128, 255, 7], [0, 128, 255, 7]),
    ],
)
def test_ply_integer_colors_are_scaled_by_type(tmp_path, dtype, stored, expected):
    p = sphere(4)
    fields = xyz_fields(p) | {c: np.asarray(stored, dtype=dtype) for c in ("red", "green", "blue")}
    cloud = read_points(write_ply(tmp_path / "ci.ply", fields), merge_duplicates=False)
    assert np.allclose(cloud.colors * 255, np.column_stack([expected] * 3))


def test_ply_wide_integer_colors_past_255_are_said(tmp_path, caplog):
    """16-bit values in an 'int' channel: scaled by the type (255), clipped, and logged."""
    p = sphere(4)
    fields = xyz_fields(p) | {
        c: np.asarray([0, 1000, 65535, 7], dtype=np.int32) for c in ("red", "green", "blue")
    }
    path = write_ply(tmp_path / "cw.ply", fields)
    with caplog.at_level(logging.WARNING, logger="recon.io"):
        read_points(path, merge_duplicates=False)
    assert "cw.ply" in caplog.text and "from 0 to 65535, outside 0 to 255" in caplog.text


# ----------------------------------------------------------------------------------- OBJ


def test_obj_normals_are_paired_by_the_faces_not_by_order(tmp_path, caplog):
    """As many vn as v, in another order: the faces' f v//vn must decide, not the order."""
    p = sphere(300)
    perm = np.random.default_rng(3).permutation(len(p))  # vn line j is the normal of perm[j]
    inv = np.argsort(perm)
    lines = [f"v {a:.9g} {b:.9g} {c:.9g}" for a, b, c in p]
    lines += [f"vn {a:.9g} {b:.9g} {c:.9g}" for a, b, c in p[perm]]
    lines += [
        "f " + " ".join(f"{i + 1}//{inv[i] + 1}" for i in (k, k + 1, k + 2))
        for k in range(0, len(p), 3)
    ]
    path = tmp_path / "faceidx.obj"
    path.write_text("\n".join(lines) + "\n")
    with caplog.at_level(logging.WARNING, logger="recon.io"):
        cloud = read_points(path)
    assert cloud.normals is not None and caplog.text == ""
    assert np.allclose(cloud.normals, p, atol=1e-6)


def test_obj_vertices_in_no_face_get_no_file_normal(tmp_path, caplog):
    """vn in another order than v: a vertex in no face has no normal of its own."""
    p = sphere(300)
    perm = np.random.default_rng(5).permutation(len(p))
    inv = np.argsort(perm)
    lines = [f"v {a:.9g} {b:.9g} {c:.9g}" for a, b, c in p]
    lines += [f"vn {a:.9g} {b:.9g} {c:.9g}" for a, b, c in p[perm]]
    lines += [
        "f " + " ".join(f"{i + 1}//{inv[i] + 1}" for i in (k, k + 1, k + 2))
        for k in range(0, 297, 3)
    ]
    path = tmp_path / "partial.obj"
    path.write_text("\n".join(lines) + "\n")
    with caplog.at_level(logging.WARNING, logger="recon.io"):
        _, _, normals, _ = obj.read_points(path, 1000, {})
    assert "partial.obj" in caplog.text and "3 get no normal from any face" in caplog.text
    assert np.isnan(normals[297:]).all()
    assert np.allclose(normals[:297], p[:297], atol=1e-6)


def test_obj_normals_paired_a_to_a_by_the_faces_pair_in_order(tmp_path, caplog):
    """f a//a everywhere (as oprecon writes): vertices in no face keep their vn too."""
    p = sphere(30)
    lines = [f"v {a:.9g} {b:.9g} {c:.9g}" for a, b, c in p]
    lines += [f"vn {a:.9g} {b:.9g} {c:.9g}" for a, b, c in p]
    lines += [f"f {k + 1}//{k + 1} {k + 2}//{k + 2} {k + 3}//{k + 3}" for k in range(0, 27, 3)]
    path = tmp_path / "aa.obj"
    path.write_text("\n".join(lines) + "\n")
    with caplog.at_level(logging.WARNING, logger="recon.io"):
        cloud = read_points(path)
    assert caplog.text == "" and np.allclose(cloud.normals, p, atol=1e-6)


def test_obj_split_normals_are_not_used_for_their_vertices(tmp_path, caplog):
    """A vertex whose faces give it two normals (a crease) keeps neither."""
    text = (
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nv 1 1 1\n"
        "vn 0 0 -1\nvn 0 -1 0\nvn 0 0 1\nvn 1 0 0\n"
        "f 1//1 3//1 2//1\nf 1//2 2//2 4//2\n"
    )
    path = tmp_path / "split.obj"
    path.write_text(text)
    with caplog.at_level(logging.WARNING, logger="recon.io"):
        _, _, normals, _ = obj.read_points(path, 100, {})
    assert "2 get different normals from different faces" in caplog.text
    assert "1 get no normal from any face" in caplog.text
    assert np.isnan(normals[[0, 1, 4]]).all()
    assert np.array_equal(normals[2:4], [[0, 0, -1], [0, -1, 0]])


def test_obj_normals_without_pairing_faces_are_not_used(tmp_path, caplog):
    """Faces without //vn say nothing about which normal is whose."""
    p = sphere(30)
    lines = [f"v {a:.9g} {b:.9g} {c:.9g}" for a, b, c in p]
    lines += [f"vn {a:.9g} {b:.9g} {c:.9g}" for a, b, c in p[::-1]]
    lines += [f"f {k + 1} {k + 2} {k + 3}" for k in range(0, 30, 3)]
    path = tmp_path / "nopair.obj"
    path.write_text("\n".join(lines) + "\n")
    with caplog.at_level(logging.WARNING, logger="recon.io"):
        cloud = read_points(path)
    assert cloud.normals is None and "nopair.obj" in caplog.text


def test_obj_points_with_one_normal_each_and_no_faces_pair_in_order(tmp_path, caplog):
    p = sphere(30)
    lines = [f"v {a:.9g} {b:.9g} {c:.9g}" for a, b, c in p]
    lines += [f"vn {a:.9g} {b:.9g} {c:.9g}" for a, b, c in p]
    path = tmp_path / "points.obj"
    path.write_text("\n".join(lines) + "\n")
    with caplog.at_level(logging.WARNING, logger="recon.io"):
        cloud = read_points(path)
    assert caplog.text == "" and np.allclose(cloud.normals, p, atol=1e-6)


def test_obj_tabs_and_indented_lines_are_read(tmp_path):
    """'v\\t1\\t2\\t3' and '  v 1 2 3' were refused: "OBJ file has no 'v' vertex lines"."""
    p = sphere(30)
    lines = [
        (f"v\t{a:.9g}\t{b:.9g}\t{c:.9g}" if k % 2 else f"  v {a:.9g} {b:.9g} {c:.9g}")
        for k, (a, b, c) in enumerate(p)
    ]
    lines += [f"\tf\t{k + 1} {k + 2}\t{k + 3}" for k in range(0, 30, 3)]
    path = tmp_path / "tabs.obj"
    path.write_text("\n".join(lines) + "\n")
    cloud = read_points(path)
    assert np.allclose(cloud.absolute_points(), p, atol=1e-8)
    vertices, faces = read_mesh(path)
    assert faces.shape == (10, 3) and np.array_equal(faces[1], [3, 4, 5])


# ----------------------------------------------------------------------------------- PCD


def write_pcd_ascii(path: Path, p: np.ndarray, rgb_tokens: list[str]) -> Path:
    n = len(p)
    head = (
        "VERSION 0.7\nFIELDS x y z rgb\nSIZE 4 4 4 4\nTYPE F F F F\nCOUNT 1 1 1 1\n"
        f"WIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA ascii\n"
    )
    rows = [f"{a:.9g} {b:.9g} {c:.9g} {t}" for (a, b, c), t in zip(p, rgb_tokens, strict=True)]
    path.write_text(head + "\n".join(rows) + "\n")
    return path


def packed(rgb: np.ndarray, alpha: int) -> np.ndarray:
    return (alpha << 24) | (rgb[:, 0] << 16) | (rgb[:, 1] << 8) | rgb[:, 2]


def pcd_rgb(n: int) -> np.ndarray:
    rgb = np.random.default_rng(4).integers(0, 256, size=(n, 3)).astype(np.uint32)
    rgb[:, 0] = np.arange(n) % 15  # red <= 14: every packed value below 1e6
    return rgb


@pytest.mark.parametrize("alpha", [0, 255])
def test_pcd_ascii_float_rgb_written_as_integers(tmp_path, alpha):
    """PCL writes an rgb of TYPE F as the packed integer; below 1e6 it was read as a float."""
    p = sphere(100)
    rgb = pcd_rgb(len(p))
    path = write_pcd_ascii(tmp_path / "int.pcd", p, [str(v) for v in packed(rgb, alpha)])
    cloud = read_points(path)
    assert np.array_equal(np.round(cloud.colors * 255), rgb)


def test_pcd_ascii_float_rgb_written_as_signed_integers(tmp_path):
    p = sphere(100)
    rgb = pcd_rgb(len(p))
    signed = packed(rgb, 255).astype(np.uint32).view(np.int32)
    path = write_pcd_ascii(tmp_path / "signed.pcd", p, [str(v) for v in signed])
    assert np.array_equal(np.round(read_points(path).colors * 255), rgb)


@pytest.mark.parametrize("alpha", [0, 1, 0xFE, 0xFF])
def test_pcd_ascii_float_rgb_written_as_floats(tmp_path, alpha):
    """The older encoding: the float whose bits are the colour, printed (tiny or huge)."""
    p = sphere(100)
    rgb = pcd_rgb(len(p))
    floats = packed(rgb, alpha).astype(np.uint32).view(np.float32)
    path = write_pcd_ascii(tmp_path / "float.pcd", p, [f"{v:.9g}" for v in floats])
    assert np.array_equal(np.round(read_points(path).colors * 255), rgb)


def test_pcd_ascii_float_rgb_nan_is_not_a_colour(tmp_path, caplog):
    p = sphere(100)
    floats = packed(pcd_rgb(len(p)), 0).astype(np.uint32).view(np.float32)
    tokens = [f"{v:.9g}" for v in floats]
    tokens[5] = "nan"
    path = write_pcd_ascii(tmp_path / "nan.pcd", p, tokens)
    with caplog.at_level(logging.WARNING, logger="recon.io"):
        cloud = read_points(path)
    assert cloud.colors is None and "nan.pcd" in caplog.text


# ------------------------------------------------------------------------------ PLY text


PLY_HEAD = (
    "ply\nformat ascii 1.0\nelement vertex {n}\nproperty float x\nproperty float y\n"
    "property float z\n"
)


@pytest.mark.parametrize("text", [True, False])
def test_ply_without_vertices_says_so_in_both_encodings(tmp_path, text):
    """The ascii file said "rows have 1 values, the header declares 3 properties"."""
    path = write_ply(tmp_path / "zero.ply", xyz_fields(np.zeros((0, 3))), text=text)
    with pytest.raises(InputError, match=r"zero\.ply: only 0 distinct finite point"):
        read_points(path)


def test_ply_ascii_blank_lines_in_the_data_are_skipped(tmp_path):
    """A blank line was counted as a row, and the file reported as truncated."""
    path = tmp_path / "blank.ply"
    path.write_text(
        PLY_HEAD.format(n=4)
        + "element face 2\nproperty list uchar int vertex_indices\nend_header\n"
        + "0 0 0\n\n1 0 0\n0 1 0\n  \n0 0 1\n\n3 0 1 2\n\n3 0 1 3\n\n"
    )
    cloud = read_points(path, merge_duplicates=False)
    assert np.array_equal(cloud.absolute_points(), [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    _, faces = read_mesh(path)
    assert np.array_equal(faces, [[0, 1, 2], [0, 1, 3]])


def test_ply_ascii_blank_lines_in_a_skipped_element(tmp_path):
    path = tmp_path / "blank2.ply"
    path.write_text(
        "ply\nformat ascii 1.0\nelement camera 2\nproperty float k\n"
        + PLY_HEAD.format(n=4)[len("ply\nformat ascii 1.0\n") :]
        + "end_header\n7\n\n8\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n"
    )
    assert len(read_points(path).points) == 4


def test_ply_utf8_comment_in_the_header_is_accepted(tmp_path):
    """Open3D reads "comment Créé par Müller"; it was refused as non-ASCII."""
    path = write_ply(tmp_path / "utf8.ply", xyz_fields(sphere(20)))
    raw = path.read_bytes().replace(
        b"format binary_little_endian 1.0\n",
        "format binary_little_endian 1.0\ncomment Créé par Müller\nobj_info Ünïcode\n".encode(),
        1,
    )
    path.write_bytes(raw)
    assert np.allclose(read_points(path).absolute_points(), sphere(20))


def test_ply_non_ascii_outside_comments_is_still_refused(tmp_path):
    path = write_ply(tmp_path / "utf8name.ply", xyz_fields(sphere(20)))
    path.write_bytes(path.read_bytes().replace(b"element vertex", "element vértex".encode(), 1))
    with pytest.raises(InputError, match=r"utf8name\.ply: PLY header contains non-ASCII bytes"):
        read_points(path)


def test_ply_intensity_and_classification_are_read_for_the_transfer(tmp_path):
    """Regression: ``info`` listed a PLY's ``intensity``, but ``fit --transfer intensity``
    said the input had none (the PLY reader kept no per-point scalar)."""
    from recon.io import write_points

    p = sphere(200)
    path = tmp_path / "s.ply"
    classes = np.arange(200) % 7
    write_points(
        path,
        p,
        vertex_properties={
            "intensity": np.arange(200.0),
            "classification": classes.astype(np.uint8),
        },
    )
    cloud = read_points(path)
    np.testing.assert_array_equal(cloud.attributes["intensity"], np.arange(200.0))
    np.testing.assert_array_equal(cloud.attributes["classification"], classes)
    assert cloud.attributes["classification"].dtype == np.uint8


def test_ply_classes_above_255_are_kept_with_their_values(tmp_path, caplog):
    """Regression: an ``int classification`` of 300-302 was read as 255 for every point with
    no word, and ``oprecon normals`` wrote 255; then the fit's read clipped them to 255 with a
    warning. Every read keeps the values now (``--transfer classification`` writes them as
    ``int``: tests/test_wide_classes.py), with no warning."""
    p = sphere(60)
    classes = (300 + np.arange(60) % 3).astype(np.int32)
    for text in (False, True):
        path = write_ply(
            tmp_path / f"c{int(text)}.ply", {**xyz_fields(p), "classification": classes}, text=text
        )
        for all_properties in (True, False):
            with caplog.at_level(logging.WARNING, logger="recon.io"):
                caplog.clear()
                got = read_points(path, all_properties=all_properties)
            assert caplog.text == ""
            np.testing.assert_array_equal(got.attributes["classification"], classes)
            assert got.attributes["classification"].dtype == np.int32


def test_ply_classes_in_0_255_stay_uint8_whatever_the_declared_type(tmp_path):
    """LAS classes (0-255) are uint8 in every reader, as ``--transfer classification`` writes
    them; a PLY declaring them ``int`` or ``float`` gives the same."""
    p = sphere(40)
    classes = np.arange(40) % 7
    for dtype in (np.int32, np.uint16, np.float32):
        path = write_ply(
            tmp_path / "c.ply", {**xyz_fields(p), "classification": classes.astype(dtype)}
        )
        got = read_points(path).attributes["classification"]
        assert got.dtype == np.uint8
        np.testing.assert_array_equal(got, classes)


def test_ply_other_vertex_properties_are_kept_on_request(tmp_path, caplog):
    """``all_properties=True`` (``oprecon normals``) keeps every other scalar vertex property
    under its own name and type, in the file's order; a lone ``red`` (no colours) cannot be
    written back beside the colours and is named in a warning. Without it, they are not read
    (the fit has no use for them)."""
    p = sphere(50)
    rng = np.random.default_rng(1)
    fields = {
        **xyz_fields(p),
        "quality": rng.uniform(size=50).astype(np.float32),
        "gps_time": 3e8 + rng.uniform(size=50),  # double, not float32-exact
        "alpha": np.full(50, 200, dtype=np.uint8),
        "intensity": np.arange(50, dtype=np.uint16),
        "segment": -np.arange(50, dtype=np.int16),
        "red": np.full(50, 7, dtype=np.uint8),
    }
    for text in (False, True):
        path = write_ply(tmp_path / f"q{int(text)}.ply", fields, text=text)
        assert set(read_points(path).attributes) == {"intensity"}
        with caplog.at_level(logging.WARNING, logger="recon.io"):
            caplog.clear()
            attrs = read_points(path, all_properties=True).attributes
        assert list(attrs) == ["quality", "gps_time", "alpha", "intensity", "segment"]
        for name in ("quality", "gps_time", "alpha", "segment"):
            assert attrs[name].dtype == fields[name].dtype, name
            np.testing.assert_array_equal(attrs[name], fields[name])
        np.testing.assert_array_equal(attrs["intensity"], np.arange(50.0))
        assert "red" in caplog.text and "not kept" in caplog.text


def test_write_points_keeps_the_types_of_vertex_properties(tmp_path):
    """Every PLY type round-trips through ``write_points``; float64 is written as ``float``
    when float32 holds each value exactly, else as ``double`` (no value is rounded)."""
    from recon.io import write_points

    p = sphere(4)
    props = {
        "a": np.array([-1, 2, 3, 4], dtype=np.int8),
        "b": np.array([-300, 2, 3, 4], dtype=np.int16),
        "c": np.array([4_000_000_000, 2, 3, 4], dtype=np.uint32),
        "d": np.array([0.5, 1.0, 2.0, 3.0]),
        "e": np.array([3e8 + 0.123456, 1.0, 2.0, 3.0]),
        "f": np.array([1, 2, 3, 2**40], dtype=np.int64),
    }
    want = {"a": "i1", "b": "i2", "c": "u4", "d": "f4", "e": "f8", "f": "f8"}
    for ascii in (False, True):
        path = tmp_path / f"w{int(ascii)}.ply"
        write_points(path, p, vertex_properties=props, ascii=ascii)
        v = PlyData.read(str(path))["vertex"]
        for name, values in props.items():
            assert v[name].dtype.str[1:] == want[name], name
            np.testing.assert_array_equal(v[name], values)
