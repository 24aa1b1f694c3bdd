"""Issue #7: broken, hostile and degenerate inputs through ``oprecon fit`` (and ``normals``).

Every case is generated here (small and deterministic). Each asserts the exit code, that stderr
names the file and the problem without a traceback, that nothing (no output, no temporary
file) is left in the output folder, and that the input's bytes are unchanged.
"""

from __future__ import annotations

import hashlib
import json
import os
import struct
import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from recon.cli.main import app

from recon.io import read_mesh, read_points

#: Keep every fit that actually runs tiny.
FAST = ["--set", "seeds.min_particles=0", "--set", "dynamics.max_steps=100"]


# --------------------------------------------------------------------------------------------
# generators


def sphere(n: int = 300, radius: float = 1.0, centre=(0.0, 0.0, 0.0), seed: int = 0):
    rng = np.random.default_rng(seed)
    p = rng.normal(size=(n, 3))
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    return p * radius + np.asarray(centre, dtype=np.float64)


def grid_plane(m: int = 18) -> np.ndarray:
    """An m x m grid in z = 0: exactly coplanar."""
    g = np.stack(np.meshgrid(np.arange(m), np.arange(m)), axis=-1).reshape(-1, 2)
    return np.column_stack([g.astype(np.float64), np.zeros(len(g))])


def ply_bytes(
    xyz: np.ndarray,
    normals: np.ndarray | None = None,
    *,
    ascii: bool = False,
    header_count: int | None = None,
    truncate: int = 0,
    dtype: str = "<f8",
) -> bytes:
    """A vertex-only PLY; ``header_count`` lies about the count, ``truncate`` cuts bytes."""
    cols = [xyz] if normals is None else [xyz, normals]
    data = np.hstack(cols)
    names = ["x", "y", "z"] + ([] if normals is None else ["nx", "ny", "nz"])
    typ = "double" if dtype.endswith("f8") else "float"
    count = len(data) if header_count is None else header_count
    fmt = "ascii" if ascii else "binary_little_endian"
    head = ["ply", f"format {fmt} 1.0", f"element vertex {count}"]
    head += [f"property {typ} {n}" for n in names] + ["end_header"]
    header = ("\n".join(head) + "\n").encode()
    if ascii:
        body = "".join(" ".join(repr(float(v)) for v in row) + "\n" for row in data).encode()
    else:
        body = np.ascontiguousarray(data, dtype=dtype).tobytes()
    out = header + body
    return out[: len(out) - truncate] if truncate else out


def ply_raw(header_lines: list[str], body: bytes = b"") -> bytes:
    return ("\n".join(header_lines) + "\n").encode("latin-1") + body


def xyz_bytes(xyz: np.ndarray) -> bytes:
    return "".join(" ".join(repr(float(v)) for v in row) + "\n" for row in xyz).encode()


def pcd_bytes(
    xyz: np.ndarray,
    *,
    kind: str = "binary",
    points: int | None = None,
    fields: str = "x y z",
    truncate: int = 0,
) -> bytes:
    n = len(xyz) if points is None else points
    k = len(fields.split())
    head = [
        "# .PCD v0.7",
        "VERSION 0.7",
        f"FIELDS {fields}",
        "SIZE " + " ".join(["4"] * k),
        "TYPE " + " ".join(["F"] * k),
        "COUNT " + " ".join(["1"] * k),
        f"WIDTH {n}",
        "HEIGHT 1",
        "VIEWPOINT 0 0 0 1 0 0 0",
        f"POINTS {n}",
        f"DATA {kind}",
    ]
    header = ("\n".join(head) + "\n").encode()
    if kind == "ascii":
        body = xyz_bytes(xyz[:, :k])
    else:
        body = np.ascontiguousarray(xyz[:, :k], dtype="<f4").tobytes()
    out = header + body
    return out[: len(out) - truncate] if truncate else out


def _replace_row(data: bytes, row: int, new: bytes) -> bytes:
    """Replace data row ``row`` (0-based, after ``end_header``) of an ascii file."""
    head, body = data.split(b"end_header\n", 1)
    rows = body.split(b"\n")
    rows[row] = new
    return head + b"end_header\n" + b"\n".join(rows)


def noise_bytes(n: int, seed: int = 3) -> bytes:
    return np.random.default_rng(seed).integers(0, 256, n, dtype=np.uint8).tobytes()


S = sphere()

# (id, file name, content, problem words expected in stderr (lower case, any order))
BAD_INPUTS: list[tuple[str, str, Callable[[], bytes], tuple[str, ...]]] = [
    # -- whole-file problems
    ("empty-file", "scan.ply", lambda: b"", ("empty",)),
    ("unknown-binary-format", "scan.bin", lambda: noise_bytes(3000), ("unknown file format",)),
    # -- PLY headers
    ("ply-wrong-magic", "scan.ply", lambda: b"plx\n" + ply_bytes(S)[4:], ("not a ply",)),
    (
        "ply-no-end-header",
        "scan.ply",
        lambda: ply_raw(["ply", "format ascii 1.0", "element vertex 3", "property float x"]),
        ("no end_header",),
    ),
    (
        "ply-memory-bomb-vertices",
        "scan.ply",
        lambda: ply_bytes(S, header_count=10**12),
        ("truncated", "1000000000000"),
    ),
    (
        "ply-memory-bomb-faces",
        "scan.ply",
        lambda: ply_raw(
            [
                "ply",
                "format binary_little_endian 1.0",
                "element vertex 300",
                "property double x",
                "property double y",
                "property double z",
                "element face 4000000000",
                "property list uchar int vertex_indices",
                "end_header",
            ],
            S.astype("<f8").tobytes(),
        ),
        ("truncated", "4000000000 face"),
    ),
    ("ply-binary-truncated-body", "scan.ply", lambda: ply_bytes(S, truncate=100), ("truncated",)),
    (
        "ply-ascii-fewer-rows",
        "scan.ply",
        lambda: ply_bytes(S, ascii=True, header_count=400),
        ("truncated",),
    ),
    ("ply-negative-count", "scan.ply", lambda: ply_bytes(S, header_count=-5), ("negative",)),
    (
        "ply-count-not-integer",
        "scan.ply",
        lambda: ply_bytes(S).replace(b"element vertex 300", b"element vertex 3e2"),
        ("not an integer",),
    ),
    (
        "ply-unknown-type",
        "scan.ply",
        lambda: ply_bytes(S).replace(b"property double x", b"property quad x"),
        ("unknown property type",),
    ),
    (
        "ply-bad-format-line",
        "scan.ply",
        lambda: ply_bytes(S).replace(b"binary_little_endian", b"binary_middle_endian"),
        ("unsupported format",),
    ),
    (
        "ply-no-vertex-element",
        "scan.ply",
        lambda: ply_bytes(S).replace(b"element vertex", b"element points"),
        ("no 'vertex'",),
    ),
    (
        "ply-no-z",
        "scan.ply",
        lambda: ply_bytes(S).replace(b"property double z", b"property double w"),
        ("lacks x, y, z",),
    ),
    (
        "ply-non-ascii-header",
        "scan.ply",
        # (a comment may hold any bytes: UTF-8 comments are common; a property may not)
        lambda: ply_bytes(S).replace(b"end_header", b"property float \xff\xfe\nend_header"),
        ("non-ascii",),
    ),
    (
        "ply-ascii-garbage-value",
        "scan.ply",
        lambda: _replace_row(ply_bytes(S, ascii=True), 20, b"0.5 foo 1"),
        ("element 'vertex'",),
    ),
    (
        "ply-ascii-wrong-columns",
        "scan.ply",
        lambda: _replace_row(ply_bytes(S, ascii=True), 20, b"0.5 0.25"),
        ("element 'vertex'",),
    ),
    (
        "ply-list-in-vertex",
        "scan.ply",
        lambda: ply_raw(
            [
                "ply",
                "format ascii 1.0",
                "element vertex 300",
                "property float x",
                "property float y",
                "property float z",
                "property list uchar int ids",
                "end_header",
            ],
            xyz_bytes(S).replace(b"\n", b" 0\n"),
        ),
        ("list properties",),
    ),
    (
        "ply-duplicate-property",
        "scan.ply",
        lambda: ply_bytes(S).replace(b"property double z", b"property double z\nproperty float x"),
        ("duplicate property",),
    ),
    # -- PCD
    (
        "pcd-absurd-count",
        "scan.pcd",
        lambda: pcd_bytes(S, points=10**12),
        ("1000000000000 points exceed",),
    ),
    (
        "pcd-memory-bomb",
        "scan.pcd",
        lambda: pcd_bytes(S, points=40_000_000),
        ("truncated", "40000000"),
    ),
    ("pcd-truncated-binary", "scan.pcd", lambda: pcd_bytes(S, truncate=40), ("truncated",)),
    (
        "pcd-ascii-memory-bomb",
        "scan.pcd",
        lambda: pcd_bytes(S, kind="ascii", points=10**7),
        ("truncated",),
    ),
    (
        "pcd-compressed",
        "scan.pcd",
        lambda: pcd_bytes(S, kind="binary_compressed"),
        ("binary_compressed",),
    ),
    ("pcd-no-z", "scan.pcd", lambda: pcd_bytes(S, fields="x y"), ("lacks x, y, z",)),
    (
        "pcd-no-fields",
        "scan.pcd",
        lambda: b"\n".join(ln for ln in pcd_bytes(S).split(b"\n") if not ln.startswith(b"FIELDS")),
        ("no fields",),
    ),
    (
        "pcd-bad-count",
        "scan.pcd",
        lambda: pcd_bytes(S).replace(b"POINTS 300", b"POINTS many"),
        ("not an integer",),
    ),
    # -- text
    (
        "xyz-garbage-token",
        "scan.xyz",
        lambda: xyz_bytes(S).replace(b"\n", b"\n1.0 abc 2.0\n", 1),
        ("could not convert", "abc"),
    ),
    ("xyz-two-columns", "scan.xyz", lambda: xyz_bytes(S[:, :2]), ("column",)),
    (
        "xyz-ragged-rows",
        "scan.xyz",
        lambda: xyz_bytes(S).replace(b"\n", b"\n1.0 2.0\n", 1),
        ("columns",),
    ),
    ("xyz-binary-content", "scan.xyz", lambda: noise_bytes(2000, seed=5), ("not a text file",)),
    ("xyz-only-comments", "scan.xyz", lambda: b"# nothing\n// here\n\n", ("no data rows",)),
    # -- OBJ
    ("obj-no-vertices", "scan.obj", lambda: b"# empty\nf 1 2 3\n", ("no 'v' vertex",)),
    (
        "obj-bad-vertex",
        "scan.obj",
        lambda: b"v 0 0 0\nv 1 x 0\nv 0 1 0\nv 0 0 1\n",
        ("line 2", "non-numeric"),
    ),
    # -- degenerate geometry
    (
        "all-identical",
        "scan.ply",
        lambda: ply_bytes(np.ones((300, 3))),
        ("only 1 distinct", "at least 4"),
    ),
    (
        "two-points",
        "scan.ply",
        lambda: ply_bytes(np.array([[0.0, 0, 0], [1, 1, 1]] * 50)),
        ("only 2 distinct",),
    ),
    (
        "collinear",
        "scan.ply",
        lambda: ply_bytes(np.outer(np.linspace(-1, 1, 300), [1.0, 2.0, 3.0])),
        ("one line",),
    ),
    (
        "all-non-finite",
        "scan.ply",
        lambda: ply_bytes(np.full((100, 3), np.nan)),
        ("0 distinct finite",),
    ),
    ("coordinates-overflow", "scan.ply", lambda: ply_bytes(sphere(radius=1e300)), ("too large",)),
    ("coordinates-underflow", "scan.ply", lambda: ply_bytes(sphere(radius=1e-300)), ("too small",)),
    (
        "far-outlier-everywhere",
        "scan.ply",
        lambda: ply_bytes(np.vstack([S, [[1e15, 1e15, 1e15]]])),
        ("outliers", "spacing"),
    ),
]


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _run(args: list[str]):
    return CliRunner().invoke(app, args)


def _assert_clean_failure(res, code: int, names: list[str], words: tuple[str, ...]) -> None:
    err = res.stderr
    assert res.exit_code == code, (res.exit_code, err, res.exception)
    assert "Traceback" not in res.output and "Traceback" not in err
    assert not isinstance(res.exception, Exception) or isinstance(res.exception, SystemExit)
    assert any(n in err for n in names), err
    low = err.lower()
    for w in words:
        assert w.lower() in low, (w, err)
    assert err.count("\n") <= 2, err  # one line (plus a possible log line)


@pytest.mark.parametrize("case", BAD_INPUTS, ids=[c[0] for c in BAD_INPUTS])
def test_bad_input_fails_cleanly(tmp_path, case):
    _, name, make, words = case
    src = tmp_path / "in" / name
    src.parent.mkdir()
    src.write_bytes(make())
    before = _sha(src)
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    res = _run(
        [
            "fit",
            str(src),
            "-o",
            str(out_dir / "mesh.ply"),
            "--particles",
            str(out_dir / "particles.ply"),
            *FAST,
        ]
    )
    _assert_clean_failure(res, 2, [str(src)], words)
    assert sorted(os.listdir(out_dir)) == []
    assert sorted(os.listdir(src.parent)) == [name]
    assert _sha(src) == before


@pytest.mark.parametrize("command", ["fit", "info", "normals"])
def test_ply_version_2_0_exits_2_and_writes_nothing(tmp_path, command):
    """Issue #10: ``format binary_little_endian 2.0`` used to be read as 1.0 and exit 0."""
    src = tmp_path / "in" / "scan.ply"
    src.parent.mkdir()
    good = ply_bytes(S)
    assert b"format binary_little_endian 1.0\n" in good
    src.write_bytes(good.replace(b"binary_little_endian 1.0", b"binary_little_endian 2.0", 1))
    before = _sha(src)
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    args = [command, str(src)]
    if command != "info":
        args += ["-o", str(out_dir / "mesh.ply")]
    if command == "fit":
        args += ["--particles", str(out_dir / "particles.ply"), *FAST]
    res = _run(args)
    _assert_clean_failure(res, 2, [str(src)], ("ply version", "2.0"))
    assert os.listdir(out_dir) == []
    assert os.listdir(src.parent) == ["scan.ply"]
    assert _sha(src) == before


@pytest.mark.parametrize(
    ("spacing", "extra", "words"),
    [
        ("1e-300", [], ("spacing", "too many cells")),
        ("1e-200", [], ("spacing", "too many cells")),
        ("1e-300", ["--tiles", "auto"], ()),  # the tile sizing met 0 points x inf: nan
    ],
)
def test_a_spacing_far_below_the_datas_fails_cleanly(tmp_path, spacing, extra, words):
    """Regression: ``--spacing 1e-300`` overflowed the memory estimate's particle count
    (OverflowError traceback, exit 1), and the grid-size check warned of an overflow."""
    src = tmp_path / "scan.ply"
    src.write_bytes(ply_bytes(S))
    out = tmp_path / "out"
    out.mkdir()
    args = ["fit", str(src), "-o", str(out / "mesh.ply"), "--spacing", spacing, *extra, *FAST]
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        res = _run(args)
    _assert_clean_failure(res, 2, [str(src)], words)
    assert os.listdir(out) == []


def test_there_are_at_least_thirty_adversarial_cases():
    assert len(BAD_INPUTS) + len(VALID_ODD_INPUTS) + len(PATH_CASES) + len(CONFIG_CASES) >= 30


# --------------------------------------------------------------------------------------------
# odd but valid inputs: the fit runs and writes finite files


def _nan_normals() -> bytes:
    nrm = sphere()
    nrm[:4] = np.nan
    nrm[4:8] = 0.0
    return ply_bytes(S, nrm)


VALID_ODD_INPUTS: list[tuple[str, str, Callable[[], bytes]]] = [
    ("coplanar-grid", "scan.ply", lambda: ply_bytes(grid_plane())),
    ("duplicated-halves", "scan.ply", lambda: ply_bytes(np.vstack([S, S]))),
    (
        "far-apart-clusters",
        "scan.ply",
        lambda: ply_bytes(np.vstack([sphere(200), sphere(200, centre=(2e4, 0, 0), seed=1)])),
    ),
    ("tiny-scale-offset", "scan.ply", lambda: ply_bytes(sphere(radius=1e-9, centre=(1, 2, 3)))),
    (
        "huge-scale-offset",
        "scan.ply",
        lambda: ply_bytes(sphere(radius=1e7, centre=(5e9, -3e9, 1e8))),
    ),
    ("zero-normals", "scan.ply", lambda: ply_bytes(S, np.zeros_like(S))),
    ("nan-normals", "scan.ply", lambda: ply_bytes(S, np.full_like(S, np.nan))),
    ("some-invalid-normals", "scan.ply", _nan_normals),
    (
        "some-non-finite-points",
        "scan.xyz",
        lambda: xyz_bytes(np.vstack([S, [[np.nan, 0, 0], [np.inf, 1, 1], [0, -np.inf, 2]]])),
    ),
    ("ascii-pcd", "scan.pcd", lambda: pcd_bytes(S, kind="ascii")),
    ("one-far-outlier", "scan.ply", lambda: ply_bytes(np.vstack([S, [[1e9, 0.0, 0.0]]]))),
]


@pytest.mark.parametrize("case", VALID_ODD_INPUTS, ids=[c[0] for c in VALID_ODD_INPUTS])
def test_odd_but_valid_input_fits(tmp_path, case):
    cid, name, make = case
    src = tmp_path / name
    src.write_bytes(make())
    before = _sha(src)
    out = tmp_path / "out" / "mesh.ply"
    res = _run(
        [
            "fit",
            str(src),
            "-o",
            str(out),
            "--mkdir",
            "-q",
            "--particles",
            str(out.with_name("p.ply")),
            *FAST,
        ]
    )
    assert res.exit_code == 0, (res.stderr, res.exception)
    assert "Traceback" not in res.stderr
    assert _sha(src) == before
    assert sorted(os.listdir(out.parent)) == ["mesh.ply", "mesh.report.json", "p.ply"]
    v, f = read_mesh(out)
    assert len(f) > 0 and np.isfinite(v).all()
    p = read_points(out.with_name("p.ply"), merge_duplicates=False)
    assert np.isfinite(p.absolute_points()).all() and np.isfinite(p.normals).all()
    text = out.with_name("mesh.report.json").read_text()
    assert "NaN" not in text and "Infinity" not in text
    json.loads(text)
    data = read_points(src, merge_duplicates=False).absolute_points()
    lo, hi = data.min(axis=0), data.max(axis=0)
    slack = 0.2 * float(np.max(hi - lo))
    assert np.all(v.min(axis=0) >= lo - slack) and np.all(v.max(axis=0) <= hi + slack)
    if cid == "coplanar-grid":
        assert np.all(v[:, 2] == 0.0)  # flat
        report = json.loads(text)
        assert report["topology"]["boundary_loops"] >= 1  # an open sheet, not a closed pillow
        assert not report["topology"]["watertight"]
    if cid == "far-apart-clusters":
        assert json.loads(text)["topology"]["components"] == 2


# --------------------------------------------------------------------------------------------
# output paths


def _same_path_spelling(tmp_path: Path, src: Path) -> str:
    return str(tmp_path / "." / "sub" / ".." / src.name)


def _link(kind: str) -> Callable[[Path, Path], str]:
    def make(tmp: Path, src: Path) -> str:
        link = tmp / "link.ply"
        getattr(link, kind)(src)
        return str(link)

    return make


PATH_CASES = [
    ("output-is-input", lambda tmp, src: str(src), ("refusing to overwrite an input",)),
    ("output-is-input-other-spelling", _same_path_spelling, ("refusing to overwrite an input",)),
    (
        "output-is-input-relative",
        lambda tmp, src: "./" + src.name,
        ("refusing to overwrite an input",),
    ),
    ("output-is-symlink-to-input", _link("symlink_to"), ("refusing to overwrite an input",)),
    ("output-is-hardlink-to-input", _link("hardlink_to"), ("refusing to overwrite an input",)),
    ("output-folder-missing", lambda tmp, src: str(tmp / "nope" / "m.ply"), ("--mkdir",)),
    ("output-is-a-folder", lambda tmp, src: str(tmp), ("is a directory",)),
    ("output-bad-extension", lambda tmp, src: str(tmp / "m.stl"), ("cannot write meshes",)),
]


@pytest.mark.parametrize("case", PATH_CASES, ids=[c[0] for c in PATH_CASES])
@pytest.mark.parametrize("command", ["fit", "normals"])
def test_output_path_refused(tmp_path, monkeypatch, case, command):
    cid, make_out, words = case
    if command == "normals" and cid == "output-bad-extension":
        words = ("cannot write point clouds", "use .ply")  # regression: was PLY as .stl
    (tmp_path / "sub").mkdir()
    src = tmp_path / "scan.ply"
    src.write_bytes(ply_bytes(S))
    before = _sha(src)
    out = make_out(tmp_path, src)
    monkeypatch.chdir(tmp_path)
    listing = sorted(os.listdir(tmp_path))
    res = _run([command, str(src), "-o", out, *(FAST if command == "fit" else [])])
    _assert_clean_failure(res, 2, [out, Path(out).name], words)
    assert sorted(os.listdir(tmp_path)) == listing
    assert sorted(os.listdir(tmp_path / "sub")) == []
    assert _sha(src) == before


def test_particles_or_preview_onto_input_refused(tmp_path):
    src = tmp_path / "scan.ply"
    src.write_bytes(ply_bytes(S))
    before = _sha(src)
    for opt, words in (
        ("--particles", ("refusing to overwrite",)),
        ("--preview", ("the preview is a PNG image",)),  # refused by its name before the fit
    ):
        res = _run(["fit", str(src), "-o", str(tmp_path / "m.ply"), opt, str(src), *FAST])
        _assert_clean_failure(res, 2, [str(src)], words)
    assert sorted(os.listdir(tmp_path)) == ["scan.ply"]
    assert _sha(src) == before


@pytest.mark.parametrize(
    ("option", "name", "words"),
    [
        *(
            ("--particles", n, ("cannot write point clouds", "use .ply"))
            for n in ("particles.xyz", "particles.obj", "particles")
        ),
        *(
            ("--preview", n, ("the preview is a PNG image", "use .png"))
            for n in ("preview.jpg", "preview.JPEG", "preview.svg", "preview")
        ),
    ],
)
def test_an_output_in_another_format_is_refused_before_the_fit(
    tmp_path, monkeypatch, option, name, words
):
    """Regression: ``--particles p.xyz`` (and ``normals -o n.xyz``) wrote binary PLY under
    that name, which no reader of the extension could read; ``--preview p.jpg`` wrote PNG
    bytes under that name, after the whole fit."""
    import recon.fitting

    def no_fit(*args, **kwargs):
        raise AssertionError("the fit started")

    monkeypatch.setattr(recon.fitting, "fit_file", no_fit)
    src = tmp_path / "scan.ply"
    src.write_bytes(ply_bytes(S))
    out = tmp_path / name
    res = _run(["fit", str(src), "-o", str(tmp_path / "m.ply"), option, str(out), *FAST])
    _assert_clean_failure(res, 2, [name], words)
    assert sorted(os.listdir(tmp_path)) == ["scan.ply"]


@pytest.mark.parametrize("tiled", [False, True])
@pytest.mark.parametrize(
    ("output", "words"), [(".", ["empty output path"]), ("/", ["is a directory"])]
)
def test_an_output_without_a_file_name_is_refused_by_name(tmp_path, output, words, tiled):
    """Regression: ``fit -o .`` (or ``/``) ended in "ValueError: PosixPath('.') has an empty
    name", a traceback with exit 1: the report's name was made before the path was checked."""
    src = tmp_path / "scan.ply"
    src.write_bytes(ply_bytes(S))
    tiles = ["--tile-size", "1"] if tiled else []
    res = _run(["fit", str(src), "-o", output, *tiles, *FAST])
    _assert_clean_failure(res, 2, [output], words)
    assert sorted(os.listdir(tmp_path)) == ["scan.ply"]


@pytest.mark.parametrize("tiled", [False, True])
def test_particles_onto_the_mesh_output_say_so(tmp_path, tiled):
    """Regression: ``--particles`` naming the ``-o`` file was refused as "refusing to
    overwrite an input file", which it is not."""
    src = tmp_path / "scan.ply"
    src.write_bytes(ply_bytes(S))
    out = tmp_path / "m.ply"
    tiles = ["--tile-size", "1"] if tiled else []
    res = _run(["fit", str(src), "-o", str(out), "--particles", str(out), *tiles, *FAST])
    _assert_clean_failure(res, 2, ["m.ply"], ["is also the mesh output"])
    assert "input file" not in res.stderr
    assert sorted(os.listdir(tmp_path)) == ["scan.ply"]


@pytest.mark.parametrize("name", ["m.jpg", "m"])
def test_a_report_picture_in_another_format_than_png_is_refused(tmp_path, name):
    """Regression: ``oprecon report MESH --png m.jpg`` wrote PNG bytes under that name."""
    from recon.io import write_mesh

    mesh = tmp_path / "a.ply"
    write_mesh(mesh, sphere(40), np.array([[0, 1, 2], [0, 2, 3], [0, 3, 1], [1, 3, 2]]))
    out = tmp_path / name
    res = _run(["report", str(mesh), "--png", str(out)])
    _assert_clean_failure(res, 2, [str(out)], ("the picture is a PNG image", "use .png"))
    assert sorted(os.listdir(tmp_path)) == ["a.ply"]
    res = _run(["report", str(mesh), "--png", str(tmp_path / "m.PNG")])  # any case of .png
    assert res.exit_code == 0, res.output
    assert (tmp_path / "m.PNG").read_bytes().startswith(b"\x89PNG")


def test_report_path_onto_input_refused(tmp_path):
    """``m.ply`` writes ``m.report.json``: refused when that is the input."""
    src = tmp_path / "m.report.json"
    src.write_bytes(xyz_bytes(S))
    before = _sha(src)
    res = _run(["fit", str(src), "-o", str(tmp_path / "m.ply"), *FAST])
    _assert_clean_failure(res, 2, [str(src)], ("refusing to overwrite",))
    assert sorted(os.listdir(tmp_path)) == ["m.report.json"]
    assert _sha(src) == before


def test_mkdir_creates_the_folder_for_fit_and_normals(tmp_path):
    src = tmp_path / "scan.ply"
    src.write_bytes(ply_bytes(S))
    for command, extra in (("fit", FAST), ("normals", [])):
        out = tmp_path / command / "deep" / "o.ply"
        res = _run([command, str(src), "-o", str(out), "--mkdir", "-q", *extra])
        assert res.exit_code == 0, res.stderr
        assert out.is_file()
        names = os.listdir(out.parent)
        assert not [n for n in names if n.startswith(".")], names


@pytest.mark.parametrize("command", ["fit", "normals"])
def test_a_failed_run_takes_back_the_folders_mkdir_made(tmp_path, command):
    """Regression: ``fit --mkdir`` on a bad input left the empty folders it had made; a
    folder that existed before, or that holds a file, stays."""
    src = tmp_path / "scan.ply"
    src.write_bytes(b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nend_header\n")
    (tmp_path / "kept").mkdir()
    out = tmp_path / "kept" / "new" / "deep" / "o.ply"
    extra = FAST if command == "fit" else []
    res = _run([command, str(src), "-o", str(out), "--mkdir", *extra])
    assert res.exit_code == 2, res.output
    assert os.listdir(tmp_path / "kept") == []  # new/deep made and taken back; kept stays


# --------------------------------------------------------------------------------------------
# configuration files


CONFIG_CASES = [
    (
        "python-object-tag",
        "seeds: !!python/object/apply:os.system ['echo pwned']\n",
        ("line 1", "tag"),
    ),
    ("malformed-yaml", "dynamics:\n  dt: 0.1\n   max_steps: [1, 2\n", ("line", "column")),
    ("unknown-key", "dynamics:\n  dtt: 0.1\n", ("dynamics.dtt", "did you mean")),
    ("wrong-type", "dynamics:\n  max_steps: lots\n", ("dynamics.max_steps", "integer")),
    ("out-of-range", "dynamics:\n  dt: -1\n", ("dynamics.dt", "out of range")),
    ("not-a-mapping", "- 1\n- 2\n", ("expected a mapping",)),
]


@pytest.mark.parametrize("case", CONFIG_CASES, ids=[c[0] for c in CONFIG_CASES])
def test_bad_config_fails_cleanly(tmp_path, case):
    _, text, words = case
    src = tmp_path / "scan.ply"
    src.write_bytes(ply_bytes(S))
    cfg = tmp_path / "cfg.yaml"
    cfg.write_text(text)
    before = _sha(cfg), _sha(src)
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    res = _run(["fit", str(src), "-o", str(out_dir / "m.ply"), "--config", str(cfg)])
    _assert_clean_failure(res, 2, [str(cfg)], words)
    assert os.listdir(out_dir) == []
    assert (_sha(cfg), _sha(src)) == before


@pytest.mark.parametrize(
    "override,words",
    [
        ("dynamics.dt=abc", ("dynamics.dt", "number")),
        ("dynamics.nope=1", ("dynamics.nope",)),
        ("growth.max_rounds=-3", ("growth.max_rounds", "out of range")),
        ("seeds.spacing=!!python/name:os.system", ("seeds.spacing",)),
    ],
)
def test_bad_override_names_the_key(tmp_path, override, words):
    src = tmp_path / "scan.ply"
    src.write_bytes(ply_bytes(S))
    res = _run(["fit", str(src), "-o", str(tmp_path / "m.ply"), "--set", override])
    _assert_clean_failure(res, 2, [words[0]], words)
    assert os.listdir(tmp_path) == ["scan.ply"]


# --------------------------------------------------------------------------------------------
# runs that go wrong after the input was read


def test_time_limit_exits_2_without_outputs(tmp_path):
    src = tmp_path / "scan.ply"
    src.write_bytes(ply_bytes(S))
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    res = _run(["fit", str(src), "-o", str(out_dir / "m.ply"), "--time-limit", "1e-6", *FAST])
    _assert_clean_failure(res, 2, [str(src)], ("time limit",))
    assert os.listdir(out_dir) == []


@pytest.mark.parametrize(
    "exc,code,word",
    [
        (KeyboardInterrupt, 130, "interrupted"),
        (OSError(28, "No space left on device"), 2, "no space left"),
        (MemoryError, 2, "out of memory"),
    ],
)
def test_failure_while_writing_leaves_nothing(tmp_path, monkeypatch, exc, code, word):
    """The mesh is written, then writing the particles fails: no file at all survives."""
    import recon.io

    def broken(*args, **kwargs):
        raise exc

    monkeypatch.setattr(recon.io, "write_points", broken)
    src = tmp_path / "scan.ply"
    src.write_bytes(ply_bytes(S))
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    res = _run(
        [
            "fit",
            str(src),
            "-o",
            str(out_dir / "m.ply"),
            "--particles",
            str(out_dir / "p.ply"),
            "-q",
            *FAST,
        ]
    )
    assert res.exit_code == code, (res.stderr, res.exception)
    assert word in res.stderr.lower() and "Traceback" not in res.stderr
    assert os.listdir(out_dir) == []


def test_normals_failure_leaves_nothing(tmp_path, monkeypatch):
    import recon.normals

    def broken(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(recon.normals, "compute_normals", broken)
    src = tmp_path / "scan.ply"
    src.write_bytes(ply_bytes(S))
    res = _run(["normals", str(src), "-o", str(tmp_path / "n" / "o.ply"), "--mkdir"])
    assert res.exit_code == 130 and "interrupted" in res.stderr
    assert not (tmp_path / "n").exists()  # the folder --mkdir made is taken back


def test_numbers_in_hostile_header_are_checked_before_allocation(tmp_path):
    """A 10^15-vertex header over a tiny file is refused instantly (no MemoryError path)."""
    src = tmp_path / "bomb.ply"
    src.write_bytes(ply_bytes(S[:10], header_count=10**15))
    res = _run(["info", str(src)])
    _assert_clean_failure(res, 2, [str(src)], ("truncated", "bytes"))


def test_struct_packed_pcd_header_claims_match_file(tmp_path):
    """A binary PCD whose POINTS agrees with WIDTH x HEIGHT but not with the data."""
    body = struct.pack("<3f", 0.0, 0.0, 0.0) * 10
    head = (
        b"VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 1000\n"
        b"HEIGHT 1000\nPOINTS 1000000\nDATA binary\n"
    )
    src = tmp_path / "s.pcd"
    src.write_bytes(head + body)
    res = _run(["info", str(src)])
    _assert_clean_failure(res, 2, [str(src)], ("truncated",))


# --------------------------------------------------------------------------------------------
# divergence: one restart with dt halved, then a clear error


def _diverging_run(monkeypatch, fail_calls: set[int], exploding: bool = False):
    """Make ``Simulation.run`` fail on the given call numbers (0-based)."""
    from recon.dynamics import Simulation, StepStats
    from recon.errors import DivergenceError

    real = Simulation.run
    calls = {"n": 0, "dt": []}

    def run(self, n_steps, callback=None):
        k = calls["n"]
        calls["n"] += 1
        calls["dt"].append(self.params.dt)
        if k in fail_calls or (fail_calls == {-1}):
            if exploding:
                return StepStats(kinetic=1.0, potential=1e300, max_speed=1.0, rebuilt=False)
            raise DivergenceError(f"particle dynamics diverged at step {k}: test")
        return real(self, n_steps, callback)

    monkeypatch.setattr(Simulation, "run", run)
    return calls


@pytest.mark.parametrize("exploding", [False, True])
def test_divergence_restarts_the_phase_once_with_half_dt(tmp_path, monkeypatch, exploding):
    calls = _diverging_run(monkeypatch, {2}, exploding)
    src = tmp_path / "scan.ply"
    src.write_bytes(ply_bytes(S))
    out = tmp_path / "m.ply"
    res = _run(["fit", str(src), "-o", str(out), "-q", *FAST])
    assert res.exit_code == 0, (res.stderr, res.exception)
    report = json.loads(out.with_name("m.report.json").read_text())
    assert any("restarted with dynamics.dt = 0.1" in w for w in report["warnings"])
    assert report["config"]["dynamics"]["dt"] == 0.1
    assert calls["dt"][:3] == [0.2, 0.2, 0.2] and set(calls["dt"][3:]) == {0.1}
    v, _ = read_mesh(out)
    assert np.isfinite(v).all()


@pytest.mark.parametrize("exploding", [False, True])
def test_divergence_twice_is_a_clear_error(tmp_path, monkeypatch, exploding):
    _diverging_run(monkeypatch, {-1}, exploding)
    src = tmp_path / "scan.ply"
    src.write_bytes(ply_bytes(S))
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    res = _run(["fit", str(src), "-o", str(out_dir / "m.ply"), *FAST])
    _assert_clean_failure(res, 2, [str(src)], ("diverged during growth", "halved to 0.1"))
    assert os.listdir(out_dir) == []


def test_particle_cap_is_a_clear_error(tmp_path):
    src = tmp_path / "scan.ply"
    src.write_bytes(ply_bytes(S))
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    res = _run(["fit", str(src), "-o", str(out_dir / "m.ply"), "--max-particles", "10", *FAST])
    _assert_clean_failure(res, 2, [str(src)], ("max_particles=10",))
    assert os.listdir(out_dir) == []


@pytest.mark.parametrize(
    "case",
    [c for c in VALID_ODD_INPUTS if "normals" in c[0] or "finite" in c[0]],
    ids=lambda c: c[0],
)
def test_normals_output_is_finite(tmp_path, case):
    _, name, make = case
    src = tmp_path / name
    src.write_bytes(make())
    out = tmp_path / "n" / "o.ply"
    res = _run(["normals", str(src), "-o", str(out), "--mkdir", "-q"])
    assert res.exit_code == 0, res.stderr
    cloud = read_points(out, merge_duplicates=False)
    assert np.isfinite(cloud.absolute_points()).all() and np.isfinite(cloud.normals).all()
    assert np.allclose(np.linalg.norm(cloud.normals, axis=1), 1.0, atol=1e-6)
    assert os.listdir(out.parent) == ["o.ply"]


def test_exit_codes_of_compare_and_report(tmp_path):
    """0 success, 1 a completed run that failed a check, 2 bad input."""
    from recon.io import write_mesh

    v = sphere(40)
    f = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 1], [1, 3, 2]])
    a, b = tmp_path / "a.ply", tmp_path / "b.ply"
    write_mesh(a, v, f)
    write_mesh(b, v + 0.5, f)
    assert _run(["compare", str(a), str(a), "--max-chamfer", "1e-3"]).exit_code == 0
    failed = _run(["compare", str(a), str(b), "--max-chamfer", "1e-6"])
    assert failed.exit_code == 1 and "Traceback" not in failed.output
    bad = tmp_path / "bad.ply"
    bad.write_bytes(ply_bytes(S, header_count=10**9))
    for args in (["compare", str(bad), str(a)], ["report", str(bad)], ["info", str(bad)]):
        _assert_clean_failure(_run(args), 2, [str(bad)], ("truncated",))
    png = tmp_path / "sub" / "m.png"
    _assert_clean_failure(
        _run(["report", str(a), "--png", str(png)]),
        2,
        [str(png)],
        ("does not exist", "create it first"),
    )
    _assert_clean_failure(_run(["report", str(a), "--png", str(a)]), 2, [str(a)], ("refusing",))


def test_duplicates_kept_on_request_is_a_clear_error(tmp_path):
    src = tmp_path / "scan.ply"
    src.write_bytes(ply_bytes(np.vstack([S, S, S])))
    res = _run(
        [
            "fit",
            str(src),
            "-o",
            str(tmp_path / "m.ply"),
            "--set",
            "io.merge_duplicates=false",
            *FAST,
        ]
    )
    _assert_clean_failure(res, 2, [str(src)], ("exact duplicates", "io.merge_duplicates"))
    assert os.listdir(tmp_path) == ["scan.ply"]


def test_divergence_in_release_restarts_release_only(tmp_path, monkeypatch):
    from recon.dynamics import Simulation
    from recon.errors import DivergenceError

    real = Simulation.run
    seen = {"failed": False, "dt": []}

    def run(self, n_steps, callback=None):
        released = not self.state.is_pinned.any()
        seen["dt"].append((released, self.params.dt))
        if released and not seen["failed"]:
            seen["failed"] = True
            raise DivergenceError("particle dynamics diverged: test")
        return real(self, n_steps, callback)

    monkeypatch.setattr(Simulation, "run", run)
    src = tmp_path / "scan.ply"
    src.write_bytes(ply_bytes(S))
    out = tmp_path / "m.ply"
    res = _run(["fit", str(src), "-o", str(out), "-q", *FAST])
    assert res.exit_code == 0, (res.stderr, res.exception)
    report = json.loads(out.with_name("m.report.json").read_text())
    assert any("during release" in w for w in report["warnings"])
    assert {dt for released, dt in seen["dt"] if not released} == {0.2}
    assert {dt for released, dt in seen["dt"][-3:]} == {0.1}


@pytest.mark.parametrize(
    "text,words",
    [
        ("max_chamfer: [1\n", ("invalid yaml at line 2", "column")),
        ("max_chamfer: !!python/object/apply:os.getcwd []\n", ("tag", "not allowed")),
        ("max_chamfr: 0.1\n", ("unknown key 'max_chamfr'",)),
    ],
)
def test_compare_tolerance_file_errors(tmp_path, text, words):
    from recon.io import write_mesh

    mesh = tmp_path / "a.ply"
    write_mesh(mesh, sphere(10), np.array([[0, 1, 2], [0, 2, 3]]))
    tol = tmp_path / "tol.yaml"
    tol.write_text(text)
    res = _run(["compare", str(mesh), str(mesh), "--tolerances", str(tol)])
    _assert_clean_failure(res, 2, [str(tol)], words)
