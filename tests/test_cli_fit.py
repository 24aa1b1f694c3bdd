"""`oprecon fit` end to end through click's runner."""

import json
from pathlib import Path

import numpy as np
from click.testing import CliRunner
from recon.cli.main import app

from recon.io import read_mesh, read_points, write_points

FAST = ["--set", "seeds.min_particles=0"]


def _sphere_file(tmp_path: Path, n=800) -> Path:
    rng = np.random.default_rng(0)
    p = rng.normal(size=(n, 3))
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    path = tmp_path / "sphere.ply"
    write_points(path, p)
    return path


def _run(args):
    return CliRunner().invoke(app, args, catch_exceptions=False)


def test_fit_writes_mesh_report_particles_and_preview(tmp_path):
    src = _sphere_file(tmp_path)
    out = tmp_path / "mesh.ply"
    res = _run(
        [
            "fit",
            str(src),
            "-o",
            str(out),
            "--particles",
            str(tmp_path / "p.ply"),
            "--preview",
            str(tmp_path / "m.png"),
            *FAST,
        ]
    )
    assert res.exit_code == 0, res.output
    v, f = read_mesh(out)
    assert len(f) > 500 and np.isfinite(v).all()
    report = json.loads((tmp_path / "mesh.report.json").read_text())
    for key in (
        "spacing",
        "seeds",
        "particles",
        "steps",
        "time_s",
        "coverage",
        "fidelity",
        "topology",
        "triangle_quality",
        "history",
    ):
        assert key in report
    assert report["topology"]["watertight"] is True
    assert report["fidelity"]["mean_relative"] < 0.01
    assert len(read_points(tmp_path / "p.ply").points) == report["particles"]
    assert (tmp_path / "m.png").stat().st_size > 10_000
    assert "spacing r0" in res.stderr and "min angle" in res.stderr
    assert "largest hole" in res.stderr and "none (closed)" in res.stderr
    assert report["topology"]["largest_hole_r0"] == 0.0


def test_fit_obj_output_and_json_on_stdout(tmp_path):
    src = _sphere_file(tmp_path)
    out = tmp_path / "mesh.obj"
    res = _run(["fit", str(src), "-o", str(out), "--json", "--quiet", "--no-report", *FAST])
    assert res.exit_code == 0, res.output
    assert json.loads(res.stdout)["topology"]["components"] == 1
    assert not (tmp_path / "mesh.report.json").exists()
    assert out.read_text().startswith(("#", "v "))


def test_fit_is_byte_deterministic(tmp_path):
    src = _sphere_file(tmp_path)
    a, b = tmp_path / "a.ply", tmp_path / "b.ply"
    for out in (a, b):
        assert _run(["fit", str(src), "-o", str(out), "-q", "--seed", "3", *FAST]).exit_code == 0
    assert a.read_bytes() == b.read_bytes()


def test_cli_options_override_config_file(tmp_path):
    src = _sphere_file(tmp_path)
    cfg = tmp_path / "c.yaml"
    cfg.write_text("seeds:\n  spacing: 0.5\n")
    out = tmp_path / "m.ply"
    res = _run(
        ["fit", str(src), "-o", str(out), "-q", "--config", str(cfg), "--spacing", "0.2", *FAST]
    )
    assert res.exit_code == 0, res.output
    rep = json.loads((tmp_path / "m.report.json").read_text())
    assert rep["spacing"] == 0.2
    assert rep["config"]["seeds"]["spacing"] == 0.2


def test_cli_spacing_wins_over_the_other_spacing_form_of_a_config(tmp_path):
    """Regression: a config's seeds.spacing_relative plus --spacing on the command line was
    refused as "exclusive" instead of the command line winning (and the other way round)."""
    src = _sphere_file(tmp_path)
    cfg = tmp_path / "c.yaml"
    cfg.write_text("seeds:\n  spacing_relative: 0.05\n")
    out = tmp_path / "m.ply"
    args = ["fit", str(src), "-o", str(out), "-q", "--config", str(cfg), *FAST]
    res = _run([*args, "--spacing", "0.2"])
    assert res.exit_code == 0, res.output
    rep = json.loads((tmp_path / "m.report.json").read_text())
    assert rep["spacing"] == 0.2 and rep["config"]["seeds"]["spacing_relative"] is None
    cfg.write_text("seeds:\n  spacing: 0.5\n")
    res = _run([*args, "--spacing-relative", "0.05", "--no-report"])
    assert res.exit_code == 0, res.output
    # both forms on the command line are still a usage error
    res = _run([*args, "--spacing", "0.2", "--spacing-relative", "0.05"])
    assert res.exit_code == 2


def test_missing_input_exits_2_without_output(tmp_path):
    out = tmp_path / "m.ply"
    res = CliRunner().invoke(app, ["fit", str(tmp_path / "nope.ply"), "-o", str(out)])
    assert res.exit_code == 2
    assert "nope.ply" in res.stderr and "Traceback" not in res.output
    assert list(tmp_path.iterdir()) == []


def test_refuses_to_overwrite_the_input(tmp_path):
    src = _sphere_file(tmp_path)
    before = src.read_bytes()
    res = CliRunner().invoke(app, ["fit", str(src), "-o", str(src)])
    assert res.exit_code == 2
    assert src.read_bytes() == before


def test_bad_config_key_is_named(tmp_path):
    src = _sphere_file(tmp_path)
    res = CliRunner().invoke(
        app, ["fit", str(src), "-o", str(tmp_path / "m.ply"), "--set", "dynamics.dtt=0.1"]
    )
    assert res.exit_code == 2
    assert "dynamics.dtt" in res.stderr and "dt" in res.stderr


def test_unknown_preset_lists_the_available_ones(tmp_path):
    src = _sphere_file(tmp_path)
    res = CliRunner().invoke(
        app, ["fit", str(src), "-o", str(tmp_path / "m.ply"), "--preset", "nonsense"]
    )
    assert res.exit_code == 2
    assert "unknown preset" in res.stderr


def test_time_limit_fails_cleanly_without_output(tmp_path):
    src = _sphere_file(tmp_path)
    res = CliRunner().invoke(
        app, ["fit", str(src), "-o", str(tmp_path / "m.ply"), "--time-limit", "0.001", *FAST]
    )
    assert res.exit_code == 2
    assert "time limit" in res.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["sphere.ply"]


def test_help_teaches_with_examples():
    res = _run(["fit", "--help"])
    assert "Examples" in res.output and "--max-gap" in res.output


def _fit_stopped_before_it_starts(tmp_path, monkeypatch, uncached, *extra):
    """`oprecon fit` with the kernels' cache state faked and the fit itself replaced by an
    input error, so only what is said before the fit is exercised."""
    import recon.fitting
    from recon.errors import OpreconError
    from recon.kernels import warm

    def stop(*args, **kwargs):
        raise OpreconError("stopped before the fit")

    monkeypatch.setattr(warm, "uncached", lambda names=warm.FIT_KERNELS: list(uncached))
    monkeypatch.setattr(recon.fitting, "fit_file", stop)
    return _run(["fit", str(_sphere_file(tmp_path, n=50)), "-o", str(tmp_path / "m.ply"), *extra])


def test_a_first_run_says_it_compiles_the_kernels_first(tmp_path, monkeypatch):
    res = _fit_stopped_before_it_starts(tmp_path, monkeypatch, ["pair_loop.step_particles"])
    assert res.exit_code == 2 and "stopped before the fit" in res.stderr
    note = res.stderr.index("compiling the numba kernels first")
    assert note < res.stderr.index("stopped before the fit")


def test_no_compile_note_when_cached_or_quiet(tmp_path, monkeypatch):
    res = _fit_stopped_before_it_starts(tmp_path, monkeypatch, [])
    assert res.exit_code == 2 and "compiling" not in res.stderr
    res = _fit_stopped_before_it_starts(tmp_path, monkeypatch, ["pair_loop.step_particles"], "-q")
    assert res.exit_code == 2 and "compiling" not in res.stderr


def test_a_first_runs_summary_says_its_times_include_the_compile(tmp_path, monkeypatch):
    from recon.kernels import warm

    src = _sphere_file(tmp_path)
    for uncached, said in ((["pair_loop.step_particles"], True), ([], False)):
        monkeypatch.setattr(warm, "uncached", lambda names=(), u=uncached: list(u))
        res = _run(["fit", str(src), "-o", str(tmp_path / "m.ply"), *FAST])
        assert res.exit_code == 0, res.output
        lines = res.stderr.rstrip().splitlines()
        assert ("include compiling the numba kernels" in lines[-1]) is said
        assert "min angle" in res.stderr  # the summary itself


def test_the_summary_says_what_the_fit_did_with_the_creases():
    """Regression: the summary said "(detected; mesh unchanged)" whatever ``creases.fit``
    was; by default the mesh keeps the creases sharp."""
    from types import SimpleNamespace

    from recon.cli.fit import _crease_use

    from recon.fitting.report import CreaseStats

    found = CreaseStats(50.0, 7.9, 5.7, 10, 812, 40)
    none = CreaseStats(50.0, 0.0, 0.0, 0, 0, 0)
    on, off = {"creases": {"fit": True}}, {"creases": {"fit": False}}
    assert _crease_use(SimpleNamespace(creases=found, config=on)) == "kept sharp in the mesh"
    assert "creases.fit is off" in _crease_use(SimpleNamespace(creases=found, config=off))
    assert _crease_use(SimpleNamespace(creases=none, config=on)) == "none found"
