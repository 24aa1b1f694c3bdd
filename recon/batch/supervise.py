"""The supervisor: runs one item in a child process and enforces its time limit.

The time limit is enforced twice: cooperatively through ``dynamics.time_limit`` (the fit stops
itself), and by killing the child when it overruns the limit by a grace period
(:func:`kill_grace_for`). A killed child's temporary files are removed
(:func:`recon.batch.outputs.remove_temp_files`). :func:`supervise_item` runs in a thread of
this process (executor ``"local"``) or as a task on a Dask worker (``"dask"``), so results,
summary and resume behave the same in both.
"""

from __future__ import annotations

import contextlib
import logging
import os
import queue
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from ..errors import OpreconError
from .outputs import remove_temp_files
from .protocol import read_frame, write_frame
from .resume import write_record
from .summary import (
    STATUS_FAILED,
    STATUS_INTERRUPTED,
    STATUS_OK,
    STATUS_TIMEOUT,
    BatchEvent,
    EventFn,
    ItemResult,
)

log = logging.getLogger(__name__)

__all__ = ["POLL", "STOP_GRACE", "child_command", "kill_grace_for", "supervise_item"]

#: Time for a child process to import the pipeline and report that it started [s].
_STARTUP_TIMEOUT = 600.0
#: After a stop request, time a child gets to clean up before it is killed [s].
STOP_GRACE = 5.0
#: How often a supervisor checks its child, and an executor its supervisors [s].
POLL = 0.2


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


def _signal_text(code: int | None) -> str:
    """How a process ended, from its return code."""
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
    """The last non-empty lines of a captured stderr, on one line."""
    try:
        fh.seek(0)
        text = fh.read().decode("utf-8", "replace")
    except (OSError, ValueError):
        return ""
    lines = [ln for ln in text.strip().splitlines() if ln.strip()]
    return " | ".join(lines[-n_lines:])[-n_chars:]


def child_command() -> list[str]:
    """The command line that starts a child process (:func:`recon.batch.worker.child_main`)."""
    root = str(Path(__file__).resolve().parents[2])
    code = (
        "import sys; sys.path[:] = [p for p in sys.path if p not in ('', '.')]; "
        f"r = {root!r}; r in sys.path or sys.path.insert(0, r); "
        "from recon.batch.worker import child_main; child_main()"
    )
    return [sys.executable, "-c", code]


#: The variables that set a child's threads (numba's pool, GNU OpenMP, OpenBLAS, MKL).
THREAD_ENV = ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


def _child_env(threads: int | None, force: bool = False) -> dict[str, str]:
    """This environment, with ``threads`` threads for numba, OpenMP and BLAS.

    Variables already set here are kept unless ``force`` (the user asked for ``threads``).
    """
    env = dict(os.environ)
    if threads:
        for var in THREAD_ENV:
            if force:
                env[var] = str(threads)
            else:
                env.setdefault(var, str(threads))
    env.setdefault("PYTHONUNBUFFERED", "1")
    return env


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
        Built by :func:`~recon.batch.run.run_batch`: ``name``, ``input``, ``output_dir``,
        ``config``, ``meshes``, ``products``, ``state``, ``temp_names``, ``fingerprint``,
        ``time_limit`` [s] or None, ``kill_grace`` [s], ``job``, ``job_path`` and
        ``job_prepare`` (a :class:`~recon.batch.protocol.JobRef`), ``threads`` and
        ``threads_given`` (see :func:`_child_env`).
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
            child_command(),
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=stderr_file,
            env=_child_env(spec.get("threads"), bool(spec.get("threads_given"))),
            close_fds=True,
            # a batch that ignores Ctrl-C (started with `&` in a script) keeps its items out of
            # its process group: a child puts its own SIGINT handler back (the stop request
            # arrives as one), so a Ctrl-C to the group would interrupt the running item
            **_own_group_when_deaf(),
        )
    except OSError as exc:
        stderr_file.close()
        return result(STATUS_FAILED, error=f"cannot start a worker process: {exc}")
    messages: queue.Queue[Any] = queue.Queue()

    def read() -> None:
        while True:
            try:
                msg = read_frame(proc.stdout)
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
            write_frame(proc.stdin, dict(spec))
        except OSError:
            pass  # it died at once; the reader reports EOF
        while outcome is None and metrics is None:
            try:
                msg = messages.get(timeout=POLL)
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
                deadline = min(deadline, now + STOP_GRACE)
                started = started if started is not None else now
    finally:
        _end_process(proc)
        reader.join(timeout=5)
        stderr_file.close()
        remove_temp_files(folder, spec.get("temp_names", ()), proc.pid)
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
        write_record(
            Path(spec["state"]), spec["name"], spec["fingerprint"], spec["products"], metrics
        )
    except OpreconError as exc:
        return result(STATUS_FAILED, time_s=time_s, error=f"cannot write the batch record: {exc}")
    known = {k: metrics.get(k) for k in ("particles", "faces", "coverage", "fidelity_mean")}
    return result(STATUS_OK, time_s=time_s, outputs=list(spec["products"]), **known)


def _since(t: float | None) -> float | None:
    """Seconds since the monotonic time ``t`` (rounded), or None."""
    return None if t is None else round(time.monotonic() - t, 3)


def _own_group_when_deaf() -> dict[str, Any]:
    """``Popen`` arguments that start the child in its own process group when this process
    ignores SIGINT (nothing otherwise): it is then stopped through its stdin or killed, as
    always, and a Ctrl-C to this process's group passes it by, as it passes this one."""
    if os.name != "posix" or signal.getsignal(signal.SIGINT) is not signal.SIG_IGN:
        return {}
    return {"start_new_session": True}


def _end_process(proc: subprocess.Popen) -> None:
    """Close the child's stdin, give it a moment to exit, then kill it."""
    with contextlib.suppress(OSError):
        if proc.stdin is not None:
            proc.stdin.close()
    try:
        proc.wait(timeout=STOP_GRACE if proc.poll() is None else 1)
    except subprocess.TimeoutExpired:
        proc.kill()
        with contextlib.suppress(subprocess.TimeoutExpired):
            proc.wait(timeout=10)
    with contextlib.suppress(OSError):
        if proc.stdout is not None:
            proc.stdout.close()
