"""Classes beyond the LAS range 0-255 (a PLY's ``int classification`` of 300, negative classes,
fractional labels) through ``fit --transfer classification``: read with the file's values,
transferred as the majority of those values and written as ``int`` (``float`` when they are
not integers), by the untiled fit and by the tiled writer alike. Classes 0-255 stay ``uchar``.

Regression: the fit's read clipped them to 255 (with a warning), and the transfer cast its
majority to uint8, so that 300 would have become 44.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from plyfile import PlyData, PlyElement
from recon.cli.main import app

from recon.attributes import transfer_attributes
from recon.config import config_from_dict
from recon.io import cloud_from_arrays, read_points

ROOT = Path(__file__).resolve().parent.parent
FAST = ["--set", "seeds.min_particles=0", "--set", "dynamics.max_steps=150"]
TOP, BOTTOM = 300, -7  # classes of the sphere's halves


def _points_ply(path: Path, pts: np.ndarray, classes: np.ndarray, text: bool = False) -> Path:
    rows = np.zeros(
        len(pts), dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("classification", classes.dtype)]
    )
    for j, c in enumerate("xyz"):
        rows[c] = pts[:, j]
    rows["classification"] = classes
    PlyData([PlyElement.describe(rows, "vertex")], text=text).write(str(path))
    return path


def _halves_cloud(classes: tuple, dtype) -> tuple:
    """Points of a unit cube, ``classes[0]`` where x < 0.5, ``classes[1]`` beyond; two
    vertices deep inside the halves."""
    pts = np.random.default_rng(0).uniform(0, 1, size=(400, 3))
    cls = np.where(pts[:, 0] < 0.5, *classes).astype(dtype)
    verts = np.array([[0.1, 0.5, 0.5], [0.9, 0.5, 0.5]])
    return cloud_from_arrays(pts, attributes={"classification": cls}), verts


# --------------------------------------------------------------------------------------------
# the transfer


@pytest.mark.parametrize("dtype", [np.int32, np.int16, np.uint16, np.float32, np.float64])
def test_wide_classes_are_transferred_with_their_values(dtype):
    """int32 as the file gave them, float64 as a tiled fit carries them: the same int32."""
    classes = (300, 70000) if dtype != np.int16 and dtype != np.uint16 else (300, 301)
    if dtype in (np.int32, np.int16, np.float32, np.float64):
        classes = (classes[0], -7)
    cloud, verts = _halves_cloud(classes, dtype)
    out = transfer_attributes(cloud, verts, r0=0.05, transfer=["classification"])
    got = out.properties["classification"]
    assert got.tolist() == list(classes)
    assert got.dtype == np.int32


@pytest.mark.parametrize("dtype", [np.uint8, np.float64])
def test_classes_0_255_are_still_transferred_as_uint8(dtype):
    cloud, verts = _halves_cloud((2, 255), dtype)
    out = transfer_attributes(cloud, verts, r0=0.05, transfer=["classification"])
    assert out.properties["classification"].dtype == np.uint8
    assert out.properties["classification"].tolist() == [2, 255]


def test_fractional_labels_are_transferred_as_float32():
    cloud, verts = _halves_cloud((2.5, 6.0), np.float32)
    out = transfer_attributes(cloud, verts, r0=0.05, transfer=["classification"])
    assert out.properties["classification"].dtype == np.float32
    assert out.properties["classification"].tolist() == [2.5, 6.0]


def test_the_class_type_is_the_narrowest_of_uchar_int_float():
    from recon.attributes import class_type, class_values

    assert class_type(np.array([0, 255])) == "u1"
    assert class_type(np.array([0.0, 255.0])) == "u1"
    assert class_type(np.zeros(0, np.int32)) == "u1"
    assert class_type(np.array([0, 256])) == "i4"
    assert class_type(np.array([-1.0, 3.0])) == "i4"
    assert class_type(np.array([-(2**31), 2**31 - 1], dtype=np.int64)) == "i4"
    assert class_type(np.array([2**31], dtype=np.uint32)) == "f4"
    assert class_type(np.array([2.5])) == "f4"
    assert class_type(np.array([np.nan, 1.0])) == "f4"
    assert class_values(np.array([300.0, -7.0])).dtype == np.int32


# --------------------------------------------------------------------------------------------
# the read


def test_the_fit_reads_wide_classes_with_their_values_and_no_warning(tmp_path, caplog):
    pts = np.random.default_rng(1).uniform(size=(30, 3))
    for dtype, values in (
        (np.int32, 300 + np.arange(30) % 3),
        (np.int8, np.arange(30) % 3 - 1),
        (np.float32, np.arange(30) % 3 + 0.5),
    ):
        classes = values.astype(dtype)
        for text in (False, True):
            path = _points_ply(tmp_path / f"c{int(text)}.ply", pts, classes, text=text)
            with caplog.at_level(logging.WARNING, logger="recon.io"):
                caplog.clear()
                got = read_points(path).attributes["classification"]
            assert caplog.text == ""
            assert got.dtype == dtype
            np.testing.assert_array_equal(got, classes)


def test_classes_no_mesh_type_holds_are_read_and_said_to_be_rounded(tmp_path, caplog):
    """A ``uint`` class past int32 is written as float by the transfer: rounded."""
    pts = np.random.default_rng(1).uniform(size=(30, 3))
    classes = (np.uint32(2**32 - 1) - np.arange(30) % 2).astype(np.uint32)
    path = _points_ply(tmp_path / "u.ply", pts, classes)
    with caplog.at_level(logging.WARNING, logger="recon.io"):
        kept = read_points(path, all_properties=True).attributes["classification"]
        assert caplog.text == ""  # `oprecon normals` writes them back as they are
        got = read_points(path).attributes["classification"]
    for a in (kept, got):
        assert a.dtype == np.uint32
        np.testing.assert_array_equal(a, classes)
    assert "4294967294 to 4294967295" in caplog.text and "rounded" in caplog.text


# --------------------------------------------------------------------------------------------
# the fit, untiled


def _classified_sphere(tmp_path: Path, dtype=np.int32) -> Path:
    """The bundled sparse sphere, class TOP above z = 0 and BOTTOM below."""
    pts = read_points(ROOT / "sample_data" / "sphere-sparse.ply").absolute_points()
    classes = np.where(pts[:, 2] >= 0, TOP, BOTTOM).astype(dtype)
    return _points_ply(tmp_path / "sphere-classes.ply", pts, classes)


def test_fit_transfers_wide_classes_with_their_values(tmp_path, caplog):
    src = _classified_sphere(tmp_path)
    out = tmp_path / "mesh.ply"
    with caplog.at_level(logging.WARNING):
        res = CliRunner().invoke(
            app, ["fit", str(src), "-o", str(out), "-q", "--transfer", "classification", *FAST]
        )
    assert res.exit_code == 0, res.output
    assert "clipped" not in caplog.text + res.output
    v = PlyData.read(str(out))["vertex"]
    cls = np.asarray(v["classification"])
    assert cls.dtype == np.int32
    z = np.asarray(v["z"])
    top, bottom = z > 0.4, z < -0.4
    assert top.sum() > 50 and bottom.sum() > 50
    assert np.all(cls[top] == TOP) and np.all(cls[bottom] == BOTTOM)
    assert set(np.unique(cls)) == {TOP, BOTTOM}


# --------------------------------------------------------------------------------------------
# the tiled fit's pieces: the split, the per-tile transfer, the streamed writer


def test_tiles_carry_and_transfer_wide_classes(tmp_path):
    from recon.tiling import TileGrid
    from recon.tiling.source import read_box, scan_header, split_input
    from recon.tiling.tasks import vertex_attributes

    src = _classified_sphere(tmp_path)
    cfg = config_from_dict({"output": {"transfer": ["classification"]}})
    header = scan_header(src, cfg)
    grid = TileGrid.cover(header.lo, header.hi, 1.2, 0.3)
    store = split_input(header, grid, tmp_path / "work", cfg)
    assert len(store.tiles()) > 1
    vertices = np.array([[0.0, 0.0, 0.9], [0.0, 0.0, -0.9]])
    got = {}
    for t in store.tiles():
        rows = read_box(store, t, grid.halo)
        cls = store.point_attributes(rows)["classification"]
        assert set(np.unique(cls)) <= {TOP, BOTTOM}
        inside = grid.cell_of(vertices) == t
        if inside.any():
            props = vertex_attributes(store, rows, vertices[inside], 0.1, cfg.output)[1]
            got.update(zip(np.flatnonzero(inside).tolist(), props[:, 0].tolist(), strict=True))
    assert got == {0: TOP, 1: BOTTOM}


def _stitched(tmp_path: Path, blocks: list[np.ndarray]) -> dict:
    """A stitched mesh as :func:`recon.tiling.assemble.stitch_streamed` gives it: one block of
    3 vertices (one triangle) per array of their property values."""
    from recon.tiling.vertices import UsedVertices, VertexStore

    store = VertexStore()
    for k, values in enumerate(blocks):
        pos = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]) + [2.0 * k, 0, 0]
        store.add_arrays(pos, np.tile([0.0, 0, 1], (3, 1)), None, values.reshape(3, 1))
    used = UsedVertices(tmp_path, store)
    faces = [np.array([[3 * k, 3 * k + 1, 3 * k + 2]]) for k in range(len(blocks))]
    for f in faces:
        used.add(f.ravel())
    used.finish()
    return {"store": store, "used": used, "units": faces, "n_faces": len(faces)}


@pytest.mark.parametrize("ascii", [False, True])
@pytest.mark.parametrize(
    ("blocks", "ply_type", "dtype"),
    [
        ([[2, 6, 6], [255, 0, 2]], "uchar", np.uint8),
        ([[2, 6, 6], [300, -7, 70000]], "int", np.int32),
        ([[2, 6, 6], [2.5, -7, 300]], "float", np.float32),
    ],
)
def test_the_tiled_writer_writes_classes_in_the_type_that_holds_them(
    tmp_path, blocks, ply_type, dtype, ascii
):
    from recon.tiling.writer import write_streamed

    values = [np.asarray(b, dtype=np.float64) for b in blocks]
    path = tmp_path / "m.ply"
    write_streamed(path, _stitched(tmp_path, values), "f4", True, ascii, False, ["classification"])
    assert f"property {ply_type} classification".encode() in path.read_bytes()[:400]
    cls = PlyData.read(str(path))["vertex"]["classification"]
    assert cls.dtype == dtype
    np.testing.assert_array_equal(cls, np.concatenate(values))
