"""Exception types raised by the library.

The CLI maps :class:`OpreconError` (and its subclasses) to a one-line message on stderr and exit
code 2; anything else is a bug and shows a traceback only with ``--debug``.
"""

from __future__ import annotations

import difflib
from collections.abc import Iterable


class OpreconError(Exception):
    """Bad input, bad configuration or an unrecoverable condition the user can act on."""


class InputError(OpreconError):
    """A file or an array that cannot be used as input (names the file and the problem)."""


class ConfigError(OpreconError):
    """A configuration key, type or value that is not valid (names the dotted key)."""


class DivergenceError(OpreconError):
    """The particle dynamics produced non-finite or exploding state."""


class LimitExceeded(OpreconError):
    """A particle, step or time cap was reached (the message names the cap)."""


def did_you_mean(name: str, valid: Iterable[str]) -> str:
    """`` (did you mean 'x'?)`` for the closest of ``valid``, or an empty string.

    >>> did_you_mean("spacng", ["spacing", "seed"])
    " (did you mean 'spacing'?)"
    """
    close = difflib.get_close_matches(name, list(valid), n=1, cutoff=0.5)
    return f" (did you mean '{close[0]}'?)" if close else ""
