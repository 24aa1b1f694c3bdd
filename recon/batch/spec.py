"""The batch file: its YAML schema, and its validation into a :class:`BatchSpec`.

A batch file (YAML) names the inputs, where the meshes go and how they are configured::

    version: 1                  # optional; the batch-file format version (only 1)
    inputs:                     # required: paths and globs (``*``, ``?``, ``[ab]``, ``**``)
      - scans/*.ply
      - extra/bunny.xyz
    output_dir: meshes          # required; created when missing
    config: base.yaml           # optional base configuration file ...
    preset: open_scan           # ... or a named preset (not both)
    set:                        # optional overrides for every item (dotted or nested keys)
      dynamics.max_steps: 2000
      seeds: {thinning: 1.2}
    overrides:                  # optional per-item overrides, applied in order (later wins)
      - match: "*bunny*"        # a glob or a name, or a list of them
        set: {dynamics.dt: 0.1}
    formats: [ply, obj]         # optional mesh formats: ply (default) and/or obj
    particles: false            # optional: also write <name>.particles.ply
    preview: false              # optional: also write <name>.png
    item_time_limit: 3600       # optional per-item wall-clock limit [s] (CLI wins)

Relative paths (``inputs``, ``output_dir``, ``config``) resolve against the batch file's folder.
Precedence, highest first: ``--set`` on the command line > matching ``overrides`` (later entries
win) > global ``set`` > ``config``/``preset`` > defaults.

Each section of the file is a frozen dataclass (:class:`BatchFile`, :class:`OverrideEntry`)
whose fields name their reader in ``metadata``; :func:`read_section` builds one from a mapping.
Values are checked by the configuration's own :func:`recon.schema.coerce` and
:func:`recon.schema.check_range` where the batch file accepts what a configuration key would,
and ``set`` sections by :func:`recon.config.apply_overrides`, so errors read the same. Every
error names the batch file, the line and the dotted key (with the nearest valid key for an
unknown one).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, NamedTuple

import yaml

from ..config import (
    ReconConfig,
    apply_overrides,
    load_config,
    load_yaml_file,
    parse_override,
)
from ..errors import ConfigError, OpreconError, did_you_mean
from ..schema import check_range, coerce

__all__ = [
    "BATCH_VERSION",
    "MESH_FORMATS",
    "BatchFile",
    "BatchSpec",
    "Override",
    "OverrideEntry",
    "load_batch",
    "read_section",
]

BATCH_VERSION = 1
MESH_FORMATS = ("ply", "obj")

KeyPath = Sequence[str | int]


def key_text(path: KeyPath) -> str:
    """Dotted key of a path in the file: ``("overrides", 0, "set")`` -> ``overrides[0].set``."""
    out = ""
    for part in path:
        out += f"[{part}]" if isinstance(part, int) else (f".{part}" if out else str(part))
    return out


# --------------------------------------------------------------------------------------------
# where things are in the file


class _Marks:
    """Line numbers of keys and items in a composed YAML document."""

    def __init__(self, node: yaml.Node | None) -> None:
        self.root = node

    def line(self, path: KeyPath) -> int | None:
        """1-based line of the key (or list item) at ``path``; the nearest known ancestor's line
        when the path does not exist."""
        node = self.root
        line = None if node is None else node.start_mark.line + 1
        for part in path:
            if isinstance(node, yaml.MappingNode):
                found = None
                for key_node, value_node in node.value:
                    if isinstance(key_node, yaml.ScalarNode) and key_node.value == str(part):
                        found = (key_node, value_node)
                if found is None:
                    return line
                line = found[0].start_mark.line + 1
                node = found[1]
            elif isinstance(node, yaml.SequenceNode) and isinstance(part, int):
                if not 0 <= part < len(node.value):
                    return line
                node = node.value[part]
                line = node.start_mark.line + 1
            else:
                return line
        return line


class Located:
    """Errors that name the batch file, the line of a key and its dotted path."""

    def __init__(self, path: Path, marks: _Marks) -> None:
        self.path = path
        self.marks = marks

    def line(self, key: KeyPath) -> int | None:
        """Line of ``key`` in the file (see :meth:`_Marks.line`)."""
        return self.marks.line(key)

    def where(self, key: KeyPath) -> str:
        """``<file>, line <n>`` of ``key`` (just the file for the whole document)."""
        line = self.marks.line(key) if key else None
        return f"{self.path}, line {line}" if line is not None else f"{self.path}"

    def error(self, key: KeyPath, message: str) -> ConfigError:
        """``<file>, line <n>: <dotted key>: <message>``."""
        text = key_text(key)
        where = self.where(key)
        return ConfigError(f"{where}: {text}: {message}" if text else f"{where}: {message}")

    def located(self, key: KeyPath, exc: ConfigError) -> ConfigError:
        """A configuration error (whose message starts with its dotted key) placed at ``key``."""
        return ConfigError(f"{self.where(key)}: {exc}")


# --------------------------------------------------------------------------------------------
# readers: (located, value, key path) -> parsed value

Reader = Callable[[Located, Any, KeyPath], Any]


class Setting(NamedTuple):
    """One flattened key of a ``set`` mapping and where it was written."""

    value: Any
    key: tuple[str | int, ...]


def read_mapping(at: Located, data: Any, key: KeyPath, known: Sequence[str] | None) -> dict:
    """A mapping with string keys, all in ``known`` (when given)."""
    if not isinstance(data, dict):
        raise at.error(key, f"expected a mapping of keys to values, got {data!r}")
    for k in data:
        if not isinstance(k, str):
            raise at.error(key, f"keys must be strings, got {k!r}")
        if known is not None and k not in known:
            raise at.error(
                [*key, k], f"unknown key{did_you_mean(k, known)}; valid keys: " + ", ".join(known)
            )
    return data


def read_string(at: Located, data: Any, key: KeyPath) -> str:
    """A non-empty string."""
    if not isinstance(data, str) or not data.strip():
        raise at.error(key, f"expected a non-empty string, got {data!r}")
    return data


def read_optional_string(at: Located, data: Any, key: KeyPath) -> str | None:
    """A non-empty string, or null."""
    return None if data is None else read_string(at, data, key)


def read_strings(at: Located, data: Any, key: KeyPath) -> tuple[str, ...]:
    """A non-empty string or a non-empty list of them."""
    if isinstance(data, str):
        return (read_string(at, data, key),)
    if not isinstance(data, list) or not data:
        raise at.error(key, f"expected a string or a non-empty list of strings, got {data!r}")
    return tuple(read_string(at, v, [*key, i]) for i, v in enumerate(data))


def read_boolean(at: Located, data: Any, key: KeyPath) -> bool:
    """true or false, checked like a configuration key."""
    try:
        return coerce(key_text(key), data, bool)
    except ConfigError as exc:
        raise at.located(key, exc) from None


def read_settings(at: Located, data: Any, key: KeyPath) -> dict[str, Setting]:
    """A ``set`` mapping (dotted or nested keys) flattened to ``{dotted key: Setting}``."""
    read_mapping(at, data, key, None)
    out: dict[str, Setting] = {}

    def walk(node: dict, prefix: str, node_key: tuple) -> None:
        for k, v in node.items():
            if not isinstance(k, str) or not k:
                raise at.error(node_key, f"keys must be non-empty strings, got {k!r}")
            k_key = (*node_key, k)
            if isinstance(v, dict) and v:
                walk(v, f"{prefix}{k}.", k_key)
            elif prefix + k in out:  # nested and dotted (``seeds: {thinning: 1}``, then
                # ``seeds.thinning: 2``): YAML sees two keys, the configuration one
                raise at.error(k_key, f"{prefix + k} is set twice (nested and dotted)")
            else:
                out[prefix + k] = Setting(v, k_key)

    walk(data, "", tuple(key))
    return out


def read_optional_settings(at: Located, data: Any, key: KeyPath) -> dict[str, Setting] | None:
    """A ``set`` mapping (see :func:`read_settings`), or null."""
    return None if data is None else read_settings(at, data, key)


def read_formats(at: Located, data: Any, key: KeyPath) -> tuple[str, ...]:
    """Mesh formats, lower case without a dot, each once."""
    formats: list[str] = []
    for i, fmt in enumerate(read_strings(at, data, key)):
        f = fmt.lower().lstrip(".")
        try:
            check_range(key_text([*key, i]), f, {"choices": MESH_FORMATS})
        except ConfigError as exc:
            raise at.located([*key, i], exc) from None
        if f not in formats:
            formats.append(f)
    return tuple(formats)


def read_seconds(at: Located, data: Any, key: KeyPath) -> float | None:
    """A positive number of seconds (infinity: no limit), or null."""
    if data is None:
        return None
    if isinstance(data, bool) or not isinstance(data, (int, float)) or not data > 0:
        raise at.error(key, f"expected a positive number of seconds, got {data!r}")
    return float(data)


def read_version(at: Located, data: Any, key: KeyPath) -> int:
    """The batch-file format version: only :data:`BATCH_VERSION`."""
    if isinstance(data, bool) or data != BATCH_VERSION:
        raise at.error(
            key,
            f"unsupported batch-file version {data!r} (this oprecon reads version {BATCH_VERSION})",
        )
    return BATCH_VERSION


def read_overrides(at: Located, data: Any, key: KeyPath) -> tuple[OverrideEntry, ...]:
    """The list of ``{match, set}`` entries (null or empty: none)."""
    if not data:
        return ()
    if not isinstance(data, list):
        raise at.error(key, f"expected a list of {{match, set}} entries, got {data!r}")
    return tuple(read_section(OverrideEntry, at, e, [*key, i]) for i, e in enumerate(data))


def _key(doc: str, read: Reader, default: Any = None, *, required: bool = False) -> Any:
    """A section field: its documentation and its reader (``required`` fields have no default)."""
    meta = {"doc": doc, "read": read, "required": required}
    if required:
        return field(metadata=meta)
    return field(default=default, metadata=meta)


def read_section(cls: type, at: Located, data: Any, key: KeyPath) -> Any:
    """Build the section dataclass ``cls`` from ``data`` found at ``key`` in the file.

    Parameters
    ----------
    cls : dataclass type
        Its fields carry ``doc``, ``read`` (a reader) and ``required`` in ``metadata``.
    at : Located
    data : Any
        The section as parsed from YAML.
    key : sequence of str or int
        Where the section is in the file (empty for the whole document).

    Returns
    -------
    cls
        Keys missing from ``data`` take the field defaults.

    Raises
    ------
    ConfigError
        Not a mapping, an unknown key (with the nearest valid key), a missing required key, or
        an invalid value; located at the line of the offending key.
    """
    specs = fields(cls)
    read_mapping(at, data, key, [f.name for f in specs])
    for f in specs:
        if f.metadata["required"] and f.name not in data:
            raise at.error(key, f"missing required key '{f.name}'")
    values = {
        f.name: f.metadata["read"](at, data[f.name], [*key, f.name])
        for f in specs
        if f.name in data
    }
    return cls(**values)


# --------------------------------------------------------------------------------------------
# the sections


@dataclass(frozen=True, kw_only=True)
class OverrideEntry:
    """One entry of ``overrides`` as written."""

    match: tuple[str, ...] = _key(
        "Globs or names compared with each input.", read_strings, required=True
    )
    set: dict[str, Setting] = _key(
        "Dotted keys set for the inputs it matches.", read_settings, required=True
    )


@dataclass(frozen=True, kw_only=True)
class BatchFile:
    """A batch file as written (paths unresolved, ``set`` sections not yet applied)."""

    version: int = _key("Batch-file format version.", read_version, BATCH_VERSION)
    inputs: tuple[str, ...] = _key("Paths and globs of the inputs.", read_strings, required=True)
    output_dir: str = _key("Folder the outputs go to.", read_string, required=True)
    config: str | None = _key("Base configuration file.", read_optional_string)
    preset: str | None = _key("Named preset (instead of config).", read_optional_string)
    set: dict[str, Setting] | None = _key("Overrides for every item.", read_optional_settings)
    overrides: tuple[OverrideEntry, ...] = _key("Per-item overrides.", read_overrides, ())
    formats: tuple[str, ...] = _key("Mesh formats: ply and/or obj.", read_formats, ("ply",))
    particles: bool = _key("Also write <name>.particles.ply.", read_boolean, False)
    preview: bool = _key("Also write <name>.png.", read_boolean, False)
    item_time_limit: float | None = _key("Per-item wall-clock limit [s].", read_seconds)


# --------------------------------------------------------------------------------------------
# the validated batch


@dataclass(frozen=True)
class Override:
    """One entry of ``overrides``: the patterns it matches and the dotted keys it sets."""

    index: int
    patterns: tuple[str, ...]
    values: Mapping[str, Any]
    line: int | None = None


@dataclass(frozen=True)
class BatchSpec:
    """A validated batch file.

    Attributes
    ----------
    path : Path
        The batch file (absolute).
    inputs : tuple of str
        Entries of ``inputs`` as written (paths and globs).
    output_dir : Path
        Absolute output folder.
    base_config : ReconConfig
        Defaults < ``config``/``preset`` < global ``set``.
    overrides : tuple of Override
        Per-item overrides in file order.
    cli_overrides : mapping
        Dotted keys from the command line (``--set``), applied last.
    formats : tuple of str
        Mesh formats, ``"ply"`` and/or ``"obj"``.
    particles, preview : bool
        Also write the particles (PLY) and a PNG preview.
    item_time_limit : float or None [s]
        From the batch file; None when the file does not set it.
    """

    path: Path
    inputs: tuple[str, ...]
    output_dir: Path
    base_config: ReconConfig
    overrides: tuple[Override, ...] = ()
    cli_overrides: Mapping[str, Any] = field(default_factory=dict)
    formats: tuple[str, ...] = ("ply",)
    particles: bool = False
    preview: bool = False
    item_time_limit: float | None = None

    @property
    def folder(self) -> Path:
        """The folder relative paths resolve against."""
        return self.path.parent


def _apply(
    at: Located, cfg: ReconConfig, settings: Mapping[str, Setting], key: KeyPath
) -> ReconConfig:
    """Apply flattened settings key by key (so that errors name the key and its line)."""
    for dotted, setting in settings.items():
        try:
            apply_overrides(cfg, {dotted: setting.value})
        except ConfigError as exc:
            raise at.error(setting.key, str(exc)) from None
    try:
        return apply_overrides(cfg, {k: s.value for k, s in settings.items()})
    except ConfigError as exc:
        raise at.error(key, str(exc)) from None


def _base_config(
    at: Located, raw: dict, doc: BatchFile, resolve_preset: Callable[[str], Path] | None
) -> ReconConfig:
    """Defaults < ``config`` or ``preset`` < global ``set``."""
    if "config" in raw and "preset" in raw:
        raise at.error(["preset"], "'config' and 'preset' are exclusive; give one")
    base_path: Path | None = None
    if doc.config is not None:
        base_path = Path(doc.config).expanduser()
        if not base_path.is_absolute():
            base_path = at.path.parent / base_path
    elif doc.preset is not None:
        if resolve_preset is None:
            raise at.error(["preset"], "presets cannot be resolved here; use 'config: file.yaml'")
        try:
            base_path = resolve_preset(doc.preset)
        except OpreconError as exc:
            raise at.error(["preset"], str(exc)) from None
    try:
        cfg = load_config(base_path)
    except ConfigError as exc:
        raise at.error(["config" if "config" in raw else "preset"], str(exc)) from None
    if doc.set is not None:
        cfg = _apply(at, cfg, doc.set, ["set"])
    return cfg


def load_batch(
    path: str | os.PathLike[str],
    *,
    resolve_preset: Callable[[str], Path] | None = None,
    cli_overrides: Sequence[str] | Mapping[str, Any] = (),
) -> BatchSpec:
    """Read and validate a batch file.

    Parameters
    ----------
    path : path-like
        The YAML batch file (schema in the module docstring).
    resolve_preset : callable(str) -> Path, optional
        Maps a ``preset`` name to its YAML file (the CLI passes
        :func:`cli.common.resolve_preset`). Required when the file names a preset.
    cli_overrides : sequence of ``"key=value"`` or mapping
        Command-line ``--set`` overrides, applied to every item last.

    Returns
    -------
    BatchSpec

    Raises
    ------
    ConfigError
        Unreadable or invalid file; the message names the file, the line and the dotted key
        (with the nearest valid key for unknown keys).
    """
    p = Path(os.path.abspath(Path(path).expanduser()))
    raw = load_yaml_file(p)
    try:
        marks = _Marks(yaml.compose(p.read_text(encoding="utf-8"), Loader=yaml.SafeLoader))
    except yaml.YAMLError:  # pragma: no cover - load_yaml_file has parsed it already
        marks = _Marks(None)
    at = Located(p, marks)
    if raw is None:
        raise ConfigError(
            f"{p}: the batch file is empty; it needs at least 'inputs' and 'output_dir'"
        )
    doc: BatchFile = read_section(BatchFile, at, raw, [])

    output_dir = Path(doc.output_dir).expanduser()
    if not output_dir.is_absolute():
        output_dir = p.parent / output_dir
    output_dir = Path(os.path.abspath(output_dir))
    if output_dir.exists() and not output_dir.is_dir():
        raise at.error(["output_dir"], f"'{output_dir}' exists and is not a folder")

    cfg = _base_config(at, raw, doc, resolve_preset)
    overrides: list[Override] = []
    for i, entry in enumerate(doc.overrides):
        key = ["overrides", i]
        _apply(at, cfg, entry.set, [*key, "set"])
        patterns = tuple(s.removeprefix("./") for s in entry.match)
        values = {k: s.value for k, s in entry.set.items()}
        overrides.append(Override(i, patterns, values, at.line(key)))

    if isinstance(cli_overrides, Mapping):
        cli = dict(cli_overrides)
    else:
        cli = dict(parse_override(t) for t in cli_overrides)
    for k, value in cli.items():
        try:
            apply_overrides(cfg, {k: value})
        except ConfigError as exc:
            raise ConfigError(f"--set {k}={value!r}: {exc}") from None

    return BatchSpec(
        p,
        doc.inputs,
        output_dir,
        cfg,
        tuple(overrides),
        cli,
        doc.formats,
        doc.particles,
        doc.preview,
        doc.item_time_limit,
    )
