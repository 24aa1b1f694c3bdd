"""LAS/LAZ and E57 input (issue #14 part 1): round trips, classes, precision, bad files.

Every file is written here with laspy and pye57 (the ``lidar`` extra, part of ``dev``).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from recon.cli.main import app

from recon.errors import InputError
from recon.io import read_mesh, read_points

laspy = pytest.importorskip("laspy")
pye57 = pytest.importorskip("pye57")

#: Keep every fit that actually runs tiny.
FAST = ["--set", "seeds.min_particles=0", "--set", "dynamics.max_steps=150"]

OFFSET = np.array([5_000_123.0, 4_999_877.0, 312.0])

WKT = (
    'PROJCS["ETRS89 / UTM zone 32N",GEOGCS["ETRS89",DATUM["European_Terrestrial_Reference_'
    'System_1989",SPHEROID["GRS 1980",6378137,298.257222101]],PRIMEM["Greenwich",0],UNIT['
    '"degree",0.0174532925199433]],PROJECTION["Transverse_Mercator"],AUTHORITY["EPSG","25832"]]'
)


def cloud_arrays(n: int = 400, seed: int = 0):
    """A wavy patch with two classes (2 on the left half, 6 on the right), colours, intensity."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0.0, 10.0, size=(n, 2))
    z = 0.3 * np.sin(xy[:, 0]) * np.cos(xy[:, 1] / 2.0)
    pts = np.column_stack([xy, z])
    cls = np.where(xy[:, 0] < 5.0, 2, 6).astype(np.uint8)
    rgb8 = rng.integers(0, 256, size=(n, 3)).astype(np.uint16)
    intensity = rng.integers(0, 65536, size=n).astype(np.uint16)
    return pts, cls, rgb8, intensity


def write_las(
    path: Path,
    pts: np.ndarray,
    *,
    cls=None,
    rgb16=None,
    intensity=None,
    point_format: int = 3,
    scale: float = 1e-4,
    wkt: str | None = None,
) -> Path:
    header = laspy.LasHeader(point_format=point_format, version="1.4" if wkt else "1.2")
    header.scales = np.array([scale] * 3)
    header.offsets = np.floor(pts.min(axis=0))
    if wkt is not None:
        header.vlrs.append(laspy.vlrs.known.WktCoordinateSystemVlr(wkt))
    las = laspy.LasData(header)
    las.x, las.y, las.z = pts[:, 0], pts[:, 1], pts[:, 2]
    if cls is not None:
        las.classification = cls
    if rgb16 is not None:
        las.red, las.green, las.blue = rgb16[:, 0], rgb16[:, 1], rgb16[:, 2]
    if intensity is not None:
        las.intensity = intensity
    las.write(str(path))
    return path


def write_e57(
    path: Path, pts: np.ndarray, rgb8=None, intensity=None, scans: int = 1, translation=None
) -> Path:
    """pye57 stores coordinates as float32: georeferenced scans go through the pose."""
    with pye57.E57(str(path), mode="w") as e57:
        for part in np.array_split(np.arange(len(pts)), scans):
            data = {f"cartesian{c}": pts[part, j].copy() for j, c in enumerate("XYZ")}
            if rgb8 is not None:
                for j, c in enumerate(("Red", "Green", "Blue")):
                    data[f"color{c}"] = rgb8[part, j].astype(np.uint8)
            if intensity is not None:
                data["intensity"] = intensity[part].astype(np.float32)
            e57.write_scan_raw(data, translation=translation)
    return path


def test_an_e57_whose_scans_differ_in_colour_says_its_colours_are_not_read(tmp_path, caplog):
    """Regression: one scan with colours and one without gave a cloud without colours and no
    word of it."""
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(400, 3))
    path = tmp_path / "mixed.e57"
    with pye57.E57(str(path), mode="w") as e57:
        for k, part in enumerate(np.array_split(np.arange(len(pts)), 2)):
            data = {f"cartesian{c}": pts[part, j].copy() for j, c in enumerate("XYZ")}
            if k == 0:
                for c in ("Red", "Green", "Blue"):
                    data[f"color{c}"] = np.full(len(part), 200, dtype=np.uint8)
            e57.write_scan_raw(data)
    with caplog.at_level("WARNING", logger="recon.io.e57"):
        cloud = read_points(path)
    assert cloud.colors is None
    assert "1 of 2 scans have colours, the other scans none" in caplog.text


def _sorted_rows(a: np.ndarray) -> np.ndarray:
    return a[np.lexsort(a.T[::-1])]


# --------------------------------------------------------------------------------------------
# round trips


@pytest.mark.parametrize("ext", [".las", ".laz"])
def test_las_round_trip_keeps_points_colours_intensity_classes(tmp_path, ext):
    pts, cls, rgb8, intensity = cloud_arrays()
    path = write_las(
        tmp_path / f"c{ext}", pts + OFFSET, cls=cls, rgb16=rgb8 * 257, intensity=intensity
    )
    cloud = read_points(path)
    las = laspy.read(str(path))
    expected = np.column_stack([np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)])
    assert cloud.format.startswith("laz" if ext == ".laz" else "las")
    assert cloud.info["point_format"] == 3
    assert len(cloud) == len(pts)
    # float64 end to end: the absolute coordinates are the file's scaled integers, exactly
    assert np.array_equal(cloud.absolute_points(), expected)
    assert np.all(np.abs(cloud.absolute_points() - (pts + OFFSET)) <= 0.5e-4 + 1e-9)
    # 16-bit LAS colours -> 8 bits exactly (v16 = 257 v8)
    assert np.array_equal(np.rint(cloud.colors * 255).astype(np.uint16), rgb8)
    assert np.array_equal(cloud.attributes["intensity"], intensity.astype(np.float64))
    assert np.array_equal(cloud.attributes["classification"], cls)
    assert cloud.info["classes"] == {2: int((cls == 2).sum()), 6: int((cls == 6).sum())}


def test_las_colours_stored_as_8_bit_values_are_read_as_8_bit(tmp_path):
    pts, _, rgb8, _ = cloud_arrays()
    rgb8[0] = [255, 0, 128]  # the maximum stays 255: the writer stored 8-bit values
    cloud = read_points(write_las(tmp_path / "c.las", pts, rgb16=rgb8))
    assert np.array_equal(np.rint(cloud.colors * 255).astype(np.uint16), rgb8)


def test_las_without_colour_has_no_colours(tmp_path):
    pts, cls, _, _ = cloud_arrays()
    cloud = read_points(write_las(tmp_path / "c.las", pts, cls=cls, point_format=1))
    assert cloud.colors is None
    assert set(cloud.attributes) == {"intensity", "classification"}


def test_las_is_read_in_chunks_with_the_same_result(tmp_path):
    from recon.io import las as las_module

    pts, cls, rgb8, intensity = cloud_arrays(n=1000)
    path = write_las(tmp_path / "c.laz", pts, cls=cls, rgb16=rgb8 * 257, intensity=intensity)
    whole = {}
    las_module.read_points(path, 10**9, whole)
    chunked_info: dict = {}
    fmt, xyz, _, col, attrs = las_module.read_points(
        path, 10**9, chunked_info, classes=[6], chunk_points=97
    )
    keep = cls == 6
    assert np.allclose(xyz, pts[keep], atol=0.5e-4 + 1e-12)
    assert np.array_equal(attrs["classification"], cls[keep])
    assert np.array_equal(attrs["intensity"], intensity[keep].astype(np.float64))
    assert chunked_info["classes"] == whole["classes"]


def test_e57_round_trip_with_several_scans(tmp_path):
    pts, _, rgb8, intensity = cloud_arrays()
    local = pts.astype(np.float32).astype(np.float64)  # what pye57 stores
    path = write_e57(tmp_path / "c.e57", local, rgb8, intensity, scans=2, translation=OFFSET)
    cloud = read_points(path)
    assert cloud.format == "e57"
    assert cloud.info["scans"] == 2
    assert len(cloud) == len(pts)
    # the scan pose is applied in float64: georeferenced E57 keeps its precision
    assert np.allclose(cloud.absolute_points(), local + OFFSET, rtol=0, atol=1e-8)
    assert np.array_equal(np.rint(cloud.colors * 255).astype(np.uint16), rgb8)
    assert np.allclose(cloud.attributes["intensity"], intensity.astype(np.float32))
    assert "classification" not in cloud.attributes


def test_lidar_files_are_recognised_by_content(tmp_path):
    pts, cls, _, _ = cloud_arrays()
    las_path = write_las(tmp_path / "c.las", pts, cls=cls)
    e57_path = write_e57(tmp_path / "c.e57", pts)
    for src, fmt in ((las_path, "las"), (e57_path, "e57")):
        renamed = src.rename(src.with_suffix(".dat"))
        assert read_points(renamed).format.startswith(fmt)


# --------------------------------------------------------------------------------------------
# classes


def test_classes_keep_only_the_chosen_classes(tmp_path):
    pts, cls, _, _ = cloud_arrays()
    path = write_las(tmp_path / "c.laz", pts, cls=cls)
    cloud = read_points(path, classes=[6])
    assert len(cloud) == int((cls == 6).sum())
    assert set(np.unique(cloud.attributes["classification"]).tolist()) == {6}
    assert np.all(cloud.absolute_points()[:, 0] >= 5.0 - 1e-4)
    assert len(read_points(path, classes=[2, 6])) == len(pts)


def test_classes_with_no_point_left_names_the_classes_present(tmp_path):
    pts, cls, _, _ = cloud_arrays()
    path = write_las(tmp_path / "c.las", pts, cls=cls)
    with pytest.raises(InputError, match=r"c\.las: no point of class 9 .*2 \(.*6 \("):
        read_points(path, classes=[9])


@pytest.mark.parametrize("kind", ["e57", "ply"])
def test_classes_on_a_file_without_classification_is_refused(tmp_path, kind):
    pts, _, _, _ = cloud_arrays()
    if kind == "e57":
        path = write_e57(tmp_path / "c.e57", pts)
    else:
        from recon.io import write_points

        path = tmp_path / "c.ply"
        write_points(path, pts)
    with pytest.raises(InputError, match="no point classification"):
        read_points(path, classes=[2])


def test_cli_classes_exit_2_without_output(tmp_path):
    pts, cls, _, _ = cloud_arrays()
    src = write_las(tmp_path / "c.las", pts, cls=cls)
    out = tmp_path / "out"
    out.mkdir()
    res = CliRunner().invoke(app, ["fit", str(src), "-o", str(out / "m.ply"), "--classes", "9"])
    assert res.exit_code == 2
    assert "no point of class 9" in res.output and "Traceback" not in res.output
    assert list(out.iterdir()) == []


# --------------------------------------------------------------------------------------------
# precision


def test_georeferenced_laz_keeps_sub_millimetre_precision_end_to_end(tmp_path):
    """A tilted plane at x, y ~ 5e6: the fitted mesh lies on it to well below a millimetre.

    float32 anywhere on the way (reading, the fit, writing) would put the vertices ~0.25 m off.
    """
    rng = np.random.default_rng(3)
    n = 1500
    xy = rng.uniform(0.0, 20.0, size=(n, 2))
    plane = np.array([0.02, -0.01])
    z = xy @ plane + 0.5
    pts = np.column_stack([xy, z]) + OFFSET
    src = write_las(tmp_path / "geo.laz", pts, cls=np.full(n, 2, np.uint8), scale=1e-5)
    out = tmp_path / "geo.ply"
    res = CliRunner().invoke(app, ["fit", str(src), "-o", str(out), "--quiet", *FAST])
    assert res.exit_code == 0, res.output
    verts, faces = read_mesh(out)
    assert len(faces) > 100
    rel = verts - OFFSET
    assert np.all(np.abs(verts[:, :2] - 5e6) < 1e3)
    off_plane = rel[:, 2] - (rel[:, :2] @ plane + 0.5)
    assert np.max(np.abs(off_plane)) < 1e-4  # 0.1 mm, on a 20 m patch at 5e6


# --------------------------------------------------------------------------------------------
# info


def test_info_reports_point_format_crs_and_classes(tmp_path):
    pts, cls, rgb8, _ = cloud_arrays()
    src = write_las(
        tmp_path / "c.las", pts + OFFSET, cls=cls, rgb16=rgb8 * 257, wkt=WKT, point_format=7
    )
    res = CliRunner().invoke(app, ["info", str(src), "--json"])
    assert res.exit_code == 0, res.output
    d = json.loads(res.output)
    assert d["point_format"] == 7
    assert 'EPSG","25832' in d["crs"]
    assert d["classes"] == {"2": int((cls == 2).sum()), "6": int((cls == 6).sum())}
    assert d["has_colors"] is True
    table = CliRunner().invoke(app, ["info", str(src)])
    assert "point format   LAS 1.4, point format 7" in table.output
    assert f"2 ground {int((cls == 2).sum()):,}" in table.output
    assert "ETRS89 / UTM zone 32N" in table.output


def test_info_without_crs_says_so(tmp_path):
    pts, cls, _, _ = cloud_arrays()
    res = CliRunner().invoke(app, ["info", str(write_las(tmp_path / "c.laz", pts, cls=cls))])
    assert res.exit_code == 0, res.output
    assert "none in the file" in res.output
    assert "(LAZ)" in res.output


# --------------------------------------------------------------------------------------------
# bad files: InputError naming the file; through the CLI exit 2, no traceback, nothing written


def _truncated_las(tmp_path: Path) -> Path:
    pts, cls, _, _ = cloud_arrays()
    src = write_las(tmp_path / "full.las", pts, cls=cls)
    data = src.read_bytes()
    bad = tmp_path / "cut.las"
    bad.write_bytes(data[: len(data) // 2])
    return bad


def _truncated_laz(tmp_path: Path) -> Path:
    pts, cls, _, _ = cloud_arrays(n=3000)
    src = write_las(tmp_path / "full.laz", pts, cls=cls)
    data = src.read_bytes()
    bad = tmp_path / "cut.laz"
    bad.write_bytes(data[: len(data) // 2])
    return bad


def _garbage(name: str):
    def make(tmp_path: Path) -> Path:
        p = tmp_path / name
        p.write_bytes(np.random.default_rng(0).integers(0, 256, 5000, dtype=np.uint8).tobytes())
        return p

    return make


def _bad_header(tmp_path: Path) -> Path:
    p = tmp_path / "header.las"
    p.write_bytes(b"LASF" + b"\x00" * 50)
    return p


def _empty(name: str):
    def make(tmp_path: Path) -> Path:
        p = tmp_path / name
        p.write_bytes(b"")
        return p

    return make


def _bad_e57(tmp_path: Path) -> Path:
    p = tmp_path / "bad.e57"
    p.write_bytes(b"ASTM-E57" + b"\x01" * 2000)
    return p


BAD_FILES = {
    "truncated-las": (_truncated_las, "truncated|not a valid LAS"),
    "truncated-laz": (_truncated_laz, "truncated|not a valid LAS"),
    "garbage-las": (_garbage("noise.las"), "not a LAS/LAZ file"),
    "garbage-laz": (_garbage("noise.laz"), "not a LAS/LAZ file"),
    "bad-header": (_bad_header, "not a valid LAS/LAZ file"),
    "empty-las": (_empty("empty.las"), "file is empty"),
    "empty-e57": (_empty("empty.e57"), "file is empty"),
    "garbage-e57": (_garbage("noise.e57"), "not an E57 file"),
    "bad-e57": (_bad_e57, "not a valid E57 file"),
}


@pytest.mark.parametrize("case", sorted(BAD_FILES))
def test_bad_lidar_files_raise_input_error_naming_the_file(tmp_path, case):
    make, pattern = BAD_FILES[case]
    path = make(tmp_path)
    with pytest.raises(InputError, match=pattern) as err:
        read_points(path)
    assert str(err.value).startswith(str(path))


@pytest.mark.parametrize("case", ["truncated-laz", "garbage-las", "bad-e57"])
def test_bad_lidar_files_exit_2_and_leave_nothing(tmp_path, case):
    make, pattern = BAD_FILES[case]
    path = make(tmp_path)
    before = path.read_bytes()
    out = tmp_path / "out"
    out.mkdir()
    res = CliRunner().invoke(app, ["fit", str(path), "-o", str(out / "m.ply")])
    assert res.exit_code == 2
    assert res.output.count("\n") == 1 and "Traceback" not in res.output
    assert str(path) in res.output
    assert list(out.iterdir()) == []
    assert path.read_bytes() == before


def test_laz_without_a_backend_names_the_extra(tmp_path, monkeypatch):
    pts, cls, _, _ = cloud_arrays()
    path = write_las(tmp_path / "c.laz", pts, cls=cls)
    monkeypatch.setattr(laspy.LazBackend, "detect_available", staticmethod(lambda: ()))
    with pytest.raises(InputError, match=r"c\.laz: .*'lazrs'.*pip install \"oprecon\[lidar\]\""):
        read_points(path)


@pytest.mark.parametrize(("module", "ext"), [("laspy", ".las"), ("pye57", ".e57")])
def test_missing_package_gives_one_line_naming_the_extra(tmp_path, monkeypatch, module, ext):
    pts, cls, _, _ = cloud_arrays()
    path = (
        write_las(tmp_path / f"c{ext}", pts, cls=cls)
        if ext == ".las"
        else write_e57(tmp_path / f"c{ext}", pts)
    )
    monkeypatch.setitem(sys.modules, module, None)  # import fails as if not installed
    res = CliRunner().invoke(app, ["info", str(path)])
    assert res.exit_code == 2
    assert f"needs the package '{module}': pip install \"oprecon[lidar]\"" in res.output
    assert res.output.count("\n") == 1


def test_info_classes_describes_only_those_points(tmp_path):
    pts, cls, _, _ = cloud_arrays()
    src = write_las(tmp_path / "c.laz", pts, cls=cls)
    res = CliRunner().invoke(app, ["info", str(src), "--classes", "6", "--json"])
    assert res.exit_code == 0, res.output
    d = json.loads(res.output)
    assert d["points"] == int((cls == 6).sum())
    assert d["classes_kept"] == [6]
    assert d["classes"] == {"2": int((cls == 2).sum()), "6": int((cls == 6).sum())}
    bad = CliRunner().invoke(app, ["info", str(src), "--classes", "two"])
    assert bad.exit_code == 2 and "expected class numbers" in bad.output


def test_info_on_e57_reports_scans_and_attributes(tmp_path):
    pts, _, rgb8, intensity = cloud_arrays()
    src = write_e57(tmp_path / "c.e57", pts, rgb8, intensity, scans=3)
    res = CliRunner().invoke(app, ["info", str(src)])
    assert res.exit_code == 0, res.output
    assert "scans          3" in res.output
    assert "attributes     intensity" in res.output
    assert "colours        yes" in res.output


# --------------------------------------------------------------------------------------------
# scanner positions


def test_e57_points_carry_their_scans_positions(tmp_path):
    """Each scan's pose translation is where it was scanned from: the points keep theirs
    through the cleaning (a point repeated in the second scan is merged into the first's)
    and through ``take``; ``oprecon info`` says the positions are known."""
    rng = np.random.default_rng(3)
    a, b = rng.integers(-64, 64, size=(2, 300, 3)) / 16.0  # exact in float32 and after moving
    where = [OFFSET + [1.0, 2.0, 3.0], OFFSET + [-4.0, 0.0, 1.5]]
    b = b[:200]
    b[:20] = a[:20] + where[0] - where[1]  # the same places, seen by both scans
    path = tmp_path / "two.e57"
    with pye57.E57(str(path), mode="w") as e57:
        for pts, t in ((a, where[0]), (b, where[1])):
            local = pts.astype(np.float32)
            data = {f"cartesian{c}": local[:, j].copy() for j, c in enumerate("XYZ")}
            e57.write_scan_raw(data, translation=t)
    cloud = read_points(path)
    assert cloud.info["scan_positions"] == [list(w) for w in where]
    assert len(cloud) == 480 and cloud.viewpoints.shape == (480, 3)
    absolute = cloud.viewpoints + cloud.origin
    seen = np.abs(absolute - where[0]).max(axis=1) < 1e-6
    assert seen.sum() == 300 and np.abs(absolute[~seen] - where[1]).max() < 1e-6
    # each point keeps its own scanner when the rows move
    from_a = {tuple(r) for r in np.round(a + where[0], 6)}
    rows = np.array([tuple(r) in from_a for r in np.round(cloud.absolute_points(), 6)])
    assert np.array_equal(rows, seen)
    order = np.random.default_rng(0).permutation(len(cloud))
    assert np.array_equal(cloud.take(order).viewpoints, cloud.viewpoints[order])
    res = CliRunner().invoke(app, ["info", str(path)])
    assert res.exit_code == 0, res.output
    assert "scans          2, scanner positions known (the normals face them)" in res.output


def test_e57_scanner_position_is_known_from_a_pose_or_spherical_coordinates():
    """A cartesian scan without a pose may hold points another program merged: no position."""
    from recon.io.e57 import sensor_position

    class Header:
        def __init__(self, pose):
            self.pose = pose
            self.translation = np.array([1.0, 2.0, 3.0])

        def has_pose(self):
            return self.pose

    xyz = {"cartesianX", "cartesianY", "cartesianZ"}
    rae = {"sphericalRange", "sphericalAzimuth", "sphericalElevation"}
    assert np.array_equal(sensor_position(Header(True), xyz), [1.0, 2.0, 3.0])
    assert np.array_equal(sensor_position(Header(False), rae), [0.0, 0.0, 0.0])
    assert sensor_position(Header(False), xyz) is None
    # a pose under terrain 250 m up (easting, northing, 0: a georeference) is not a scanner;
    # one among the scan's points is
    terrain = np.array([[0.0, 0.0, 250.0], [40.0, 30.0, 262.0]])
    assert sensor_position(Header(True), xyz, terrain) is None
    assert np.array_equal(sensor_position(Header(True), xyz, terrain + [0, 0, -249]), [1, 2, 3])


def test_cloud_from_arrays_checks_viewpoints():
    from recon.io import cloud_from_arrays

    p = np.random.default_rng(0).normal(size=(50, 3))
    cloud = cloud_from_arrays(np.vstack([p, p[:5]]), viewpoints=np.ones((55, 3)))
    assert cloud.viewpoints.shape == (50, 3)  # the repeats merged, their rows with them
    with pytest.raises(InputError, match="viewpoints: expected shape"):
        cloud_from_arrays(p, viewpoints=np.ones((49, 3)))
    with pytest.raises(InputError, match="viewpoints: not every row is finite"):
        cloud_from_arrays(p, viewpoints=np.full((50, 3), np.nan))
