"""Entry point: the ``oprecon`` command group."""

from __future__ import annotations

import sys

try:  # Ctrl-C while the command line loads: the message and exit code of any interrupt
    import warnings

    import click

    from recon import __version__

    from .common import EXIT_INTERRUPTED
except KeyboardInterrupt:
    sys.stderr.write("oprecon: interrupted\n")
    sys.exit(130)

CONTEXT_SETTINGS = {"help_option_names": ["-h", "--help"], "max_content_width": 100}


class _Group(click.Group):
    """The command group, with the interrupt's message and exit code also where click would
    answer Ctrl-C itself: after the arguments are parsed and before a command's own guard
    (:func:`recon.cli.common.catch_errors`) is set up, click printed "Aborted!" and exited 1."""

    def invoke(self, ctx: click.Context) -> object:
        try:
            return super().invoke(ctx)
        except KeyboardInterrupt:
            click.echo("oprecon: interrupted", err=True)
            sys.exit(EXIT_INTERRUPTED)


@click.group(cls=_Group, context_settings=CONTEXT_SETTINGS)
@click.version_option(__version__, "--version", prog_name="oprecon")
@click.option("--debug", is_flag=True, help="Show Python tracebacks for errors.")
@click.pass_context
def app(ctx: click.Context, debug: bool) -> None:
    """Turn scattered 3-D points into clean triangle meshes with oriented particle systems.

    \b
    Typical use:
      oprecon info scan.ply                    what is in the file
      oprecon fit scan.ply -o mesh.ply         reconstruct (writes mesh.report.json too)
      oprecon compare mesh.ply ref.ply         gate on a reference mesh
      oprecon report mesh.ply --input scan.ply quality of any mesh
      oprecon batch campaign.yaml              many scans, resumable
      oprecon normals scan.ply -o oriented.ply consistently oriented normals
      oprecon remesh mc.ply -o clean.ply       near-equilateral remesh of a mesh
      oprecon config show                      every setting with its default

    Exit codes: 0 success, 1 a completed run failed a check, 2 bad input or usage,
    130 interrupted.
    """
    ctx.ensure_object(dict)
    ctx.obj["debug"] = debug


def _register() -> None:
    from . import batch, compare, config_cmd, fit, info, normals, remesh, report

    for module in (info, normals, fit, remesh, compare, report, batch, config_cmd):
        app.add_command(module.command)


try:
    _register()
except KeyboardInterrupt:  # Ctrl-C while the commands are still being imported
    sys.stderr.write("oprecon: interrupted\n")
    sys.exit(EXIT_INTERRUPTED)


def main() -> None:
    # numba notes on every parallel run that the TBB it found is too old, then uses another
    # threading layer; that is noise for a user of the command line.
    warnings.filterwarnings("ignore", message="The TBB threading layer requires")
    try:
        app.main(prog_name="oprecon", standalone_mode=True)
    except KeyboardInterrupt:
        click.echo("oprecon: interrupted", err=True)
        sys.exit(EXIT_INTERRUPTED)


if __name__ == "__main__":
    main()
