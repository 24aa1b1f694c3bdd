"""Compilation options shared by every kernel.

All kernels are compiled with ``cache=True`` and a ``fastmath`` flag set that deliberately omits
``nnan`` and ``ninf``: the integrator tests every particle's new state for non-finite values
(:class:`recon.errors.DivergenceError`), and with those two flags LLVM may fold such tests to
``True``. The remaining flags (reassociation, contraction, reciprocal and approximate functions,
no signed zeros) keep the vectorisation and FMA benefits of ``fastmath=True``.

References
----------
.. [NB] Numba documentation, "Performance tips: fastmath".
"""

from __future__ import annotations

FASTMATH: frozenset[str] = frozenset({"nsz", "arcp", "contract", "afn", "reassoc"})
"""LLVM fast-math flags: ``fastmath=True`` minus ``nnan``/``ninf`` (see the module docstring)."""

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
