"""Every preset in configs/ is a valid configuration that changes what it says it changes."""

from pathlib import Path

import pytest
from click.testing import CliRunner
from recon.cli.main import app

from recon.config import ReconConfig, load_config

CONFIGS = Path(__file__).resolve().parent.parent / "configs"
PRESETS = ["closed_scan", "open_scan", "sparse", "noisy"]


@pytest.mark.parametrize("name", PRESETS)
def test_preset_loads_and_differs_from_defaults(name):
    cfg = load_config(CONFIGS / f"{name}.yaml")
    assert cfg != ReconConfig()


def test_presets_pull_in_the_documented_direction():
    default = ReconConfig()
    closed = load_config(CONFIGS / "closed_scan.yaml")
    open_ = load_config(CONFIGS / "open_scan.yaml")
    sparse = load_config(CONFIGS / "sparse.yaml")
    noisy = load_config(CONFIGS / "noisy.yaml")
    assert closed.growth.max_gap > open_.growth.max_gap
    assert sparse.seeds.min_particles > default.seeds.min_particles
    assert noisy.normals.k > default.normals.k
    assert noisy.dynamics.fidelity < default.dynamics.fidelity


@pytest.mark.parametrize("name", PRESETS)
def test_config_show_preset(name):
    res = CliRunner().invoke(app, ["config", "show", "--preset", name])
    assert res.exit_code == 0, res.output
    assert "growth:" in res.output


def test_preset_and_set_precedence():
    res = CliRunner().invoke(
        app,
        ["config", "show", "--preset", "noisy", "--no-comments", "--set", "dynamics.fidelity=3"],
    )
    assert "fidelity: 3.0" in res.output
    assert "release_steps: 200" in res.output


def test_every_config_file_validates():
    for path in CONFIGS.glob("*.yaml"):
        if path.name.startswith("batch"):
            continue
        load_config(path)
