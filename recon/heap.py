"""Keep freed memory in the process for reuse (glibc's malloc), instead of returning it.

glibc serves every allocation above its mmap threshold (at most 32 MiB on 64-bit systems) with
a fresh ``mmap`` and hands it back with ``munmap`` when it is freed. The next array of that size
then faults in and zeroes every page again. A fit allocates arrays of tens to hundreds of MiB
on every step and every growth round (numpy temporaries, the numba kernels' outputs, the
neighbour lists' scratch rows); at 4M points nearly all of them are above 32 MiB, and the fit
took 440 s against 365 s with the policy below (README, Performance, "Memory reuse").

:func:`keep_freed_memory` sets two of glibc's ``mallopt`` parameters for the whole process:

- ``M_MMAP_MAX = 0``: large blocks come from the heap, as small ones do (from the main
  thread's heap; a thread's own arena still maps a block larger than its 64 MiB heap);
- ``M_TRIM_THRESHOLD`` to its largest value, 2 GiB (``mallopt`` takes a C ``int``): freed
  memory at the heap's top is kept for the next allocation unless more than 2 GiB of it is
  free at once.

Both or neither: ``M_MMAP_MAX = 0`` with glibc's trim threshold returns the heap's top after
every large free and faults it in again, which was slower than glibc's defaults (README).

The cost is memory: blocks freed early are only reused, never returned, so the peak resident
memory of a fit rises (1.9 GiB against 1.7-1.8 GiB at 1M points). The commands that run one fit
in a process of their own call it (``oprecon fit`` without tiles, ``normals``, ``remesh``, and
``batch``'s item processes); the library does not change the allocator of a program that
imports it. Long-lived workers (Dask) are left alone: they return memory to the system so that
their memory monitor sees what is in use.

Nothing is changed when ``OPRECON_MALLOC=system`` is set, when the environment already sets
these parts of glibc's malloc (``MALLOC_MMAP_MAX_``, ``MALLOC_TRIM_THRESHOLD_``,
``MALLOC_MMAP_THRESHOLD_``, ``MALLOC_TOP_PAD_``, or the same four as ``glibc.malloc``
tunables in ``GLIBC_TUNABLES``), when ``LD_PRELOAD`` brings another allocator (jemalloc,
tcmalloc, mimalloc: glibc's ``mallopt`` would answer without reaching it), or when the C
library is not glibc.

References
----------
``mallopt(3)``, the GNU C Library manual (Memory Allocation Tunables).
"""

from __future__ import annotations

import ctypes
import logging
import os
import sys
from collections.abc import Mapping

log = logging.getLogger(__name__)

#: ``mallopt`` parameter numbers (glibc's ``malloc.h``).
M_TRIM_THRESHOLD = -1
M_MMAP_MAX = -4

#: glibc's default of ``M_MMAP_MAX``, put back when the trim threshold cannot be set.
MMAP_MAX_DEFAULT = 65536

#: The largest trim threshold ``mallopt`` takes (its value is a C ``int``) [bytes].
TRIM_THRESHOLD_MAX = 2**31 - 1

#: Environment variables by which a user tunes glibc's malloc: when one is set it is respected.
GLIBC_MALLOC_ENV = (
    "MALLOC_MMAP_MAX_",
    "MALLOC_TRIM_THRESHOLD_",
    "MALLOC_MMAP_THRESHOLD_",
    "MALLOC_TOP_PAD_",
)

#: The same four as glibc tunables (``GLIBC_TUNABLES=glibc.malloc.trim_threshold=...``).
GLIBC_MALLOC_TUNABLES = (
    "glibc.malloc.mmap_max",
    "glibc.malloc.trim_threshold",
    "glibc.malloc.mmap_threshold",
    "glibc.malloc.top_pad",
)

#: Allocators that replace glibc's malloc through ``LD_PRELOAD``.
PRELOADED_ALLOCATORS = ("jemalloc", "tcmalloc", "mimalloc")

#: ``OPRECON_MALLOC=system`` keeps the C library's own policy.
OPT_OUT_ENV = "OPRECON_MALLOC"

_applied = False


def _user_tuned(environ: Mapping[str, str]) -> str | None:
    """The variable by which the environment sets the policy itself, or None."""
    choice = environ.get(OPT_OUT_ENV, "").strip().lower()
    if choice == "system":
        return OPT_OUT_ENV
    if choice:
        log.warning("%s=%s is not understood (only 'system'): ignored", OPT_OUT_ENV, choice)
    for var in GLIBC_MALLOC_ENV:
        if var in environ:
            return var
    tunables = [t.split("=")[0].strip() for t in environ.get("GLIBC_TUNABLES", "").split(":")]
    if any(t in GLIBC_MALLOC_TUNABLES for t in tunables):
        return "GLIBC_TUNABLES"
    preload = environ.get("LD_PRELOAD", "").lower()
    if any(name in preload for name in PRELOADED_ALLOCATORS):
        return "LD_PRELOAD"
    return None


def _glibc() -> ctypes.CDLL | None:
    """The process's C library when it is glibc (it has ``gnu_get_libc_version``)."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        libc = ctypes.CDLL(None)
        libc.gnu_get_libc_version  # noqa: B018 - the lookup is the test
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return None
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    return libc


def keep_freed_memory() -> bool:
    """Make glibc's malloc keep freed memory for reuse (module docstring); idempotent.

    Returns
    -------
    bool
        Whether the policy is in effect after the call (False: not glibc, the environment sets
        its own, or ``mallopt`` refused).
    """
    global _applied
    if _applied:
        return True
    reason = _user_tuned(os.environ)
    if reason is not None:
        log.debug("malloc: left as the environment sets it (%s)", reason)
        return False
    libc = _glibc()
    if libc is None:
        log.debug("malloc: not glibc, left alone")
        return False
    if not libc.mallopt(M_MMAP_MAX, 0):
        log.warning("malloc: mallopt refused M_MMAP_MAX; glibc's policy kept")
        return False
    if not libc.mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD_MAX):
        # half the policy is worse than none (module docstring): undo the first half
        libc.mallopt(M_MMAP_MAX, MMAP_MAX_DEFAULT)
        log.warning("malloc: mallopt refused M_TRIM_THRESHOLD; glibc's policy kept")
        return False
    _applied = True
    log.debug("malloc: freed memory kept for reuse")
    return True
