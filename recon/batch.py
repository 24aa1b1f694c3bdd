"""Batch runs: many point clouds, one configuration, one summary; one failure doesn't stop the rest.

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
Globs list only files, sorted, and skip files inside ``output_dir``; an explicit path that does
not exist, or a glob that matches nothing, becomes a *failed* item (the others still run).

``match`` patterns are compared (``fnmatch``, case-sensitive) with the input's file name, its
stem, its output name and its path (relative to the batch file's folder, and absolute); an item
takes every override that matches. Precedence, highest first: ``--set`` on the command line >
matching ``overrides`` (later entries win) > global ``set`` > ``config``/``preset`` > defaults.
The per-item time limit is ``min(item_time_limit, dynamics.time_limit)``.

Outputs, per item, in ``output_dir``: ``<name>.<fmt>`` for each format, ``<name>.report.json``
(always written: the summary and resume need it), ``<name>.particles.ply`` and ``<name>.png`` when
asked for, and ``<name>.batch.json``, the record used to resume. ``<name>`` is the input's stem;
inputs sharing a stem get their parent folders' names prepended (``a_scan``, ``b_scan``) until
the names differ, then the extension (``scan_ply``), then a counter. ``batch_summary.json`` and
``batch_summary.csv`` list every item with its status: ``ok``, ``failed``, ``timeout``,
``skipped`` (up to date) or ``interrupted`` (unfinished at Ctrl-C).

Resume: an item is skipped when its outputs and ``<name>.batch.json`` exist and the record
matches the item's fingerprint: a hash of the resolved configuration (without
``dynamics.time_limit``), the input file's path, size and modification time, and the oprecon
version. ``force=True`` runs every item.

Execution: every item runs in its own child process (``python -c``), watched by a supervisor that
enforces the time limit twice: cooperatively through ``dynamics.time_limit``, and by killing the
child when it overruns the limit by a grace period. A killed child's temporary files (``.<file>.
<pid>-<hex>.tmp<suffix>``, see :func:`recon.io.atomic_output`) are removed. The supervisors are
threads of this process (executor ``"local"``) or tasks on a Dask cluster (``"dask"``); the same
:func:`supervise_item` runs in both, so results, summary and resume behave the same.

References
----------
[Dask] Dask distributed documentation, "Futures" and "LocalCluster".
       https://distributed.dask.org/
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import difflib
import fnmatch
import glob
import hashlib
import io as _io
import json
import logging
import os
import pickle
import queue
import signal
import struct
import subprocess
import sys
import tempfile
import threading
import time
import traceback
import uuid
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from concurrent.futures import FIRST_COMPLETED, ThreadPoolExecutor, wait
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import yaml

from . import __version__
from .config import (
    ReconConfig,
    apply_overrides,
    config_from_dict,
    config_to_dict,
    load_config,
    load_yaml_file,
    parse_override,
)
from .errors import ConfigError, LimitExceeded, OpreconError
from .interrupts import deferred_interrupts

log = logging.getLogger(__name__)

__all__ = [
    "BATCH_VERSION",
    "DEFAULT_ITEM_TIME_LIMIT",
    "STATUSES",
    "BatchEvent",
    "BatchItem",
    "BatchPlan",
    "BatchReport",
    "BatchSpec",
    "ItemResult",
    "assign_names",
    "load_batch",
    "plan_batch",
    "run_batch",
    "run_item",
    "supervise_item",
    "write_summary",
]

BATCH_VERSION = 1
MESH_FORMATS = ("ply", "obj")
#: Per-item wall-clock limit [s] when neither the command line nor the batch file sets one.
DEFAULT_ITEM_TIME_LIMIT = 3600.0
STATUS_OK = "ok"
STATUS_FAILED = "failed"
STATUS_TIMEOUT = "timeout"
STATUS_SKIPPED = "skipped"
STATUS_INTERRUPTED = "interrupted"
STATUSES = (STATUS_OK, STATUS_FAILED, STATUS_TIMEOUT, STATUS_SKIPPED, STATUS_INTERRUPTED)
SUMMARY_JSON = "batch_summary.json"
SUMMARY_CSV = "batch_summary.csv"
STATE_SUFFIX = ".batch.json"
DASK_MISSING = 'the dask executor needs the optional dependency: pip install "oprecon[distributed]"'

#: Time for a child process to import the pipeline and report that it started [s].
_STARTUP_TIMEOUT = 600.0
#: After a stop request, time a child gets to clean up before it is killed [s].
_STOP_GRACE = 5.0
#: A child whose stdin closed (stop request, or its parent died) exits after this at the latest [s].
_ORPHAN_EXIT = 15.0
_POLL = 0.2
_TOP_KEYS = (
    "version",
    "inputs",
    "output_dir",
    "config",
    "preset",
    "set",
    "overrides",
    "formats",
    "particles",
    "preview",
    "item_time_limit",
)
_OVERRIDE_KEYS = ("match", "set")
_DEFAULT_JOB = "recon.batch:run_item"
_SUMMARY_COLUMNS = (
    "name",
    "input",
    "status",
    "time_s",
    "particles",
    "faces",
    "coverage",
    "fidelity_mean",
    "error",
    "outputs",
)


def kill_grace_for(limit: float) -> float:
    """Grace period [s] past a time limit of ``limit`` seconds before the child is killed.

    Parameters
    ----------
    limit : float [s]

    Returns
    -------
    float [s]
        10 % of the limit, at least 5 s and at most 120 s.
    """
    return min(120.0, max(5.0, 0.1 * limit))


# --------------------------------------------------------------------------------------------
# the batch file


def _suggest(name: str, valid: Iterable[str]) -> str:
    close = difflib.get_close_matches(name, list(valid), n=1, cutoff=0.5)
    return f" (did you mean '{close[0]}'?)" if close else ""


def _key_text(path: Sequence[str | int]) -> str:
    out = ""
    for part in path:
        out += f"[{part}]" if isinstance(part, int) else (f".{part}" if out else str(part))
    return out


class _Marks:
    """Line numbers of keys and items in a composed YAML document."""

    def __init__(self, node: yaml.Node | None) -> None:
        self.root = node

    def line(self, path: Sequence[str | int]) -> int | None:
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

    def duplicates(self) -> list[tuple[str, int]]:
        """Keys repeated within one mapping: ``(dotted key, line)`` of each repetition."""
        out: list[tuple[str, int]] = []

        def walk(node: yaml.Node, prefix: str) -> None:
            if isinstance(node, yaml.MappingNode):
                seen: set[str] = set()
                for key_node, value_node in node.value:
                    key = str(key_node.value) if isinstance(key_node, yaml.ScalarNode) else "?"
                    if key in seen:
                        out.append((prefix + key, key_node.start_mark.line + 1))
                    seen.add(key)
                    walk(value_node, f"{prefix}{key}.")
            elif isinstance(node, yaml.SequenceNode):
                for i, item in enumerate(node.value):
                    walk(item, f"{prefix.rstrip('.')}[{i}].")

        if self.root is not None:
            walk(self.root, "")
        return out


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


class _Checker:
    """Error messages that name the batch file, the line and the dotted key."""

    def __init__(self, path: Path, marks: _Marks) -> None:
        self.path = path
        self.marks = marks

    def error(self, path: Sequence[str | int], message: str) -> ConfigError:
        line = self.marks.line(path) if path else None
        where = f"{self.path}, line {line}" if line is not None else f"{self.path}"
        key = _key_text(path)
        return ConfigError(f"{where}: {key}: {message}" if key else f"{where}: {message}")

    def string(self, data: Any, path: Sequence[str | int]) -> str:
        if not isinstance(data, str) or not data.strip():
            raise self.error(path, f"expected a non-empty string, got {data!r}")
        return data

    def strings(self, data: Any, path: Sequence[str | int]) -> tuple[str, ...]:
        if isinstance(data, str):
            return (self.string(data, path),)
        if not isinstance(data, list) or not data:
            raise self.error(
                path, f"expected a string or a non-empty list of strings, got {data!r}"
            )
        return tuple(self.string(v, [*path, i]) for i, v in enumerate(data))

    def boolean(self, data: Any, path: Sequence[str | int]) -> bool:
        if not isinstance(data, bool):
            raise self.error(path, f"expected true or false, got {data!r}")
        return data

    def mapping(self, data: Any, path: Sequence[str | int], known: Sequence[str] | None) -> dict:
        if not isinstance(data, dict):
            raise self.error(path, f"expected a mapping of keys to values, got {data!r}")
        for k in data:
            if not isinstance(k, str):
                raise self.error(path, f"keys must be strings, got {k!r}")
            if known is not None and k not in known:
                raise self.error(
                    [*path, k], f"unknown key{_suggest(k, known)}; valid keys: " + ", ".join(known)
                )
        return data

    def settings(self, data: Any, path: Sequence[str | int]) -> dict[str, tuple[Any, tuple]]:
        """Flatten a ``set`` mapping (dotted or nested keys) to ``{dotted: (value, path)}``."""
        self.mapping(data, path, None)
        out: dict[str, tuple[Any, tuple]] = {}

        def walk(node: dict, prefix: str, node_path: tuple) -> None:
            for k, v in node.items():
                if not isinstance(k, str) or not k:
                    raise self.error(node_path, f"keys must be non-empty strings, got {k!r}")
                key_path = (*node_path, k)
                if isinstance(v, dict) and v:
                    walk(v, f"{prefix}{k}.", key_path)
                else:
                    out[prefix + k] = (v, key_path)

        walk(data, "", tuple(path))
        return out

    def apply(
        self, cfg: ReconConfig, settings: Mapping[str, tuple[Any, tuple]], path: Sequence[str | int]
    ) -> ReconConfig:
        """Apply flattened settings key by key (so that errors name the key and its line)."""
        for dotted, (value, key_path) in settings.items():
            try:
                apply_overrides(cfg, {dotted: value})
            except ConfigError as exc:
                raise self.error(key_path, str(exc)) from None
        try:
            return apply_overrides(cfg, {k: v for k, (v, _) in settings.items()})
        except ConfigError as exc:
            raise self.error(path, str(exc)) from None


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
    data = load_yaml_file(p)
    try:
        marks = _Marks(yaml.compose(p.read_text(encoding="utf-8"), Loader=yaml.SafeLoader))
    except yaml.YAMLError:  # pragma: no cover - load_yaml_file has parsed it already
        marks = _Marks(None)
    chk = _Checker(p, marks)
    duplicates = marks.duplicates()
    if duplicates:
        dotted, line = duplicates[0]
        raise ConfigError(f"{p}, line {line}: {dotted}: duplicate key")
    if data is None:
        raise ConfigError(
            f"{p}: the batch file is empty; it needs at least 'inputs' and 'output_dir'"
        )
    chk.mapping(data, [], _TOP_KEYS)
    for key in ("inputs", "output_dir"):
        if key not in data:
            raise chk.error([], f"missing required key '{key}'")

    version = data.get("version", BATCH_VERSION)
    if isinstance(version, bool) or version != BATCH_VERSION:
        raise chk.error(
            ["version"],
            f"unsupported batch-file version {version!r} "
            f"(this oprecon reads version {BATCH_VERSION})",
        )
    inputs = chk.strings(data["inputs"], ["inputs"])
    output_dir = Path(chk.string(data["output_dir"], ["output_dir"])).expanduser()
    if not output_dir.is_absolute():
        output_dir = p.parent / output_dir
    output_dir = Path(os.path.abspath(output_dir))
    if output_dir.exists() and not output_dir.is_dir():
        raise chk.error(["output_dir"], f"'{output_dir}' exists and is not a folder")

    if "config" in data and "preset" in data:
        raise chk.error(["preset"], "'config' and 'preset' are exclusive; give one")
    base_path: Path | None = None
    if data.get("config") is not None:
        base_path = Path(chk.string(data["config"], ["config"])).expanduser()
        if not base_path.is_absolute():
            base_path = p.parent / base_path
    elif data.get("preset") is not None:
        name = chk.string(data["preset"], ["preset"])
        if resolve_preset is None:
            raise chk.error(["preset"], "presets cannot be resolved here; use 'config: file.yaml'")
        try:
            base_path = resolve_preset(name)
        except OpreconError as exc:
            raise chk.error(["preset"], str(exc)) from None
    try:
        cfg = load_config(base_path)
    except ConfigError as exc:
        raise chk.error(["config" if "config" in data else "preset"], str(exc)) from None

    if data.get("set") is not None:
        cfg = chk.apply(cfg, chk.settings(data["set"], ["set"]), ["set"])

    overrides: list[Override] = []
    raw_overrides = data.get("overrides") or []
    if not isinstance(raw_overrides, list):
        raise chk.error(
            ["overrides"], f"expected a list of {{match, set}} entries, got {raw_overrides!r}"
        )
    for i, entry in enumerate(raw_overrides):
        where = ["overrides", i]
        chk.mapping(entry, where, _OVERRIDE_KEYS)
        for key in _OVERRIDE_KEYS:
            if key not in entry:
                raise chk.error(where, f"missing required key '{key}'")
        patterns = tuple(
            s.removeprefix("./") for s in chk.strings(entry["match"], [*where, "match"])
        )
        settings = chk.settings(entry["set"], [*where, "set"])
        chk.apply(cfg, settings, [*where, "set"])
        overrides.append(
            Override(i, patterns, {k: v for k, (v, _) in settings.items()}, marks.line(where))
        )

    formats_raw = chk.strings(data.get("formats", ["ply"]), ["formats"])
    formats: list[str] = []
    for i, fmt in enumerate(formats_raw):
        f = fmt.lower().lstrip(".")
        if f not in MESH_FORMATS:
            raise chk.error(
                ["formats", i],
                f"'{fmt}' is not one of: {', '.join(MESH_FORMATS)}{_suggest(f, MESH_FORMATS)}",
            )
        if f not in formats:
            formats.append(f)

    particles = chk.boolean(data.get("particles", False), ["particles"])
    preview = chk.boolean(data.get("preview", False), ["preview"])
    limit = data.get("item_time_limit")
    if limit is not None and (
        isinstance(limit, bool)
        or not isinstance(limit, (int, float))
        or not limit > 0
        or limit != limit
    ):
        raise chk.error(
            ["item_time_limit"], f"expected a positive number of seconds, got {limit!r}"
        )

    if isinstance(cli_overrides, Mapping):
        cli = dict(cli_overrides)
    else:
        cli = dict(parse_override(t) for t in cli_overrides)
    for key, value in cli.items():
        try:
            apply_overrides(cfg, {key: value})
        except ConfigError as exc:
            raise ConfigError(f"--set {key}={value!r}: {exc}") from None

    return BatchSpec(
        p,
        inputs,
        output_dir,
        cfg,
        tuple(overrides),
        cli,
        tuple(formats),
        particles,
        preview,
        None if limit is None else float(limit),
    )


# --------------------------------------------------------------------------------------------
# planning: inputs, names, configs, resume


def _is_glob(text: str) -> bool:
    return any(c in text for c in "*?[")


def _inside(path: Path, folder: Path) -> bool:
    try:
        path.resolve().relative_to(folder.resolve())
    except ValueError:
        return False
    return True


def expand_inputs(
    entries: Sequence[str], folder: Path, exclude: Path | None = None
) -> list[tuple[str, Path | None]]:
    """Expand paths and globs to files.

    Parameters
    ----------
    entries : sequence of str
        Paths and glob patterns; relative ones resolve against ``folder``.
    folder : Path
    exclude : Path, optional
        Files a glob finds inside this folder are left out (the batch's own outputs).

    Returns
    -------
    list of (entry, path or None)
        Absolute paths in entry order (glob results sorted), each file once; ``None`` for a
        glob that matched no file. Explicit paths are returned whether or not they exist.
    """
    out: list[tuple[str, Path | None]] = []
    seen: set[Path] = set()

    def add(entry: str, path: Path) -> None:
        key = path.resolve()
        if key not in seen:
            seen.add(key)
            out.append((entry, path))

    for entry in entries:
        text = os.path.expanduser(entry)
        if _is_glob(text):
            root = None if os.path.isabs(text) else str(folder)
            found = sorted(glob.glob(text, root_dir=root, recursive=True))
            paths = [Path(os.path.abspath(folder / f if root else f)) for f in found]
            paths = [q for q in paths if q.is_file()]
            if exclude is not None:
                paths = [q for q in paths if not _inside(q, exclude)]
            if not paths:
                out.append((entry, None))
            for q in paths:
                add(entry, q)
        else:
            add(entry, Path(os.path.abspath(folder / text)))
    return out


def assign_names(paths: Sequence[Path]) -> list[str]:
    """Output base names: the stem, disambiguated deterministically when stems repeat.

    Inputs sharing a stem (case-insensitively) get the names of as many parent folders as it
    takes to tell them apart (``a/scan.ply``, ``b/scan.ply`` -> ``a_scan``, ``b_scan``); files
    in the same folder differing only in extension get it appended (``scan_ply``, ``scan_xyz``);
    any remaining clash gets ``-2``, ``-3`` ... in input order.

    Parameters
    ----------
    paths : sequence of Path
        Absolute input paths, each file once.

    Returns
    -------
    list of str
        One name per path, unique case-insensitively.

    Examples
    --------
    >>> assign_names([Path("/d/a/scan.ply"), Path("/d/b/scan.ply"), Path("/d/bunny.xyz")])
    ['a_scan', 'b_scan', 'bunny']
    """
    names = [p.stem for p in paths]
    groups: dict[str, list[int]] = {}
    for i, p in enumerate(paths):
        groups.setdefault(p.stem.lower(), []).append(i)
    for members in groups.values():
        if len(members) < 2:
            continue
        parents = [
            [s for s in paths[i].parent.parts if s not in (paths[i].anchor, "/", "\\")]
            for i in members
        ]
        depth = max(len(ps) for ps in parents)
        chosen: list[str] | None = None
        for k in range(1, depth + 1):
            cand = [
                "_".join([*ps[-k:], paths[i].stem]) for ps, i in zip(parents, members, strict=True)
            ]
            if len({c.lower() for c in cand}) == len(cand):
                chosen = cand
                break
        if chosen is None:
            chosen = [
                "_".join([*ps[-1:], paths[i].stem])
                if len(set(map(tuple, parents))) > 1
                else paths[i].stem
                for ps, i in zip(parents, members, strict=True)
            ]
            chosen = [
                f"{c}_{paths[i].suffix.lstrip('.')}" if paths[i].suffix else c
                for c, i in zip(chosen, members, strict=True)
            ]
        for c, i in zip(chosen, members, strict=True):
            names[i] = c
    used: set[str] = set()
    for i, name in enumerate(names):
        final, n = name, 1
        while final.lower() in used:
            n += 1
            final = f"{name}-{n}"
        used.add(final.lower())
        names[i] = final
    return names


@dataclass(frozen=True)
class ItemOutputs:
    """The files one item writes, all in the output folder."""

    meshes: tuple[Path, ...]
    report: Path
    state: Path
    particles: Path | None = None
    preview: Path | None = None

    def products(self) -> list[Path]:
        """Files a successful run leaves (without the resume record)."""
        extra = [p for p in (self.particles, self.preview) if p is not None]
        return [*self.meshes, self.report, *extra]

    def all_files(self) -> list[Path]:
        """Every file, including the resume record."""
        return [*self.products(), self.state]


def item_outputs(
    output_dir: Path, name: str, formats: Sequence[str], particles: bool, preview: bool
) -> ItemOutputs:
    """Output paths of the item called ``name``.

    Parameters
    ----------
    output_dir : Path
    name : str
    formats : sequence of {"ply", "obj"}
    particles, preview : bool

    Returns
    -------
    ItemOutputs
    """
    return ItemOutputs(
        meshes=tuple(output_dir / f"{name}.{fmt}" for fmt in formats),
        report=output_dir / f"{name}.report.json",
        state=output_dir / f"{name}{STATE_SUFFIX}",
        particles=output_dir / f"{name}.particles.ply" if particles else None,
        preview=output_dir / f"{name}.png" if preview else None,
    )


def _sha256(obj: Any) -> str:
    text = json.dumps(obj, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def config_hash(cfg: ReconConfig) -> str:
    """SHA-256 of the resolved configuration, without ``dynamics.time_limit``.

    The time limit does not change a finished result, so changing it re-runs nothing.

    Parameters
    ----------
    cfg : ReconConfig

    Returns
    -------
    str
        64 hex digits.
    """
    data = config_to_dict(cfg)
    data["dynamics"]["time_limit"] = None
    return _sha256(data)


def item_fingerprint(cfg: ReconConfig, input_path: Path) -> dict[str, Any]:
    """What decides whether an item's previous result is still valid.

    Parameters
    ----------
    cfg : ReconConfig
        The item's resolved configuration.
    input_path : Path
        An existing input file.

    Returns
    -------
    dict
        ``config_hash``, ``input`` (path, size [bytes], mtime_ns) and ``oprecon_version``.
    """
    st = input_path.stat()
    return {
        "config_hash": config_hash(cfg),
        "input": {
            "path": str(input_path),
            "size": int(st.st_size),
            "mtime_ns": int(st.st_mtime_ns),
        },
        "oprecon_version": __version__,
    }


@dataclass
class BatchItem:
    """One input of a batch and what will be done with it.

    Attributes
    ----------
    name : str
        Output base name.
    input_path : Path or None
        Absolute input path; None for a glob that matched nothing.
    entry : str
        The ``inputs`` entry it came from.
    config : ReconConfig or None
        Resolved configuration (None when the item cannot run).
    overrides : tuple of int
        Indices of the ``overrides`` entries that apply.
    outputs : ItemOutputs or None
    fingerprint : dict or None
        See :func:`item_fingerprint`.
    action : {"run", "skip", "fail"}
    reason : str
        Why the item runs, is skipped, or fails before running.
    time_limit : float or None [s]
        Effective per-item limit.
    """

    name: str
    input_path: Path | None
    entry: str
    config: ReconConfig | None = None
    overrides: tuple[int, ...] = ()
    outputs: ItemOutputs | None = None
    fingerprint: dict[str, Any] | None = None
    action: str = "run"
    reason: str = ""
    time_limit: float | None = None

    @property
    def input_text(self) -> str:
        """The input path, or the pattern that matched nothing."""
        return str(self.input_path) if self.input_path is not None else self.entry


@dataclass
class BatchPlan:
    """A batch resolved to items, each marked run, skip or fail."""

    spec: BatchSpec
    items: list[BatchItem]
    force: bool = False
    item_time_limit: float | None = DEFAULT_ITEM_TIME_LIMIT

    def with_action(self, action: str) -> list[BatchItem]:
        """Items whose action is ``action`` ("run", "skip" or "fail")."""
        return [it for it in self.items if it.action == action]


def _matches(pattern: str, candidates: Iterable[str]) -> bool:
    return any(fnmatch.fnmatchcase(c, pattern) for c in candidates)


def _candidates(path: Path, name: str, folder: Path) -> list[str]:
    out = [path.name, path.stem, name, path.as_posix()]
    with contextlib.suppress(ValueError):
        out.append(path.relative_to(folder).as_posix())
    return out


def _read_json(path: Path) -> Any:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


def check_up_to_date(item: BatchItem) -> tuple[bool, str]:
    """Whether an item's previous outputs can be kept, and why (not).

    Parameters
    ----------
    item : BatchItem
        With ``outputs`` and ``fingerprint`` set.

    Returns
    -------
    (bool, str)
        ``(True, "up to date")`` or ``(False, reason)``.
    """
    assert item.outputs is not None and item.fingerprint is not None
    missing = [p.name for p in item.outputs.products() if not p.exists()]
    state = _read_json(item.outputs.state) if item.outputs.state.exists() else None
    if state is None:
        if len(missing) == len(item.outputs.products()):
            return False, "not run before"
        return False, "no batch record of the previous run"
    if missing:
        return False, f"output missing: {', '.join(missing)}"
    old = state.get("fingerprint") or {}
    new = item.fingerprint
    if old.get("oprecon_version") != new["oprecon_version"]:
        return False, (
            f"oprecon version changed ({old.get('oprecon_version')} -> {new['oprecon_version']})"
        )
    if old.get("input") != new["input"]:
        return False, "input file changed"
    if old.get("config_hash") != new["config_hash"]:
        return False, "configuration changed"
    return True, "up to date"


def plan_batch(
    spec: BatchSpec, *, force: bool = False, item_time_limit: float | None = DEFAULT_ITEM_TIME_LIMIT
) -> BatchPlan:
    """Resolve a batch to items: names, configurations, outputs and run/skip/fail decisions.

    Parameters
    ----------
    spec : BatchSpec
    force : bool
        Run items even when their outputs are up to date.
    item_time_limit : float or None [s]
        Per-item limit; None means no limit unless an item's ``dynamics.time_limit`` sets one.

    Returns
    -------
    BatchPlan

    Raises
    ------
    ConfigError
        The overrides matching an item combine into an invalid configuration (names the item
        and the overrides' lines), or an output would overwrite an input.
    """
    expanded = expand_inputs(spec.inputs, spec.folder, exclude=spec.output_dir)
    found = [(e, p) for e, p in expanded if p is not None]
    names = assign_names([p for _, p in found])
    name_of = {id(p): n for (_, p), n in zip(found, names, strict=True)}
    inputs_resolved = {p.resolve() for _, p in found}
    items: list[BatchItem] = []
    for entry, path in expanded:
        if path is None:
            items.append(
                BatchItem(
                    name=entry,
                    input_path=None,
                    entry=entry,
                    action="fail",
                    reason=f"no file matches '{entry}'",
                )
            )
            continue
        name = name_of[id(path)]
        cands = _candidates(path, name, spec.folder)
        matched = tuple(
            o.index for o in spec.overrides if any(_matches(pat, cands) for pat in o.patterns)
        )
        cfg = spec.base_config
        try:
            for o in spec.overrides:
                if o.index in matched:
                    cfg = apply_overrides(cfg, o.values)
            if spec.cli_overrides:
                cfg = apply_overrides(cfg, spec.cli_overrides)
        except ConfigError as exc:
            lines = ", ".join(
                f"overrides[{o.index}] (line {o.line})"
                for o in spec.overrides
                if o.index in matched
            )
            raise ConfigError(
                f"{spec.path}: item '{name}' ({path}) with {lines or 'no overrides'}: {exc}"
            ) from None
        limits = [x for x in (item_time_limit, cfg.dynamics.time_limit) if x is not None]
        limit = min(limits) if limits else None
        if limit is not None and limit != cfg.dynamics.time_limit:
            cfg = apply_overrides(cfg, {"dynamics.time_limit": limit})
        outputs = item_outputs(spec.output_dir, name, spec.formats, spec.particles, spec.preview)
        item = BatchItem(
            name=name,
            input_path=path,
            entry=entry,
            config=cfg,
            overrides=matched,
            outputs=outputs,
            time_limit=limit,
        )
        clash = [q for q in outputs.all_files() if q.resolve() in inputs_resolved]
        if clash:
            raise ConfigError(
                f"{spec.path}: output_dir: item '{name}' would overwrite the input "
                f"{clash[0]}; choose another output_dir"
            )
        if not path.exists():
            item.action, item.reason = "fail", f"{path}: no such file"
        elif not path.is_file():
            item.action, item.reason = "fail", f"{path}: not a file"
        else:
            item.fingerprint = item_fingerprint(cfg, path)
            if force:
                item.reason = "--force"
            else:
                ok, item.reason = check_up_to_date(item)
                item.action = "skip" if ok else "run"
        items.append(item)
    for o in spec.overrides:
        if not any(o.index in it.overrides for it in items):
            log.warning(
                "%s: overrides[%d] (line %s) matches no input: %s",
                spec.path,
                o.index,
                o.line,
                ", ".join(o.patterns),
            )
    return BatchPlan(spec, items, force, item_time_limit)


# --------------------------------------------------------------------------------------------
# results


@dataclass
class ItemResult:
    """The outcome of one item (a row of the summary).

    Attributes
    ----------
    name, input : str
    status : {"ok", "failed", "timeout", "skipped", "interrupted"}
    time_s : float or None [s]
        Wall-clock time of the run (None when it did not run).
    particles, faces : int or None
    coverage : float or None
        Fraction of the data near a particle.
    fidelity_mean : float or None [length]
        Mean distance from the input points to the mesh.
    error : str
        One-line message for failed, timed-out and interrupted items; the reason for skipped.
    outputs : list of str
        Files written (or kept, for skipped items).
    detail : str
        Traceback of unexpected errors (JSON summary only).
    """

    name: str
    input: str
    status: str
    time_s: float | None = None
    particles: int | None = None
    faces: int | None = None
    coverage: float | None = None
    fidelity_mean: float | None = None
    error: str = ""
    outputs: list[str] = field(default_factory=list)
    detail: str = ""


def metrics_from_report(report: Mapping[str, Any] | None) -> dict[str, Any]:
    """Summary columns from a fit report (``<mesh>.report.json``).

    Parameters
    ----------
    report : mapping or None

    Returns
    -------
    dict
        ``particles``, ``faces``, ``coverage``, ``fidelity_mean`` (missing ones are None).
    """
    report = report or {}
    fid = report.get("fidelity") or {}
    topo = report.get("topology") or {}

    def num(v: Any) -> Any:
        return v.item() if hasattr(v, "item") else v

    return {
        "particles": num(report.get("particles")),
        "faces": num(topo.get("n_faces")) if isinstance(topo, Mapping) else None,
        "coverage": num(report.get("coverage")),
        "fidelity_mean": num(fid.get("mean")) if isinstance(fid, Mapping) else None,
    }


@dataclass
class BatchEvent:
    """Something that happened to an item, for progress displays.

    Attributes
    ----------
    kind : {"start", "progress", "finish"}
    name : str
        The item.
    phase : str
        Pipeline phase of a "progress" event.
    info : dict
        The pipeline's progress info (step, particles, coverage, max_steps).
    result : ItemResult or None
        Set for "finish".
    """

    kind: str
    name: str
    phase: str = ""
    info: dict[str, Any] = field(default_factory=dict)
    result: ItemResult | None = None


EventFn = Callable[[BatchEvent], None]


@dataclass
class BatchReport:
    """The outcome of :func:`run_batch`."""

    plan: BatchPlan
    results: list[ItemResult]
    interrupted: bool = False
    elapsed_s: float = 0.0
    summary_json: Path | None = None
    summary_csv: Path | None = None
    executor: str = "local"

    def counts(self) -> dict[str, int]:
        """Items per status."""
        out = dict.fromkeys(STATUSES, 0)
        for r in self.results:
            out[r.status] = out.get(r.status, 0) + 1
        return out

    @property
    def exit_code(self) -> int:
        """130 interrupted, 1 when an item failed or timed out, else 0."""
        if self.interrupted:
            return 130
        bad = (STATUS_FAILED, STATUS_TIMEOUT, STATUS_INTERRUPTED)
        return 1 if any(r.status in bad for r in self.results) else 0


def write_summary(report: BatchReport) -> tuple[Path, Path]:
    """Write ``batch_summary.json`` and ``batch_summary.csv`` into the output folder, atomically.

    Parameters
    ----------
    report : BatchReport

    Returns
    -------
    (Path, Path)
        The JSON and CSV files.
    """
    from .io import atomic_output

    out_dir = report.plan.spec.output_dir
    out_dir.mkdir(parents=True, exist_ok=True)
    doc = {
        "oprecon_version": __version__,
        "batch_file": str(report.plan.spec.path),
        "output_dir": str(out_dir),
        "finished": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "elapsed_s": round(report.elapsed_s, 3),
        "executor": report.executor,
        "interrupted": report.interrupted,
        "counts": report.counts(),
        "items": [dataclasses.asdict(r) for r in report.results],
    }
    jpath, cpath = out_dir / SUMMARY_JSON, out_dir / SUMMARY_CSV
    with atomic_output(jpath) as tmp:
        tmp.write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")
    buf = _io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(_SUMMARY_COLUMNS)
    for r in report.results:
        row = dataclasses.asdict(r)
        row["outputs"] = ";".join(r.outputs)
        writer.writerow(["" if row[c] is None else row[c] for c in _SUMMARY_COLUMNS])
    with atomic_output(cpath) as tmp:
        tmp.write_text(buf.getvalue(), encoding="utf-8")
    return jpath, cpath


# --------------------------------------------------------------------------------------------
# the item job (runs in the child process)


def run_item(
    spec: Mapping[str, Any], on_progress: Callable[[str, dict[str, Any]], None] | None = None
) -> dict[str, Any]:
    """Fit one item: the job a child process runs.

    Parameters
    ----------
    spec : mapping
        Built by :func:`run_batch`: ``input``, ``config`` (a config dict), ``meshes`` (paths,
        first one written by :func:`recon.pipeline.fit_file`), ``particles``, ``preview``.
    on_progress : callable(phase, info), optional
        Passed to the pipeline.

    Returns
    -------
    dict
        Summary columns, see :func:`metrics_from_report`.
    """
    from .io import write_mesh
    from .pipeline import fit_file

    cfg = config_from_dict(spec["config"])
    meshes = [Path(m) for m in spec["meshes"]]
    result = fit_file(
        spec["input"],
        meshes[0],
        cfg,
        particles_path=spec.get("particles"),
        preview_path=spec.get("preview"),
        write_report=True,
        mkdir=True,
        on_progress=on_progress,
    )
    normals = result.mesh.normals if cfg.output.vertex_normals else None
    for extra in meshes[1:]:
        write_mesh(extra, result.mesh.vertices, result.mesh.faces, normals, ascii=cfg.io.ascii)
    return metrics_from_report(result.report)


def _prepare_run_item() -> None:
    """Import the pipeline and compile its kernels before the item's clock starts."""
    from . import pipeline  # noqa: F401

    try:
        from .dynamics import warmup
    except ImportError:  # pragma: no cover - older pipeline
        return
    try:
        warmup()
    except Exception as exc:  # noqa: BLE001 - the fit itself will report real problems
        log.debug("kernel warm-up failed: %s", exc)


run_item.prepare = _prepare_run_item  # type: ignore[attr-defined]


# --------------------------------------------------------------------------------------------
# child process protocol: length-prefixed pickles on the child's original stdout

_HEADER = struct.Struct("!I")


def _write_frame(fh: Any, obj: Any) -> None:
    data = pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)
    fh.write(_HEADER.pack(len(data)) + data)
    fh.flush()


def _read_exact(fh: Any, n: int) -> bytes | None:
    buf = b""
    while len(buf) < n:
        chunk = fh.read(n - len(buf))
        if not chunk:
            return None
        buf += chunk
    return buf


def _read_frame(fh: Any) -> Any:
    head = _read_exact(fh, _HEADER.size)
    if head is None:
        return None
    data = _read_exact(fh, _HEADER.unpack(head)[0])
    return None if data is None else pickle.loads(data)


def _resolve_job(text: str, path: str | None) -> Callable[..., Any]:
    import importlib

    if path and path not in sys.path:
        sys.path.insert(0, path)
    module, _, qualname = text.partition(":")
    obj: Any = importlib.import_module(module)
    for part in qualname.split("."):
        obj = getattr(obj, part)
    return obj


def _plain(info: Mapping[str, Any]) -> dict[str, Any]:
    out = {}
    for k, v in info.items():
        v = v.item() if hasattr(v, "item") and not isinstance(v, (list, dict)) else v
        if isinstance(v, (int, float, str, bool)) or v is None:
            out[str(k)] = v
    return out


def _interrupt_main_thread() -> None:
    """Raise KeyboardInterrupt in the main thread, even while it sleeps or waits."""
    main = threading.main_thread()
    if hasattr(signal, "pthread_kill") and main.ident is not None:
        signal.pthread_kill(main.ident, signal.SIGINT)
    else:  # pragma: no cover - Windows
        import _thread

        _thread.interrupt_main()


def _child_main() -> None:
    """Entry point of the child process (see :func:`supervise_item`)."""
    proto = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)  # anything written to stdout (C libraries too) goes to the captured stderr
    sys.stdout = sys.stderr
    signal.signal(signal.SIGINT, signal.default_int_handler)

    def on_term(signum: int, frame: Any) -> None:
        raise KeyboardInterrupt

    with contextlib.suppress(ValueError, OSError, AttributeError):
        signal.signal(signal.SIGTERM, on_term)
    spec = _read_frame(sys.stdin.buffer)
    if spec is None:
        sys.exit(2)
    finished = threading.Event()

    def watch_stdin() -> None:
        # the parent closes our stdin to ask us to stop, or because it died
        with contextlib.suppress(Exception):
            sys.stdin.buffer.read()
        if finished.is_set():
            return
        _interrupt_main_thread()
        if not finished.wait(_ORPHAN_EXIT):
            os._exit(130)  # stuck in native code and nobody left to kill us

    threading.Thread(target=watch_stdin, daemon=True).start()
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("%(levelname)s %(name)s: %(message)s"))
    root = logging.getLogger("recon")
    root.addHandler(handler)
    root.setLevel(logging.WARNING)

    t0 = time.perf_counter()
    try:
        job = _resolve_job(spec["job"], spec.get("job_path"))
        prepare = getattr(job, "prepare", None)
        if prepare is not None:  # imports and compilation do not count against the limit
            prepare()
        _write_frame(proto, ("start", os.getpid()))
        t0 = time.perf_counter()

        def on_progress(phase: str, info: dict[str, Any]) -> None:
            _write_frame(proto, ("progress", str(phase), _plain(info)))

        with deferred_interrupts():  # never stop a k-d tree query or a compile half-way
            metrics = job(spec, on_progress)
        finished.set()
        _write_frame(proto, ("done", dict(metrics or {}), time.perf_counter() - t0))
    except KeyboardInterrupt:
        finished.set()
        with contextlib.suppress(Exception):
            _write_frame(proto, ("interrupted", time.perf_counter() - t0))
        sys.exit(130)
    except BaseException as exc:  # noqa: BLE001 - every failure is reported to the parent
        finished.set()
        elapsed = time.perf_counter() - t0
        limit = spec.get("time_limit")
        is_timeout = isinstance(exc, LimitExceeded) and limit is not None and elapsed >= limit
        if isinstance(exc, OpreconError):
            message, detail = str(exc), ""
        else:
            message = f"{type(exc).__name__}: {exc}"
            detail = traceback.format_exc()
        _write_frame(proto, ("error", message, detail, is_timeout, elapsed))
        sys.exit(1)


# --------------------------------------------------------------------------------------------
# the supervisor (a thread here, or a task on a Dask worker)


def _remove_temp_files(folder: Path, names: Iterable[str], pid: int | None = None) -> int:
    """Remove :func:`recon.io.atomic_output` temporaries of ``names`` (of process ``pid``)."""
    n = 0
    pid_pat = "*" if pid is None else str(pid)
    for name in names:
        pattern = f".{glob.escape(name)}.{pid_pat}-*.tmp*"
        for hit in glob.glob(pattern, root_dir=folder):
            with contextlib.suppress(OSError):
                (folder / hit).unlink()
                n += 1
    if n:
        log.debug("removed %d temporary file(s) in %s", n, folder)
    return n


def _signal_text(code: int | None) -> str:
    if code is None:
        return "unknown status"
    if code < 0:
        try:
            name = signal.Signals(-code).name
        except ValueError:
            name = f"signal {-code}"
        hint = " (out of memory?)" if -code == getattr(signal, "SIGKILL", 9) else ""
        return f"killed by {name}{hint}"
    return f"exit code {code}"


def _tail(fh: Any, n_lines: int = 6, n_chars: int = 800) -> str:
    try:
        fh.seek(0)
        text = fh.read().decode("utf-8", "replace")
    except (OSError, ValueError):
        return ""
    lines = [ln for ln in text.strip().splitlines() if ln.strip()]
    return " | ".join(lines[-n_lines:])[-n_chars:]


def _child_command() -> list[str]:
    root = str(Path(__file__).resolve().parent.parent)
    code = (
        "import sys; sys.path[:] = [p for p in sys.path if p not in ('', '.')]; "
        f"r = {root!r}; r in sys.path or sys.path.insert(0, r); "
        "from recon.batch import _child_main; _child_main()"
    )
    return [sys.executable, "-c", code]


def _child_env(threads: int | None) -> dict[str, str]:
    env = dict(os.environ)
    if threads:
        for var in (
            "NUMBA_NUM_THREADS",
            "OMP_NUM_THREADS",
            "OPENBLAS_NUM_THREADS",
            "MKL_NUM_THREADS",
        ):
            env.setdefault(var, str(threads))
    env.setdefault("PYTHONUNBUFFERED", "1")
    return env


def _write_state(spec: Mapping[str, Any], metrics: Mapping[str, Any]) -> None:
    from .io import atomic_output

    doc = {
        "name": spec["name"],
        "fingerprint": spec["fingerprint"],
        "finished": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "outputs": list(spec["products"]),
        "metrics": dict(metrics),
    }
    with atomic_output(Path(spec["state"])) as tmp:
        tmp.write_text(json.dumps(doc, indent=1, default=str) + "\n", encoding="utf-8")


def supervise_item(
    spec: Mapping[str, Any],
    *,
    on_event: EventFn | None = None,
    should_stop: Callable[[], bool] | None = None,
) -> ItemResult:
    """Run one item in a child process and enforce its time limit.

    The child is sent ``spec``, reports progress, and returns the job's metrics. The
    supervisor kills it (and removes its temporary files) when it runs past
    ``time_limit + kill_grace`` seconds, when ``should_stop()`` turns true (after asking it to
    stop and waiting a few seconds), or reports it failed when it dies. On success the outputs
    are checked and the resume record ``<name>.batch.json`` is written.

    Parameters
    ----------
    spec : mapping
        Built by :func:`run_batch`: ``name``, ``input``, ``output_dir``, ``config``,
        ``meshes``, ``products``, ``state``, ``temp_names``, ``fingerprint``, ``time_limit``
        [s] or None, ``kill_grace`` [s], ``job`` ("module:function"), ``job_path``,
        ``threads``.
    on_event : callable(BatchEvent), optional
        Receives "start" and "progress" events (from this thread).
    should_stop : callable() -> bool, optional
        Polled about five times a second.

    Returns
    -------
    ItemResult
        Never raises for a failing item.
    """
    name, input_text = spec["name"], spec["input"]
    folder = Path(spec["output_dir"])

    def result(status: str, **kw: Any) -> ItemResult:
        return ItemResult(name=name, input=input_text, status=status, **kw)

    if should_stop is not None and should_stop():
        return result(STATUS_INTERRUPTED, error="interrupted before it started")
    stderr_file = tempfile.TemporaryFile()
    try:
        proc = subprocess.Popen(
            _child_command(),
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=stderr_file,
            env=_child_env(spec.get("threads")),
            close_fds=True,
        )
    except OSError as exc:
        stderr_file.close()
        return result(STATUS_FAILED, error=f"cannot start a worker process: {exc}")
    messages: queue.Queue[Any] = queue.Queue()

    def read() -> None:
        while True:
            try:
                msg = _read_frame(proc.stdout)
            except Exception as exc:  # noqa: BLE001 - a garbled stream is a crash
                msg = None
                log.debug("%s: unreadable message from the worker: %s", name, exc)
            messages.put(msg)
            if msg is None:
                return

    reader = threading.Thread(target=read, daemon=True, name=f"oprecon-read-{name}")
    reader.start()
    limit = spec.get("time_limit")
    grace = spec.get("kill_grace") or (kill_grace_for(limit) if limit else 0.0)
    t_launch = time.monotonic()
    deadline = t_launch + _STARTUP_TIMEOUT
    started: float | None = None
    outcome: ItemResult | None = None
    metrics: dict[str, Any] | None = None
    stopping = False
    try:
        try:
            _write_frame(proc.stdin, dict(spec))
        except OSError:
            pass  # it died at once; the reader reports EOF
        while outcome is None and metrics is None:
            try:
                msg = messages.get(timeout=_POLL)
            except queue.Empty:
                msg = ()
            now = time.monotonic()
            if msg is None:
                with contextlib.suppress(subprocess.TimeoutExpired):
                    proc.wait(timeout=10)
                if stopping:
                    outcome = result(STATUS_INTERRUPTED, error="interrupted")
                else:
                    tail = _tail(stderr_file)
                    outcome = result(
                        STATUS_FAILED,
                        time_s=_since(started),
                        error=f"worker process died ({_signal_text(proc.poll())})"
                        + (f": {tail}" if tail else ""),
                    )
            elif msg and msg[0] == "start":
                started = now
                deadline = now + limit + grace if limit else float("inf")
                if on_event is not None:
                    on_event(BatchEvent("start", name))
            elif msg and msg[0] == "progress":
                if on_event is not None:
                    on_event(BatchEvent("progress", name, phase=msg[1], info=msg[2]))
            elif msg and msg[0] == "done":
                metrics = dict(msg[1])
                metrics["time_s"] = round(float(msg[2]), 3)
            elif msg and msg[0] == "error":
                _, message, detail, is_timeout, elapsed = msg
                outcome = result(
                    STATUS_TIMEOUT if is_timeout else STATUS_FAILED,
                    time_s=round(float(elapsed), 3),
                    error=message,
                    detail=detail,
                )
            elif msg and msg[0] == "interrupted":
                outcome = result(STATUS_INTERRUPTED, time_s=_since(started), error="interrupted")
            if outcome is not None or metrics is not None:
                break
            if now > deadline:
                proc.kill()
                if started is None:
                    outcome = result(
                        STATUS_FAILED,
                        error=f"the worker process did not start within {_STARTUP_TIMEOUT:g} s",
                    )
                else:
                    outcome = result(
                        STATUS_TIMEOUT,
                        time_s=_since(started),
                        error=f"killed after exceeding the time limit of {limit:g} s "
                        f"(+{grace:g} s grace)",
                    )
                break
            if not stopping and should_stop is not None and should_stop():
                stopping = True
                with contextlib.suppress(OSError):
                    proc.stdin.close()  # the child raises KeyboardInterrupt and cleans up
                deadline = min(deadline, now + _STOP_GRACE)
                started = started if started is not None else now
    finally:
        _end_process(proc)
        reader.join(timeout=5)
        stderr_file.close()
        _remove_temp_files(folder, spec.get("temp_names", ()), proc.pid)
    if outcome is not None:
        if stopping and outcome.status != STATUS_INTERRUPTED:
            outcome.status, outcome.error = STATUS_INTERRUPTED, "interrupted"
        return outcome
    assert metrics is not None
    time_s = metrics.pop("time_s", None)
    missing = [Path(p).name for p in spec["products"] if not Path(p).exists()]
    if missing:
        return result(
            STATUS_FAILED, time_s=time_s, error=f"finished without writing {', '.join(missing)}"
        )
    try:
        _write_state(spec, metrics)
    except OpreconError as exc:
        return result(STATUS_FAILED, time_s=time_s, error=f"cannot write the batch record: {exc}")
    known = {k: metrics.get(k) for k in ("particles", "faces", "coverage", "fidelity_mean")}
    return result(STATUS_OK, time_s=time_s, outputs=list(spec["products"]), **known)


def _since(t: float | None) -> float | None:
    return None if t is None else round(time.monotonic() - t, 3)


def _end_process(proc: subprocess.Popen) -> None:
    """Close the child's stdin, give it a moment to exit, then kill it."""
    with contextlib.suppress(OSError):
        if proc.stdin is not None:
            proc.stdin.close()
    try:
        proc.wait(timeout=_STOP_GRACE if proc.poll() is None else 1)
    except subprocess.TimeoutExpired:
        proc.kill()
        with contextlib.suppress(subprocess.TimeoutExpired):
            proc.wait(timeout=10)
    with contextlib.suppress(OSError):
        if proc.stdout is not None:
            proc.stdout.close()


# --------------------------------------------------------------------------------------------
# executors


def _job_reference(job: Callable[..., Any] | str | None) -> tuple[str, str | None]:
    if job is None:
        return _DEFAULT_JOB, None
    if isinstance(job, str):
        return job, None
    qualname = getattr(job, "__qualname__", "")
    module = getattr(job, "__module__", None)
    if not module or not qualname or "<" in qualname:
        raise ValueError(f"job must be a module-level function, got {job!r}")
    path = None
    mod = sys.modules.get(module)
    if mod is not None and getattr(mod, "__file__", None):
        path = str(Path(mod.__file__).resolve().parent)
        if module.count("."):
            path = str(Path(path).parents[module.count(".") - 1])
    return f"{module}:{qualname}", path


def _item_spec(
    item: BatchItem, job: tuple[str, str | None], kill_grace: float | None, threads: int | None
) -> dict[str, Any]:
    assert item.outputs is not None and item.config is not None
    out = item.outputs
    limit = item.time_limit
    return {
        "name": item.name,
        "input": str(item.input_path),
        "output_dir": str(out.state.parent),
        "config": config_to_dict(item.config),
        "meshes": [str(m) for m in out.meshes],
        "particles": str(out.particles) if out.particles else None,
        "preview": str(out.preview) if out.preview else None,
        "report": str(out.report),
        "state": str(out.state),
        "products": [str(p) for p in out.products()],
        "temp_names": [p.name for p in out.all_files()],
        "fingerprint": item.fingerprint,
        "time_limit": limit,
        "kill_grace": kill_grace
        if kill_grace is not None
        else (kill_grace_for(limit) if limit else None),
        "job": job[0],
        "job_path": job[1],
        "threads": threads,
    }


def default_jobs() -> int:
    """Number of usable cores."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


def _run_local(
    specs: list[dict[str, Any]], jobs: int, emit: EventFn, results: dict[str, ItemResult]
) -> bool:
    """Supervisor threads in this process; returns True when interrupted."""
    stop = threading.Event()
    events: queue.Queue[BatchEvent] = queue.Queue()
    pool = ThreadPoolExecutor(max_workers=jobs, thread_name_prefix="oprecon-batch")
    futures = {
        pool.submit(supervise_item, s, on_event=events.put, should_stop=stop.is_set): s["name"]
        for s in specs
    }
    pending = set(futures)

    def record(fut: Any) -> None:
        name = futures[fut]
        if name in results:
            return
        if fut.cancelled():
            res = ItemResult(
                name,
                _input_of(specs, name),
                STATUS_INTERRUPTED,
                error="interrupted before it started",
            )
        else:
            try:
                res = fut.result()
            except Exception as exc:  # noqa: BLE001 - a bug in the supervisor: report it
                res = ItemResult(
                    name,
                    _input_of(specs, name),
                    STATUS_FAILED,
                    error=f"{type(exc).__name__}: {exc}",
                    detail=traceback.format_exc(),
                )
        results[name] = res

    interrupted = False
    try:
        while pending:
            done, pending = wait(pending, timeout=_POLL, return_when=FIRST_COMPLETED)
            for fut in done:
                record(fut)
            while True:  # progress in arrival order, then the items that finished
                try:
                    emit(events.get_nowait())
                except queue.Empty:
                    break
            for fut in done:
                emit(BatchEvent("finish", futures[fut], result=results[futures[fut]]))
    except KeyboardInterrupt:
        interrupted = True
        stop.set()
        for fut in pending:
            fut.cancel()
        while pending:  # the supervisors stop their children, then return
            try:
                done, pending = wait(pending, timeout=_POLL, return_when=FIRST_COMPLETED)
            except KeyboardInterrupt:
                continue
            for fut in done:
                record(fut)
    finally:
        stop.set()  # whatever ended the loop, no child outlives it
        pool.shutdown(wait=True, cancel_futures=True)
        for fut in futures:
            record(fut)
    return interrupted


def _input_of(specs: list[dict[str, Any]], name: str) -> str:
    return next((s["input"] for s in specs if s["name"] == name), "")


def _worker_version() -> str:
    from recon import __version__ as version

    return version


class _DaskStop:
    """``should_stop`` on a Dask worker: a named distributed Event, checked once a second."""

    def __init__(self, name: str) -> None:
        self.name = name
        self.event: Any = None
        self.checked = 0.0
        self.value = False

    def __call__(self) -> bool:
        now = time.monotonic()
        if self.value or now - self.checked < 1.0:
            return self.value
        self.checked = now
        try:
            if self.event is None:
                from distributed import Event

                self.event = Event(self.name)
            self.value = bool(self.event.is_set())
        except Exception as exc:  # noqa: BLE001 - lost the scheduler: keep going
            log.debug("cannot read the stop event: %s", exc)
        return self.value


def _dask_item(spec: dict[str, Any], stop_name: str) -> ItemResult:
    """The task submitted to Dask: :func:`supervise_item` with a cluster-wide stop flag."""
    return supervise_item(spec, should_stop=_DaskStop(stop_name))


def _import_dask() -> Any:
    try:
        import dask.distributed as dd
    except ImportError:
        raise OpreconError(DASK_MISSING) from None
    return dd


@contextlib.contextmanager
def _sigint_ignored() -> Iterator[None]:
    """Ignore SIGINT meanwhile, so that processes started now (Dask workers) ignore Ctrl-C."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


@contextlib.contextmanager
def _quiet_loggers(names: Sequence[str], active: bool = True) -> Iterator[None]:
    """Silence third-party loggers (tracebacks of a cluster shutting down after Ctrl-C)."""
    loggers = [logging.getLogger(n) for n in names] if active else []
    levels = [lg.level for lg in loggers]
    for lg in loggers:
        lg.setLevel(logging.CRITICAL + 1)
    try:
        yield
    finally:
        for lg, level in zip(loggers, levels, strict=True):
            lg.setLevel(level)


def _run_dask(
    specs: list[dict[str, Any]],
    jobs: int,
    scheduler: str | None,
    emit: EventFn,
    results: dict[str, ItemResult],
) -> bool:
    """Supervisors as tasks on a Dask cluster; returns True when interrupted."""
    dd = _import_dask()
    cluster = None
    client = None
    interrupted = False
    futures: dict[Any, str] = {}

    def record(fut: Any) -> None:
        name = futures[fut]
        if name in results:
            return
        try:
            res = fut.result()
        except Exception as exc:  # noqa: BLE001 - e.g. KilledWorker
            res = ItemResult(
                name,
                _input_of(specs, name),
                STATUS_FAILED,
                error=f"Dask task failed: {type(exc).__name__}: {exc}",
            )
        results[name] = res

    try:
        if scheduler:
            try:
                client = dd.Client(scheduler, timeout="20s", set_as_default=False)
            except (OSError, TimeoutError) as exc:
                raise OpreconError(
                    f"cannot connect to the Dask scheduler at {scheduler}: {exc}"
                ) from None
        else:
            with _sigint_ignored():  # Ctrl-C is handled here, not in the workers
                cluster = dd.LocalCluster(
                    n_workers=jobs,
                    processes=True,
                    threads_per_worker=1,
                    dashboard_address=None,
                    silence_logs=logging.ERROR,
                )
            client = dd.Client(cluster, set_as_default=False)
        try:
            versions = client.run(_worker_version)
        except Exception as exc:  # noqa: BLE001 - the workers cannot import oprecon
            raise OpreconError(
                "cannot run oprecon on the Dask workers (install the same "
                f"oprecon version on every worker): {exc}"
            ) from None
        wrong = {w: v for w, v in versions.items() if v != __version__}
        if wrong:
            raise OpreconError(
                f"Dask workers run other oprecon versions than {__version__}: "
                + ", ".join(f"{w} has {v}" for w, v in sorted(wrong.items()))
            )
        if not versions:
            log.warning("the Dask scheduler has no workers yet; items wait until workers join")
        token = uuid.uuid4().hex[:12]
        stop_name = f"oprecon-batch-stop-{token}"
        stop = dd.Event(stop_name, client=client)
        for s in specs:
            fut = client.submit(
                _dask_item, s, stop_name, key=f"oprecon-{s['name']}-{token}", pure=False
            )
            futures[fut] = s["name"]
        try:
            for fut in dd.as_completed(list(futures), loop=client.loop):
                record(fut)
                emit(BatchEvent("finish", futures[fut], result=results[futures[fut]]))
        except KeyboardInterrupt:
            interrupted = True
            with contextlib.suppress(Exception):
                stop.set()
            # the supervisors see the flag within a second, stop their children and return
            remaining = [f for f in futures if futures[f] not in results]
            until = time.monotonic() + _STOP_GRACE + 5
            with contextlib.suppress(KeyboardInterrupt):
                while time.monotonic() < until and not all(f.done() for f in remaining):
                    time.sleep(_POLL)
            for fut in remaining:
                if fut.done() and fut.status == "finished":
                    record(fut)
    finally:
        with _quiet_loggers(("distributed", "tornado"), active=interrupted):
            with contextlib.suppress(Exception):
                if client is not None and futures:
                    client.cancel([f for f in futures if futures[f] not in results])
            with contextlib.suppress(Exception):
                if client is not None:
                    client.close()
            with contextlib.suppress(Exception):
                if cluster is not None:
                    cluster.close()
    return interrupted


def run_batch(
    plan: BatchPlan,
    *,
    jobs: int | None = None,
    executor: str = "local",
    scheduler: str | None = None,
    job: Callable[..., Any] | str | None = None,
    on_event: EventFn | None = None,
    kill_grace: float | None = None,
    write_summary_files: bool = True,
) -> BatchReport:
    """Run the items of a plan and write the summary.

    Parameters
    ----------
    plan : BatchPlan
        From :func:`plan_batch`; items marked "skip" and "fail" are reported, not run.
    jobs : int, optional
        Items at a time (local), or LocalCluster workers (dask without ``scheduler``);
        default: the number of cores.
    executor : {"local", "dask"}
    scheduler : str, optional
        Address of a running Dask scheduler (``tcp://host:8786``); only with "dask".
    job : callable or "module:function", optional
        The function a child runs, ``job(spec, on_progress) -> metrics``; default
        :func:`run_item`. Must be importable by name (for tests: a module-level function).
    on_event : callable(BatchEvent), optional
        Called from this thread for every start, progress and finish.
    kill_grace : float, optional [s]
        Time past the limit before a child is killed; default :func:`kill_grace_for`.
    write_summary_files : bool
        Write ``batch_summary.json`` and ``.csv`` into the output folder.

    Returns
    -------
    BatchReport
        With ``interrupted`` set when Ctrl-C stopped the run (the unfinished items are
        ``interrupted``, none left a partial file; the summary is still written).

    Raises
    ------
    OpreconError
        Dask missing or unreachable, or its workers run another oprecon version.
    """
    if executor not in ("local", "dask"):
        raise ValueError(f"executor: expected 'local' or 'dask', got {executor!r}")
    if scheduler and executor != "dask":
        raise ValueError("scheduler needs executor='dask'")
    if executor == "dask":
        _import_dask()
    n_jobs = max(1, int(jobs)) if jobs else default_jobs()
    t0 = time.monotonic()
    emit: EventFn = on_event if on_event is not None else (lambda event: None)
    job_ref = _job_reference(job)
    results: dict[str, ItemResult] = {}
    for item in plan.items:
        if item.action == "fail":
            results[item.name] = ItemResult(
                item.name, item.input_text, STATUS_FAILED, error=item.reason
            )
        elif item.action == "skip":
            assert item.outputs is not None
            metrics = metrics_from_report(_read_json(item.outputs.report))
            results[item.name] = ItemResult(
                item.name,
                item.input_text,
                STATUS_SKIPPED,
                error=item.reason,
                **metrics,
                outputs=[str(p) for p in item.outputs.products()],
            )
    to_run = plan.with_action("run")
    interrupted = False
    if to_run:
        plan.spec.output_dir.mkdir(parents=True, exist_ok=True)
        local = executor == "local" or not scheduler
        threads = max(1, default_jobs() // min(n_jobs, len(to_run))) if local else None
        specs = [_item_spec(it, job_ref, kill_grace, threads) for it in to_run]
        for s in specs:  # leftovers of an earlier run that was killed
            _remove_temp_files(plan.spec.output_dir, s["temp_names"])
        try:
            if executor == "dask":
                interrupted = _run_dask(specs, n_jobs, scheduler, emit, results)
            else:
                interrupted = _run_local(specs, min(n_jobs, len(specs)), emit, results)
        except KeyboardInterrupt:
            interrupted = True
        for s in specs:
            if s["name"] not in results or results[s["name"]].status != STATUS_OK:
                _remove_temp_files(plan.spec.output_dir, s["temp_names"])
            if s["name"] not in results:
                results[s["name"]] = ItemResult(
                    s["name"], s["input"], STATUS_INTERRUPTED, error="interrupted"
                )
    report = BatchReport(
        plan,
        [results[it.name] for it in plan.items],
        interrupted,
        time.monotonic() - t0,
        executor=executor,
    )
    if write_summary_files:
        report.summary_json, report.summary_csv = write_summary(report)
    return report
