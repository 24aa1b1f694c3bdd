"""The ``oprecon`` entry point: Ctrl-C before a command's own guard is set up."""

from __future__ import annotations

import os
import signal
import subprocess
import sys

import pytest

#: A child that runs ``oprecon ARGS...`` in-process after the test's set-up (``PRELUDE``).
_CHILD = """
import signal, sys
{prelude}
sys.argv = ["oprecon", *sys.argv[1:]]
from recon.cli.main import main
main()
"""

#: Ctrl-C in the group's own callback, after click parsed the arguments and before the
#: command runs (where click answered with "Aborted!" and exit code 1).
_INTERRUPT_IN_THE_GROUP = """
import click

def ensure_object(self, object_type, _plain=click.Context.ensure_object):
    signal.raise_signal(signal.SIGINT)
    return _plain(self, object_type)

click.Context.ensure_object = ensure_object
"""

#: Ctrl-C while the entry point imports the command line's shared module.
_INTERRUPT_AT_IMPORT = """
import importlib.abc

class Interrupt(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name == "recon.cli.common":
            sys.meta_path.remove(self)
            signal.raise_signal(signal.SIGINT)
        return None

sys.meta_path.insert(0, Interrupt())
"""


def _run_child(prelude: str, args: list[str]) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", _CHILD.format(prelude=prelude), *args],
        capture_output=True,
        text=True,
        timeout=120,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )


@pytest.mark.skipif(os.name != "posix", reason="signals to the process need POSIX")
@pytest.mark.parametrize(
    "prelude", [_INTERRUPT_IN_THE_GROUP, _INTERRUPT_AT_IMPORT], ids=["group", "import"]
)
def test_an_interrupt_before_the_commands_guard_exits_130_with_its_message(tmp_path, prelude):
    """Regression: click printed "Aborted!" and exited 1 (in the group), or Python printed a
    traceback (at the import), where every other interrupt exits 130 with one line."""
    res = _run_child(prelude, ["info", str(tmp_path / "missing.ply")])
    assert res.returncode == 130, (res.returncode, res.stderr[-2000:])
    assert res.stderr.strip().splitlines() == ["oprecon: interrupted"], res.stderr[-2000:]
