"""``oprecon config show|validate``."""

from __future__ import annotations

from pathlib import Path

import click

from recon.config import dump_config

from .common import build_config, catch_errors, config_options


@click.group("config")
def command() -> None:
    """Show or check pipeline configurations.

    \b
    Examples:
      oprecon config show                         defaults, every key documented
      oprecon config show --preset open_scan      a preset as it resolves
      oprecon config show --set dynamics.dt=0.1   with an override
      oprecon config validate my.yaml             check a file without running
    """


@command.command("show")
@config_options
@click.option("--no-comments", is_flag=True, help="Plain YAML without documentation comments.")
@catch_errors
def show(
    config_path: Path | None, preset: str | None, overrides: tuple[str, ...], no_comments: bool
) -> None:
    """Print the effective configuration as YAML (defaults < file < --set)."""
    cfg = build_config(config_path, preset, overrides)
    click.echo(dump_config(cfg, comments=not no_comments), nl=False)


@command.command("validate")
@click.argument("path", type=click.Path(path_type=Path))
@catch_errors
def validate(path: Path) -> None:
    """Check a YAML configuration file; exit 0 if valid, 2 with the offending key if not."""
    build_config(path, None, ())
    click.echo(f"{path}: valid")
