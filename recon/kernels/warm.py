"""Load a fit's compiled kernels from numba's cache in a background thread.

Every kernel is compiled with ``cache=True``, so a new process does not compile it, but its
first call still loads the machine code from ``__pycache__`` and links it: the kernels of a
fit, about 10 ms each and 0.2-0.3 s for the first (numba sets up its typing and target
registries then), measured on bunny-clean in a fresh process. Those loads happen one by one
on the fit's critical path, the first inside the normal estimate.

:func:`warm_fit_kernels` loads them in a daemon thread while the fit's first stages (k-d tree
queries, normal estimate) run. It only *loads*: a kernel is loaded for the signatures that its
cache index holds for the current source and machine, and nothing is ever compiled there (a
missing or stale cache is left to the first call, as before). Loading holds numba's compiler
lock, so a fit that calls a kernel being loaded waits for that load, then finds it ready;
the compiled code, hence every result, is the same either way.

numba hangs two callbacks on llvmlite's FFI lock that emit its ``numba:llvm_lock`` events
(the compile timers of its metadata) around every call into LLVM. A cache load makes about
470 such calls per kernel (numba 0.68: 15,088 for the fit's kernels, in ``add_module``'s scan
of the symbols), and the events cost 0.07-0.16 s of the 0.32-0.41 s those loads take after
the first (three pairs of fresh processes loading bunny-clean's kernels).
:func:`load_cached` takes them off for each load, holding numba's compiler lock, and puts
them back.
"""

from __future__ import annotations

import contextlib
import importlib
import threading
from collections.abc import Iterator, Sequence

from numba.core.compiler_lock import global_compiler_lock
from numba.core.dispatcher import Dispatcher

#: The kernels a fit calls from Python, ``module.function`` under :mod:`recon.kernels`, in
#: the order of their first call on a smooth scan (bunny-clean).
FIT_KERNELS: tuple[str, ...] = (
    "grid_query.coordinate_extent",
    "grid_query.grid_build",
    "grid_query.knn_grid_kernel",
    "pca.scatter_matrices",
    "thin_sides.span_screen",
    "thin_sides.split_sides_kernel",
    "gauss_map.gauss_map_kernel",
    "signs.surely_agree_within",
    "local_surface.select_agreeing",
    "local_surface.fit_quadrics_kernel",
    "poisson_disk.poisson_disk_kernel",
    "grid_query.anchor_feet_kernel",
    "cell_list.bin_particles",
    "cell_list.build_neighbor_list_kernel",
    "cell_list.sublist_within",
    "growth_rules.grow_kernel",
    "local_surface.max_angular_gap_kernel",
    "grid_query.covered_kernel",
    "pair_loop.step_particles",
    "cell_list.list_covers",
    "signs.surely_agree",
    "mesh_tables.circumradii",
    "mesh_tables.area_vectors",
    "mesh_tables.overlap_candidates",
    "mesh_tables.edge_table",
    "mesh_tables.half_edge_order",
    "mesh_tables.fan_labels",
    "mesh_tables.half_edge_winding",
    "mesh_tables.vertex_component_labels",
    "mesh_tables.bounding_spheres",
    "edge_flip.flip_edges_kernel",
    "sphere_pairs.sphere_pairs",
    "tri_intersect.pairs_intersect",
)

#: The kernels whose compiles are the longest of a first fit's: 26 s (and 9 s for the pass it
#: calls), 28 and 14 s of the 182 s that compiling every kernel of a bunny-sparse fit took on
#: the 2-core AVX2 development machine (numba's ``numba:compile`` events, exclusive times,
#: 2026-11-30). While one of them has no cache, a fit compiles for minutes before its first
#: step.
SLOW_TO_COMPILE: tuple[str, ...] = (
    "pair_loop.step_particles",
    "gauss_map.gauss_map_kernel",
    "grid_query.anchor_feet_kernel",
)

_lock = threading.Lock()
_started: threading.Thread | None = None


def cached_signatures(dispatcher: Dispatcher) -> list[tuple]:
    """The argument signatures that ``dispatcher``'s on-disk cache holds for its current
    source, bytecode and machine (empty when the cache is missing or stale)."""
    cache = getattr(dispatcher, "_cache", None)
    cache_file = getattr(cache, "_cache_file", None)
    if cache_file is None:  # no cache=True (a NullCache)
        return []
    codegen = dispatcher.targetctx.codegen()
    return [key[0] for key in cache_file._load_index() if key == cache._index_key(key[0], codegen)]


def uncached(names: Sequence[str] = FIT_KERNELS) -> list[str]:
    """Those of ``names`` (``module.function`` under :mod:`recon.kernels`) whose cache holds no
    signature for the current source and machine: a fit compiles them at their first call
    (the first run on a machine, after an upgrade, or with the cache deleted). Empty without
    the JIT, and when numba's cache cannot be read this way (the note it feeds is then left
    out: nothing depends on it)."""
    try:
        return [
            name
            for name, kernel in zip(names, resolve(names), strict=True)
            if isinstance(kernel, Dispatcher) and not cached_signatures(kernel)
        ]
    except Exception:  # noqa: BLE001 - numba internals renamed: no note, the fit is the same
        return []


def load_cached(dispatchers: Sequence[object]) -> int:
    """Load every cached overload of ``dispatchers`` (plain functions, e.g. with
    ``NUMBA_DISABLE_JIT``, are skipped); returns how many signatures were loaded.

    Each goes through ``Dispatcher.compile``, which takes numba's compiler lock, returns an
    overload already there and otherwise loads the cache entry; it would compile only if an
    entry that the index lists could not be read, as the first call would then."""
    n = 0
    for dispatcher in dispatchers:
        if not isinstance(dispatcher, Dispatcher):
            continue
        for sig in cached_signatures(dispatcher):
            if tuple(sig) not in dispatcher.overloads:
                with global_compiler_lock, _llvm_lock_events_off():
                    dispatcher.compile(sig)
                n += 1
    return n


@contextlib.contextmanager
def _llvm_lock_events_off() -> Iterator[None]:
    """Without the callbacks on llvmlite's FFI lock (numba's ``numba:llvm_lock`` events; the
    module docstring) inside the block; they are put back, in their order, after it, also
    when the block raises. The caller holds numba's compiler lock, so no compile runs
    meanwhile; calls into LLVM from other threads (none in a fit) emit no events meanwhile
    either, which only numba's timers and traces would miss. Where llvmlite keeps its
    callbacks elsewhere, the block runs with them."""
    from llvmlite.binding import ffi

    lock = getattr(getattr(ffi, "lib", None), "_lock", None)
    callbacks = getattr(lock, "_cblist", None)
    guard = getattr(lock, "_lock", None)
    if not isinstance(callbacks, list) or not callbacks or guard is None:
        yield
        return
    saved: list = []
    try:
        with guard:  # the FFI lock's own: no FFI call is between its callbacks meanwhile
            saved = list(callbacks)
            callbacks.clear()
        yield
    finally:
        with guard:
            callbacks[:0] = [c for c in saved if c not in callbacks]


def resolve(names: Sequence[str]) -> list[object]:
    """The kernel objects named ``module.function`` under :mod:`recon.kernels`."""
    out = []
    for name in names:
        module, function = name.rsplit(".", 1)
        out.append(getattr(importlib.import_module(f"{__package__}.{module}"), function))
    return out


def _load_quietly(dispatchers: Sequence[object]) -> None:
    """:func:`load_cached` as a pure optimisation: it reads numba's cache through internals
    that a future numba may rename, and any failure there only means the kernels load on
    their first call, as without this thread, so it is not reported."""
    try:
        load_cached(dispatchers)
    except Exception:  # noqa: BLE001 - nothing a fit depends on happens here
        pass


def warm_fit_kernels(names: Sequence[str] = FIT_KERNELS) -> threading.Thread:
    """Start (once per process) the daemon thread that loads ``names``' cached code; returns
    it (already finished or running)."""
    global _started
    with _lock:
        if _started is None:
            kernels = resolve(names)  # imported here, in the caller's thread
            _started = threading.Thread(
                target=_load_quietly, args=(kernels,), name="oprecon-warm-kernels", daemon=True
            )
            _started.start()
        return _started


def finish_warming(timeout: float | None = None) -> None:
    """Wait (up to ``timeout`` seconds; None: as long as it takes) for the loading thread,
    when this process started one. A measurement of the process's own allocations
    (``tracemalloc`` counts every thread's) would otherwise count the loads: 17 MB traced for
    the fit's kernels (bunny-clean's, 2026-11-30)."""
    with _lock:
        thread = _started
    if thread is not None:
        thread.join(timeout)
