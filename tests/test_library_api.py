"""``recon.fit`` as a library user calls it: the same input checks as ``oprecon fit`` (the
io.* limits, duplicates), configs given as a mapping or a YAML path, clear errors for
arguments of the wrong kind, and the public names listed by ``dir(recon)``."""

from __future__ import annotations

import numpy as np
import pytest

import recon
from recon.errors import InputError
from recon.fitting import FitResult

FAST = {"seeds.min_particles": 0}


def _sphere(n: int = 800, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    p = rng.normal(size=(n, 3))
    return p / np.linalg.norm(p, axis=1, keepdims=True)


# -- 1. the io.* keys that `oprecon fit` honours ---------------------------------------------


def test_fit_keeps_repeated_points_without_io_merge_duplicates():
    """800 points and 200 of them again: merged by default, all 1000 kept when
    ``io.merge_duplicates`` is off (as `oprecon fit` does with the same file)."""
    p = _sphere()
    doubled = np.r_[p, p[:200]]
    kept = recon.fit(doubled, recon.load_config(overrides={**FAST, "io.merge_duplicates": False}))
    assert kept.report.input.points == 1000


def test_fit_merges_repeated_points_by_default():
    p = _sphere()
    merged = recon.fit(np.r_[p, p[:200]], recon.load_config(overrides=FAST))
    assert merged.report.input.points == 800


def test_fit_refuses_more_points_than_io_max_points():
    cfg = recon.load_config(overrides={"io.max_points": 100})
    with pytest.raises(InputError, match=r"800 points exceed the limit of 100 \(io.max_points\)"):
        recon.fit(_sphere(), cfg)


def test_fit_counts_the_rows_given_against_io_max_points_as_the_readers_do():
    """The readers count a file's rows (duplicates included) against the limit."""
    p = _sphere()
    cfg = recon.load_config(overrides={"io.max_points": 900})
    with pytest.raises(InputError, match="1000 points exceed the limit of 900"):
        recon.fit(np.r_[p, p[:200]], cfg)


def test_fit_refuses_a_fit_past_io_max_memory_before_fitting(monkeypatch):
    from recon.fitting import pipeline

    def never(*args, **kwargs):
        raise AssertionError("the fit started although io.max_memory refuses it")

    monkeypatch.setattr(pipeline, "_reconstruct", never)
    cfg = recon.load_config(overrides={"io.max_memory": "1MB"})
    with pytest.raises(InputError, match="max.memory"):
        recon.fit(_sphere(), cfg)


def test_fit_reports_the_memory_estimate_it_checked():
    cfg = recon.load_config(overrides={**FAST, "io.max_memory": "64GB"})
    res = recon.fit(_sphere(), cfg)
    mem = res.report.input.memory_estimate
    assert mem is not None and mem["points"] == 800 and mem["peak_bytes"] > 0


# -- 2. the arguments' kinds -----------------------------------------------------------------


def test_fit_takes_a_mapping_of_dotted_overrides_as_its_config():
    res = recon.fit(_sphere(), {"seeds.min_particles": 0, "seed": 7})
    assert isinstance(res, FitResult)
    assert res.report.config["seed"] == 7
    assert res.report.config["seeds"]["min_particles"] == 0


def test_fit_applies_a_mapping_before_reading_the_points():
    with pytest.raises(InputError, match="io.max_points"):
        recon.fit(_sphere(), {"io.max_points": 100})


def test_fit_reads_a_yaml_config_from_a_path(tmp_path):
    path = tmp_path / "small.yaml"
    path.write_text("io:\n  max_points: 100\n")
    for given in (path, str(path)):
        with pytest.raises(InputError, match="io.max_points"):
            recon.fit(_sphere(), given)


def test_fit_takes_a_list_of_key_value_strings_as_its_config():
    """As ``recon.load_config(overrides=...)`` and ``--set`` take them (a second read: the
    docstring said so, the check refused them)."""
    with pytest.raises(InputError, match="io.max_points"):
        recon.fit(_sphere(), ["io.max_points=100"])


@pytest.mark.parametrize("config", [5, [3], object()])
def test_fit_refuses_a_config_of_another_kind_naming_load_config(config):
    with pytest.raises(TypeError, match=r"recon\.load_config"):
        recon.fit(_sphere(), config)


def test_fit_refuses_a_progress_callback_that_cannot_be_called_before_any_work(monkeypatch):
    from recon.fitting import pipeline

    def never(*args, **kwargs):
        raise AssertionError("the fit started with an on_progress that cannot be called")

    monkeypatch.setattr(pipeline, "_reconstruct", never)
    with pytest.raises(TypeError, match="on_progress"):
        recon.fit(_sphere(), on_progress=5)


@pytest.mark.parametrize("normals", ["x", [["a", "b", "c"]], {"n": 1}])
def test_fit_refuses_normals_that_are_not_numbers_with_an_input_error(normals):
    with pytest.raises(InputError, match="normals"):
        recon.fit(_sphere(), normals=normals)


def test_fit_of_none_says_it_got_none():
    with pytest.raises(InputError, match="points.*got None"):
        recon.fit(None)


def test_fit_refuses_ragged_rows_with_an_input_error():
    with pytest.raises(InputError, match="points"):
        recon.fit([[0.0, 0.0, 1.0], [1.0, 0.0]])


def test_fit_refuses_complex_points():
    with pytest.raises(InputError, match="points.*complex"):
        recon.fit(_sphere() + 0j)


def test_fit_refuses_complex_normals():
    p = _sphere()
    with pytest.raises(InputError, match="normals.*complex"):
        recon.fit(p, normals=p + 1j)


def test_fit_documents_its_parameters_returns_and_errors():
    doc = recon.fit.__doc__ or ""
    for section in ("Parameters\n", "Returns\n", "Raises\n"):
        assert section in doc
    for name in ("points", "config", "normals", "on_progress", "InputError", "TypeError"):
        assert name in doc


# -- 4. the lazy public names ----------------------------------------------------------------


def test_dir_lists_the_public_names_of_the_package():
    names = dir(recon)
    for name in recon.__all__:
        assert name in names
    assert {"fit", "load_config"} <= set(names)
