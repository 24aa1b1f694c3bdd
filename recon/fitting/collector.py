"""Python's cyclic garbage collector during a fit.

A fit allocates few Python objects of its own (its state lives in numpy arrays), but a fresh
process's first fit loads its compiled kernels from numba's cache, and those allocations
trigger one full collection. That collection walks every object the process holds, mostly
the modules imported before the fit (about 130,000 objects with open3d, scipy and numba):
measured on bunny-clean in fresh processes, 69-73 ms of the fit's 80-84 ms of collector
pauses, with the GIL held (so the kernels' loading thread waits too).

:func:`survivors_frozen` moves the objects alive when the fit starts into the collector's
permanent generation (:func:`gc.freeze`) and back when it ends (:func:`gc.unfreeze`): the
collector still runs during the fit, over what the fit allocates. Nothing is left frozen
after the fit, and garbage made before it is collected after it as before.
"""

from __future__ import annotations

import contextlib
import gc
from collections.abc import Iterator

__all__ = ["survivors_frozen"]


@contextlib.contextmanager
def survivors_frozen() -> Iterator[None]:
    """Freeze the objects alive now for the duration of the block, then unfreeze them.

    Does nothing when the collector is disabled or something froze objects already (a
    caller's own :func:`gc.freeze`, e.g. before forking, or an enclosing fit): their
    frozen objects stay as they are.

    Examples
    --------
    >>> import gc
    >>> with survivors_frozen():
    ...     gc.get_freeze_count() > 0
    True
    >>> gc.get_freeze_count()
    0
    """
    if not gc.isenabled() or gc.get_freeze_count() > 0:
        yield
        return
    gc.freeze()
    try:
        yield
    finally:
        gc.unfreeze()
