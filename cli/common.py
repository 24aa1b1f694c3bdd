"""Shared pieces of the CLI: error handling, logging, configuration options."""

from __future__ import annotations

import functools
import logging
import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import click

from recon.config import ReconConfig, load_config
from recon.errors import OpreconError
from recon.interrupts import (
    deferred_interrupts,
    ignore_interrupts_at_exit,
    wait_for_query_threads,
)
from recon.presets import preset_path

EXIT_OK = 0
EXIT_CHECK_FAILED = 1
EXIT_BAD_INPUT = 2
EXIT_INTERRUPTED = 130


def format_rows(rows: list[tuple[str, str]], indent: str = "  ") -> list[str]:
    """``name  value`` lines with the names padded to one column (the summaries' layout)."""
    width = max((len(k) for k, _ in rows), default=0)
    return [f"{indent}{k:<{width}}  {v}" for k, v in rows]


def mesh_output_option(func: Callable[..., Any]) -> Callable[..., Any]:
    """``-o/--output``: the mesh a command writes, with its report beside it."""
    return click.option(
        "-o",
        "--output",
        "output_path",
        required=True,
        type=click.Path(path_type=Path),
        help="Mesh to write: .ply (binary unless --ascii) or .obj. A report "
        "<name>.report.json is written beside it.",
    )(func)


def fail(message: str, code: int = EXIT_BAD_INPUT) -> None:
    """Print ``oprecon: error: message`` on stderr and exit with ``code``."""
    click.echo(f"oprecon: error: {message}", err=True)
    sys.exit(code)


#: The summary's last line after a run that compiled (its phase times hold the compiles).
COMPILE_TIMES_NOTE = "  note: the times above include compiling the numba kernels (first run)"


def note_first_compile(
    quiet: bool, kernels: tuple[str, ...] | None = None, how_long: str = "a few minutes of CPU"
) -> bool:
    """Say on stderr, before a run starts, when it will first compile numba's kernels (no
    cache for this version on this machine yet): minutes in which nothing else is shown.
    ``kernels``: those of :data:`recon.kernels.warm.SLOW_TO_COMPILE` the command calls (all
    of them for a fit); ``how_long``: what the compile of those takes. Returns whether it
    said so (then the summary ends with :data:`COMPILE_TIMES_NOTE`)."""
    if quiet:
        return False
    from recon.kernels.warm import SLOW_TO_COMPILE, uncached

    if not uncached(SLOW_TO_COMPILE if kernels is None else kernels):
        return False
    click.echo(
        "oprecon: compiling the numba kernels first (this version's first run on this "
        f"machine: {how_long}, once; later runs load them from the cache)",
        err=True,
    )
    return True


def setup_logging(quiet: bool = False, verbose: bool = False) -> None:
    level = logging.WARNING if quiet else (logging.DEBUG if verbose else logging.INFO)
    root = logging.getLogger("recon")
    root.handlers.clear()
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("%(message)s"))
    root.addHandler(handler)
    root.setLevel(level)
    root.propagate = False


def resolve_preset(name: str) -> Path:
    """The YAML file of a bundled preset (package data of ``recon.configs``)."""
    return preset_path(name)


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


#: Thread-count variables of the native libraries loaded by a fit, set by ``--threads``.
#: numba's own pool is sized by ``NUMBA_NUM_THREADS`` when it starts; within it the count is
#: set per fit (the ``threads`` config key, :func:`recon.kernels.options.thread_count`).
THREAD_ENV = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")

THREADS_HELP = (
    "Threads for the numba kernels, OpenMP and BLAS [threads]. Default: all usable cores "
    "(batch: cores / jobs). The mesh is the same for any count."
)


def set_thread_env(threads: int | None) -> None:
    """Set :data:`THREAD_ENV` to ``threads``; call before the pipeline (numpy, numba, open3d) is
    imported: OpenBLAS, GNU OpenMP and Open3D read these variables when they load.

    The OpenMP wait policy is left alone: ``OMP_WAIT_POLICY=PASSIVE`` made no measurable
    difference to ``oprecon fit`` (README, Performance, "Threads").
    """
    if threads is not None:
        for var in THREAD_ENV:
            os.environ[var] = str(threads)


def threads_option(func: Callable[..., Any]) -> Callable[..., Any]:
    """``--threads N``: passed on as ``threads``, after :func:`set_thread_env`."""

    @click.option(
        "--threads", type=click.IntRange(min=1), metavar="N", default=None, help=THREADS_HELP
    )
    @functools.wraps(func)
    def wrapper(*args: Any, threads: int | None = None, **kwargs: Any) -> Any:
        set_thread_env(threads)
        return func(*args, threads=threads, **kwargs)

    return wrapper


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
    """Turn library errors into one-line messages with the documented exit codes.

    Ctrl-C (or SIGTERM) in the command exits 130 with ``oprecon: interrupted``; one during the
    interpreter's exit after the command is ignored
    (:func:`recon.interrupts.ignore_interrupts_at_exit`): the command's outcome stands.
    """

    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        ctx = click.get_current_context()
        debug = bool((ctx.find_root().obj or {}).get("debug"))
        ignore_interrupts_at_exit()  # (a Ctrl-C in the teardown killed it without a word)
        from recon.io.files import folders_undone_on_failure  # (at run time: start-up)

        try:
            with deferred_interrupts(), folders_undone_on_failure():
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
