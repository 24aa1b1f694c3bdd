"""``oprecon batch``: reconstruct many point clouds, in parallel, with a summary and resume."""

from __future__ import annotations

import math
import shutil
import sys
from pathlib import Path
from typing import Any

import click

from recon.batch import (
    DEFAULT_ITEM_TIME_LIMIT,
    STATUS_FAILED,
    STATUS_OK,
    STATUS_TIMEOUT,
    BatchEvent,
    BatchPlan,
    BatchReport,
    load_batch,
    plan_batch,
    run_batch,
)

from .common import (
    EXIT_INTERRUPTED,
    catch_errors,
    common_run_options,
    note_first_compile,
    resolve_preset,
)


def _short(path: Path | str | None, folder: Path) -> str:
    if path is None:
        return "-"
    p = Path(path)
    try:
        return p.relative_to(folder).as_posix()
    except ValueError:
        return str(p)


def _clip(text: str, width: int) -> str:
    return text if len(text) <= width else text[: max(0, width - 3)] + "..."


def _table(header: list[str], rows: list[list[str]], right: set[int] = frozenset()) -> str:
    widths = [max(len(r[i]) for r in [header, *rows]) for i in range(len(header))]
    lines = []
    for r in [header, *rows]:
        cells = [
            c.rjust(w) if i in right else c.ljust(w)
            for i, (c, w) in enumerate(zip(r, widths, strict=True))
        ]
        lines.append("  " + "  ".join(cells).rstrip())
    return "\n".join(lines)


def format_plan(plan: BatchPlan) -> str:
    """What a run would do: one line per item (action, name, input, reason)."""
    cwd = Path.cwd()
    n_run, n_skip, n_fail = (len(plan.with_action(a)) for a in ("run", "skip", "fail"))
    head = (
        f"batch {_short(plan.spec.path, cwd)} -> {plan.spec.output_dir}: "
        f"{len(plan.items)} item(s), {n_run} to run, {n_skip} up to date, {n_fail} failing"
    )
    rows = []
    for it in plan.items:
        ovr = ",".join(str(i) for i in it.overrides) or "-"
        rows.append(
            [
                it.action,
                it.name,
                _short(it.input_path, cwd) if it.input_path else it.entry,
                ovr,
                it.reason,
            ]
        )
    return head + "\n" + _table(["action", "name", "input", "overrides", "why"], rows)


def _num(value: Any, fmt: str) -> str:
    return "-" if value is None else format(value, fmt)


def format_results(report: BatchReport, error_width: int = 100) -> str:
    """The summary table of a finished batch (stderr)."""
    rows = []
    for r in report.results:
        rows.append(
            [
                r.status,
                r.name,
                _num(r.time_s, ".1f"),
                _num(r.particles, ","),
                _num(r.faces, ","),
                "-" if r.coverage is None else f"{100 * r.coverage:.1f}%",
                _num(r.fidelity_mean, ".3g"),
                _clip(r.error, error_width) if r.status != "skipped" else "",
            ]
        )
    return _table(
        ["status", "item", "time s", "particles", "faces", "coverage", "fid. mean", "error"],
        rows,
        right={2, 3, 4, 5, 6},
    )


class BatchProgress:
    """Progress on stderr: an items bar with the running items' phases on a terminal, one line
    per finished item otherwise."""

    def __init__(self, total: int, enabled: bool) -> None:
        self.enabled = enabled and total > 0
        self.tty = sys.stderr.isatty()
        self.total = total
        self.done = 0
        self.running: dict[str, str] = {}
        self.bar: Any = None

    def _text(self) -> str:
        width = shutil.get_terminal_size((100, 20)).columns - 60
        text = "  ".join(f"{n}: {s}" for n, s in self.running.items())
        return _clip(text, max(20, width))

    def __call__(self, event: BatchEvent) -> None:
        if not self.enabled:
            return
        step = 0
        if event.kind == "start":
            self.running[event.name] = "started"
        elif event.kind == "progress":
            info = event.info
            cov = info.get("coverage")
            self.running[event.name] = f"{event.phase} {info.get('particles', 0):,}p" + (
                f" {100 * cov:.0f}%" if cov is not None else ""
            )
        elif event.kind == "finish":
            self.running.pop(event.name, None)
            self.done += 1
            step = 1
            if not self.tty and event.result is not None:
                r = event.result
                took = f" ({r.time_s:.1f} s)" if r.time_s is not None else ""
                err = f": {_clip(r.error, 200)}" if r.error and r.status != STATUS_OK else ""
                click.echo(f"[{self.done}/{self.total}] {r.status} {r.name}{took}{err}", err=True)
        if not self.tty:
            return
        if self.bar is None:
            self.bar = click.progressbar(
                length=self.total,
                label="items",
                file=sys.stderr,
                show_pos=True,
                width=20,
                item_show_func=lambda s: s,
            )
            self.bar.__enter__()
        self.bar.update(step, self._text() or " ")

    def close(self) -> None:
        if self.bar is not None:
            self.bar.__exit__(None, None, None)
            self.bar = None


def _not_nan(ctx: click.Context, param: click.Parameter, value: float | None) -> float | None:
    """Refuse ``nan`` (click's FloatRange compares it with its bounds and lets it through)."""
    if value is not None and math.isnan(value):
        raise click.BadParameter("expected a number of seconds > 0 (inf: no limit), got nan")
    return value


@click.command("batch")
@click.argument("batch_file", metavar="BATCH.yaml", type=click.Path(path_type=Path))
@click.option(
    "-j",
    "--jobs",
    type=click.IntRange(min=1),
    help="Items run at a time (local), or LocalCluster workers (dask without "
    "--scheduler). Default: the number of cores.",
)
@click.option(
    "--executor",
    type=click.Choice(["local", "dask"]),
    default="local",
    show_default=True,
    help="local: worker processes on this machine; dask: tasks on a Dask cluster "
    '(needs pip install "oprecon[distributed]").',
)
@click.option(
    "--scheduler",
    metavar="ADDRESS",
    help="Dask scheduler to use, e.g. tcp://10.0.0.5:8786 (with --executor dask); "
    "without it a LocalCluster is started.",
)
@click.option(
    "--item-time-limit",
    type=click.FloatRange(min=0, min_open=True),
    callback=_not_nan,
    metavar="SECONDS",
    help="Wall-clock limit per item; an item past it is stopped, then killed "
    f"(default: item_time_limit in the file, else {DEFAULT_ITEM_TIME_LIMIT:g}; inf: none).",
)
@click.option(
    "--threads",
    type=click.IntRange(min=1),
    metavar="N",
    help="Threads per item (numba, OpenMP, BLAS in each worker process). Default: cores // "
    "items at a time, at least 1, so parallel items do not oversubscribe the machine "
    "(unless NUMBA_NUM_THREADS / OMP_NUM_THREADS are set). The meshes are the same for any "
    "count.",
)
@click.option("--force", is_flag=True, help="Run every item, even those that are up to date.")
@click.option(
    "--dry-run",
    is_flag=True,
    help="List what would run, be skipped or fail, and why; run nothing (exit 1 when an input "
    "is missing).",
)
@click.option(
    "--set",
    "overrides",
    multiple=True,
    metavar="SECTION.KEY=VALUE",
    help="Override a key for every item, over the batch file (repeatable).",
)
@common_run_options
@catch_errors
def command(
    batch_file: Path,
    jobs: int | None,
    executor: str,
    scheduler: str | None,
    item_time_limit: float | None,
    threads: int | None,
    force: bool,
    dry_run: bool,
    overrides: tuple[str, ...],
    quiet: bool,
) -> None:
    """Reconstruct every input named in the batch file BATCH.yaml.

    Items run in parallel worker processes; one item's failure, timeout or crash does not stop
    the others. Re-running skips items whose outputs are up to date (same input, resolved
    configuration and oprecon version). A table goes to stderr, and batch_summary.json and
    batch_summary.csv to the output folder. See configs/examples/batch_example.yaml.

    \b
    Examples:
      oprecon batch scans.yaml
      oprecon batch scans.yaml --dry-run
      oprecon batch scans.yaml --jobs 4 --item-time-limit 600 --set seed=1
      oprecon batch scans.yaml --jobs 2 --threads 4
      oprecon batch scans.yaml --executor dask --scheduler tcp://10.0.0.5:8786

    Exit codes: 0 every item ok or up to date, 1 some item failed or timed out, 2 invalid
    batch file or usage, 130 interrupted (finished items are kept).
    """
    if scheduler and executor != "dask":
        raise click.UsageError("--scheduler needs --executor dask")
    spec = load_batch(batch_file, resolve_preset=resolve_preset, cli_overrides=overrides)
    limit = item_time_limit or spec.item_time_limit or DEFAULT_ITEM_TIME_LIMIT
    plan = plan_batch(spec, force=force, item_time_limit=limit)
    if dry_run:
        click.echo(format_plan(plan))
        sys.exit(1 if plan.with_action("fail") else 0)
    progress = BatchProgress(total=len(plan.with_action("run")), enabled=not quiet)
    if plan.with_action("run") and not scheduler:  # a remote cluster's caches are its own
        note_first_compile(quiet)
    try:
        report = run_batch(
            plan,
            jobs=jobs,
            executor=executor,
            scheduler=scheduler,
            on_event=progress,
            threads=threads,
        )
    finally:
        progress.close()
    counts = report.counts()
    if not quiet:
        click.echo(format_results(report), err=True)
        parts = ", ".join(f"{n} {s}" for s, n in counts.items() if n or s in ("ok", "failed"))
        click.echo(
            f"oprecon: {parts} in {report.elapsed_s:.1f} s; summary in {report.summary_json}",
            err=True,
        )
    else:
        for r in report.results:
            if r.status in (STATUS_FAILED, STATUS_TIMEOUT):
                click.echo(f"oprecon: {r.status}: {r.name}: {r.error}", err=True)
    if report.interrupted:
        click.echo("oprecon: interrupted", err=True)
        sys.exit(EXIT_INTERRUPTED)
    sys.exit(report.exit_code)
