"""The distribution: every package of the tree is shipped, under the one top-level name `recon`."""

from pathlib import Path

import pytest

tomllib = pytest.importorskip("tomllib")

ROOT = Path(__file__).resolve().parent.parent


def _setuptools_table() -> dict:
    with open(ROOT / "pyproject.toml", "rb") as fh:
        return tomllib.load(fh)["tool"]["setuptools"]


def _tree_packages() -> set[str]:
    """Dotted names of the folders holding modules or YAML files, with cli/ and configs/ mapped
    into `recon`. A data-only folder (configs/examples) must be listed too: setuptools warns
    about, and may one day drop, a folder it finds importable but not listed."""
    mapping = {"recon": "recon", "cli": "recon.cli", "configs": "recon.configs"}
    found = set()
    for top, dotted in mapping.items():
        for pattern in ("__init__.py", "*.yaml"):
            for path in (ROOT / top).rglob(pattern):
                rel = path.parent.relative_to(ROOT / top).parts
                found.add(".".join((dotted, *rel)))
    return found


def test_every_package_in_the_tree_is_listed_in_pyproject():
    listed = set(_setuptools_table()["packages"])
    assert listed == _tree_packages()


def test_only_recon_is_a_top_level_name():
    table = _setuptools_table()
    assert {name.split(".")[0] for name in table["packages"]} == {"recon"}
    assert table["package-dir"] == {
        "recon": "recon",
        "recon.cli": "cli",
        "recon.configs": "configs",
    }


def test_presets_ship_as_package_data():
    from recon.presets import available_presets, preset_path

    shipped = set(available_presets())
    in_tree = {p.stem for p in (ROOT / "configs").glob("*.yaml")}
    assert shipped == in_tree and {"open_scan", "closed_scan", "sparse", "noisy"} <= shipped
    assert preset_path("noisy").read_text().strip()
    package_data = _setuptools_table()["package-data"]
    assert "*.yaml" in package_data["recon.configs"]
    assert "*.yaml" in package_data["recon.configs.examples"]
