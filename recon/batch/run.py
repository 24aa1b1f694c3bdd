"""Running a planned batch: skipped and failed items, the item specs, the executor, the summary.

Every item to run becomes an item spec (a dict, see :mod:`recon.batch.protocol`) and runs in its
own child process under a supervisor (:mod:`recon.batch.supervise`), on the chosen executor
(:mod:`recon.batch.executors`). Leftover temporaries of killed writers are removed before and
after; ``batch_summary.json`` and ``.csv`` are written at the end, also after Ctrl-C.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from ..config import config_to_dict
from ..io.files import check_output_path
from .executors import default_jobs, import_dask, run_dask, run_local
from .outputs import read_json, remove_temp_files
from .plan import BatchItem, BatchPlan
from .protocol import JobRef
from .summary import (
    STATUS_FAILED,
    STATUS_INTERRUPTED,
    STATUS_OK,
    STATUS_SKIPPED,
    SUMMARY_JSON,
    BatchReport,
    EventFn,
    ItemResult,
    metrics_from_report,
    write_summary,
)
from .supervise import kill_grace_for
from .worker import RUN_ITEM

__all__ = ["run_batch"]


def _item_spec(
    item: BatchItem,
    job: JobRef,
    kill_grace: float | None,
    threads: int | None,
    threads_given: bool = False,
) -> dict[str, Any]:
    """The item spec sent to the child (and passed to the job)."""
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
        **job.to_spec(),
        "threads": threads,
        "threads_given": threads_given,
    }


def run_batch(
    plan: BatchPlan,
    *,
    jobs: int | None = None,
    executor: str = "local",
    scheduler: str | None = None,
    job: Callable[..., Any] | str | JobRef | None = None,
    on_event: EventFn | None = None,
    kill_grace: float | None = None,
    write_summary_files: bool = True,
    threads: int | None = None,
) -> BatchReport:
    """Run the items of a plan and write the summary.

    Parameters
    ----------
    plan : BatchPlan
        From :func:`~recon.batch.plan.plan_batch`; items marked "skip" and "fail" are
        reported, not run.
    jobs : int, optional
        Items at a time (local), or LocalCluster workers (dask without ``scheduler``);
        default: the number of cores.
    executor : {"local", "dask"}
    scheduler : str, optional
        Address of a running Dask scheduler (``tcp://host:8786``); only with "dask".
    job : callable, "module:function" or JobRef, optional
        The function a child runs, ``job(spec, on_progress) -> metrics``; default
        :data:`~recon.batch.worker.RUN_ITEM` (the fit). Must be importable by name (for tests:
        a module-level function); a :class:`~recon.batch.protocol.JobRef` can also name a
        function to run before the item's clock starts.
    on_event : callable(BatchEvent), optional
        Called from this thread for every start, progress and finish.
    kill_grace : float, optional [s]
        Time past the limit before a child is killed; default
        :func:`~recon.batch.supervise.kill_grace_for`.
    write_summary_files : bool
        Write ``batch_summary.json`` and ``.csv`` into the output folder.
    threads : int, optional
        Threads per item (numba, OpenMP, BLAS: the child's ``NUMBA_NUM_THREADS``,
        ``OMP_NUM_THREADS``, ...). Default, on this machine: cores // items at a time (at
        least 1), so parallel items do not oversubscribe the cores, unless those variables are
        set in this environment; on a remote Dask cluster: the workers' own.

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
        import_dask()
    n_jobs = max(1, int(jobs)) if jobs else default_jobs()
    t0 = time.monotonic()
    emit: EventFn = on_event if on_event is not None else (lambda event: None)
    job_ref = RUN_ITEM if job is None else JobRef.of(job)
    results: dict[str, ItemResult] = {}
    for item in plan.items:
        if item.action == "fail":
            results[item.name] = ItemResult(
                item.name, item.input_text, STATUS_FAILED, error=item.reason
            )
        elif item.action == "skip":
            assert item.outputs is not None
            metrics = metrics_from_report(read_json(item.outputs.report))
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
    if to_run or write_summary_files:
        # a folder nobody can write in is refused now, not after every item has run
        plan.spec.output_dir.mkdir(parents=True, exist_ok=True)
        check_output_path(plan.spec.output_dir / SUMMARY_JSON)
    if to_run:
        local = executor == "local" or not scheduler
        per_item = threads or (
            max(1, default_jobs() // min(n_jobs, len(to_run))) if local else None
        )
        specs = [
            _item_spec(it, job_ref, kill_grace, per_item, threads is not None) for it in to_run
        ]
        for s in specs:  # leftovers of an earlier run that was killed
            remove_temp_files(plan.spec.output_dir, s["temp_names"])
        try:
            if executor == "dask":
                interrupted = run_dask(specs, n_jobs, scheduler, emit, results)
            else:
                interrupted = run_local(specs, min(n_jobs, len(specs)), emit, results)
        except KeyboardInterrupt:
            interrupted = True
        for s in specs:
            if s["name"] not in results or results[s["name"]].status != STATUS_OK:
                remove_temp_files(plan.spec.output_dir, s["temp_names"])
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
