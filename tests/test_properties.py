"""Property-based tests of the readers and writers (hypothesis).

* Random valid point sets round-trip exactly through every writer/reader pair.
* Random byte mutations of valid files never raise anything but ``OpreconError`` (or read).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from recon.errors import OpreconError
from recon.io import read_mesh, read_points, write_mesh, write_points

SETTINGS = settings(
    max_examples=25,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
    derandomize=True,
)
MUTATION_SETTINGS = settings(SETTINGS, max_examples=60)

#: A tetrahedron appended to every random set, so that it always spans 3-D.
TETRA = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])


def _finite(width: int) -> st.SearchStrategy[float]:
    return st.floats(
        min_value=-1e3, max_value=1e3, allow_nan=False, allow_infinity=False, width=width
    )


@st.composite
def point_sets(draw: st.DrawFn, width: int = 64) -> np.ndarray:
    """(n, 3) float64 points: random values plus a tetrahedron as large as they are (so the
    set spans 3-D), at a random scale and offset; float32-exact when ``width`` is 32."""
    n = draw(st.integers(min_value=0, max_value=40))
    dtype = np.float64 if width == 64 else np.float32
    body = draw(hnp.arrays(dtype, (n, 3), elements=_finite(width))).astype(np.float64)
    size = max(1.0, float(np.ptp(body))) if n else 1.0
    scale = draw(st.sampled_from([1e-6, 1e-3, 1.0, 1e3]))
    offsets = [0.0, 1.0, 1e3, 1e6, -5e6] if width == 64 else [0.0, 1.0, 1e3]
    offset = draw(st.sampled_from(offsets)) * size * scale
    pts = np.vstack([body, TETRA * size]) * scale + offset
    if width == 32:
        pts = pts.astype(np.float32).astype(np.float64)
    return pts


def _write_xyz(path: Path, pts: np.ndarray) -> None:
    np.savetxt(path, pts, fmt="%.17g")


def _write_pcd(path: Path, pts: np.ndarray, kind: str) -> None:
    head = (
        "# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 8 8 8\nTYPE F F F\nCOUNT 1 1 1\n"
        f"WIDTH {len(pts)}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {len(pts)}\nDATA {kind}\n"
    )
    with open(path, "wb") as fh:
        fh.write(head.encode())
        if kind == "ascii":
            np.savetxt(fh, pts, fmt="%.17g")
        else:
            fh.write(np.ascontiguousarray(pts, dtype="<f8").tobytes())


WRITERS = {
    "ply-binary": ("p.ply", lambda p, x: write_points(p, x)),
    "ply-ascii": ("p.ply", lambda p, x: write_points(p, x, ascii=True)),
    "xyz-savetxt": ("p.xyz", _write_xyz),
    "obj": ("p.obj", lambda p, x: write_mesh(p, x, np.zeros((0, 3), dtype=np.int64))),
    "pcd-ascii": ("p.pcd", lambda p, x: _write_pcd(p, x, "ascii")),
    "pcd-binary": ("p.pcd", lambda p, x: _write_pcd(p, x, "binary")),
}


@pytest.mark.parametrize("fmt", sorted(WRITERS))
@SETTINGS
@given(pts=point_sets())
def test_points_round_trip_exactly(tmp_path, fmt, pts):
    name, write = WRITERS[fmt]
    path = tmp_path / name
    write(path, pts)
    cloud = read_points(path, merge_duplicates=False)
    back = cloud.absolute_points()
    assert back.shape == pts.shape
    if fmt.startswith("ply") or fmt == "obj":
        # float32 is written when it keeps 1e-7 of the extent; exact when float32 suffices
        extent = float(np.max(pts.max(axis=0) - pts.min(axis=0)))
        assert np.all(np.abs(back - pts) <= 1e-7 * extent)
    else:
        np.testing.assert_array_equal(back, pts)


@pytest.mark.parametrize("fmt", ["ply-binary", "ply-ascii", "obj"])
@SETTINGS
@given(pts=point_sets(width=32))
def test_float32_points_round_trip_bit_exactly(tmp_path, fmt, pts):
    name, write = WRITERS[fmt]
    path = tmp_path / name
    write(path, pts)
    np.testing.assert_array_equal(read_points(path, merge_duplicates=False).absolute_points(), pts)


@pytest.mark.parametrize("ext,ascii", [(".ply", False), (".ply", True), (".obj", False)])
@SETTINGS
@given(pts=point_sets(width=32), data=st.data())
def test_meshes_round_trip(tmp_path, ext, ascii, pts, data):
    n = len(pts)
    faces = data.draw(
        hnp.arrays(np.int64, (data.draw(st.integers(0, 30)), 3), elements=st.integers(0, n - 1))
    )
    nrm = pts - pts.mean(axis=0) + 1e-3
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    path = tmp_path / f"m{ext}"
    write_mesh(path, pts, faces, nrm, ascii=ascii)
    v, f = read_mesh(path)
    np.testing.assert_array_equal(v, pts)
    np.testing.assert_array_equal(f, faces.reshape(-1, 3))


@pytest.mark.parametrize("ascii", [False, True])
@SETTINGS
@given(pts=point_sets(width=32))
def test_normals_round_trip(tmp_path, ascii, pts):
    nrm = pts - pts.mean(axis=0) + 1e-3
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    path = tmp_path / "n.ply"
    write_points(path, pts, nrm, ascii=ascii)
    cloud = read_points(path, merge_duplicates=False)
    np.testing.assert_allclose(cloud.normals, nrm, atol=1e-6)


# --------------------------------------------------------------------------------------------
# mutations


def _sphere(n: int = 60) -> np.ndarray:
    rng = np.random.default_rng(1)
    p = rng.normal(size=(n, 3))
    return p / np.linalg.norm(p, axis=1, keepdims=True)


def _valid_files(tmp: Path) -> dict[str, bytes]:
    p = _sphere()
    out = {}
    write_points(tmp / "b.ply", p, p)
    write_points(tmp / "a.ply", p, p, ascii=True)
    write_mesh(tmp / "m.ply", p, np.array([[0, 1, 2], [2, 3, 4], [5, 6, 7]]))
    write_mesh(tmp / "m.obj", p, np.array([[0, 1, 2], [2, 3, 4]]))
    _write_xyz(tmp / "p.xyz", np.hstack([p, p]))
    _write_pcd(tmp / "a.pcd", p, "ascii")
    _write_pcd(tmp / "b.pcd", p, "binary")
    for key, name in [
        ("ply-binary", "b.ply"),
        ("ply-ascii", "a.ply"),
        ("ply-mesh", "m.ply"),
        ("obj", "m.obj"),
        ("xyz", "p.xyz"),
        ("pcd-ascii", "a.pcd"),
        ("pcd-binary", "b.pcd"),
    ]:
        out[key] = (tmp / name).read_bytes()
    return out


_VALID: dict[str, bytes] = {}


def _valid(key: str, tmp_path_factory) -> bytes:
    if not _VALID:
        _VALID.update(_valid_files(tmp_path_factory.mktemp("valid")))
    return _VALID[key]


_INTERESTING = [
    b"0",
    b"9",
    b"-",
    b".",
    b"e",
    b" ",
    b"\n",
    b"\x00",
    b"\xff",
    b"nan",
    b"inf",
    b"99999999999",
    b"end_header\n",
    b"element face 7\n",
    b"property list uchar int vertex_indices\n",
    b"DATA binary\n",
    b"POINTS 1000\n",
    b"f 1 2 99\n",
]


@st.composite
def mutations(draw: st.DrawFn, data: bytes) -> bytes:
    """1-4 random edits: flip a byte, insert a (meaningful) token, delete a run, truncate."""
    buf = bytearray(data)
    for _ in range(draw(st.integers(1, 4))):
        kind = draw(st.sampled_from(["flip", "insert", "delete", "truncate", "header"]))
        limit = max(len(buf) - 1, 0)
        # the header holds most of the structure: aim a third of the edits at its first 200 bytes
        pos = draw(st.integers(0, min(limit, 200) if kind == "header" else limit))
        if kind in ("flip", "header") and buf:
            buf[pos] = draw(st.integers(0, 255))
        elif kind == "insert":
            buf[pos:pos] = draw(st.sampled_from(_INTERESTING) | st.binary(min_size=1, max_size=8))
        elif kind == "delete":
            del buf[pos : pos + draw(st.integers(1, 16))]
        elif kind == "truncate":
            del buf[pos:]
    return bytes(buf)


def _check_mutant(path: Path, blob: bytes, mesh: bool) -> None:
    path.write_bytes(blob)
    try:
        if mesh:
            v, f = read_mesh(path)
            assert f.ndim == 2 and f.shape[1] == 3
            assert (f.size == 0) or (f.min() >= 0 and f.max() < len(v))
        else:
            cloud = read_points(path)
            assert np.isfinite(cloud.points).all() and len(cloud) >= 4
    except OpreconError as exc:
        assert str(exc).startswith(str(path)), exc


MUTATED = [
    ("ply-binary", "x.ply", False),
    ("ply-ascii", "x.ply", False),
    ("ply-mesh", "x.ply", True),
    ("obj", "x.obj", True),
    ("xyz", "x.xyz", False),
    ("pcd-ascii", "x.pcd", False),
    ("pcd-binary", "x.pcd", False),
]


@pytest.mark.parametrize("key,name,mesh", MUTATED, ids=[m[0] for m in MUTATED])
@MUTATION_SETTINGS
@given(data=st.data())
def test_mutated_files_raise_only_opreconerror(tmp_path, tmp_path_factory, key, name, mesh, data):
    original = _valid(key, tmp_path_factory)
    blob = data.draw(mutations(original))
    _check_mutant(tmp_path / name, blob, mesh)
    if not mesh:  # the same bytes under an unknown extension go through format sniffing
        _check_mutant(tmp_path / "x.unknown", blob, False)
