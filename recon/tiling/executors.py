"""Where the tiles run: a local process pool (``--jobs``) or a Dask cluster (``--executor dask``,
a LocalCluster started here or a running scheduler), the executors of ``oprecon batch``.

:func:`run_tasks` submits one task per tile (a few per job at a time), retries a failed task
once, reports tiles done and in flight, and raises :class:`TileError` naming the tiles that
failed twice with their bounds. A task that runs past its time budget is taken for stuck (a
worker short of memory can spin without end inside OpenBLAS's allocator): its worker is
stopped and the task counts as failed.
Ctrl-C cancels the tasks and stops the worker processes before it propagates; the workers of a
coordinator that dies without cleaning up (killed) die with it (Linux).
"""

from __future__ import annotations

import contextlib
import ctypes
import logging
import multiprocessing
import os
import signal
import sys
import threading
import time
import traceback
from collections.abc import Callable, Iterable, Iterator, Mapping
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor
from concurrent.futures import wait as wait_futures
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from typing import Any

from ..batch.executors import dask_client, default_jobs
from ..errors import LimitExceeded, OpreconError

log = logging.getLogger(__name__)

__all__ = [
    "EXECUTORS",
    "LazyTasks",
    "TileError",
    "TileEvent",
    "TileRunner",
    "TileStuck",
    "held_records",
    "run_tasks",
    "tile_runner",
]

EXECUTORS = ("local", "dask")
#: Seconds at most between looks at the running tasks (one finishing ends the wait).
POLL = 0.1
#: Tasks submitted at a time per job (one running, one queued behind it).
IN_FLIGHT_PER_JOB = 2


class TileStuck(RuntimeError):
    """A tile's task ran past its time budget and was stopped."""


class TileError(OpreconError):
    """Tiles failed twice; ``exit_code`` is 2 when every failure was an input problem (an
    :class:`OpreconError` in the tile), else 1."""

    def __init__(self, message: str, exit_code: int) -> None:
        super().__init__(message)
        self.exit_code = exit_code


@dataclass(frozen=True)
class TileEvent:
    """Progress of a phase: ``done`` of ``total`` tiles finished, ``in_flight`` running."""

    phase: str
    done: int
    in_flight: int
    total: int
    message: str = ""


class TileRunner:
    """Submits functions to a process pool or a Dask client, and knows when each started."""

    def __init__(self, kind: str, jobs: int, client: Any = None) -> None:
        self.kind = kind
        self.jobs = jobs
        self.client = client
        self.pools: list[ProcessPoolExecutor] = []
        self.finished = threading.Event()  # a Dask task finished
        self._count = 0  # tasks submitted
        self._ids: dict[Any, int] = {}  # future -> its number
        self._starts: dict[int, float] = {}  # number -> time.monotonic() when it started
        self._announced: Any = None  # the current pool's workers put started numbers here
        if client is None:
            self._new_pool()

    def _new_pool(self) -> ProcessPoolExecutor:
        ctx = multiprocessing.get_context("spawn")  # numba/OpenMP state does not survive fork
        # (a new queue for each pool: a worker stopped half-way through a put holds its lock)
        self._announced = ctx.SimpleQueue()
        # a child dies with the thread that started it: only the main thread's are bound so
        main = threading.current_thread() is threading.main_thread()
        pool = ProcessPoolExecutor(
            max_workers=self.jobs,
            mp_context=ctx,
            initializer=_init_worker,
            initargs=(self._announced, os.getpid() if main else None),
        )
        self.pools.append(pool)
        return pool

    def submit(self, fn: Callable[..., Any], *args: Any) -> Any:
        self._count += 1
        if self.client is not None:
            future = self.client.submit(fn, *args, pure=False)
            future.add_done_callback(lambda _: self.finished.set())
            # (a Dask task's start is not seen here: its budget counts from its submission)
            self._starts[self._count] = time.monotonic()
        else:
            try:
                future = self.pools[-1].submit(_announce, self._count, fn, args)
            except BrokenProcessPool:  # a worker died (killed, out of memory): start new ones
                self._close_pool(self.pools[-1])
                future = self._new_pool().submit(_announce, self._count, fn, args)
        self._ids[future] = self._count
        return future

    def started(self, future: Any) -> float | None:
        """``time.monotonic()`` when the task of ``future`` started (None: not yet)."""
        if self.client is None:
            with contextlib.suppress(OSError, EOFError, ValueError):
                while not self._announced.empty():
                    self._starts[self._announced.get()] = time.monotonic()
        return self._starts.get(self._ids.get(future, -1))

    def forget(self, future: Any) -> None:
        """Drop what is known of a future that was handled."""
        self._starts.pop(self._ids.pop(future, -1), None)

    def stop(self, stuck: list[Any], in_flight: list[Any]) -> list[Any]:
        """Stop the tasks of ``stuck``; returns the futures of ``in_flight`` that were lost
        with them. A process pool's workers are all stopped (a pool with a killed worker is
        broken) and new ones started: every task in flight is lost. A Dask task is
        cancelled (its worker thread cannot be stopped and runs on)."""
        if self.client is not None:
            self.cancel(stuck)
            return list(stuck)
        self._close_pool(self.pools[-1])
        self._new_pool()
        return list(in_flight)

    def wait(self, futures: list[Any], timeout: float) -> None:
        """Return when one of ``futures`` is done, or after ``timeout`` seconds."""
        if self.client is None:
            wait_futures(futures, timeout=timeout, return_when=FIRST_COMPLETED)
            return
        self.finished.wait(timeout)  # set by a task that finished (also before this call)
        self.finished.clear()

    @staticmethod
    def _close_pool(pool: ProcessPoolExecutor) -> None:
        """Stop a pool's worker processes now (they ignore Ctrl-C; see ``_init_worker``)."""
        processes = list((getattr(pool, "_processes", None) or {}).values())
        pool.shutdown(wait=False, cancel_futures=True)
        for p in processes:
            with contextlib.suppress(Exception):
                if p.is_alive():
                    p.terminate()
        for p in processes:
            with contextlib.suppress(Exception):
                p.join(5)
                if p.is_alive():  # SIGTERM did not end it
                    p.kill()
                    p.join(5)

    def close(self) -> None:
        for pool in self.pools:
            self._close_pool(pool)

    def cancel(self, futures: list[Any]) -> None:
        for f in futures:
            with contextlib.suppress(Exception):
                f.cancel()


#: In a worker: where it announces the number of each task it starts (see TileRunner.started).
_ANNOUNCED: Any = None
#: prctl(2)'s option: the signal a process gets when the thread that started it ends.
_PR_SET_PDEATHSIG = 1


def _init_worker(announced: Any, parent: int | None) -> None:  # pragma: no cover - in workers
    """Workers leave Ctrl-C to the coordinator, which stops them, die with the coordinator
    when ``parent`` (its pid) is given and the platform can (Linux), and, like ``oprecon``,
    keep numba's notice about an old TBB off stderr."""
    import warnings

    global _ANNOUNCED
    _ANNOUNCED = announced
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    warnings.filterwarnings("ignore", message="The TBB threading layer requires")
    if parent is not None and sys.platform.startswith("linux"):
        with contextlib.suppress(OSError, AttributeError):
            ctypes.CDLL(None).prctl(_PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
        if os.getppid() != parent:  # the coordinator died before the line above
            os._exit(1)


def _announce(number: int, fn: Callable[..., Any], args: tuple) -> Any:  # pragma: no cover
    """Run ``fn(*args)`` in a worker, first telling the coordinator that task ``number``
    started (a plain pipe write: it is out before the task can hang)."""
    _ANNOUNCED.put(number)
    return fn(*args)


@contextlib.contextmanager
def tile_runner(kind: str, jobs: int | None, scheduler: str | None = None) -> Iterator[TileRunner]:
    """A :class:`TileRunner` for ``kind`` (``local`` or ``dask``), closed (workers stopped) on
    exit, also on Ctrl-C."""
    if kind not in EXECUTORS:
        raise OpreconError(f"executor: expected one of {', '.join(EXECUTORS)}, got {kind!r}")
    jobs = int(jobs) if jobs else default_jobs()
    if kind == "local":
        runner = TileRunner(kind, jobs)
        try:
            yield runner
        finally:
            runner.close()
        return
    with dask_client(scheduler, jobs) as (client, versions):
        yield TileRunner(kind, max(1, len(versions)) if scheduler else jobs, client=client)


def run_tasks(
    runner: TileRunner,
    phase: str,
    tasks: Mapping[int, tuple[Callable[..., Any], tuple[Any, ...]]],
    describe: Callable[[int], str],
    on_event: Callable[[TileEvent], None] | None = None,
    on_result: Callable[[int, Any], None] | None = None,
    deadline: tuple[float, float] | None = None,
    budget: Callable[[int], float] | None = None,
) -> dict[int, Any]:
    """Run ``tasks`` (tile -> (function, args)); a task that fails is run once more.

    ``deadline``: (start, limit) in ``time.perf_counter`` seconds: past ``start + limit`` the
    tasks in flight are cancelled and :class:`~recon.errors.LimitExceeded` is raised (the
    whole tiled fit's ``dynamics.time_limit``; each tile's own fit has it too, and a tile
    past it was retried, so the run went on well past the limit).

    ``budget(tile)``: the seconds a tile's task may run (from its start on a process pool,
    from its submission on Dask). A task past it is stopped (:meth:`TileRunner.stop`) and
    fails with :class:`TileStuck`; the other tasks lost with it run again, not counted as
    failures.

    At most :data:`IN_FLIGHT_PER_JOB` tasks per job are submitted at a time, the next as one
    finishes, and a finished task's future is dropped once its result is handled, so what
    the coordinator (and a LocalCluster's scheduler in it) holds does not grow with the tile
    count. ``tasks[tile]`` is looked up when the tile is submitted (a mapping may build the
    job then: :class:`LazyTasks`). With ``on_result``, each result is handed to it as it
    arrives and not kept (the returned dict is empty); else the results are returned.

    Raises
    ------
    TileError
        Some tiles failed twice (the message lists each with its bounds and error).
    """
    emit = on_event or (lambda e: None)
    total = len(tasks)
    window = max(1, IN_FLIGHT_PER_JOB * int(runner.jobs))
    pending = iter(tasks)
    retried: set[int] = set()  # tiles run a second time
    futures: dict[Any, int] = {}
    limits: dict[Any, float] = {}  # future -> its task's budget [s]
    results: dict[int, Any] = {}
    failed: dict[int, BaseException] = {}
    finished = 0

    def submit(tile: int) -> None:
        fn, args = tasks[tile]
        future = runner.submit(fn, *args)
        futures[future] = tile
        if budget is not None:
            limits[future] = float(budget(tile))

    def fill() -> None:
        while len(futures) < window:
            tile = next(pending, None)
            if tile is None:
                return
            submit(tile)

    forget = getattr(runner, "forget", lambda f: None)  # (the tests' thread runners)

    def handled(f: Any) -> int:
        limits.pop(f, None)
        forget(f)
        return futures.pop(f)

    def retry(tile: int, exc: BaseException) -> bool:
        """Run a failed tile again if it has not been; False: it failed twice."""
        log.debug(
            "%s failed: %s",
            describe(tile),
            "".join(traceback.format_exception(type(exc), exc, exc.__traceback__)),
        )
        if tile in retried:
            failed[tile] = exc
            return False
        retried.add(tile)
        message = f"{describe(tile)} failed ({_short(exc)}); retrying"
        emit(TileEvent(phase, finished, min(runner.jobs, len(futures) + 1), total, message))
        submit(tile)
        return True

    def stuck() -> list[Any]:
        now = time.monotonic()
        out = []
        for f in futures:
            start = runner.started(f)
            if start is not None and now - start > limits[f] and not f.done():
                out.append(f)
        return out

    try:
        fill()
        emit(TileEvent(phase, 0, min(runner.jobs, total), total))
        while futures:
            if deadline is not None and time.perf_counter() - deadline[0] > deadline[1]:
                raise LimitExceeded(
                    f"time limit of {deadline[1]:g} s reached in the {phase} phase of the tiled "
                    "fit (raise dynamics.time_limit or --time-limit)"
                )
            over = stuck() if budget is not None else []
            if over:
                late = {f: limits[f] for f in over}
                for f in runner.stop(over, list(futures)):
                    tile = handled(f)
                    if f not in late:  # lost with a stuck task: not its failure
                        submit(tile)
                        continue
                    exc = TileStuck(
                        f"ran longer than {late[f]:.0f} s and was taken for stuck (if it was "
                        "only slow, raise tiling.task_time_limit)"
                    )
                    if not retry(tile, exc):
                        finished += 1
                fill()
                emit(TileEvent(phase, finished, min(runner.jobs, len(futures)), total))
                continue
            done = [f for f in futures if f.done()]
            if not done:
                runner.wait(list(futures), POLL)
                continue
            for f in done:
                tile = handled(f)
                try:
                    result = f.result()
                except Exception as exc:  # noqa: BLE001 - a tile's failure is reported below
                    if retry(tile, exc):
                        continue
                else:
                    if on_result is None:
                        results[tile] = result
                    else:
                        on_result(tile, result)
                    del result
                finished += 1
                fill()
                emit(TileEvent(phase, finished, min(runner.jobs, len(futures)), total))
            del done, f
    except BaseException:
        runner.cancel(list(futures))
        raise
    if failed:
        lines = [f"{describe(t)}: {_short(e)}" for t, e in sorted(failed.items())]
        code = 2 if all(isinstance(e, OpreconError) for e in failed.values()) else 1
        raise TileError(
            f"{len(failed)} of {total} tile(s) failed twice in the {phase} phase: "
            + "; ".join(lines),
            code,
        )
    return results


def held_records(runner: TileRunner) -> dict[str, int]:
    """The records of tasks this process holds on a Dask runner (empty for local
    processes): the client's futures and recent messages and, when the scheduler runs
    here (a LocalCluster), its task states, transition log, events, past computations and
    the recent messages of its connections. Each is bounded (see
    :data:`recon.batch.executors.DASK_RECORDS`), none grows with the task count, except
    ``key_names``: Dask's own cache of every task key's name (``dask.utils.key_split``, at
    most 100,000 entries, a few hundred bytes each)."""
    client = runner.client
    if client is None:
        return {}
    from dask.utils import key_split

    out = {"futures": len(client.futures), "key_names": key_split.cache_info().currsize}
    comm = getattr(client, "scheduler_comm", None)
    out["client_messages"] = len(getattr(comm, "recent_message_log", ()))
    scheduler = getattr(getattr(client, "cluster", None), "scheduler", None)
    if scheduler is not None:
        comms = [*scheduler.stream_comms.values(), *scheduler.client_comms.values()]
        out.update(
            tasks=len(scheduler.tasks),
            transition_log=len(scheduler.transition_log),
            events=sum(len(e) for e in scheduler.get_events().values()),
            computations=len(scheduler.computations),
            scheduler_messages=sum(len(c.recent_message_log) for c in comms),
        )
    return out


class LazyTasks(Mapping):
    """tile -> (function, args) for :func:`run_tasks`, each built by ``make(tile)`` when the
    tile is submitted, so that the jobs of every tile are never held at once."""

    def __init__(
        self, tiles: Iterable[int], make: Callable[[int], tuple[Callable[..., Any], tuple]]
    ) -> None:
        self.tiles = list(tiles)
        self.make = make

    def __getitem__(self, tile: int) -> tuple[Callable[..., Any], tuple]:
        return self.make(tile)

    def __iter__(self) -> Iterator[int]:
        return iter(self.tiles)

    def __len__(self) -> int:
        return len(self.tiles)


def _short(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0] if text else ''}".rstrip(": ")
