"""Compilation options shared by every kernel.

All kernels are compiled with ``cache=True`` and a reduced ``fastmath`` flag set:

- ``nnan`` and ``ninf`` are omitted because the integrator tests every particle's new state for
  non-finite values (:class:`recon.errors.DivergenceError`), and with those flags LLVM may fold
  such tests to ``True``;
- ``reassoc`` and ``contract`` are omitted because they let the result depend on inlining and
  vectorisation decisions, which differ between the serial and the threaded twin of a kernel;
  without them both give bit-identical states. The per-pair loop does not vectorise (gathers,
  branches), and measured on the 100k-particle benchmark the two flags made no difference
  beyond the timing noise.

What remains (``nsz``, ``arcp``, ``afn``) lets LLVM use reciprocals and ignore signed zeros.

Numba's cache is keyed on the source file of each jitted function only: after editing a kernel
module that others call (quaternion, weights, the term modules, local_surface, this file), delete
``recon/kernels/__pycache__/*.nb[ic]`` so that the callers are recompiled.

References
----------
.. [NB] Numba documentation, "Performance tips: fastmath".
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import numba

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
