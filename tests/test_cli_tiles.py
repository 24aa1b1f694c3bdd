"""``oprecon fit --tile-size / --tiles auto`` end to end: PLY and LAS inputs, the report's tiles
section, a tile failing twice (exit 1, its bounds named), bad options (exit 2), nothing left
behind."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from recon.cli.main import app

from recon.io import read_mesh, write_points
from recon.topology import mesh_topology

OPRECON = Path(sys.executable).with_name("oprecon")


def _sheet(n: int = 2500, offset=(0.0, 0.0, 0.0)) -> np.ndarray:
    xy = np.random.default_rng(3).uniform(0, 8, (n, 2))
    z = 0.4 * np.sin(xy[:, 0] / 1.3) * np.cos(xy[:, 1] / 1.7)
    return np.column_stack([xy, z]) + np.asarray(offset)


def _run(args, env=None):
    return CliRunner().invoke(app, args, catch_exceptions=False, env=env)


@pytest.fixture(scope="module")
def sheet_file(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("cli_tiles") / "sheet.ply"
    write_points(path, _sheet())
    return path


def _leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.startswith(".oprecon"))


def _las_sheet(pts: np.ndarray, offset=None):
    """A LAS (point format 3) of ``pts`` at 0.1 mm, to fill in and write."""
    laspy = pytest.importorskip("laspy")
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales = np.array([0.0001] * 3)
    header.offsets = np.zeros(3) if offset is None else np.asarray(offset)
    las = laspy.LasData(header)
    las.x, las.y, las.z = pts[:, 0], pts[:, 1], pts[:, 2]
    return las


def test_fit_in_tiles_writes_one_seamless_mesh_and_a_tiles_report(
    sheet_file, tmp_path, monkeypatch
):
    from recon.kernels import warm

    # as on a first run: the note before, and the summary saying its times hold the compile
    monkeypatch.setattr(warm, "uncached", lambda names=(): ["pair_loop.step_particles"])
    out = tmp_path / "mesh.ply"
    res = _run(
        [
            "fit",
            str(sheet_file),
            "-o",
            str(out),
            "--tile-size",
            "4",
            "--jobs",
            "2",
            "--json",
            "--particles",
            str(tmp_path / "p.ply"),
        ]
    )
    assert res.exit_code == 0, res.output
    report = json.loads(res.stdout)
    assert report["tiles"]["count"] == 4 and report["tiles"]["jobs"] == 2
    assert json.loads((tmp_path / "mesh.report.json").read_text())["tiles"]["grid"] == [2, 2, 1]
    v, f = read_mesh(out)
    topo = mesh_topology(v, f)
    assert topo["boundary_loops"] == 1 and topo["non_manifold_edges"] == 0
    assert topo["duplicate_faces"] == 0
    assert (tmp_path / "p.ply").exists()
    assert "tiles 4/4 done" in res.stderr and "seams" in res.stderr
    assert "compiling the numba kernels first" in res.stderr
    assert "include compiling the numba kernels" in res.stderr.rstrip().splitlines()[-1]
    assert _leftovers(tmp_path) == []


def test_a_tiled_fit_takes_its_r0_as_a_share_of_the_diagonal(sheet_file, tmp_path):
    """Regression: ``--spacing-relative`` with tiles always stopped with "seeds.spacing and
    seeds.spacing_relative are exclusive; set one" (the scan's r0 was set beside it)."""
    from recon.io import read_points

    out = tmp_path / "mesh.ply"
    res = _run(["fit", str(sheet_file), "-o", str(out), "--tile-size", "4",
                "--spacing-relative", "0.02", "--json", "-q"])  # fmt: skip
    assert res.exit_code == 0, res.output
    report = json.loads(res.stdout)
    p = read_points(sheet_file).points
    diag = float(np.linalg.norm(p.max(axis=0) - p.min(axis=0)))
    assert report["tiles"]["count"] == 4
    assert report["spacing"] == pytest.approx(0.02 * diag, rel=1e-6)


def test_tiles_too_small_for_clean_seams_are_warned_of(sheet_file, tmp_path):
    """Regression: tiles of 5.5-6.5 r0 left dozens of loops and faces wound inside out at
    their seams without a word (exit 0, no warning); from 12 r0 on they are clean."""
    res = _run(["fit", str(sheet_file), "-o", str(tmp_path / "m.ply"), "--tile-size", "4",
                "--spacing", "0.4", "--json", "-q"])  # fmt: skip
    assert res.exit_code == 0, res.output
    (warning,) = [w for w in json.loads(res.stdout)["warnings"] if "r0 across" in w]
    assert "tiles of 4 are only 10.0 r0 across" in warning and "--tile-size 4.8" in warning
    res = _run(["fit", str(sheet_file), "-o", str(tmp_path / "n.ply"), "--tile-size", "4",
                "--spacing", "0.3", "--json", "-q"])  # fmt: skip
    assert not [w for w in json.loads(res.stdout)["warnings"] if "r0 across" in w]


def test_the_time_limit_holds_for_the_whole_tiled_fit(sheet_file, tmp_path):
    """Regression: ``--time-limit`` stopped each tile's fit, and a tile past it was retried:
    a tiled fit with a limit of 1 s ran 8.6 s and exited 0. The limit is the whole run's."""
    out = tmp_path / "mesh.ply"
    res = _run(["fit", str(sheet_file), "-o", str(out), "--tile-size", "4",
                "--time-limit", "0.001"])  # fmt: skip
    assert res.exit_code == 2, res.output
    assert "time limit of 0.001 s reached in the fit phase of the tiled fit" in res.stderr
    assert not out.exists() and _leftovers(tmp_path) == []


def test_a_tile_failing_twice_exits_1_with_its_bounds_and_writes_nothing(sheet_file, tmp_path):
    out = tmp_path / "mesh.ply"
    res = _run(
        ["fit", str(sheet_file), "-o", str(out), "--tile-size", "4", "--jobs", "2"],
        env={"OPRECON_TILE_FAIL": "1!"},
    )
    assert res.exit_code == 1, res.output
    assert "tile 1 (0, 1, 0) [" in res.stderr and "failed twice" in res.stderr
    assert "retrying" in res.stderr
    assert "Traceback" not in res.output
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_a_hung_tile_is_stopped_and_run_again(sheet_file, tmp_path):
    """Regression: a tile whose worker hung (OpenBLAS spinning on a failed allocation) kept
    the tiled fit waiting for ever. Past tiling.task_time_limit its worker is stopped and
    the tile fitted again: the run ends with the mesh."""
    out = tmp_path / "mesh.ply"
    res = _run(
        [
            "fit",
            str(sheet_file),
            "-o",
            str(out),
            "--tile-size",
            "4",
            "--jobs",
            "2",
            "--set",
            "tiling.task_time_limit=20",
        ],  # fmt: skip
        env={"OPRECON_TILE_FAIL": "1~"},
    )
    assert res.exit_code == 0, res.output
    assert "tile 1 (0, 1, 0) [" in res.stderr and "ran longer than 20 s" in res.stderr
    assert "taken for stuck" in res.stderr and "retrying" in res.stderr
    topo = mesh_topology(*read_mesh(out)[:2])
    assert topo["components"] == 1
    assert _leftovers(tmp_path) == []


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--tile-size", "0"], "'--tile-size': 0.0 is not in the range x>0"),
        (["--tile-size", "-3"], "is not in the range x>0"),
        (["--tile-size", "0.3"], "smaller than the halo"),
        (["--tile-size", "1e-9"], "give a larger --tile-size"),
        (["--tile-size", "4", "--tiles", "auto"], "--tile-size and --tiles auto are exclusive"),
        (["--tiles", "some"], "'--tiles'"),
        (["--tile-size", "4", "--scheduler", "tcp://x:1"], "--scheduler needs --executor dask"),
        (["--tile-size", "4", "--transfer", "intensity"], "the input has no intensity"),
        (["--tile-size", "4", "--quality", "-o", "m.obj"], "OBJ has no vertex properties"),
        (["--set", "tiling.size=-1"], "tiling.size"),
        (["--set", "tiling.memory=lots", "--tiles", "auto"], "tiling.memory"),
    ],
)
def test_bad_tiling_options_exit_2(sheet_file, tmp_path, extra, message, monkeypatch):
    monkeypatch.chdir(tmp_path)
    res = _run(["fit", str(sheet_file), "-o", str(tmp_path / "m.ply"), *extra])
    assert res.exit_code == 2, res.output
    assert message in res.output
    assert "Traceback" not in res.output
    assert list(tmp_path.iterdir()) == []


def test_tiles_auto_does_not_tile_a_scan_that_fits(sheet_file, tmp_path):
    out = tmp_path / "m.ply"
    res = _run(
        [
            "fit",
            str(sheet_file),
            "-o",
            str(out),
            "--tiles",
            "auto",
            "--set",
            "dynamics.max_steps=300",
        ]
    )
    assert res.exit_code == 0, res.output
    assert "not tiling" in res.stderr
    assert "tiles" not in json.loads((tmp_path / "m.report.json").read_text())


def test_tiles_auto_tiles_a_scan_past_the_budget(sheet_file, tmp_path):
    # 2500 points need ~376 MiB by the estimate (350 of them fixed); a 360 MiB budget is met
    # by small tiles only
    out = tmp_path / "m.ply"
    res = _run(
        [
            "fit",
            str(sheet_file),
            "-o",
            str(out),
            "--tiles",
            "auto",
            "--max-memory",
            "360M",
            "--jobs",
            "2",
            "--json",
        ]
    )
    assert res.exit_code == 0, res.output
    report = json.loads(res.stdout)
    assert report["tiles"]["count"] >= 2


def test_a_las_scan_is_split_in_chunks_and_fitted_in_tiles(tmp_path):
    offset = np.array([5_200_000.0, 4_800_000.0, 250.0])
    pts = _sheet(2500, offset)
    las = _las_sheet(pts, offset)
    las.classification = np.full(len(pts), 2, dtype=np.uint8)
    src = tmp_path / "sheet.las"
    las.write(str(src))
    out = tmp_path / "m.ply"
    res = _run(["fit", str(src), "-o", str(out), "--tile-size", "4", "--jobs", "2", "--json"])
    assert res.exit_code == 0, res.output
    report = json.loads(res.stdout)
    assert report["tiles"]["count"] == 4
    v, f = read_mesh(out)
    topo = mesh_topology(v, f)
    assert topo["boundary_loops"] == 1 and topo["non_manifold_edges"] == 0
    # georeferenced coordinates come back in place (the mesh lies on the data)
    assert np.all(v.min(axis=0) > offset - 1.0) and np.all(v.max(axis=0) < offset + 9.0)
    assert _leftovers(tmp_path) == []


def test_a_tiled_fit_of_some_classes_measures_the_points_it_keeps(tmp_path):
    """Regression: with ``--classes`` a tiled fit took the file header's box for the scan's
    diagonal (85.1 against 67.3 kept), and a class no point has stopped it with "fewer than 4
    points to fit" where the untiled fit lists the classes the file has."""
    pts = _sheet(3000)
    las = _las_sheet(pts)
    las.classification = np.where(pts[:, 0] < 4.0, 2, 6).astype(np.uint8)
    src = tmp_path / "two.las"
    las.write(str(src))
    kept = pts[pts[:, 0] >= 4.0]
    diag = float(np.linalg.norm(kept.max(axis=0) - kept.min(axis=0)))
    res = _run(["fit", str(src), "-o", str(tmp_path / "m.ply"), "--tile-size", "2.5",
                "--classes", "6", "--json", "-q"])  # fmt: skip
    assert res.exit_code == 0, res.output
    report = json.loads(res.stdout)
    assert report["tiles"]["count"] > 1
    assert report["input"]["bbox_diagonal"] == pytest.approx(diag, rel=1e-3)
    res = _run(["fit", str(src), "-o", str(tmp_path / "n.ply"), "--tile-size", "2.5",
                "--classes", "9"])  # fmt: skip
    assert res.exit_code == 2
    assert "no point of class 9 (the file has classes: 2 (" in res.stderr, res.stderr


@pytest.mark.skipif(os.name != "posix", reason="SIGINT to a process group needs POSIX")
@pytest.mark.skipif(not OPRECON.exists(), reason="the oprecon entry point is not installed")
def test_ctrl_c_during_the_tile_fits_exits_130_and_leaves_nothing(tmp_path):
    src = tmp_path / "sheet.ply"
    write_points(src, _sheet(6000))
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    endless = [
        "--set",
        "dynamics.max_steps=100000",
        "--set",
        "growth.max_rounds=1000",
        "--set",
        "growth.min_add_fraction=0",
        "--set",
        "dynamics.release_steps=100000",
        "--set",
        "dynamics.kinetic_tolerance=0",  # no early stop at rest
    ]
    cmd = [
        str(OPRECON),
        "fit",
        str(src),
        "-o",
        str(out_dir / "m.ply"),
        "--tile-size",
        "4",
        "--jobs",
        "2",
        *endless,
    ]

    def restore_sigint() -> None:
        signal.signal(signal.SIGINT, signal.SIG_DFL)

    # a new process group, as a terminal's foreground job: Ctrl-C reaches every process in it
    proc = subprocess.Popen(
        cmd,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        preexec_fn=restore_sigint,
        start_new_session=True,
    )
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and not list(out_dir.glob(".oprecon-tiles-*/points-*")):
            time.sleep(0.2)
        time.sleep(6.0)  # the workers are fitting
        assert proc.poll() is None, proc.stderr.read().decode()
        os.killpg(proc.pid, signal.SIGINT)
        code = proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    stderr = proc.stderr.read().decode()
    assert code == 130, stderr[-2000:]
    assert "interrupted" in stderr and "Traceback" not in stderr
    assert os.listdir(out_dir) == []
    time.sleep(1.0)
    alive = subprocess.run(
        ["ps", "-o", "pid=,stat=", "-g", str(proc.pid)], capture_output=True, text=True
    ).stdout.split("\n")
    assert [line for line in alive if line.strip() and "Z" not in line.split()[-1]] == []


def _group_alive(group: int) -> list[str]:
    """The processes of session ``group`` that are not zombies (``ps`` lines)."""
    lines = subprocess.run(
        ["ps", "-o", "pid=,stat=,args=", "-g", str(group)], capture_output=True, text=True
    ).stdout.splitlines()
    return [line for line in lines if line.strip() and "Z" not in line.split()[1]]


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="workers die with it on Linux")
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGKILL])
def test_a_coordinator_started_in_the_background_leaves_no_workers_behind(tmp_path, sig):
    """Regression: started with Ctrl-C ignored (``oprecon fit ... &`` in a script) and sent
    SIGTERM, the coordinator died at once: its work folder stayed and its workers ran on.
    SIGTERM now cleans up as Ctrl-C does (exit 130, nothing left); killed outright
    (SIGKILL), it still takes its workers with it."""
    src = tmp_path / "sheet.ply"
    write_points(src, _sheet(2500))
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    cmd = [str(OPRECON), "fit", str(src), "-o", str(out_dir / "m.ply"), "--tile-size", "4",
           "--jobs", "2"]  # fmt: skip

    def ignore_sigint() -> None:  # as a shell does for a background job of a script
        signal.signal(signal.SIGINT, signal.SIG_IGN)

    proc = subprocess.Popen(
        cmd,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        preexec_fn=ignore_sigint,
        start_new_session=True,
        env={**os.environ, "OPRECON_TILE_FAIL": "0!~"},  # tile 0's worker hangs
    )
    try:
        deadline = time.monotonic() + 90
        while time.monotonic() < deadline and not list(out_dir.glob(".oprecon-tiles-*/hung-0")):
            time.sleep(0.2)
        assert proc.poll() is None, proc.stderr.read().decode()
        assert len(_group_alive(proc.pid)) >= 3  # the coordinator and its two workers
        os.kill(proc.pid, sig)  # the coordinator only
        code = proc.wait(timeout=60)
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline and _group_alive(proc.pid):
            time.sleep(0.2)
        assert _group_alive(proc.pid) == []
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    if sig == signal.SIGTERM:
        stderr = proc.stderr.read().decode()
        assert code == 130, stderr[-2000:]
        assert "interrupted" in stderr and "Traceback" not in stderr
        assert os.listdir(out_dir) == []
    else:
        assert code == -signal.SIGKILL


def test_las_colours_end_up_on_the_tiled_mesh(tmp_path):
    """A two-coloured LAS sheet (16-bit colours: red for x < 4, blue beyond) in 2 x 2 tiles:
    each tile colours its own vertices from its points, so the halves keep their colours."""
    from recon.io import read_points

    pts = _sheet(2500)
    las = _las_sheet(pts)
    red = pts[:, 0] < 4.0
    las.red = np.where(red, 65535, 0).astype(np.uint16)
    las.green = np.zeros(len(pts), dtype=np.uint16)
    las.blue = np.where(red, 0, 65535).astype(np.uint16)
    src = tmp_path / "sheet.las"
    las.write(str(src))
    out = tmp_path / "m.ply"
    res = _run(["fit", str(src), "-o", str(out), "--tile-size", "4", "--jobs", "2", "-q"])
    assert res.exit_code == 0, res.output
    mesh = read_points(out)
    v, rgb = mesh.absolute_points(), np.rint(mesh.colors * 255)
    assert len(rgb) == len(read_mesh(out)[0])
    left, right = v[:, 0] < 3.5, v[:, 0] > 4.5
    assert left.sum() > 100 and right.sum() > 100
    assert np.all(rgb[left] == [255, 0, 0]) and np.all(rgb[right] == [0, 0, 255])
    assert np.all(rgb[:, 1] == 0)


def _las_two_halves(tmp_path, offset=(0.0, 0.0, 0.0)) -> Path:
    """A LAS sheet whose halves differ: x < 4 red, intensity 100, class 2; beyond blue,
    intensity 1000, class 6."""
    pts = _sheet(2500, offset)
    las = _las_sheet(pts, np.asarray(offset, dtype=np.float64))
    left = pts[:, 0] - offset[0] < 4.0
    las.red = np.where(left, 65535, 0).astype(np.uint16)
    las.green = np.zeros(len(pts), dtype=np.uint16)
    las.blue = np.where(left, 0, 65535).astype(np.uint16)
    las.intensity = np.where(left, 100, 1000).astype(np.uint16)
    las.classification = np.where(left, 2, 6).astype(np.uint8)
    src = tmp_path / "sheet.las"
    las.write(str(src))
    return src


def test_transfer_quality_and_preview_on_a_tiled_fit(tmp_path):
    """--transfer intensity,classification --quality --preview on a 2 x 2 tiled fit: every
    vertex gets its side's intensity and class, quality is the distance to the nearest input
    point in r0 (checked against the whole cloud), and the preview is a PNG."""
    from PIL import Image
    from plyfile import PlyData
    from scipy.spatial import cKDTree

    from recon.io import read_points

    src = _las_two_halves(tmp_path)
    out, png = tmp_path / "m.ply", tmp_path / "m.png"
    args = ["fit", str(src), "-o", str(out), "--tile-size", "4", "--jobs", "2", "-q"]
    args += ["--transfer", "intensity,classification", "--quality", "--preview", str(png)]
    res = _run(args)
    assert res.exit_code == 0, res.output
    v = PlyData.read(str(out))["vertex"]
    names = [p.name for p in v.properties]
    assert names[-6:] == ["red", "green", "blue", "intensity", "classification", "quality"]
    assert v["classification"].dtype == np.uint8 and v["quality"].dtype == np.float32
    xyz = np.column_stack([v["x"], v["y"], v["z"]]).astype(np.float64)
    assert len(xyz) == len(read_mesh(out)[0])
    left, right = xyz[:, 0] < 3.5, xyz[:, 0] > 4.5
    assert left.sum() > 100 and right.sum() > 100
    assert np.all(v["classification"][left] == 2) and np.all(v["classification"][right] == 6)
    assert np.allclose(v["intensity"][left], 100) and np.allclose(v["intensity"][right], 1000)
    assert set(np.unique(v["classification"])) == {2, 6}
    r0 = json.loads(out.with_suffix(".report.json").read_text())["spacing"]
    data = read_points(src).absolute_points()
    expected = cKDTree(data).query(xyz)[0] / r0
    assert np.allclose(np.asarray(v["quality"]), expected, rtol=1e-5, atol=1e-5)
    with Image.open(png) as im:
        assert im.format == "PNG" and im.size[0] >= 100
    report = json.loads(out.with_suffix(".report.json").read_text())
    assert report["output"]["preview"] == str(png)


def test_a_tiled_obj_gets_colours_when_asked(tmp_path):
    src = _las_two_halves(tmp_path)
    out = tmp_path / "m.obj"
    args = ["fit", str(src), "-o", str(out), "--tile-size", "4", "--jobs", "2", "-q"]
    res = _run([*args, "--obj-colors"])
    assert res.exit_code == 0, res.output
    rows = [ln.split() for ln in out.read_text().splitlines() if ln.startswith("v ")]
    assert rows and all(len(r) == 7 for r in rows)
    v = np.array([[float(x) for x in r[1:]] for r in rows])
    left, right = v[:, 0] < 3.5, v[:, 0] > 4.5
    assert np.allclose(v[left, 3:], [1, 0, 0]) and np.allclose(v[right, 3:], [0, 0, 1])


def test_a_tiled_las_fit_of_scan_lines_takes_the_spacing_across_them(tmp_path):
    """The tiles' spacing samples measure the gaps between scan lines as the untiled fit
    does (a LAS file is sampled tile by tile), and the note; r0 from the gap and the count
    before thinning in both (the untiled fit took the thinned count once: 0.045 against
    0.051)."""
    from tests.test_scale import scan_lines

    pts = scan_lines()
    src = tmp_path / "lines.las"
    _las_sheet(pts).write(str(src))
    untiled = _run(["fit", str(src), "-o", str(tmp_path / "a.ply"), "--json"])
    assert untiled.exit_code == 0, untiled.output
    tiled = _run(["fit", str(src), "-o", str(tmp_path / "b.ply"), "--tile-size", "2.5", "--json"])
    assert tiled.exit_code == 0, tiled.output
    a, b = json.loads(untiled.stdout), json.loads(tiled.stdout)
    assert b["tiles"]["count"] == 4
    assert b["spacing"] == pytest.approx(a["spacing"], rel=0.05)
    assert any("lines or clumps" in w for w in b["warnings"]), b["warnings"]
    v, f = read_mesh(tmp_path / "b.ply")
    assert mesh_topology(v, f)["boundary_loops"] == 1


def test_a_tiled_mesh_in_many_pieces_is_warned_of_as_an_untiled_one(tmp_path):
    """Six separate patches, some cut by the tiles: the streamed topology counts the largest
    component's faces, so a tiled fit gets the fragments warning's largest-share rule too
    (it was skipped: the streamed topology counted the components only; the patches are far
    above the debris size, so no other rule warns)."""
    from recon.fitting.mesh_warnings import largest_component_faces

    rng = np.random.default_rng(5)
    parts = []
    for x, y in [(0, 0), (4, 0), (8, 0), (0, 4), (4, 4), (8, 4)]:
        xy = rng.uniform(0, 2.5, (800, 2))
        z = 0.2 * np.sin(2.0 * xy[:, 0]) * np.cos(1.5 * xy[:, 1])
        parts.append(np.column_stack([xy[:, 0] + x, xy[:, 1] + y, z]))
    src, out = tmp_path / "six.ply", tmp_path / "mesh.ply"
    write_points(src, np.vstack(parts))
    res = _run(["fit", str(src), "-o", str(out), "--tile-size", "3", "--json", "-q"])
    assert res.exit_code == 0, res.output
    report = json.loads(res.stdout)
    assert report["tiles"]["count"] > 6 and report["topology"]["components"] == 6
    _, f = read_mesh(out)
    share = largest_component_faces(f) / len(f)
    assert share < 0.25
    pieces = [w for w in report["warnings"] if "falls apart into 6 components" in w]
    assert len(pieces) == 1, report["warnings"]
    assert f"the largest holding only {share:.0%} of the faces" in pieces[0]
    assert "average" not in pieces[0]  # not the debris rule
