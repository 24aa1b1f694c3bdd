"""Resume: fingerprints of items, and the ``<name>.batch.json`` record that proves one is done.

An item is skipped when its outputs and ``<name>.batch.json`` exist and the record matches the
item's fingerprint: a hash of the resolved configuration (without ``dynamics.time_limit`` and
``threads``), the input file's path, size and modification time, and the oprecon version. The
supervisor writes the record after a successful run (:func:`write_record`); planning reads it
(:func:`check_up_to_date`).
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from ..config import ReconConfig, config_to_dict
from ..version import __version__
from .outputs import ItemOutputs, read_json, write_json

__all__ = ["check_up_to_date", "config_hash", "item_fingerprint", "write_record"]


def _sha256(obj: Any) -> str:
    """Hash of a plain JSON value (keys sorted, compact)."""
    text = json.dumps(obj, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def config_hash(cfg: ReconConfig) -> str:
    """SHA-256 of the resolved configuration, without ``dynamics.time_limit`` and ``threads``.

    Neither changes a finished result, so changing them re-runs nothing.

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
    data.pop("threads", None)  # the mesh does not depend on it
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


def check_up_to_date(outputs: ItemOutputs, fingerprint: Mapping[str, Any]) -> tuple[bool, str]:
    """Whether an item's previous outputs can be kept, and why (not).

    Parameters
    ----------
    outputs : ItemOutputs
        The item's files.
    fingerprint : mapping
        The item's :func:`item_fingerprint` now.

    Returns
    -------
    (bool, str)
        ``(True, "up to date")`` or ``(False, reason)``.
    """
    missing = [p.name for p in outputs.products() if not p.exists()]
    state = read_json(outputs.state) if outputs.state.exists() else None
    if state is None:
        if len(missing) == len(outputs.products()):
            return False, "not run before"
        return False, "no batch record of the previous run"
    if missing:
        return False, f"output missing: {', '.join(missing)}"
    old = state.get("fingerprint") or {}
    new = fingerprint
    if old.get("oprecon_version") != new["oprecon_version"]:
        return False, (
            f"oprecon version changed ({old.get('oprecon_version')} -> {new['oprecon_version']})"
        )
    if old.get("input") != new["input"]:
        return False, "input file changed"
    if old.get("config_hash") != new["config_hash"]:
        return False, "configuration changed"
    return True, "up to date"


def write_record(
    path: Path,
    name: str,
    fingerprint: Mapping[str, Any],
    products: list[str],
    metrics: Mapping[str, Any],
) -> None:
    """Write the resume record ``<name>.batch.json`` of a finished item, atomically.

    Parameters
    ----------
    path : Path
        The record (``ItemOutputs.state``).
    name : str
        The item.
    fingerprint : mapping
        Its :func:`item_fingerprint`.
    products : list of str
        The files it wrote.
    metrics : mapping
        Its summary columns.

    Raises
    ------
    InputError
        The record cannot be written.
    """
    doc = {
        "name": name,
        "fingerprint": fingerprint,
        "finished": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "outputs": list(products),
        "metrics": dict(metrics),
    }
    write_json(path, doc)
