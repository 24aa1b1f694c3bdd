"""Batch runs: many point clouds, one configuration, one summary; one failure doesn't stop the rest.

A batch file (YAML, schema in :mod:`recon.batch.spec`) names the inputs, where the meshes go and
how they are configured. :func:`load_batch` validates it, :func:`plan_batch` resolves it to
items (names, configurations, run/skip/fail), :func:`run_batch` runs the items and writes
``batch_summary.json`` and ``batch_summary.csv``::

    spec = load_batch("scans.yaml")
    report = run_batch(plan_batch(spec), jobs=4)

Every item runs in its own child process (:mod:`recon.batch.worker`), watched by a supervisor
(:mod:`recon.batch.supervise`) that enforces the time limit and removes a killed child's
temporary files; the supervisors are threads here or tasks on a Dask cluster
(:mod:`recon.batch.executors`). Items whose outputs are up to date are skipped
(:mod:`recon.batch.resume`).

Modules, in the order a batch meets them: ``spec`` (the batch file), ``plan`` (inputs, names,
run/skip/fail), ``outputs`` (the files an item writes), ``resume`` (fingerprints and records),
``run`` (:func:`run_batch`), ``executors`` (local threads, Dask), ``supervise`` (one item's
child process and its time limit), ``protocol`` (frames between supervisor and child),
``worker`` (the child and the fit job), ``summary`` (statuses, results, the summary files).
"""

from __future__ import annotations

from .plan import (
    DEFAULT_ITEM_TIME_LIMIT,
    BatchItem,
    BatchPlan,
    assign_names,
    expand_inputs,
    plan_batch,
)
from .run import run_batch
from .spec import BATCH_VERSION, BatchSpec, load_batch
from .summary import (
    STATUS_FAILED,
    STATUS_INTERRUPTED,
    STATUS_OK,
    STATUS_SKIPPED,
    STATUS_TIMEOUT,
    STATUSES,
    BatchEvent,
    BatchReport,
    ItemResult,
    metrics_from_report,
    write_summary,
)

__all__ = [
    "BATCH_VERSION",
    "DEFAULT_ITEM_TIME_LIMIT",
    "STATUSES",
    "STATUS_FAILED",
    "STATUS_INTERRUPTED",
    "STATUS_OK",
    "STATUS_SKIPPED",
    "STATUS_TIMEOUT",
    "BatchEvent",
    "BatchItem",
    "BatchPlan",
    "BatchReport",
    "BatchSpec",
    "ItemResult",
    "assign_names",
    "expand_inputs",
    "load_batch",
    "metrics_from_report",
    "plan_batch",
    "run_batch",
    "write_summary",
]
