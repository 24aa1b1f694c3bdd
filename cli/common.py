"""Shared pieces of the CLI: error handling, logging, configuration options."""

from __future__ import annotations

import functools
import logging
import os
import signal
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import click

from recon.config import ReconConfig, load_config
from recon.errors import OpreconError

EXIT_OK = 0
EXIT_CHECK_FAILED = 1
EXIT_BAD_INPUT = 2
EXIT_INTERRUPTED = 130

PRESET_DIR = Path(__file__).resolve().parent.parent / "configs"


def fail(message: str, code: int = EXIT_BAD_INPUT) -> None:
    """Print ``oprecon: error: message`` on stderr and exit with ``code``."""
    click.echo(f"oprecon: error: {message}", err=True)
    sys.exit(code)


def setup_logging(quiet: bool = False, verbose: bool = False) -> None:
    level = logging.WARNING if quiet else (logging.DEBUG if verbose else logging.INFO)
    root = logging.getLogger("recon")
    root.handlers.clear()
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("%(message)s"))
    root.addHandler(handler)
    root.setLevel(level)
    root.propagate = False


def available_presets() -> list[str]:
    return sorted(p.stem for p in PRESET_DIR.glob("*.yaml")) if PRESET_DIR.is_dir() else []


def resolve_preset(name: str) -> Path:
    path = PRESET_DIR / f"{name}.yaml"
    if not path.is_file():
        names = ", ".join(available_presets()) or "none installed"
        raise OpreconError(f"unknown preset '{name}' (available: {names})")
    return path


def config_options(func: Callable[..., Any]) -> Callable[..., Any]:
    """``--config``, ``--preset`` and ``--set`` for commands that take a pipeline config."""

    @click.option(
        "--config",
        "config_path",
        type=click.Path(dir_okay=False, path_type=Path),
        help="YAML configuration file (see `oprecon config show`).",
    )
    @click.option("--preset", help="Named preset from configs/, e.g. open_scan, sparse, noisy.")
    @click.option(
        "--set",
        "overrides",
        multiple=True,
        metavar="SECTION.KEY=VALUE",
        help="Override one key, e.g. --set dynamics.dt=0.1 (repeatable).",
    )
    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        return func(*args, **kwargs)

    return wrapper


def build_config(
    config_path: Path | None, preset: str | None, overrides: tuple[str, ...] = ()
) -> ReconConfig:
    """Defaults < preset/config file < --set overrides. CLI options are applied by the caller."""
    if config_path is not None and preset is not None:
        raise click.UsageError("--config and --preset are exclusive; give one")
    path = resolve_preset(preset) if preset is not None else config_path
    return load_config(path, list(overrides))


def common_run_options(func: Callable[..., Any]) -> Callable[..., Any]:
    """``--quiet`` and ``--verbose`` for commands that do work."""

    @click.option(
        "-q", "--quiet", is_flag=True, help="Only errors on stderr (no progress, no log)."
    )
    @click.option("-v", "--verbose", is_flag=True, help="Debug log on stderr.")
    @functools.wraps(func)
    def wrapper(*args: Any, quiet: bool = False, verbose: bool = False, **kwargs: Any) -> Any:
        setup_logging(quiet=quiet, verbose=verbose)
        return func(*args, quiet=quiet, **kwargs)

    return wrapper


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
    when it has its default action, so that temporary files are removed then too. Does nothing
    outside the main thread, when SIGINT has a custom handler already, or without
    ``setitimer`` (Windows).
    """

    RETRY_S = 0.02

    def __enter__(self) -> deferred_interrupts:
        self.active = (
            hasattr(signal, "setitimer")
            and threading.current_thread() is threading.main_thread()
            and signal.getsignal(signal.SIGINT) is signal.default_int_handler
        )
        if self.active:
            self.old_alarm = signal.signal(signal.SIGALRM, self._handle)
            signal.signal(signal.SIGINT, self._handle)
            self.term = signal.getsignal(signal.SIGTERM) == signal.SIG_DFL
            if self.term:
                signal.signal(signal.SIGTERM, self._handle)
        return self

    def __exit__(self, *exc: object) -> None:
        if self.active:
            signal.setitimer(signal.ITIMER_REAL, 0.0)
            signal.signal(signal.SIGINT, signal.default_int_handler)
            signal.signal(signal.SIGALRM, self.old_alarm)
            if self.term:
                signal.signal(signal.SIGTERM, signal.SIG_DFL)

    def _handle(self, signum: int, frame: Any) -> None:
        if _unsafe_to_interrupt(frame):
            signal.setitimer(signal.ITIMER_REAL, self.RETRY_S)
            return
        signal.setitimer(signal.ITIMER_REAL, 0.0)
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


def _caused_by_interrupt(exc: BaseException) -> bool:
    seen: set[int] = set()
    node: BaseException | None = exc
    while node is not None and id(node) not in seen:
        if isinstance(node, KeyboardInterrupt):
            return True
        seen.add(id(node))
        node = node.__cause__ or node.__context__
    return False


def catch_errors(func: Callable[..., Any]) -> Callable[..., Any]:
    """Turn library errors into one-line messages with the documented exit codes."""

    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        ctx = click.get_current_context()
        debug = bool((ctx.find_root().obj or {}).get("debug"))
        try:
            with deferred_interrupts():
                return func(*args, **kwargs)
        except OpreconError as exc:
            if debug:
                raise
            fail(str(exc), EXIT_BAD_INPUT)
        except KeyboardInterrupt:
            click.echo("oprecon: interrupted", err=True)
            wait_for_query_threads()
            sys.exit(EXIT_INTERRUPTED)
        except MemoryError:
            if debug:
                raise
            fail("out of memory (lower dynamics.max_particles or thin the input)", EXIT_BAD_INPUT)
        except OSError as exc:  # a file problem the library did not wrap (e.g. a full disk)
            if debug:
                raise
            where = f"{exc.filename}: " if exc.filename else ""
            fail(f"{where}{exc.strerror or exc}", EXIT_BAD_INPUT)
        except Exception as exc:
            # Ctrl-C inside a compiled-code callback (numba loading a cached kernel) surfaces
            # as a SystemError caused by the KeyboardInterrupt: still an interrupt
            if not _caused_by_interrupt(exc):
                raise
            click.echo("oprecon: interrupted", err=True)
            wait_for_query_threads()
            sys.exit(EXIT_INTERRUPTED)

    return wrapper


def parse_viewpoint(
    ctx: click.Context, param: click.Parameter, text: str | None
) -> list[float] | None:
    """Click callback: ``"x,y,z"`` -> three floats (a scanner position)."""
    if text is None:
        return None
    try:
        values = [float(v) for v in text.replace(" ", "").split(",")]
    except ValueError:
        raise click.BadParameter(f"expected x,y,z numbers, got {text!r}") from None
    if len(values) != 3:
        raise click.BadParameter(f"expected 3 numbers x,y,z, got {len(values)}")
    return values
