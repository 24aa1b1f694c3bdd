"""Executors: where the supervisors of a batch run.

``"local"``: a pool of supervisor threads in this process, each watching one child process at a
time. ``"dask"``: each supervisor is a task on a Dask cluster (a LocalCluster started here, or a
running scheduler), stopped through a cluster-wide event on Ctrl-C. Both run the same
:func:`recon.batch.supervise.supervise_item` and fill the same ``results`` mapping.

References
----------
[Dask] Dask distributed documentation, "Futures" and "LocalCluster".
       https://distributed.dask.org/
"""

from __future__ import annotations

import contextlib
import logging
import os
import queue
import signal
import threading
import time
import traceback
import uuid
from collections.abc import Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, ThreadPoolExecutor, wait
from typing import Any

from ..errors import OpreconError
from ..version import __version__
from .summary import STATUS_FAILED, STATUS_INTERRUPTED, BatchEvent, EventFn, ItemResult
from .supervise import POLL, STOP_GRACE, supervise_item

log = logging.getLogger(__name__)

__all__ = [
    "DASK_MISSING",
    "DASK_RECORDS",
    "default_jobs",
    "import_dask",
    "run_dask",
    "run_local",
]

DASK_MISSING = 'the dask executor needs the optional dependency: pip install "oprecon[distributed]"'

#: How many records of finished tasks the Dask scheduler and client keep, set for the
#: client and the LocalCluster started here (a running scheduler keeps its own settings).
#: ``low-level-log-length`` bounds the scheduler's transition log, its event topics and
#: every connection's recent messages (default 1000 each); ``computations.max-history``
#: the past computations with their task groups (default 100). At the defaults these held
#: about 15 MiB after 2,000 tiny tasks in the coordinating process; see ``bench_tiles.py
#: tasks`` and docs/large-scans.md, "Dask's records of finished tasks".
DASK_RECORDS = {
    "distributed.admin.low-level-log-length": 100,
    "distributed.diagnostics.computations.max-history": 10,
}


def default_jobs() -> int:
    """Number of usable cores."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


def run_local(
    specs: list[dict[str, Any]], jobs: int, emit: EventFn, results: dict[str, ItemResult]
) -> bool:
    """Run the items on ``jobs`` supervisor threads in this process.

    Parameters
    ----------
    specs : list of dict
        Item specs (see :func:`recon.batch.supervise.supervise_item`).
    jobs : int
        Items at a time.
    emit : callable(BatchEvent)
        Receives start, progress and finish events, from this thread.
    results : dict
        Filled with an :class:`ItemResult` per item name (also for interrupted items).

    Returns
    -------
    bool
        True when Ctrl-C stopped the run (every child was stopped before returning).
    """
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
            done, pending = wait(pending, timeout=POLL, return_when=FIRST_COMPLETED)
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
                done, pending = wait(pending, timeout=POLL, return_when=FIRST_COMPLETED)
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
    """The input of the item called ``name``."""
    return next((s["input"] for s in specs if s["name"] == name), "")


def check_scheduler_address(address: str) -> None:
    """Refuse a Dask scheduler address a client cannot dial (``notaurl``: no port) before a
    client is made: Dask's own ``ValueError`` came with a traceback, and the half-made
    client then waited 40 s to close.

    Raises
    ------
    OpreconError
        The address has no port, or is not an address at all.
    """
    from distributed.comm.addressing import get_address_host_port, parse_address

    try:
        protocol, _ = parse_address(address)
        if protocol in ("tcp", "tls", "ws", "wss"):
            get_address_host_port(address)
    except ValueError as exc:
        raise OpreconError(
            f"--scheduler {address!r}: not a Dask scheduler address ({exc}); give HOST:PORT "
            "or tcp://HOST:PORT, e.g. tcp://10.0.0.5:8786"
        ) from None


@contextlib.contextmanager
def dask_client(scheduler: str | None, jobs: int) -> Iterator[tuple[Any, dict[str, str]]]:
    """A Dask client, on the running ``scheduler`` or on a LocalCluster of ``jobs``
    single-threaded worker processes (started ignoring Ctrl-C, which the caller handles), with
    every worker checked to run this oprecon version. Client and cluster close on exit.
    Both keep :data:`DASK_RECORDS` records of finished tasks.

    Yields
    ------
    client, versions
        ``versions``: worker address -> its oprecon version (empty: no worker has joined yet).

    Raises
    ------
    OpreconError
        Dask missing or unreachable, or its workers run another oprecon version.
    """
    dd = import_dask()
    import dask

    cluster = None
    client = None
    with dask.config.set(DASK_RECORDS):  # read when the scheduler and the comms start
        try:
            if scheduler:
                check_scheduler_address(scheduler)
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
                        # its HTTP server (health, metrics) on a free local port, not 8787:
                        # a second cluster at the same time warned that 8787 was taken
                        scheduler_kwargs={"dashboard_address": "127.0.0.1:0"},
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
            yield client, versions
        finally:
            for obj in (client, cluster):
                with contextlib.suppress(Exception):
                    if obj is not None:
                        obj.close()


def _worker_version() -> str:
    """The oprecon version a Dask worker imports."""
    from recon.version import __version__ as version

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


def import_dask() -> Any:
    """``dask.distributed``, or an :class:`OpreconError` with the install hint."""
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


def run_dask(
    specs: list[dict[str, Any]],
    jobs: int,
    scheduler: str | None,
    emit: EventFn,
    results: dict[str, ItemResult],
) -> bool:
    """Run the items as supervisor tasks on a Dask cluster.

    Parameters
    ----------
    specs, emit, results
        As for :func:`run_local` (only finish events are emitted).
    jobs : int
        Workers of the LocalCluster started when no ``scheduler`` is given.
    scheduler : str or None
        Address of a running scheduler.

    Returns
    -------
    bool
        True when Ctrl-C stopped the run.

    Raises
    ------
    OpreconError
        Dask missing or unreachable, or its workers run another oprecon version.
    """
    dd = import_dask()
    stack = contextlib.ExitStack()
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
        client, versions = stack.enter_context(dask_client(scheduler, jobs))
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
            until = time.monotonic() + STOP_GRACE + 5
            with contextlib.suppress(KeyboardInterrupt):
                while time.monotonic() < until and not all(f.done() for f in remaining):
                    time.sleep(POLL)
            for fut in remaining:
                if fut.done() and fut.status == "finished":
                    record(fut)
    finally:
        with _quiet_loggers(("distributed", "tornado"), active=interrupted):
            with contextlib.suppress(Exception):
                if client is not None and futures:
                    client.cancel([f for f in futures if futures[f] not in results])
            stack.close()
    return interrupted
