"""The option the benchmarks share: ``--set SECTION.KEY=VALUE``, as ``oprecon fit --set``.

Imported by the benchmark scripts from their own folder (run as ``python benchmarks/X.py``,
or loaded by file or as ``benchmarks.X`` in the tests).
"""

from __future__ import annotations

import argparse
from typing import Any


def add_overrides(parser: argparse.ArgumentParser, help: str | None = None) -> None:  # noqa: A002
    """Add the repeatable ``--set SECTION.KEY=VALUE`` option (``args.overrides``: a list)."""
    parser.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="SECTION.KEY=VALUE",
        help=help or "override one oprecon config key (repeatable), as `oprecon fit --set`",
    )


def override_values(items: list[str]) -> dict[str, Any]:
    """``{"section.key": value}`` of ``--set`` items, values parsed as ``oprecon fit`` does."""
    from recon.config import parse_override

    return dict(map(parse_override, items))
