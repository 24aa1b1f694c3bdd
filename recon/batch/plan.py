"""Planning a batch: inputs from paths and globs, output names, configurations, run or skip.

Globs list only files, sorted, and skip files inside ``output_dir``; an explicit path that does
not exist, or a glob that matches nothing, becomes a *failed* item (the others still run).

``match`` patterns are compared (``fnmatch``, case-sensitive) with the input's file name, its
stem, its output name and its path (relative to the batch file's folder, and absolute); an item
takes every override that matches. The per-item time limit is
``min(item_time_limit, dynamics.time_limit)``.

``<name>`` is the input's stem; inputs sharing a stem get their parent folders' names
prepended (``a_scan``, ``b_scan``) until the names differ, then the extension (``scan_ply``),
then a counter. Items whose outputs are up to date are skipped (:mod:`recon.batch.resume`).
"""

from __future__ import annotations

import contextlib
import fnmatch
import glob
import logging
import math
import os
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..config import ReconConfig, apply_overrides
from ..errors import ConfigError
from .outputs import ItemOutputs, item_outputs
from .resume import check_up_to_date, item_fingerprint
from .spec import BatchSpec

log = logging.getLogger(__name__)

__all__ = [
    "DEFAULT_ITEM_TIME_LIMIT",
    "BatchItem",
    "BatchPlan",
    "assign_names",
    "expand_inputs",
    "plan_batch",
]

#: Per-item wall-clock limit [s] when neither the command line nor the batch file sets one.
DEFAULT_ITEM_TIME_LIMIT = 3600.0


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
        Paths and glob patterns; relative ones resolve against ``folder``. An entry that
        names an existing file is that file, even with glob characters in its name
        (``scan[1].ply``).
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
        if _is_glob(text) and not (folder / text).is_file():
            paths = _glob_files(text, folder)
            if exclude is not None:
                paths = [q for q in paths if not _inside(q, exclude)]
            if not paths:
                out.append((entry, None))
            for q in paths:
                add(entry, q)
        else:
            add(entry, Path(os.path.abspath(folder / text)))
    return out


def _glob_files(text: str, folder: Path) -> list[Path]:
    """The files a glob pattern matches (relative to ``folder`` unless absolute), sorted."""
    root = None if os.path.isabs(text) else str(folder)
    found = sorted(glob.glob(text, root_dir=root, recursive=True))
    paths = [Path(os.path.abspath(folder / f if root else f)) for f in found]
    return [q for q in paths if q.is_file()]


def _unmatched_reason(entry: str, folder: Path, output_dir: Path) -> str:
    """Why a glob entry gave no input: no file matches, or every match is a batch output."""
    n = len(_glob_files(os.path.expanduser(entry), folder))
    if n == 0:
        return f"no file matches '{entry}'"
    files = "1 file matches" if n == 1 else f"{n} files match"
    return (
        f"{files} '{entry}', all inside output_dir {output_dir} (a batch never reads files "
        "there: they may be its own outputs); move the inputs or choose another output_dir"
    )


def _free_name(
    name: str,
    outputs_of: Callable[[str], ItemOutputs],
    taken: set[str],
    used: set[str],
) -> tuple[str, ItemOutputs]:
    """``name``, or ``name-2``, ``name-3`` ..., the first whose outputs no earlier item writes
    (``taken``: their resolved paths, lower case) and that no other item is called (``used``,
    lower case): item ``a``'s particles ``a.particles.ply`` are the mesh of an item named
    ``a.particles``."""
    final, n = name, 1
    while True:
        outputs = outputs_of(final)
        keys = {str(q.resolve()).lower() for q in outputs.all_files()}
        if not keys & taken and (final == name or final.lower() not in used):
            return final, outputs
        n += 1
        final = f"{name}-{n}"


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
        Per-item limit; None or infinity means no limit unless an item's
        ``dynamics.time_limit`` sets one.

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
    used = {n.lower() for n in names}
    taken: set[str] = set()  # every output path an item writes (resolved, lower case)
    items: list[BatchItem] = []
    for entry, path in expanded:
        if path is None:
            items.append(
                BatchItem(
                    name=entry,
                    input_path=None,
                    entry=entry,
                    action="fail",
                    reason=_unmatched_reason(entry, spec.folder, spec.output_dir),
                )
            )
            continue
        name, outputs = _free_name(
            name_of[id(path)],
            lambda n: item_outputs(spec.output_dir, n, spec.formats, spec.particles, spec.preview),
            taken,
            used,
        )
        used.add(name.lower())
        taken |= {str(q.resolve()).lower() for q in outputs.all_files()}
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
        # an infinite limit (``item_time_limit: .inf``, ``--item-time-limit inf``) is none
        limits = [
            x for x in (item_time_limit, cfg.dynamics.time_limit) if x is not None and x < math.inf
        ]
        limit = min(limits) if limits else None
        if limit is not None and limit != cfg.dynamics.time_limit:
            cfg = apply_overrides(cfg, {"dynamics.time_limit": limit})
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
                ok, item.reason = check_up_to_date(outputs, item.fingerprint)
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
