"""Where the tiles run: a local process pool (``--jobs``) or a Dask cluster (``--executor dask``,
a LocalCluster started here or a running scheduler), the executors of ``oprecon batch``.

:func:`run_tasks` submits one task per tile (a few per job at a time), retries a failed task
once, reports tiles done and in flight, and raises :class:`TileError` naming the tiles that
failed twice with their bounds.
Ctrl-C cancels the tasks and stops the worker processes before it propagates.
"""

from __future__ import annotations

import contextlib
import logging
import multiprocessing
import signal
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
    "held_records",
    "run_tasks",
    "tile_runner",
]

EXECUTORS = ("local", "dask")
#: Seconds at most between looks at the running tasks (one finishing ends the wait).
POLL = 0.1
#: Tasks submitted at a time per job (one running, one queued behind it).
IN_FLIGHT_PER_JOB = 2


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
    """Submits functions to a process pool or a Dask client."""

    def __init__(self, kind: str, jobs: int, client: Any = None) -> None:
        self.kind = kind
        self.jobs = jobs
        self.client = client
        self.pools: list[ProcessPoolExecutor] = []
        self.finished = threading.Event()  # a Dask task finished
        if client is None:
            self._new_pool()

    def _new_pool(self) -> ProcessPoolExecutor:
        ctx = multiprocessing.get_context("spawn")  # numba/OpenMP state does not survive fork
        pool = ProcessPoolExecutor(
            max_workers=self.jobs, mp_context=ctx, initializer=_ignore_sigint
        )
        self.pools.append(pool)
        return pool

    def submit(self, fn: Callable[..., Any], *args: Any) -> Any:
        if self.client is not None:
            future = self.client.submit(fn, *args, pure=False)
            future.add_done_callback(lambda _: self.finished.set())
            return future
        try:
            return self.pools[-1].submit(fn, *args)
        except BrokenProcessPool:  # a worker died (killed, out of memory): start new ones
            self._close_pool(self.pools[-1])
            return self._new_pool().submit(fn, *args)

    def wait(self, futures: list[Any], timeout: float) -> None:
        """Return when one of ``futures`` is done, or after ``timeout`` seconds."""
        if self.client is None:
            wait_futures(futures, timeout=timeout, return_when=FIRST_COMPLETED)
            return
        self.finished.wait(timeout)  # set by a task that finished (also before this call)
        self.finished.clear()

    @staticmethod
    def _close_pool(pool: ProcessPoolExecutor) -> None:
        """Stop a pool's worker processes now (they ignore Ctrl-C; see ``_ignore_sigint``)."""
        processes = list((getattr(pool, "_processes", None) or {}).values())
        pool.shutdown(wait=False, cancel_futures=True)
        for p in processes:
            with contextlib.suppress(Exception):
                if p.is_alive():
                    p.terminate()
        for p in processes:
            with contextlib.suppress(Exception):
                p.join(5)

    def close(self) -> None:
        for pool in self.pools:
            self._close_pool(pool)

    def cancel(self, futures: list[Any]) -> None:
        for f in futures:
            with contextlib.suppress(Exception):
                f.cancel()


def _ignore_sigint() -> None:  # pragma: no cover - runs in the workers
    """Workers leave Ctrl-C to the coordinator, which stops them (and, like ``oprecon``,
    keep numba's notice about an old TBB off stderr)."""
    import warnings

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    warnings.filterwarnings("ignore", message="The TBB threading layer requires")


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
) -> dict[int, Any]:
    """Run ``tasks`` (tile -> (function, args)); a task that fails is run once more.

    ``deadline``: (start, limit) in ``time.perf_counter`` seconds: past ``start + limit`` the
    tasks in flight are cancelled and :class:`~recon.errors.LimitExceeded` is raised (the
    whole tiled fit's ``dynamics.time_limit``; each tile's own fit has it too, and a tile
    past it was retried, so the run went on well past the limit).

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
    results: dict[int, Any] = {}
    failed: dict[int, BaseException] = {}
    finished = 0

    def submit(tile: int) -> None:
        fn, args = tasks[tile]
        futures[runner.submit(fn, *args)] = tile

    def fill() -> None:
        while len(futures) < window:
            tile = next(pending, None)
            if tile is None:
                return
            submit(tile)

    try:
        fill()
        emit(TileEvent(phase, 0, min(runner.jobs, total), total))
        while futures:
            if deadline is not None and time.perf_counter() - deadline[0] > deadline[1]:
                raise LimitExceeded(
                    f"time limit of {deadline[1]:g} s reached in the {phase} phase of the tiled "
                    "fit (raise dynamics.time_limit or --time-limit)"
                )
            done = [f for f in futures if f.done()]
            if not done:
                runner.wait(list(futures), POLL)
                continue
            for f in done:
                tile = futures.pop(f)
                try:
                    result = f.result()
                except Exception as exc:  # noqa: BLE001 - a tile's failure is reported below
                    log.debug(
                        "%s failed: %s",
                        describe(tile),
                        "".join(traceback.format_exception(type(exc), exc, exc.__traceback__)),
                    )
                    if tile not in retried:
                        retried.add(tile)
                        emit(
                            TileEvent(
                                phase,
                                finished,
                                min(runner.jobs, len(futures) + 1),
                                total,
                                f"{describe(tile)} failed ({_short(exc)}); retrying",
                            )
                        )
                        submit(tile)
                        continue
                    failed[tile] = exc
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
