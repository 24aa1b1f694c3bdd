"""The files a batch writes into its output folder, and the batch's one door to ``recon.io``.

Per item ``<name>``: ``<name>.<fmt>`` for each mesh format, ``<name>.report.json`` (always
written: the summary and resume need it), ``<name>.particles.ply`` and ``<name>.png`` when asked
for, and ``<name>.batch.json``, the record used to resume (:mod:`recon.batch.resume`). Every file
is written through :func:`recon.io.atomic_output`; a writer that is killed leaves a temporary
``.<file>.<pid>-<hex>.tmp<suffix>`` that :func:`remove_temp_files` removes.
"""

from __future__ import annotations

import contextlib
import glob
import json
import logging
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

log = logging.getLogger(__name__)

__all__ = [
    "STATE_SUFFIX",
    "ItemOutputs",
    "item_outputs",
    "read_json",
    "remove_temp_files",
    "write_json",
    "write_text",
]

#: Suffix of an item's resume record.
STATE_SUFFIX = ".batch.json"


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


def read_json(path: Path) -> Any:
    """The JSON document in ``path``, or None when it is missing or unreadable."""
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


def write_text(path: Path, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` through :func:`recon.io.atomic_output`.

    Raises
    ------
    InputError
        The file cannot be written.
    """
    from ..io import atomic_output  # lazy: numpy and friends stay out of `oprecon --help`

    with atomic_output(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


def write_json(path: Path, doc: Any) -> None:
    """Write ``doc`` as JSON (:func:`recon.serialize.dumps`, one line feed at the end) atomically.

    Raises
    ------
    InputError
        The file cannot be written.
    """
    from ..serialize import dumps  # lazy: it imports numpy

    write_text(path, dumps(doc) + "\n")


def remove_temp_files(folder: Path, names: Iterable[str], pid: int | None = None) -> int:
    """Remove the :func:`recon.io.atomic_output` temporaries of ``names`` in ``folder``.

    Parameters
    ----------
    folder : Path
    names : iterable of str
        File names whose temporaries go.
    pid : int, optional
        Only those of this process (default: of any process).

    Returns
    -------
    int
        Files removed.
    """
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
