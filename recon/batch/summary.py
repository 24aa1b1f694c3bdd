"""Outcomes of items, progress events, and the batch summary (``batch_summary.json``/``.csv``).

Every item ends with one status: ``ok``, ``failed``, ``timeout``, ``skipped`` (up to date) or
``interrupted`` (unfinished at Ctrl-C). The summary lists every item with its status and the
columns of its fit report (:func:`metrics_from_report`).
"""

from __future__ import annotations

import csv
import dataclasses
import io
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from ..version import __version__
from .outputs import write_json, write_text
from .plan import BatchPlan

__all__ = [
    "STATUSES",
    "STATUS_FAILED",
    "STATUS_INTERRUPTED",
    "STATUS_OK",
    "STATUS_SKIPPED",
    "STATUS_TIMEOUT",
    "BatchEvent",
    "BatchReport",
    "EventFn",
    "ItemResult",
    "metrics_from_report",
    "write_summary",
]

STATUS_OK = "ok"
STATUS_FAILED = "failed"
STATUS_TIMEOUT = "timeout"
STATUS_SKIPPED = "skipped"
STATUS_INTERRUPTED = "interrupted"
STATUSES = (STATUS_OK, STATUS_FAILED, STATUS_TIMEOUT, STATUS_SKIPPED, STATUS_INTERRUPTED)
SUMMARY_JSON = "batch_summary.json"
SUMMARY_CSV = "batch_summary.csv"
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
    write_json(jpath, doc)
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(_SUMMARY_COLUMNS)
    for r in report.results:
        row = dataclasses.asdict(r)
        row["outputs"] = ";".join(r.outputs)
        writer.writerow(["" if row[c] is None else row[c] for c in _SUMMARY_COLUMNS])
    write_text(cpath, buf.getvalue())
    return jpath, cpath
