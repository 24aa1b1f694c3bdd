"""The child process: runs one item's job and reports to its supervisor.

:func:`child_main` is the entry point of the child (started by :mod:`recon.batch.supervise`); it
reads the item spec, imports and prepares the job (:class:`~recon.batch.protocol.JobRef`), and
reports start, progress and the outcome as frames (:mod:`recon.batch.protocol`). The default
job, :data:`RUN_ITEM`, is :func:`run_item`: the real fit.
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import sys
import threading
import time
import traceback
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from ..config import config_from_dict
from ..errors import LimitExceeded, OpreconError
from ..heap import keep_freed_memory
from ..interrupts import deferred_interrupts
from .protocol import JobRef, read_frame, write_frame
from .summary import metrics_from_report

log = logging.getLogger(__name__)

__all__ = ["RUN_ITEM", "child_main", "prepare_run_item", "run_item"]

#: A child whose stdin closed (stop request, or its parent died) exits after this at the latest [s].
_ORPHAN_EXIT = 15.0
#: ... and sends its main thread the interrupt again at this interval until it is raised [s]: a
#: signal that lands after the interpreter's last check and before a blocking call (a sleep, a
#: wait) starts is handled only when the call returns.
_RESEND_S = 0.25
#: What a timed-out item's message advises (the item's limit is the smaller of the batch's
#: and its configuration's ``dynamics.time_limit``).
TIMEOUT_ADVICE = (
    "raise --item-time-limit or item_time_limit in the batch file, and dynamics.time_limit "
    "where the configuration sets it lower"
)


def run_item(
    spec: Mapping[str, Any], on_progress: Callable[[str, dict[str, Any]], None] | None = None
) -> dict[str, Any]:
    """Fit one item: the job a child process runs.

    Parameters
    ----------
    spec : mapping
        Built by :func:`~recon.batch.run.run_batch`: ``input``, ``config`` (a config dict),
        ``meshes`` (paths, first one written by :func:`recon.fitting.fit_file`),
        ``particles``, ``preview``.
    on_progress : callable(phase, info), optional
        Passed to the pipeline.

    Returns
    -------
    dict
        Summary columns, see :func:`metrics_from_report`.
    """
    from ..fitting import fit_file

    cfg = config_from_dict(spec["config"])
    meshes = [Path(m) for m in spec["meshes"]]
    result = fit_file(
        spec["input"],
        meshes[0],
        cfg,
        particles_path=spec.get("particles"),
        preview_path=spec.get("preview"),
        write_report=True,
        mkdir=True,
        on_progress=on_progress,
        extra_meshes=meshes[1:],
    )
    return metrics_from_report(result.report.to_dict())


def prepare_run_item() -> None:
    """Import the pipeline and compile its kernels before the item's clock starts."""
    from .. import fitting  # noqa: F401
    from ..dynamics import warmup

    try:
        warmup()
    except Exception as exc:  # noqa: BLE001 - the fit itself will report real problems
        log.debug("kernel warm-up failed: %s", exc)


#: The default job: the real fit, prepared by importing and compiling first.
RUN_ITEM = JobRef(f"{__name__}:run_item", prepare=f"{__name__}:prepare_run_item")


def _plain(info: Mapping[str, Any]) -> dict[str, Any]:
    """The scalar entries of a progress ``info``, as plain Python values (cheap to pickle)."""
    out = {}
    for k, v in info.items():
        v = v.item() if hasattr(v, "item") and not isinstance(v, (list, dict)) else v
        if isinstance(v, (int, float, str, bool)) or v is None:
            out[str(k)] = v
    return out


def _interrupt_main_thread() -> None:
    """Raise KeyboardInterrupt in the main thread, even while it sleeps or waits."""
    main = threading.main_thread()
    if hasattr(signal, "pthread_kill") and main.ident is not None:
        signal.pthread_kill(main.ident, signal.SIGINT)
    else:  # pragma: no cover - Windows
        import _thread

        _thread.interrupt_main()


def child_main() -> None:
    """Entry point of the child process (see :func:`recon.batch.supervise.supervise_item`)."""
    proto = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)  # anything written to stdout (C libraries too) goes to the captured stderr
    sys.stdout = sys.stderr
    signal.signal(signal.SIGINT, signal.default_int_handler)
    # (SIGTERM too: within the block it waits, as Ctrl-C does, for a safe point)
    guard = deferred_interrupts(once=True, term=True)

    def on_term(signum: int, frame: Any) -> None:  # outside the guard's block
        if guard.raised.is_set():  # one interrupt: its clean-up runs to the end
            return
        guard.raised.set()  # (watch_stdin repeats an interrupt only while none was raised)
        raise KeyboardInterrupt

    with contextlib.suppress(ValueError, OSError, AttributeError):
        signal.signal(signal.SIGTERM, on_term)
    spec = read_frame(sys.stdin.buffer)
    if spec is None:
        sys.exit(2)
    finished = threading.Event()

    def watch_stdin() -> None:
        # the parent closes our stdin to ask us to stop, or because it died
        with contextlib.suppress(Exception):
            sys.stdin.buffer.read()
        deadline = time.monotonic() + _ORPHAN_EXIT
        sent = False
        while not finished.is_set():
            if time.monotonic() > deadline:
                os._exit(130)  # stuck in native code and nobody left to kill us
            # (again only where the guard raises one interrupt: not on Windows)
            if not guard.raised.is_set() and not (sent and not guard.active):
                _interrupt_main_thread()
                sent = True
            finished.wait(_RESEND_S)

    threading.Thread(target=watch_stdin, daemon=True).start()
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("%(levelname)s %(name)s: %(message)s"))
    root = logging.getLogger("recon")
    root.addHandler(handler)
    root.setLevel(logging.WARNING)

    keep_freed_memory()  # this process runs one item and exits (recon/heap.py)
    t0 = time.perf_counter()

    def on_progress(phase: str, info: dict[str, Any]) -> None:
        write_frame(proto, ("progress", str(phase), _plain(info)))

    try:
        with guard:  # never stop an import, a compile or a k-d tree query half-way
            job, prepare = JobRef.from_spec(spec).load()
            if prepare is not None:  # imports and compilation do not count against the limit
                prepare()
            write_frame(proto, ("start", os.getpid()))
            t0 = time.perf_counter()
            metrics = job(spec, on_progress)
        finished.set()
        write_frame(proto, ("done", dict(metrics or {}), time.perf_counter() - t0))
    except KeyboardInterrupt:
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # a repeated interrupt (watch_stdin) is late
        finished.set()
        with contextlib.suppress(Exception):
            write_frame(proto, ("interrupted", time.perf_counter() - t0))
        sys.exit(130)
    except BaseException as exc:  # noqa: BLE001 - every failure is reported to the parent
        finished.set()
        elapsed = time.perf_counter() - t0
        limit = spec.get("time_limit")
        is_timeout = isinstance(exc, LimitExceeded) and limit is not None and elapsed >= limit
        if is_timeout:  # the batch's own advice: it has no --time-limit
            message, detail = f"time limit of {limit:g} s reached ({TIMEOUT_ADVICE})", ""
        elif isinstance(exc, OpreconError):
            message, detail = str(exc), ""
        else:
            message = f"{type(exc).__name__}: {exc}"
            detail = traceback.format_exc()
        write_frame(proto, ("error", message, detail, is_timeout, elapsed))
        sys.exit(1)
