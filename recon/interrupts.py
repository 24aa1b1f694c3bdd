"""Ctrl-C that never lands where it would crash the process.

A KeyboardInterrupt raised while scipy's ``cKDTree.query(workers=-1)`` waits for its worker
threads frees arrays those threads still write into (a segmentation fault); one raised inside
numba's or llvmlite's compile callbacks, or in the middle of an import, is swallowed or turned
into a ``SystemError``. :class:`deferred_interrupts` holds such an interrupt back and raises it
as soon as the main thread has left the fragile code. Used by the CLI around every command and
by batch worker processes around every item.

:func:`ignore_interrupts_at_exit` covers the interpreter's teardown after a command: Python
puts SIGINT's default action back before it tears the modules down (0.6-0.8 s after a fit's
summary), and a Ctrl-C then killed the process by the signal without a word.
"""

from __future__ import annotations

import atexit
import os
import signal
import threading
import time
from typing import Any

#: Code that must not be interrupted half-way: a module being imported (an extension such as
#: open3d then fails to initialise and its C++ teardown turns exit 130 into 1), and numba's and
#: llvmlite's compile and cache-load callbacks (they swallow or garble a KeyboardInterrupt).
_FRAGILE_DIRS = tuple(f"{os.sep}{name}{os.sep}" for name in ("numba", "llvmlite", "open3d"))
_FRAGILE_FILES = ("<frozen importlib._bootstrap>", "<frozen importlib._bootstrap_external>")


def _is_query_thread(thread: Any) -> bool:
    """A worker of ``cKDTree.query(..., workers=-1)`` (a daemon thread running _thread_func)."""
    return isinstance(thread, threading.Thread) and thread.name.endswith("(_thread_func)")


def _unsafe_to_interrupt(frame: Any) -> bool:
    """Is the main thread importing, inside numba, or starting or waiting for k-d tree workers?

    scipy's ``cKDTree.query(workers=-1)`` hands raw pointers to its output arrays to daemon
    threads and waits for them; a KeyboardInterrupt in that wait frees the arrays while the
    threads still write into them (a segmentation fault).
    """
    outer = frame
    while outer is not None:
        name = outer.f_code.co_filename
        if name in _FRAGILE_FILES or any(d in name for d in _FRAGILE_DIRS):
            return True
        outer = outer.f_back
    for _ in range(8):
        if frame is None or frame.f_code.co_filename != threading.__file__:
            return False
        if _is_query_thread(frame.f_locals.get("self")):
            return True
        frame = frame.f_back
    return False


class deferred_interrupts:  # noqa: N801 - used like a function
    """Within the block, Ctrl-C is raised only where it is safe (see _unsafe_to_interrupt).

    An interrupt that arrives at an unsafe point is retried every 20 ms (SIGALRM) until the
    main thread has left the fragile code. SIGTERM (``timeout``, ``kill``) is treated as Ctrl-C
    when it has its default action, so that temporary files are removed then too, also when
    SIGINT is ignored (a process started in the background of a script: Ctrl-C stays
    ignored). Does nothing outside the main thread, when SIGINT has a custom handler already,
    or without ``setitimer`` (Windows).

    Parameters
    ----------
    once : bool
        Raise one KeyboardInterrupt at most: later interrupts within the block are ignored,
        and SIGINT stays ignored after a block that raised one (the process is on its way
        out), so that a sender which repeats its interrupt (it may have been lost, see
        :func:`recon.batch.worker.child_main`) never breaks the clean-up of the first.
    term : bool
        Treat SIGTERM as Ctrl-C within the block also when it has a handler of its own
        (put back after the block).

    Attributes
    ----------
    raised : threading.Event
        Set just before the block's KeyboardInterrupt is raised.
    active : bool
        Whether the block holds Ctrl-C back (see above): False outside it.
    term_only : bool
        Whether the block holds back SIGTERM only (SIGINT was ignored): False outside it.
    """

    RETRY_S = 0.02

    def __init__(self, once: bool = False, term: bool = False) -> None:
        self.once = once
        self.take_term = term
        self.raised = threading.Event()
        self.active = False

    def __enter__(self) -> deferred_interrupts:
        usable = (
            hasattr(signal, "setitimer") and threading.current_thread() is threading.main_thread()
        )
        sigint = signal.getsignal(signal.SIGINT) if usable else None
        self.active = usable and sigint is signal.default_int_handler
        # started with Ctrl-C ignored (in the background of a script): SIGTERM still cleans up
        self.term_only = usable and sigint == signal.SIG_IGN
        if self.active or self.term_only:
            self.old_term = signal.getsignal(signal.SIGTERM)
            self.term = self.take_term or self.old_term == signal.SIG_DFL
            if self.term_only and not self.term:
                self.term_only = False
                return self
            self.old_alarm = signal.signal(signal.SIGALRM, self._handle)
            if self.active:
                signal.signal(signal.SIGINT, self._handle)
            if self.term:
                signal.signal(signal.SIGTERM, self._handle)
        return self

    def __exit__(self, *exc: object) -> None:
        if self.active or self.term_only:
            signal.setitimer(signal.ITIMER_REAL, 0.0)
            if self.active:
                done = self.once and self.raised.is_set()
                handler = signal.SIG_IGN if done else signal.default_int_handler
                signal.signal(signal.SIGINT, handler)
            signal.signal(signal.SIGALRM, self.old_alarm)
            if self.term:
                signal.signal(signal.SIGTERM, self.old_term)
            self.active = self.term_only = False

    def _handle(self, signum: int, frame: Any) -> None:
        if self.once and self.raised.is_set():
            return
        if _unsafe_to_interrupt(frame):
            signal.setitimer(signal.ITIMER_REAL, self.RETRY_S)
            return
        signal.setitimer(signal.ITIMER_REAL, 0.0)
        self.raised.set()
        raise KeyboardInterrupt


def wait_for_query_threads(timeout: float = 10.0) -> None:
    """Let the workers of an interrupted k-d tree query finish before the interpreter exits.

    A last line of defence behind :class:`deferred_interrupts`: an interpreter shutting down
    under running daemon threads can crash. A thread that was started but has not run yet
    (still in ``threading``'s limbo) cannot be joined; it is polled until it can.
    """
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        pending = [t for t in threading.enumerate() if _is_query_thread(t) and t.daemon]
        if not pending:
            return
        for thread in pending:
            try:
                thread.join(max(0.0, deadline - time.monotonic()))
            except RuntimeError:  # started, not yet running
                time.sleep(0.005)


_exit_hook_registered = False


def _ignore_late_interrupts() -> None:
    """The ``atexit`` hook of :func:`ignore_interrupts_at_exit`."""
    if threading.current_thread() is not threading.main_thread():
        return
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if signal.getsignal(signal.SIGTERM) == signal.SIG_DFL:
        signal.signal(signal.SIGTERM, signal.SIG_IGN)


def ignore_interrupts_at_exit() -> None:
    """Ignore Ctrl-C (and SIGTERM with its default action) once the interpreter exits.

    The ``atexit`` hooks run before Python tears the modules down, and that teardown puts the
    default action of SIGINT back (SIG_IGN it leaves alone): an interrupt then ended the
    process by the signal, without a message, after the command had finished and said how (its
    outputs written and its summary printed, or its error or interrupt reported and its
    temporaries removed). From the hook on, the exit code is the command's. Registered once
    per process; a process that goes on running (a test runner) is not affected until it exits.
    """
    global _exit_hook_registered
    if not _exit_hook_registered:
        atexit.register(_ignore_late_interrupts)
        _exit_hook_registered = True
