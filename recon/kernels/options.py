"""Compilation options shared by every kernel.

All kernels are compiled with ``cache=True`` and a reduced ``fastmath`` flag set:

- ``nnan`` and ``ninf`` are omitted because the integrator tests every particle's new state for
  non-finite values (:class:`recon.errors.DivergenceError`), and with those flags LLVM may fold
  such tests to ``True``;
- ``reassoc`` and ``contract`` are omitted because they let the result depend on inlining and
  vectorisation decisions, which differ between the serial and the threaded twin of a kernel;
  without them both give bit-identical states. The step kernel's pair-term loop is vectorised
  on purpose for the polynomial weight (:func:`recon.kernels.pair_loop.step_particles`, since
  2026-11-29): without these two flags each SIMD lane does the scalar operations, and the
  states were checked bit-identical to the scalar loop's. On the 100k-particle benchmark the
  two flags made no difference beyond the timing noise (measured before that change).

What remains (``nsz``, ``arcp``, ``afn``) lets LLVM use reciprocals and ignore signed zeros.

Numba's cache is keyed on the source file of each jitted function only: after editing a kernel
module that others call (quaternion, weights, the term modules, pair_terms, local_surface, this
file), delete
``recon/kernels/__pycache__/*.nb[ic]`` so that the callers are recompiled.

References
----------
.. [NB] Numba documentation, "Performance tips: fastmath".
"""

from __future__ import annotations

import contextlib
import os
import time
from collections.abc import Iterator

import numba

#: numba's threading layers in the order tried at the first threaded kernel: GNU OpenMP
#: first (numba's own order tries TBB first, whose probe took 30-60 ms of every process here
#: and, with a TBB older than numba accepts, warned and fell back to OpenMP anyway). A layer
#: set in the environment (``NUMBA_THREADING_LAYER`` or ``..._PRIORITY``) is kept.
THREADING_LAYER_PRIORITY = "omp tbb workqueue"
if "NUMBA_THREADING_LAYER" not in os.environ:
    os.environ.setdefault("NUMBA_THREADING_LAYER_PRIORITY", THREADING_LAYER_PRIORITY)
    numba.config.THREADING_LAYER_PRIORITY = os.environ["NUMBA_THREADING_LAYER_PRIORITY"].split()

FASTMATH: frozenset[str] = frozenset({"nsz", "arcp", "afn"})
"""LLVM fast-math flags used by every kernel (see the module docstring)."""

JIT_OPTIONS: dict = {
    "cache": True,
    "fastmath": set(FASTMATH),
    "nogil": True,
    "error_model": "numpy",
}
"""Keyword arguments for every ``numba.njit`` in :mod:`recon.kernels`.

``error_model="numpy"``: a division by zero gives inf/NaN (caught by the divergence check)
instead of raising ``ZeroDivisionError`` from inside a kernel, and divisions carry no
zero test."""


EXACT_JIT_OPTIONS: dict = {**JIT_OPTIONS, "fastmath": False}
"""Keyword arguments for the geometry kernels of the stages (Poisson-disk thinning, growing
rule, local quadrics, angular gaps, circumspheres): :data:`JIT_OPTIONS` without fast-math.

These kernels were compiled without fast-math before they moved here, and their results feed
discrete decisions (which seed or candidate is kept, which triangle passes). ``arcp`` lets LLVM
replace several divisions by one value with a multiplication by its reciprocal (the quadric
fit divides five coefficients by the same scale), which changes last bits and so could change
those decisions; exact IEEE arithmetic keeps every mesh byte-identical."""


@contextlib.contextmanager
def thread_limit(parallel: bool) -> Iterator[None]:
    """Run the ``parallel=True`` kernels in the calling thread only (when ``parallel`` is False).

    The kernels have one ``prange`` loop each; with one thread the loop runs in the caller,
    without waking (and waiting for) the worker threads, which DESIGN §3 measured at
    milliseconds per region on a loaded 2-core machine. Serial and threaded runs execute the
    same compiled code, so they give bit-identical results.
    """
    if parallel:
        yield
        return
    previous = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        yield
    finally:
        numba.set_num_threads(previous)


def usable_threads(threads: int | None) -> int:
    """The thread count numba will use for ``threads`` (None: numba's own, i.e. all cores).

    Bounded by ``numba.config.NUMBA_NUM_THREADS``, the size of numba's thread pool, which is
    fixed when numba starts (from the environment variable of that name, else the cores).
    """
    limit = int(numba.config.NUMBA_NUM_THREADS)
    if threads is None:
        return limit
    return max(1, min(int(threads), limit))


@contextlib.contextmanager
def thread_count(threads: int | None) -> Iterator[int]:
    """Run numba's threaded kernels on at most ``threads`` threads inside the block.

    ``None`` leaves numba's setting alone. The count is capped by
    ``numba.config.NUMBA_NUM_THREADS`` (see :func:`usable_threads`); the previous count is
    restored afterwards, also on errors. numba's setting is per calling thread, so concurrent
    fits in different Python threads do not interfere. The results do not depend on it: every
    ``prange`` iteration writes only its own rows (see :mod:`recon.kernels.pair_loop`).

    Yields the count in effect.
    """
    previous = numba.get_num_threads()
    if threads is None:
        yield previous
        return
    numba.set_num_threads(usable_threads(threads))
    try:
        yield numba.get_num_threads()
    finally:
        numba.set_num_threads(previous)


def current_threads() -> int:
    """Numba's thread count in the calling thread: what :func:`thread_count` set for a fit
    (outside one, numba's default: all cores, or ``NUMBA_NUM_THREADS``)."""
    return int(numba.get_num_threads())


def query_workers() -> int:
    """Threads for scipy's k-d tree queries (``workers=``): numba's count in this thread.

    So ``threads`` (:func:`thread_count`) limits the k-d tree queries of a fit too; outside a
    :func:`thread_count` block it is numba's default (all cores, or ``NUMBA_NUM_THREADS``).
    A query's result does not depend on its workers.
    """
    return current_threads()


#: Below this many items a threaded region costs more than it saves even on an idle machine
#: (waking the pool takes tens of microseconds; DESIGN §3); the kernel runs in the caller.
TIMED_MIN_ITEMS = 2_000
#: A :class:`ThreadChooser` re-times the mode it is not using after this many calls ...
PROBE_EVERY = 16
#: ... and after twice as many each time that mode was again this much slower, up to
#: :data:`PROBE_EVERY_MAX` calls (so a clear loser costs little: one call in 128).
PROBE_BACKOFF = 1.5
#: See :data:`PROBE_BACKOFF`.
PROBE_EVERY_MAX = 128
#: Weight of the newest timing in a :class:`ThreadChooser`'s running mean.
TIMING_WEIGHT = 0.5


class ThreadChooser:
    """Run a kernel threaded or in the calling thread, whichever was faster lately.

    The kernels give bit-identical results either way (every ``prange`` iteration writes only
    its own rows), so the choice is a matter of speed only, and it depends on the machine's
    load: on an idle 2-core machine two threads win from ~2,000 particles, but while the other
    cores are busy a parallel region waits for descheduled threads and the calling thread alone
    is faster (measured 2026-11-23, load ~3 on 2 cores, ``bench_dynamics.py``: 27.5k particles
    2.3-2.8e7 pair interactions/s serial vs 1.3-1.8e7 threaded; 100k: 2.0-2.9e7 vs 1.6-1.8e7).
    So from :data:`TIMED_MIN_ITEMS` items (and below ``always``, if given) the chooser times
    both modes (per item, a running mean; the first call of each is not counted) and uses the
    faster, re-timing the other one after :data:`PROBE_EVERY` calls (backing off to
    :data:`PROBE_EVERY_MAX` while it keeps losing clearly). Below :data:`TIMED_MIN_ITEMS`, or
    with one numba thread (``threads=1``), it never threads.

    Usage::

        parallel = chooser.parallel(n)
        t0 = time.perf_counter()
        ...  # the kernel, under thread_limit(parallel)
        chooser.record(parallel, time.perf_counter() - t0, n)
    """

    def __init__(self, always: int | None = None) -> None:
        self.always = always
        self._per_item: list[float | None] = [None, None]  # serial, threaded [s per item]
        self._since_probe = 0
        self._interval = PROBE_EVERY
        self._probe: int | None = None  # the mode being re-timed (0 serial, 1 threaded)
        self._warm = [False, False]  # first calls (allocations, cold caches) are not timed

    def forced(self, n: int, always: int | None = None) -> bool:
        """Whether a call on ``n`` items runs threaded whatever the timings say (``always``:
        threaded from this many items, overriding the constructor's; None there and here:
        never forced)."""
        limit = self.always if always is None else always
        return limit is not None and n >= limit

    def parallel(self, n: int, always: int | None = None) -> bool:
        """Whether the next call on ``n`` items should run threaded (:meth:`forced`, else by
        the timings)."""
        if self.forced(n, always):
            return True
        if n < TIMED_MIN_ITEMS or numba.get_num_threads() < 2:
            return False
        serial, threaded = self._per_item
        if serial is None:
            return False
        if threaded is None:
            return True
        best = threaded < serial
        self._since_probe += 1
        if self._since_probe >= self._interval:
            self._since_probe = 0
            self._probe = int(not best)
            return not best
        return best

    def record(self, parallel: bool, seconds: float, n: int) -> None:
        """Account a call of ``seconds`` on ``n`` items in the given mode."""
        if n < TIMED_MIN_ITEMS:
            return
        rate = seconds / n
        slot = int(bool(parallel))
        if not self._warm[slot]:
            self._warm[slot] = True
            return
        old = self._per_item[slot]
        self._per_item[slot] = (
            rate if old is None else (TIMING_WEIGHT * rate + (1.0 - TIMING_WEIGHT) * old)
        )
        if self._probe == slot:
            self._probe = None
            other = self._per_item[1 - slot]
            losing = other is not None and self._per_item[slot] > PROBE_BACKOFF * other
            self._interval = min(2 * self._interval, PROBE_EVERY_MAX) if losing else PROBE_EVERY


@contextlib.contextmanager
def timed_threads(chooser: ThreadChooser, n: int, always: int | None = None) -> Iterator[bool]:
    """Run the block threaded or not as ``chooser`` decides for ``n`` items, and time it.

    A call that ``always`` (or the chooser's own) forces threaded is not timed: its cost per
    item, on more items than any timed call, would skew the threaded mode's running mean.

    Yields the decision (True: threaded)."""
    forced = chooser.forced(n, always)
    parallel = chooser.parallel(n, always)
    start = time.perf_counter()
    with thread_limit(parallel):
        yield parallel
    if not forced:
        chooser.record(parallel, time.perf_counter() - start, n)
