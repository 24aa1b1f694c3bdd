"""recon.io: every reader round-trips, hostile files give InputError naming file and problem."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from plyfile import PlyData, PlyElement

from recon.errors import InputError
from recon.io import (
    PointCloud,
    atomic_output,
    atomic_outputs,
    check_output_path,
    choose_origin,
    cloud_from_arrays,
    read_mesh,
    read_points,
    write_mesh,
    write_points,
)

SAMPLES = Path(__file__).resolve().parent.parent / "sample_data"


def cloud(n: int = 200, seed: int = 0) -> np.ndarray:
    """Points on a unit sphere (float32-exact values), spanning 3-D."""
    rng = np.random.default_rng(seed)
    p = rng.normal(size=(n, 3))
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    return p.astype(np.float32).astype(np.float64)


def write_plyfile(
    path: Path, fields: dict[str, np.ndarray], *, text=False, byte_order="<", extra=()
) -> None:
    """Write a vertex element (plus extra elements) with plyfile, an independent writer."""
    n = len(next(iter(fields.values())))
    arr = np.zeros(n, dtype=[(k, v.dtype.str) for k, v in fields.items()])
    for k, v in fields.items():
        arr[k] = v
    elements = [PlyElement.describe(arr, "vertex")]
    elements = (
        [e for e in extra if e.name != "face"] + elements + [e for e in extra if e.name == "face"]
    )
    PlyData(elements, text=text, byte_order=byte_order).write(str(path))


def xyz_fields(p: np.ndarray, dtype=np.float32) -> dict[str, np.ndarray]:
    return {c: p[:, i].astype(dtype) for i, c in enumerate("xyz")}


# ------------------------------------------------------------------------------ PLY readers


@pytest.mark.parametrize("text,order", [(False, "<"), (False, ">"), (True, "=")])
def test_ply_roundtrip_plyfile(tmp_path, text, order):
    p = cloud()
    path = tmp_path / "c.ply"
    write_plyfile(path, xyz_fields(p), text=text, byte_order=order)
    c = read_points(path)
    expected = {
        (False, "<"): "ply-binary_little_endian",
        (False, ">"): "ply-binary_big_endian",
        (True, "="): "ply-ascii",
    }[(text, order)]
    assert c.format == expected
    np.testing.assert_array_equal(c.absolute_points(), p)
    assert c.points.dtype == np.float64 and c.points.flags.c_contiguous
    assert c.normals is None and c.colors is None
    assert c.info["n_read"] == 200 and c.info["n_points"] == 200
    assert c.path == path


@pytest.mark.parametrize("dtype", ["i1", "u1", "i2", "u2", "i4", "u4", "f4", "f8"])
def test_ply_any_numeric_type(tmp_path, dtype):
    rng = np.random.default_rng(1)
    p = rng.integers(0, 100, size=(50, 3)).astype(np.float64)
    path = tmp_path / "t.ply"
    write_plyfile(path, xyz_fields(p, np.dtype(dtype)), byte_order=">")
    c = read_points(path, merge_duplicates=False)
    np.testing.assert_array_equal(c.absolute_points(), p)


def test_ply_normals_and_colors(tmp_path):
    p = cloud()
    fields = xyz_fields(p)
    fields.update({f"n{c}": (2.0 * p[:, i]).astype(np.float32) for i, c in enumerate("xyz")})
    rgb = np.random.default_rng(2).integers(0, 256, size=(200, 3)).astype(np.uint8)
    fields.update({c: rgb[:, i] for i, c in enumerate(("red", "green", "blue"))})
    path = tmp_path / "nc.ply"
    write_plyfile(path, fields, byte_order=">")
    c = read_points(path)
    np.testing.assert_allclose(c.normals, p, atol=1e-6)  # normalised
    np.testing.assert_allclose(np.linalg.norm(c.normals, axis=1), 1.0)
    np.testing.assert_allclose(c.colors, rgb / 255.0)
    assert c.info["properties"][:6] == ["x", "y", "z", "nx", "ny", "nz"]


@pytest.mark.parametrize("text", [False, True])
def test_ply_extra_elements_camera_and_face(tmp_path, text):
    p = cloud(100)
    camera = np.zeros(1, dtype=[("view_px", "f4"), ("view_py", "f4"), ("view_pz", "f4")])
    faces = np.zeros(3, dtype=[("vertex_indices", "i4", (3,)), ("flags", "u1")])
    faces["vertex_indices"] = [[0, 1, 2], [2, 3, 4], [5, 6, 7]]
    path = tmp_path / "e.ply"
    write_plyfile(
        path,
        xyz_fields(p),
        text=text,
        extra=[PlyElement.describe(camera, "camera"), PlyElement.describe(faces, "face")],
    )
    c = read_points(path)
    np.testing.assert_array_equal(c.absolute_points(), p)
    assert c.info["has_faces"] is True
    assert c.info["elements"] == {"camera": 1, "vertex": 100, "face": 3}
    v, f = read_mesh(path)
    np.testing.assert_array_equal(v, p)
    np.testing.assert_array_equal(f, [[0, 1, 2], [2, 3, 4], [5, 6, 7]])


@pytest.mark.parametrize("text", [False, True])
def test_ply_polygons_are_fan_triangulated(tmp_path, text):
    p = cloud(10)
    faces = np.empty(2, dtype=[("vertex_indices", "O")])
    faces["vertex_indices"][0] = np.array([0, 1, 2, 3], dtype=np.int32)
    faces["vertex_indices"][1] = np.array([4, 5, 6, 7, 8], dtype=np.int32)
    path = tmp_path / "poly.ply"
    el = PlyElement.describe(faces, "face", val_types={"vertex_indices": "i4"})
    write_plyfile(path, xyz_fields(p), text=text, extra=[el])
    _, f = read_mesh(path)
    np.testing.assert_array_equal(f, [[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7], [4, 7, 8]])


def test_real_sample_files():
    c = read_points(SAMPLES / "bunny-sparse.ply")
    assert len(c) == 2000 and c.format == "ply-binary_little_endian"
    ref = PlyData.read(str(SAMPLES / "bunny-sparse.ply"))["vertex"]
    np.testing.assert_array_equal(c.absolute_points()[:, 0], ref["x"].astype(np.float64))
    sq = read_points(SAMPLES / "square_hole-clean.ply")
    assert len(sq) == 15000 and np.all(sq.points[:, 2] == 0.0)


# ------------------------------------------------------------------------------ writers


@pytest.mark.parametrize("ascii_", [False, True])
def test_write_points_roundtrip_and_plyfile_reads_it(tmp_path, ascii_):
    p = cloud()
    n = p / np.linalg.norm(p, axis=1, keepdims=True)
    path = tmp_path / "w.ply"
    write_points(path, p, n, ascii=ascii_)
    ref = PlyData.read(str(path))
    assert ref.text == ascii_
    assert ref["vertex"]["x"].dtype == np.float32  # float32 is enough here
    c = read_points(path)
    np.testing.assert_array_equal(c.absolute_points(), p)
    np.testing.assert_allclose(c.normals, n, atol=1e-6)


def test_large_offsets_roundtrip_exactly(tmp_path):
    rng = np.random.default_rng(3)
    detail = rng.integers(0, 2_000_000, size=(500, 3)) * 1e-3  # mm detail over 2 km
    absolute = np.array([5_000_000.0, 4_200_000.0, 300.0]) + detail
    first = tmp_path / "geo.ply"
    write_points(first, absolute)
    assert PlyData.read(str(first))["vertex"]["x"].dtype == np.float64  # float32 would lose mm
    c = read_points(first)
    np.testing.assert_array_equal(c.absolute_points(), absolute)
    assert np.any(c.origin != 0) and np.abs(c.points).max() < 3000
    for ascii_ in (False, True):
        again = tmp_path / f"geo-{ascii_}.ply"
        write_points(again, c.points, origin=c.origin, ascii=ascii_)
        c2 = read_points(again)
        np.testing.assert_array_equal(c2.absolute_points(), absolute)
        np.testing.assert_array_equal(c2.origin, c.origin)


def test_tiny_scale(tmp_path):
    p = cloud(300) * 1e-6
    path = tmp_path / "tiny.ply"
    write_points(path, p)
    c = read_points(path)
    np.testing.assert_allclose(c.absolute_points(), p, rtol=0, atol=1e-13)
    assert not np.any(c.origin)


@settings(max_examples=25, deadline=None)
@given(
    scale=st.sampled_from([1e-6, 1.0, 1e3]),
    offset=st.sampled_from([0.0, 1e4, 5e6]),
    seed=st.integers(0, 2**16),
)
def test_write_read_precision_property(tmp_path_factory, scale, offset, seed):
    rng = np.random.default_rng(seed)
    p = rng.uniform(-1, 1, size=(30, 3)) * scale + offset
    path = tmp_path_factory.mktemp("prop") / "p.ply"
    write_points(path, p)
    back = read_points(path, merge_duplicates=False).absolute_points()
    extent = np.max(p.max(0) - p.min(0))
    assert np.max(np.abs(back - p)) <= 1e-7 * extent


@pytest.mark.parametrize("name", ["m.ply", "m.obj"])
@pytest.mark.parametrize("ascii_", [False, True])
def test_write_mesh_roundtrip(tmp_path, name, ascii_):
    v = cloud(12)
    f = np.array([[0, 1, 2], [1, 2, 3], [4, 5, 6], [9, 10, 11]])
    n = v / np.linalg.norm(v, axis=1, keepdims=True)
    path = tmp_path / name
    write_mesh(path, v, f, n, ascii=ascii_)
    v2, f2 = read_mesh(path)
    np.testing.assert_allclose(v2, v, atol=1e-7)
    np.testing.assert_array_equal(f2, f)
    assert f2.dtype == np.int64 and v2.dtype == np.float64


def test_write_mesh_with_origin_and_plyfile(tmp_path):
    v = cloud(12)
    f = np.array([[0, 1, 2], [3, 4, 5]])
    origin = np.array([1e6, 2e6, 0.0])
    path = tmp_path / "o.ply"
    write_mesh(path, v, f, origin=origin)
    ref = PlyData.read(str(path))
    np.testing.assert_array_equal(ref["vertex"]["x"], v[:, 0] + origin[0])
    np.testing.assert_array_equal(np.vstack(ref["face"]["vertex_indices"]), f)
    v2, _ = read_mesh(path)
    np.testing.assert_array_equal(v2, v + origin)


def test_write_mesh_rejects_bad_input(tmp_path):
    v = cloud(5)
    with pytest.raises(InputError, match="out of range"):
        write_mesh(tmp_path / "a.ply", v, np.array([[0, 1, 9]]))
    with pytest.raises(InputError, match=r"\.stl"):
        write_mesh(tmp_path / "a.stl", v, np.array([[0, 1, 2]]))
    with pytest.raises(InputError, match=r"\(n, 3\)"):
        write_points(tmp_path / "a.ply", np.zeros((4, 2)))
    assert not list(tmp_path.iterdir())


# ------------------------------------------------------------------------------ text, PCD, OBJ


def test_xyz_space_comma_comments(tmp_path):
    p = cloud(20)
    lines = ["# a comment", "// another"] + [f"{a!r}, {b!r},{c!r}" for a, b, c in p.tolist()]
    path = tmp_path / "c.xyz"
    path.write_text("\n".join(lines[:10]) + "\n\n" + "\n".join(lines[10:]) + "\n")
    c = read_points(path)
    assert c.format == "xyz"
    np.testing.assert_array_equal(c.absolute_points(), p)
    tabbed = tmp_path / "t.txt"
    np.savetxt(tabbed, p, delimiter="\t", fmt="%.17g")
    np.testing.assert_array_equal(read_points(tabbed).absolute_points(), p)


def test_xyzn_and_xyzrgb(tmp_path):
    p = cloud(50)
    path = tmp_path / "n.xyzn"
    np.savetxt(path, np.hstack([p, p]), fmt="%.17g")
    c = read_points(path)
    np.testing.assert_allclose(c.normals, p, atol=1e-12)
    rgb = np.random.default_rng(0).integers(0, 256, (50, 3))
    path2 = tmp_path / "rgb.txt"
    np.savetxt(path2, np.hstack([p, rgb]), fmt="%.17g")
    c2 = read_points(path2)
    assert c2.normals is None
    np.testing.assert_allclose(c2.colors, rgb / 255.0)


def test_csv_with_header(tmp_path):
    p = cloud(25)
    rows = np.hstack([p[:, [2]], np.arange(25)[:, None], p[:, :2], p])  # z, id, x, y, normals
    path = tmp_path / "pts.dat"
    body = "\n".join(",".join(repr(v) for v in r) for r in rows.tolist())
    path.write_text('"Z",id,X,Y,nx,ny,nz\n' + body + "\n")
    c = read_points(path)
    np.testing.assert_array_equal(c.absolute_points(), p)
    np.testing.assert_allclose(c.normals, p, atol=1e-12)
    bad = tmp_path / "bad.csv"
    bad.write_text("a,b,c\n1,2,3\n")
    with pytest.raises(InputError, match="header naming x, y, z"):
        read_points(bad)


def test_pts_with_count_intensity_rgb(tmp_path):
    p = cloud(30)
    rgb = np.random.default_rng(0).integers(0, 256, (30, 3))
    path = tmp_path / "s.pts"
    body = "\n".join(
        f"{a!r} {b!r} {c!r} -120 {r} {g} {bl}"
        for (a, b, c), (r, g, bl) in zip(p.tolist(), rgb.tolist(), strict=True)
    )
    path.write_text(f"30\n{body}\n")
    c = read_points(path)
    assert c.format == "pts"
    np.testing.assert_array_equal(c.absolute_points(), p)
    np.testing.assert_allclose(c.colors, rgb / 255.0)
    assert "intensity" in c.info["properties"]
    path4 = tmp_path / "i.pts"
    np.savetxt(path4, np.hstack([p, np.ones((30, 1))]), fmt="%.17g")
    c4 = read_points(path4)
    np.testing.assert_array_equal(c4.absolute_points(), p)
    assert c4.colors is None


def _pcd_header(n: int, data: str, fields="x y z rgb", size="4 4 4 4", typ="F F F F") -> str:
    return (
        f"# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS {fields}\n"
        f"SIZE {size}\nTYPE {typ}\nCOUNT {' '.join('1' for _ in fields.split())}\n"
        f"WIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA {data}\n"
    )


def test_pcd_binary_and_ascii(tmp_path):
    p = cloud(40).astype(np.float32)
    rgb = np.random.default_rng(0).integers(0, 256, (40, 3)).astype(np.uint32)
    packed = (rgb[:, 0] << 16) | (rgb[:, 1] << 8) | rgb[:, 2]
    rows = np.zeros(40, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("rgb", "<u4")])
    for i, c in enumerate("xyz"):
        rows[c] = p[:, i]
    rows["rgb"] = packed
    binary = tmp_path / "b.pcd"
    binary.write_bytes(_pcd_header(40, "binary").encode() + rows.tobytes())
    c = read_points(binary)
    assert c.format == "pcd-binary"
    np.testing.assert_array_equal(c.absolute_points(), p.astype(np.float64))
    np.testing.assert_allclose(c.colors, rgb / 255.0)
    ascii_ = tmp_path / "a.pcd"
    body = "\n".join(
        f"{a!r} {b!r} {cc!r} {int(v)}"
        for (a, b, cc), v in zip(p.astype(np.float64).tolist(), packed.tolist(), strict=True)
    )
    ascii_.write_text(_pcd_header(40, "ascii") + body + "\n")
    c2 = read_points(ascii_)
    assert c2.format == "pcd-ascii"
    np.testing.assert_array_equal(c2.absolute_points(), p.astype(np.float64))
    np.testing.assert_allclose(c2.colors, rgb / 255.0)


def test_pcd_normals_and_nan_points(tmp_path):
    p = cloud(20)
    p[3] = np.nan  # organised clouds mark missing points with NaN
    body = "\n".join(" ".join(repr(v) for v in (*q, *q)) for q in p.tolist())
    path = tmp_path / "n.pcd"
    path.write_text(
        _pcd_header(20, "ascii", "x y z normal_x normal_y normal_z", "4 4 4 4 4 4", "F F F F F F")
        + body
        + "\n"
    )
    c = read_points(path)
    assert len(c) == 19 and c.info["n_nonfinite_dropped"] == 1
    np.testing.assert_allclose(c.normals, np.delete(p, 3, axis=0), atol=1e-6)


def test_pcd_binary_compressed_is_refused(tmp_path):
    path = tmp_path / "c.pcd"
    path.write_bytes(_pcd_header(10, "binary_compressed").encode() + b"\x00" * 64)
    with pytest.raises(InputError, match="binary_compressed.*not supported") as e:
        read_points(path)
    assert str(path) in str(e.value)


def test_obj_points_normals_and_mesh(tmp_path):
    p = cloud(8)
    lines = ["# obj", "o thing"] + [f"v {a!r} {b!r} {c!r}" for a, b, c in p.tolist()]
    lines += [f"vn {a!r} {b!r} {c!r}" for a, b, c in p.tolist()]
    lines += ["vt 0 0", "f 1/1/1 2/1/2 3/1/3 4/1/4", "f -1 -2 -3", "f 5//5 6//6 7//7"]
    path = tmp_path / "m.obj"
    path.write_text("\n".join(lines) + "\n")
    c = read_points(path)
    assert c.format == "obj" and c.info["has_faces"]
    np.testing.assert_array_equal(c.absolute_points(), p)
    np.testing.assert_allclose(c.normals, p, atol=1e-12)
    v, f = read_mesh(path)
    np.testing.assert_array_equal(v, p)
    np.testing.assert_array_equal(f, [[0, 1, 2], [0, 2, 3], [7, 6, 5], [4, 5, 6]])


def test_unknown_extension_is_sniffed(tmp_path):
    p = cloud(20)
    a = tmp_path / "points.dat"
    np.savetxt(a, p, fmt="%.17g")
    np.testing.assert_array_equal(read_points(a).absolute_points(), p)
    b = tmp_path / "cloud.bin"
    write_points(b, p)
    assert read_points(b).format == "ply-binary_little_endian"


# ------------------------------------------------------------------------------ cleaning


def test_nonfinite_dropped_and_duplicates_merged(tmp_path, caplog):
    p = cloud(50)
    data = np.vstack([p, p[:5], [[np.nan, 0, 0], [np.inf, 1, 1]]])
    path = tmp_path / "d.ply"
    write_plyfile(path, xyz_fields(data))
    with caplog.at_level("INFO", logger="recon.io"):
        c = read_points(path)
    assert len(c) == 50
    assert c.info["n_read"] == 57
    assert c.info["n_nonfinite_dropped"] == 2
    assert c.info["n_duplicates_merged"] == 5
    np.testing.assert_array_equal(c.absolute_points(), p)  # first occurrences, in order
    assert "non-finite" in caplog.text and "merged 5" in caplog.text
    assert len(read_points(path, merge_duplicates=False)) == 55


def test_invalid_normals_few_and_many(tmp_path):
    p = cloud(100)
    nrm = p.copy()
    nrm[:3] = 0.0
    nrm[3] = np.nan
    few = cloud_from_arrays(p, nrm)
    assert few.info["n_invalid_normals"] == 4
    assert np.isnan(few.normals[:4]).all() and np.isfinite(few.normals[4:]).all()
    nrm[:20] = 0.0
    many = cloud_from_arrays(p, nrm)
    assert many.normals is None and many.info["normals_dropped"]


def test_choose_origin():
    small = np.array([[0.0, 0, 0], [1, 1, 1]])
    assert not np.any(choose_origin(small))
    geo = np.array([[5_000_123.4, 4_100_000.0, 12.0], [5_000_987.6, 4_100_500.0, 80.0]])
    o = choose_origin(geo)
    np.testing.assert_array_equal(o, [5_001_000.0, 4_100_000.0, 0.0])
    assert np.all(np.abs(geo - o) < 1000)


def test_cloud_from_arrays():
    p = cloud(30) + 1e7
    c = cloud_from_arrays(p)
    assert isinstance(c, PointCloud) and c.path is None and c.format == "array"
    np.testing.assert_array_equal(c.absolute_points(), p)
    with pytest.raises(InputError, match="input array"):
        cloud_from_arrays(np.zeros((3, 3)))


# ------------------------------------------------------------------------------ hostile files


def _bad(path: Path, *needles: str, **kw) -> InputError:
    with pytest.raises(InputError) as e:
        read_points(path, **kw)
    msg = str(e.value)
    assert msg.startswith(f"{path}: "), msg
    for needle in needles:
        assert needle in msg, msg
    return e.value


def _ply_header(n: int, fmt="binary_little_endian", props="xyz", typ="float") -> bytes:
    lines = ["ply", f"format {fmt} 1.0", f"element vertex {n}"]
    lines += [f"property {typ} {c}" for c in props] + ["end_header"]
    return ("\n".join(lines) + "\n").encode()


def test_missing_directory_empty(tmp_path):
    _bad(tmp_path / "nope.ply", "no such file")
    _bad(tmp_path, "is a directory")
    empty = tmp_path / "empty.ply"
    empty.write_bytes(b"")
    _bad(empty, "empty")


def test_wrong_magic(tmp_path):
    path = tmp_path / "m.ply"
    path.write_bytes(b"PK\x03\x04 this is a zip file" + b"\x00" * 100)
    _bad(path, "not a PLY file", "magic")


def test_truncated_binary_ply(tmp_path):
    path = tmp_path / "t.ply"
    write_points(path, cloud(100))
    data = path.read_bytes()
    path.write_bytes(data[: len(data) - 50])
    _bad(path, "truncated")
    path.write_bytes(data[:40])  # inside the header
    _bad(path, "truncated PLY header")


def test_truncated_ascii_ply(tmp_path):
    path = tmp_path / "t.ply"
    path.write_bytes(_ply_header(10, "ascii") + b"0 0 0\n1 0 0\n0 1 0\n0 0 1\n1 1 1\n" * 1)
    _bad(path, "truncated")


def test_header_memory_bomb_is_checked_before_allocating(tmp_path):
    path = tmp_path / "bomb.ply"
    path.write_bytes(_ply_header(10**12) + b"\x00" * 120)
    _bad(path, "truncated", "1000000000000 vertex")
    ascii_bomb = tmp_path / "bomb-ascii.ply"
    ascii_bomb.write_bytes(_ply_header(10**12, "ascii") + b"0 0 0\n" * 10)
    _bad(ascii_bomb, "truncated")
    pcd = tmp_path / "bomb.pcd"
    pcd.write_bytes(_pcd_header(10**12, "binary", "x y z", "4 4 4", "F F F").encode() + b"\0" * 99)
    _bad(pcd, "exceed", "max_points")
    _bad(pcd, "truncated PCD", max_points=10**13)


def test_max_points(tmp_path):
    path = tmp_path / "c.ply"
    write_points(path, cloud(100))
    _bad(path, "exceed", "max_points", max_points=50)


def test_a_ragged_row_is_named_in_our_words(tmp_path):
    """Regression: a row with fewer or more values than the rows before it gave numpy's
    message, whose advice ("use `usecols` ...") names a numpy argument the user cannot pass."""
    ply = tmp_path / "a.ply"
    ply.write_bytes(_ply_header(4, "ascii") + b"0.5 0.5 0.5\n1.5 0.5 0.5\n1.5 1.5\n0.5 0.5 1.5\n")
    xyz = tmp_path / "a.xyz"
    xyz.write_text("0 0 0\n1 0 0\n1 1 1 1 1 1 1\n0 0 1\n")
    pcd = tmp_path / "a.pcd"
    header = _pcd_header(3, "ascii", "x y z", "4 4 4", "F F F")
    pcd.write_text(header + "0.5 0.5 0.5\n1.5 0.5\n0.5 0.5 1.5\n")
    for path, row, got in ((ply, 3, 2), (xyz, 3, 7), (pcd, 2, 2)):
        msg = str(_bad(path, f"row {row} has {got} columns", "the rows before it have 3"))
        assert "usecols" not in msg, msg


def test_non_numeric_tokens(tmp_path):
    ply = tmp_path / "a.ply"
    ply.write_bytes(_ply_header(4, "ascii") + b"0 0 0\n1 0 0\n0 1 abc\n0 0 1\n")
    _bad(ply, "abc")
    xyz = tmp_path / "a.xyz"
    xyz.write_text("0 0 0\n1 0 0\n0 1 zzz\n0 0 1\n")
    _bad(xyz, "zzz")
    obj = tmp_path / "a.obj"
    obj.write_text("v 0 0 0\nv 1 0 0\nv 0 1 q\nv 0 0 1\n")
    _bad(obj, "line 3", "q")


def test_ragged_text_rows(tmp_path):
    xyz = tmp_path / "r.xyz"
    xyz.write_text("0 0 0\n1 0 0\n0 1\n0 0 1\n")
    _bad(xyz, "columns")


def test_unknown_binary_extension(tmp_path):
    path = tmp_path / "x.bin"  # (.las is a supported format since issue #14)
    path.write_bytes(bytes(range(256)) * 4)
    err = _bad(path, "unknown file format", "PLY", "PCD", "OBJ", "LAS/LAZ", "E57")
    assert ".bin" in str(err)


def test_binary_file_named_xyz(tmp_path):
    path = tmp_path / "x.xyz"
    path.write_bytes(b"\xff\xfe\x00\x81" * 100)
    _bad(path, "not a text file")


def test_bad_ply_headers(tmp_path):
    path = tmp_path / "h.ply"
    path.write_bytes(
        b"ply\nformat binary_little_endian 1.0\nelement face 2\n"
        b"property list uchar int vertex_indices\nend_header\n" + b"\0" * 40
    )
    _bad(path, "no 'vertex' element")
    path.write_bytes(_ply_header(4, props="xy") + b"\0" * 32)
    _bad(path, "lacks x, y, z")
    path.write_bytes(b"ply\nformat binary_middle_endian 1.0\nend_header\n")
    _bad(path, "unsupported format")
    path.write_bytes(_ply_header(4, typ="float128"))
    _bad(path, "unknown property type")


@pytest.mark.parametrize("version", ["2.0", "0.9", "1.1", "1.0.1", "one"])
@pytest.mark.parametrize("encoding", ["ascii", "binary_little_endian", "binary_big_endian"])
def test_ply_version_other_than_1_0_is_refused(tmp_path, encoding, version):
    """PLY has only version 1.0 (issue #10): any other version names the file and the version."""
    path = tmp_path / "v.ply"
    order = {"ascii": "=", "binary_little_endian": "<", "binary_big_endian": ">"}[encoding]
    write_plyfile(path, xyz_fields(cloud(20)), text=encoding == "ascii", byte_order=order)
    good = path.read_bytes()
    assert f"format {encoding} 1.0\n".encode() in good
    path.write_bytes(good.replace(b" 1.0\n", f" {version}\n".encode(), 1))
    err = _bad(path, "PLY version", f"'{version}'", "1.0")
    with pytest.raises(InputError) as e:
        read_mesh(path)
    assert str(e.value) == str(err)


@pytest.mark.parametrize(
    "points,needle",
    [
        (np.zeros((3, 3)) + np.arange(3)[:, None], "at least 4"),
        (np.ones((10, 3)), "only 1 distinct"),
        (np.outer(np.arange(10.0), [1, 2, 3]), "one line"),
    ],
)
def test_degenerate_inputs(tmp_path, points, needle):
    path = tmp_path / "d.ply"
    write_points(path, points)
    _bad(path, needle)


def test_read_mesh_errors(tmp_path):
    path = tmp_path / "m.xyz"
    np.savetxt(path, cloud(5))
    with pytest.raises(InputError, match=r"\.ply and \.obj"):
        read_mesh(path)
    obj = tmp_path / "m.obj"
    obj.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 7\n")
    with pytest.raises(InputError, match="out of range"):
        read_mesh(obj)
    ply = tmp_path / "m.ply"
    ply.write_bytes(
        b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\n"
        b"property float y\nproperty float z\nelement face 5\n"
        b"property list uchar int vertex_indices\nend_header\n"
        + np.zeros(9, "<f4").tobytes()
        + struct.pack("<B3i", 3, 0, 1, 2)
    )
    with pytest.raises(InputError, match="truncated"):
        read_mesh(ply)


# ------------------------------------------------------------------------------ output paths


def test_atomic_output_success_and_failure(tmp_path):
    dest = tmp_path / "out.ply"
    with atomic_output(dest) as tmp:
        assert tmp.parent == tmp_path and tmp.suffix == ".ply" and tmp != dest
        tmp.write_text("new")
        assert not dest.exists()
    assert dest.read_text() == "new"
    for exc in (RuntimeError, KeyboardInterrupt):
        with pytest.raises(exc), atomic_output(dest) as tmp:
            tmp.write_text("partial")
            raise exc()
        assert dest.read_text() == "new"
        assert sorted(p.name for p in tmp_path.iterdir()) == ["out.ply"]


@pytest.mark.parametrize("name", ["w.ply", "w.obj"])
def test_writer_failure_leaves_nothing(tmp_path, monkeypatch, name):
    """The format writer fails half-way through its temporary file: nothing is left."""
    import recon.io.obj
    import recon.io.ply

    module = recon.io.ply if name.endswith(".ply") else recon.io.obj
    real = module.write

    def boom(fh, *a, **k):
        real(fh, *a, **k)
        fh.flush()
        assert [p.stat().st_size > 0 for p in tmp_path.iterdir()] == [True]
        raise KeyboardInterrupt

    monkeypatch.setattr(module, "write", boom)
    p = cloud(10)
    with pytest.raises(KeyboardInterrupt):
        if name.endswith(".ply"):
            write_points(tmp_path / name, p)
        write_mesh(tmp_path / name, p, np.array([[0, 1, 2]]))
    assert list(tmp_path.iterdir()) == []


def test_atomic_outputs_all_or_nothing(tmp_path):
    """One set for several files (as ``fit_file`` writes them): none appears before the end."""
    p = cloud(10)
    mesh, points, report = tmp_path / "m.obj", tmp_path / "p.ply", tmp_path / "r.json"
    with atomic_outputs() as outputs:
        write_mesh(mesh, p, np.array([[0, 1, 2]]), outputs=outputs)
        write_points(points, p, outputs=outputs)
        with atomic_output(report, outputs) as tmp:
            tmp.write_text("{}")
        assert not mesh.exists() and not points.exists() and not report.exists()
        assert len(list(tmp_path.iterdir())) == 3  # one temporary each, no nested ones
    assert sorted(q.name for q in tmp_path.iterdir()) == ["m.obj", "p.ply", "r.json"]
    assert read_mesh(mesh)[1].tolist() == [[0, 1, 2]]
    before = {q.name: q.read_bytes() for q in tmp_path.iterdir()}
    for exc in (OSError(28, "No space left on device"), KeyboardInterrupt()):
        with pytest.raises(InputError if isinstance(exc, OSError) else KeyboardInterrupt) as e:
            with atomic_outputs() as outputs:
                write_mesh(mesh, p + 1, np.array([[0, 1, 2]]), outputs=outputs)
                with atomic_output(report, outputs) as tmp:
                    tmp.write_text("partial")
                    raise exc
        if isinstance(exc, OSError):
            assert str(e.value) == f"{report}: cannot write: No space left on device"
        assert {q.name: q.read_bytes() for q in tmp_path.iterdir()} == before


def test_check_output_path(tmp_path, monkeypatch):
    inp = tmp_path / "in.ply"
    write_points(inp, cloud(10))
    monkeypatch.chdir(tmp_path)
    with pytest.raises(InputError, match="overwrite an input"):
        check_output_path(Path("sub/../in.ply"), inputs=[inp])
    with pytest.raises(InputError, match="does not exist.*--mkdir"):
        check_output_path(tmp_path / "a" / "b" / "o.ply")
    out = check_output_path(tmp_path / "a" / "b" / "o.ply", mkdir=True)
    assert out.parent.is_dir()
    with pytest.raises(InputError, match="is a directory"):
        check_output_path(tmp_path / "a")
    assert check_output_path("o.ply", inputs=[inp]) == Path("o.ply")


def test_cloud_from_arrays_scales_integer_colours_and_refuses_bad_ones():
    """uint8 200 was clipped to white and NaN made black: integers are scaled by their
    type, out-of-range or non-finite colours and complex arrays are refused."""
    rng = np.random.default_rng(0)
    p = rng.normal(size=(50, 3))
    c = cloud_from_arrays(p, colors=np.full((50, 3), 200, dtype=np.uint8))
    np.testing.assert_array_equal(c.colors, np.full((50, 3), 200 / 255))
    for bad in (np.full((50, 3), np.nan), np.full((50, 3), 1.5), np.full((50, 3), -0.1)):
        with pytest.raises(InputError, match="colors: row 0"):
            cloud_from_arrays(p, colors=bad)
    with pytest.raises(InputError, match="points: complex"):
        cloud_from_arrays(p + 0j)
    with pytest.raises(InputError, match="normals: complex"):
        cloud_from_arrays(p, p + 1j)
