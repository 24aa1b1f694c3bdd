"""recon.config and ``oprecon config show|validate``: validation messages and precedence."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from click.testing import CliRunner
from recon.cli.main import app

from recon.config import (
    SECTIONS,
    NormalsConfig,
    ReconConfig,
    apply_overrides,
    config_from_dict,
    config_to_dict,
    dump_config,
    load_config,
    parse_override,
    with_values,
)
from recon.errors import ConfigError

ROOT = Path(__file__).resolve().parent.parent


def run(*args):
    return CliRunner().invoke(app, [str(a) for a in args])


def test_default_yaml_is_dump_config():
    text = (ROOT / "configs" / "default.yaml").read_text()
    assert text == dump_config(), (
        "configs/default.yaml is stale; regenerate it with: .venv/bin/python -c "
        "\"from recon.config import dump_config; open('configs/default.yaml','w')"
        '.write(dump_config())"'
    )
    assert load_config(ROOT / "configs" / "default.yaml") == ReconConfig()


def test_a_key_repeated_in_a_config_file_is_refused_with_its_line(tmp_path):
    """Regression: ``dt`` set twice in one section was accepted, the last value silently
    winning (`config validate` printed "valid")."""
    path = tmp_path / "dup.yaml"
    path.write_text("dynamics:\n  dt: 0.1\n  damping_linear: 1.0\n  dt: 0.2\n")
    with pytest.raises(ConfigError, match=r"dup\.yaml, line 4: dynamics\.dt: duplicate key"):
        load_config(path)
    r = run("config", "validate", path)
    assert r.exit_code == 2 and "line 4: dynamics.dt: duplicate key" in r.stderr, r.output
    # the same key in two sections is two keys
    path.write_text("seeds:\n  spacing_factor: 2.5\ndynamics:\n  dt: 0.1\n")
    load_config(path)


def test_dump_roundtrip_without_comments():
    data = yaml.safe_load(dump_config(comments=False))
    assert data == config_to_dict(ReconConfig())
    assert config_from_dict(data) == ReconConfig()
    assert set(SECTIONS) >= {"io", "normals", "seeds", "dynamics"}


def test_every_key_is_documented():
    text = dump_config()
    for section in SECTIONS:
        for key in config_to_dict(ReconConfig())[section]:
            line = next(ln for ln in text.splitlines() if ln.strip().startswith(f"{key}:"))
            assert "  # " in line, line


@pytest.mark.parametrize(
    "data,needle",
    [
        ({"normals": {"kk": 5}}, "unknown key 'normals.kk' (did you mean 'k'?)"),
        ({"normal": {"k": 5}}, "unknown key 'normal' (did you mean 'normals'?)"),
        ({"normals": {"k": "many"}}, "normals.k: expected an integer, got 'many'"),
        ({"io": {"ascii": "yes"}}, "io.ascii: expected true or false"),
        ({"normals": {"k": 1}}, "normals.k: 1 is out of range, allowed [3, 500]"),
        ({"normals": {"radius": 0}}, "normals.radius: 0.0 is out of range, allowed (0, inf)"),
        ({"normals": {"orientation": "outwards"}}, "did you mean 'outward'?"),
        ({"normals": {"viewpoint": [1, 2]}}, "normals.viewpoint: expected 3 numbers"),
        ({"normals": {"viewpoint": [1, 2, "z"]}}, "normals.viewpoint[2]: expected a number"),
        ({"growth": {"stretch_min": 3.0, "stretch_max": 2.5}}, "must not exceed"),
        ({"normals": 5}, "normals: expected a mapping"),
    ],
)
def test_validation_messages(data, needle):
    with pytest.raises(ConfigError) as e:
        config_from_dict(data)
    assert needle in str(e.value), str(e.value)


def test_int_to_float_and_null_section():
    cfg = config_from_dict({"normals": {"radius": 2}, "io": None})
    assert cfg.normals.radius == 2.0 and isinstance(cfg.normals.radius, float)
    assert cfg.io == ReconConfig().io


def test_overrides_and_with_values():
    cfg = apply_overrides(ReconConfig(), {"normals.k": 30})
    assert cfg.normals.k == 30
    assert parse_override("normals.viewpoint=[0, 0, 10]") == ("normals.viewpoint", [0, 0, 10])
    with pytest.raises(ConfigError, match="unknown key 'normals.kay'"):
        apply_overrides(cfg, {"normals.kay": 1})
    with pytest.raises(ConfigError, match="is a section"):
        apply_overrides(cfg, {"normals": 1})
    with pytest.raises(ConfigError, match="expected section.key=value"):
        parse_override("normals.k")
    same = with_values(cfg, normals={"k": None, "orientation": None})
    assert same is cfg
    changed = with_values(cfg, normals={"k": 7, "radius": None})
    assert changed.normals == NormalsConfig(k=7)


def test_precedence_set_over_file_over_defaults(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text("normals:\n  k: 40\n  orient_k: 12\n")
    cfg = load_config(path, ["normals.k=50"])
    assert (cfg.normals.k, cfg.normals.orient_k, cfg.normals.mode) == (50, 12, "auto")
    r = run("config", "show", "--config", path, "--set", "normals.k=50", "--no-comments")
    assert r.exit_code == 0, r.output
    shown = yaml.safe_load(r.stdout)
    assert shown["normals"]["k"] == 50 and shown["normals"]["orient_k"] == 12


def test_config_show_documents_keys():
    r = run("config", "show")
    assert r.exit_code == 0
    assert r.stdout == dump_config()
    assert "# Neighbours for the PCA normal estimate" in r.stdout


def test_config_validate(tmp_path):
    good = tmp_path / "good.yaml"
    good.write_text("normals:\n  k: 25\n")
    r = run("config", "validate", good)
    assert r.exit_code == 0 and "valid" in r.stdout
    bad = tmp_path / "bad.yaml"
    bad.write_text("normals:\n  kk: 25\n")
    r = run("config", "validate", bad)
    assert r.exit_code == 2
    assert str(bad) in r.stderr and "did you mean 'k'" in r.stderr
    assert "Traceback" not in r.output


@pytest.mark.parametrize(
    "text,needle",
    [
        ("normals:\n  k: [1\n", "invalid YAML at line"),
        ("normals:\n  k: 2\n", "out of range"),
        ("normals:\n  k: abc\n", "expected an integer"),
        ("- 1\n- 2\n", "expected a mapping"),
    ],
)
def test_config_validate_errors(tmp_path, text, needle):
    path = tmp_path / "c.yaml"
    path.write_text(text)
    r = run("config", "validate", path)
    assert r.exit_code == 2
    assert needle in r.stderr and str(path) in r.stderr, r.stderr


def test_config_missing_file_and_bad_set(tmp_path):
    r = run("config", "validate", tmp_path / "none.yaml")
    assert r.exit_code == 2 and "no such configuration file" in r.stderr
    r = run("config", "show", "--set", "normals.k=1")
    assert r.exit_code == 2 and "normals.k" in r.stderr
    r = run("config", "show", "--set", "normals.orientation=sideways")
    assert r.exit_code == 2 and "sideways" in r.stderr


def test_config_and_preset_are_exclusive(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text("{}\n")
    r = run("config", "show", "--config", path, "--preset", "default")
    assert r.exit_code == 2
    r = run("config", "show", "--preset", "no-such-preset")
    assert r.exit_code == 2 and "unknown preset 'no-such-preset'" in r.stderr


def test_sections_validate_however_they_are_built():
    from recon.config import DynamicsConfig, GrowthConfig

    with pytest.raises(ConfigError, match=r"dynamics\.dt: -1\.0 is out of range"):
        ReconConfig(dynamics=DynamicsConfig(dt=-1))
    with pytest.raises(ConfigError, match=r"growth\.stretch_min"):
        GrowthConfig(stretch_min=3.0, stretch_max=2.5)
    with pytest.raises(ConfigError, match=r"normals\.k: expected an integer"):
        NormalsConfig(k="many")
    with pytest.raises(ConfigError, match=r"^dynamics: expected a DynamicsConfig section"):
        ReconConfig(dynamics={"dt": 0.1})
    # the same coercion as the dict loader: an int where a float is expected becomes a float
    assert DynamicsConfig(dt=1).dt == 1.0 and isinstance(DynamicsConfig(dt=1).dt, float)
    # a nested prefix given to the dict loader names the full key
    from recon.schema import from_dict

    with pytest.raises(ConfigError, match=r"^config\.growth\.stretch_min"):
        from_dict(ReconConfig, {"growth": {"stretch_min": 3.0, "stretch_max": 2.5}}, "config.")


def test_a_float_key_accepts_exponent_notation_without_a_dot():
    # YAML 1.1 reads 1e-4 as a string; --set and config files must still take it as a number
    from recon.config import apply_overrides, parse_override

    cfg = apply_overrides(ReconConfig(), dict([parse_override("dynamics.kinetic_tolerance=1e-4")]))
    assert cfg.dynamics.kinetic_tolerance == 1e-4
    with pytest.raises(ConfigError, match="expected a number"):
        apply_overrides(ReconConfig(), dict([parse_override("dynamics.dt=fast")]))


@pytest.mark.parametrize("key", ["io.max_memory", "tiling.memory"])
def test_a_size_key_accepts_a_number_of_bytes(tmp_path, key):
    """Regression: a size given as a YAML number (``max_memory: 4000000000``, as the key's own
    documentation offers "a number of bytes") was refused with "expected a string"."""
    section, name = key.split(".")
    path = tmp_path / "c.yaml"
    path.write_text(f"{section}:\n  {name}: 4000000000\n")
    r = run("config", "validate", path)
    assert r.exit_code == 0, r.output
    cfg = load_config(path)
    assert getattr(getattr(cfg, section), name) == 4000000000
    assert load_config(None, [f"{key}=4000000000"]) == cfg
    assert load_config(None, [f"{key}=4.0e+9"]) == cfg  # a whole float is a whole number
    # config show prints it back as a number and reads back to the same configuration
    r = run("config", "show", "--config", path, "--no-comments")
    assert r.exit_code == 0, r.output
    assert yaml.safe_load(r.stdout)[section][name] == 4000000000
    assert config_from_dict(yaml.safe_load(dump_config(cfg))) == cfg
    # the string forms still work
    assert getattr(getattr(load_config(None, [f"{key}=8G"]), section), name) == "8G"


@pytest.mark.parametrize(
    "value,needle",
    [
        ("true", "expected a string or an integer, got True"),
        ("-5", "-5 must be a positive size"),
        ("0", "0 must be a positive size"),
        ("1.5", "expected a string or an integer, got 1.5"),
        ("[1, 2]", "expected a string or an integer, got [1, 2]"),
        ("lots", "'lots' is not a size"),
    ],
)
@pytest.mark.parametrize("key", ["io.max_memory", "tiling.memory"])
def test_a_size_key_refuses_what_is_not_a_size(tmp_path, key, value, needle):
    path = tmp_path / "c.yaml"
    section, name = key.split(".")
    path.write_text(f"{section}:\n  {name}: {value}\n")
    r = run("config", "validate", path)
    assert r.exit_code == 2
    assert r.stderr.count("\n") == 1 and "Traceback" not in r.output, r.output
    assert f"{path}: {key}: {needle}" in r.stderr, r.stderr
    with pytest.raises(ConfigError, match=f"^{key}: "):
        load_config(None, [f"{key}={value}"])
