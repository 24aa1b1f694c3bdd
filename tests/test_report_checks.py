"""``oprecon report`` judging odd meshes, and the output checks before any work.

Regressions of a tester's report: outputs in a read-only folder refused only after the run,
a false "history not drawn" warning (and a second render) when the PNG could not be written,
no first-compile notice, "watertight yes" with a repeated-index face, the counts of an
all-degenerate mesh, NaN vertices (unnamed file; written but unreadable), inside-out meshes.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from mesh_shapes import icosphere, open_cylinder, tetrahedron
from recon.cli.main import app

from recon.errors import InputError
from recon.io import check_output_path, read_mesh, write_mesh, write_points
from recon.topology import mesh_topology


def run(*args):
    return CliRunner().invoke(app, [str(a) for a in args])


def ply_text(path: Path, vertices, faces) -> Path:
    """An ASCII PLY written by hand (``write_mesh`` refuses non-finite vertices)."""
    lines = [
        "ply",
        "format ascii 1.0",
        f"element vertex {len(vertices)}",
        "property double x",
        "property double y",
        "property double z",
        f"element face {len(faces)}",
        "property list uchar int vertex_indices",
        "end_header",
    ]
    lines += [" ".join(repr(float(x)) for x in p) for p in vertices]
    lines += ["3 " + " ".join(str(int(i)) for i in t) for t in faces]
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.fixture
def read_only_dir(tmp_path, monkeypatch):
    """A folder nobody may write in: mode 0o555, and for root (whom the mode does not stop)
    ``os.access`` answering as on a read-only mount for it."""
    folder = tmp_path / "ro"
    folder.mkdir()
    folder.chmod(0o555)
    real_access = os.access

    def access(path, mode, *args, **kwargs):
        if mode & os.W_OK and Path(path).resolve() == folder.resolve():
            return False
        return real_access(path, mode, *args, **kwargs)

    if real_access(folder, os.W_OK):  # root
        monkeypatch.setattr(os, "access", access)
    yield folder
    folder.chmod(0o755)


# ---------------------------------------------------------------------------- 1. writable


def test_a_symlink_is_judged_by_its_own_folder(tmp_path, read_only_dir):
    """Regression (a second read): the check looked at the folder of the link's target, but
    the temporary is written beside the link and renamed onto it."""
    rw = tmp_path / "rw"
    rw.mkdir()
    link = rw / "link.ply"
    link.symlink_to(read_only_dir / "target.ply")
    assert check_output_path(link) == link  # rw takes the new file
    back = read_only_dir / "back.ply"
    read_only_dir.chmod(0o755)
    back.symlink_to(rw / "target.ply")
    read_only_dir.chmod(0o555)
    with pytest.raises(InputError, match="cannot write in folder"):
        check_output_path(back)


def test_check_output_path_refuses_a_folder_it_cannot_write_in(read_only_dir, tmp_path):
    with pytest.raises(InputError) as err:
        check_output_path(read_only_dir / "s.ply")
    assert str(err.value).startswith(f"{read_only_dir / 's.ply'}: ")
    assert f"'{read_only_dir}'" in str(err.value) and "write" in str(err.value)
    # writable folders, existing or made, still pass
    assert check_output_path(tmp_path / "ok.ply") == tmp_path / "ok.ply"
    assert check_output_path(tmp_path / "new" / "ok.ply", mkdir=True).parent.is_dir()


@pytest.fixture
def no_reading(monkeypatch):
    """The readers fail the test: an output refused up front is refused before them."""
    import recon.io

    def never(*args, **kwargs):
        raise AssertionError("the input was read before the output folder was checked")

    monkeypatch.setattr(recon.io, "read_points", never)
    monkeypatch.setattr(recon.io, "read_mesh", never)


@pytest.mark.parametrize("command", ["fit", "normals", "remesh", "report"])
def test_outputs_in_a_read_only_folder_are_refused_before_the_work(
    command, tmp_path, read_only_dir, no_reading
):
    points = tmp_path / "in.ply"
    v, f = icosphere(2)
    write_points(points, v, v)
    mesh = tmp_path / "m.ply"
    write_mesh(mesh, v, f)
    args = {
        "fit": ["fit", points, "-o", read_only_dir / "s.ply", "-q"],
        "normals": ["normals", points, "-o", read_only_dir / "s.ply"],
        "remesh": ["remesh", mesh, "-o", read_only_dir / "s.ply"],
        "report": ["report", mesh, "--png", read_only_dir / "s.png"],
    }[command]
    r = run(*args)
    assert r.exit_code == 2, r.output
    assert r.stderr.startswith("oprecon: error: "), r.stderr
    assert f"'{read_only_dir}'" in r.stderr and "Traceback" not in r.output
    assert list(read_only_dir.iterdir()) == []


# ---------------------------------------------------------------------------- 2. png errors


def test_a_png_that_cannot_be_written_is_an_error_not_a_history_warning(tmp_path, monkeypatch):
    from recon import render
    from recon.io import files

    mesh = tmp_path / "b.ply"
    write_mesh(mesh, *icosphere(1))
    history = {"step": [0, 1], "particles": [1, 2], "kinetic": [1.0, 0.5]}
    (tmp_path / "b.report.json").write_text(json.dumps({"history": history}))

    def full(self, path):  # the folder passed the check, the write fails (a full disk)
        raise files.input_error(path, "cannot write: No space left on device")

    monkeypatch.setattr(files.AtomicOutputs, "temporary", full)
    calls = []
    real = render.render_mesh_png
    monkeypatch.setattr(
        render, "render_mesh_png", lambda *a, **k: (calls.append(k), real(*a, **k))[1]
    )
    r = run("report", mesh, "--png", tmp_path / "b.png")
    assert r.exit_code == 2, r.output
    assert "history not drawn" not in r.stderr and "warning" not in r.stderr
    assert r.stderr.strip() == f"oprecon: error: {tmp_path / 'b.png'}: cannot write: " + (
        "No space left on device"
    )
    assert len(calls) == 1 and calls[0]["history"] is not None  # rendered once


def test_a_broken_history_still_falls_back_to_the_mesh_alone(tmp_path):
    mesh = tmp_path / "m.ply"
    write_mesh(mesh, *icosphere(1))
    (tmp_path / "m.report.json").write_text(json.dumps({"history": {"kinetic": [1.0]}}))
    r = run("report", mesh, "--png", tmp_path / "m.png")
    assert r.exit_code == 0, r.output
    assert "history not drawn: history has no 'step' list" in r.stderr
    assert (tmp_path / "m.png").is_file()


# ---------------------------------------------------------------------------- 3. compile note


def test_report_says_when_it_first_compiles_its_kernels(tmp_path, monkeypatch):
    from recon.kernels import warm

    mesh = tmp_path / "t.ply"
    write_mesh(mesh, *tetrahedron())
    asked: list[list[str]] = []

    def uncached(names=warm.FIT_KERNELS):
        asked.append(list(names))
        return list(names)

    monkeypatch.setattr(warm, "uncached", uncached)
    r = run("report", mesh, "--json")
    assert r.exit_code == 0, r.output
    assert "compiling the numba kernels first" in r.stderr
    json.loads(r.stdout)  # the note is on stderr only
    assert "sphere_pairs.sphere_pairs" in asked[-1] and "mesh_tables.fan_labels" in asked[-1]
    assert all(callable(k) for k in warm.resolve(asked[-1]))
    r = run("report", mesh, "--png", tmp_path / "t.png")
    assert "mesh_tables.edge_table" in asked[-1]  # the picture's too
    monkeypatch.setattr(warm, "uncached", lambda names=(): [])
    r = run("report", mesh)
    assert r.exit_code == 0 and "compiling" not in r.stderr


_LIST_COMPILED = """
import importlib, pkgutil, sys
from click.testing import CliRunner
from recon.cli.main import app
import recon.kernels as K
from numba.core.dispatcher import Dispatcher
r = CliRunner().invoke(app, sys.argv[1:])
assert r.exit_code == 0, r.output
for m in pkgutil.iter_modules(K.__path__):
    mod = importlib.import_module("recon.kernels." + m.name)
    for name, obj in vars(mod).items():
        if isinstance(obj, Dispatcher) and obj.overloads and obj.py_func.__module__ == mod.__name__:
            print(m.name + "." + name)
"""


def test_the_note_names_the_kernels_a_report_calls(tmp_path):
    """The kernels the notice checks are those a report loads (or compiles): run in a fresh
    process, on a mesh with every defect the report looks for, and with a picture."""
    from recon.cli.report import PNG_KERNELS, REPORT_KERNELS

    v, f = icosphere(1)
    f = f[1:].copy()  # a hole
    f[5] = f[5, ::-1]  # a flipped face
    mesh = tmp_path / "odd.ply"
    write_mesh(mesh, np.vstack([v, v + [0.5, 0, 0]]), np.vstack([f, f + len(v)]))
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    args = ["report", str(mesh), "--png", str(tmp_path / "odd.png")]
    out = subprocess.run(
        [sys.executable, "-c", _LIST_COMPILED, *args],
        capture_output=True, text=True, env=env, check=True,
    )  # fmt: skip
    called = set(out.stdout.split())
    assert called == set(REPORT_KERNELS) | set(PNG_KERNELS)


# ---------------------------------------------------------------------------- 4. repeated


def tetra_with_a_repeated_index():
    v, f = tetrahedron()
    return v, np.vstack([f, [[0, 0, 1]]])


def test_a_face_with_a_repeated_index_is_not_watertight():
    """Open3D: edge_manifold False, watertight False (the edge 0-1 is in three faces)."""
    t = mesh_topology(*tetra_with_a_repeated_index())
    assert t["watertight"] is False and t["genus"] is None
    assert t["degenerate_faces"] == 1
    assert mesh_topology(*tetrahedron())["watertight"] is True


def test_report_of_a_tetrahedron_with_a_repeated_index_face(tmp_path):
    mesh = tmp_path / "t.ply"
    write_mesh(mesh, *tetra_with_a_repeated_index())
    r = run("report", mesh, "--json")
    assert r.exit_code == 0, r.output
    topo = json.loads(r.stdout)["topology"]
    assert topo["watertight"] is False and topo["degenerate_faces"] == 1
    r = run("report", mesh)
    assert re.search(r"watertight +no\n", r.stdout), r.stdout


# ---------------------------------------------------------------------------- 5. degenerate


def test_vertices_of_degenerate_faces_are_referenced():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)
    t = mesh_topology(v, [[0, 0, 1], [1, 2, 2]])
    assert t["unreferenced_vertices"] == 0 and t["components"] == 1
    assert t["degenerate_faces"] == 2 and t["watertight"] is False
    # beside a proper surface: two vertices used by a repeated-index face only
    tv, tf = tetrahedron()
    t = mesh_topology(
        np.vstack([tv, [[5, 5, 5], [6, 5, 5], [9, 9, 9]]]), np.vstack([tf, [[4, 4, 5]]])
    )
    assert t["unreferenced_vertices"] == 1 and t["components"] == 2
    assert t["euler_characteristic"] == 2  # of the proper faces, as before


def test_report_of_an_all_degenerate_mesh_says_so(tmp_path, monkeypatch):
    mesh = tmp_path / "d.ply"
    write_mesh(mesh, np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float), [[0, 0, 1], [1, 2, 2]])
    texts: list[str] = []
    from matplotlib.figure import Figure

    real_savefig = Figure.savefig

    def savefig(fig, *args, **kwargs):
        texts.extend(t.get_text() for ax in fig.axes for t in ax.texts)
        return real_savefig(fig, *args, **kwargs)

    monkeypatch.setattr(Figure, "savefig", savefig)
    r = run("report", mesh, "--png", tmp_path / "d.png")
    assert r.exit_code == 0, r.output
    assert re.search(r"unreferenced vertices +0\n", r.stdout), r.stdout
    assert re.search(r"  components +1\n", r.stdout), r.stdout
    assert "no non-degenerate face" in r.stdout
    assert any("no non-degenerate face" in t for t in texts), texts
    r = run("report", mesh, "--json")
    assert r.exit_code == 0 and "no non-degenerate face" in r.stderr
    assert json.loads(r.stdout)["triangle_quality"]["n_measured"] == 0


# ---------------------------------------------------------------------------- 6. NaN


def test_an_unused_nan_vertex_is_refused_naming_the_file(tmp_path):
    v, f = tetrahedron()
    mesh = ply_text(tmp_path / "nan.ply", np.vstack([v, [[np.nan, 0, 0]]]), f)
    for args in (["report", mesh], ["compare", mesh, mesh]):
        r = run(*args)
        assert r.exit_code == 2, r.output
        assert r.stderr.startswith(f"oprecon: error: {mesh}: "), r.stderr
        assert "non-finite" in r.stderr and "vertex 4" in r.stderr and "no face" in r.stderr


def test_a_reference_with_an_unused_nan_vertex_is_refused_naming_it(tmp_path):
    """Regression: compare's reference was read without the check, and the error named both
    files ('A against B: vertices contain 1 non-finite values')."""
    v, f = tetrahedron()
    good = ply_text(tmp_path / "good.ply", v, f)
    ref = ply_text(tmp_path / "ref.ply", np.vstack([v, [[np.nan, 0, 0]]]), f)
    r = run("compare", good, ref)
    assert r.exit_code == 2, r.output
    assert r.stderr.startswith(f"oprecon: error: {ref}: "), r.stderr
    assert "vertex 4" in r.stderr and "against" not in r.stderr


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_write_mesh_refuses_non_finite_vertices(tmp_path, bad):
    v, f = tetrahedron()
    v[2, 1] = bad
    with pytest.raises(InputError, match="non-finite.*vertex 2"):
        write_mesh(tmp_path / "t.ply", v, f)
    assert list(tmp_path.iterdir()) == []
    v[2, 1] = 1.0
    write_mesh(tmp_path / "t.ply", v, f)
    assert np.array_equal(read_mesh(tmp_path / "t.ply")[0], v)


# ---------------------------------------------------------------------------- 7. inside out


def test_closed_components_facing_inward():
    from recon.topology import closed_orientation

    v, f = tetrahedron()
    assert closed_orientation(v, f) == {"closed_components": 1, "closed_components_inward": 0}
    assert closed_orientation(v, f[:, ::-1])["closed_components_inward"] == 1
    two = np.vstack([v, v + 3.0]), np.vstack([f, f[:, ::-1] + 4])
    assert closed_orientation(*two) == {"closed_components": 2, "closed_components_inward": 1}
    # far from the origin and tiny: the sign does not depend on the frame or the units
    s, sf = icosphere(2)
    for shift, scale in ((1e6, 1.0), (0.0, 1e-80), (3e5, 1e-3)):
        got = closed_orientation(s * scale + shift, sf[:, ::-1])
        assert got == {"closed_components": 1, "closed_components_inward": 1}
    # open, or inconsistently wound: no volume to judge
    assert closed_orientation(*open_cylinder(8, 2))["closed_components"] == 0
    mixed = f.copy()
    mixed[0] = mixed[0, ::-1]
    assert closed_orientation(v, mixed)["closed_components"] == 0


def test_report_flags_an_inside_out_mesh_and_still_exits_0(tmp_path):
    v, f = tetrahedron()
    mesh = tmp_path / "two.ply"
    write_mesh(mesh, np.vstack([v, v + 3.0]), np.vstack([f, f[:, ::-1] + 4]))
    r = run("report", mesh)
    assert r.exit_code == 0, r.output
    assert re.search(r"closed components +2\n +facing inward +1\n", r.stdout), r.stdout
    r = run("report", mesh, "--json")
    topo = json.loads(r.stdout)["topology"]
    assert topo["closed_components"] == 2 and topo["closed_components_inward"] == 1
    assert topo["consistently_oriented"] is True
