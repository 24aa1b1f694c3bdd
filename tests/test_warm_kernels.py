"""recon.kernels.warm: a fit's kernels load from numba's cache in a background thread.

Loading must never compile (a kernel without a fresh cache is left to its first call), must
give the dispatcher the cached overload (a cache hit, not a compile), and the list of a fit's
kernels must name real kernels.
"""

from __future__ import annotations

import importlib.util
import os
import sys
import textwrap
import threading
from pathlib import Path

import pytest
from numba.core.dispatcher import Dispatcher

from recon.kernels import warm

pytestmark = pytest.mark.skipif(
    os.environ.get("NUMBA_DISABLE_JIT", "0") not in ("", "0"),
    reason="without the JIT there is no cache to load",
)

SOURCE = textwrap.dedent(
    '''
    from numba import njit


    @njit(cache=True)
    def twice(x):
        """x + x."""
        return x + x


    @njit(cache=True)
    def never_called(x):
        """x - 1."""
        return x - 1
    '''
)


def _import(path: Path, name: str):
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


def test_cached_code_is_loaded_and_nothing_is_compiled(tmp_path):
    path = tmp_path / "warm_sample.py"
    path.write_text(SOURCE)
    first = _import(path, "warm_sample_a")
    assert first.twice(2.0) == 4.0  # compiles and writes the cache
    assert warm.cached_signatures(first.never_called) == []

    # a new process's view: fresh dispatchers of the same source, nothing loaded yet
    again = _import(path, "warm_sample_b")
    assert len(again.twice.overloads) == 0
    assert len(warm.cached_signatures(again.twice)) == 1
    assert warm.load_cached([again.twice, again.never_called]) == 1
    assert len(again.twice.overloads) == 1
    assert sum(again.twice._cache_hits.values()) == 1  # loaded, not compiled
    assert len(again.never_called.overloads) == 0  # no cache: left to its first call
    assert warm.load_cached([again.twice]) == 0  # already there
    assert again.twice(3.0) == 6.0
    assert sum(again.twice._cache_misses.values()) == 0


def test_plain_functions_are_skipped():
    def plain(x):
        return x

    assert warm.load_cached([plain]) == 0


def test_the_fit_kernels_are_kernels_and_the_thread_starts_once():
    kernels = warm.resolve(warm.FIT_KERNELS)
    assert all(isinstance(k, Dispatcher) for k in kernels)
    assert len(set(map(id, kernels))) == len(kernels)
    thread = warm.warm_fit_kernels()
    assert warm.warm_fit_kernels() is thread
    thread.join(timeout=120)
    assert not thread.is_alive()


def test_a_numba_without_the_cache_internals_only_skips_the_loading(monkeypatch):
    def renamed(dispatcher):
        raise AttributeError("'_CacheFile' object has no attribute '_load_index'")

    raised = []
    monkeypatch.setattr(threading, "excepthook", raised.append)
    monkeypatch.setattr(warm, "cached_signatures", renamed)
    monkeypatch.setattr(warm, "_started", None)
    thread = warm.warm_fit_kernels(("pair_loop.step_particles",))
    thread.join(timeout=120)
    assert not thread.is_alive()
    assert raised == []  # nothing escapes the thread (it would print a traceback)


class _LockEvents:
    """Counts numba's ``numba:llvm_lock`` events (one pair per call into LLVM)."""

    def __init__(self) -> None:
        from numba.core import event

        self.starts = 0
        listener = self

        class Counter(event.Listener):
            def on_start(self, ev) -> None:
                listener.starts += 1

            def on_end(self, ev) -> None:
                pass

        self.listener = Counter()
        event.register("numba:llvm_lock", self.listener)

    def close(self) -> None:
        from numba.core import event

        event.unregister("numba:llvm_lock", self.listener)


def test_loads_run_without_numbas_llvm_lock_events_and_put_them_back(tmp_path):
    """A cache load makes hundreds of calls into LLVM, each of which fired two of numba's
    timer events; the loads take the events' callbacks off and put them back after."""
    from llvmlite.binding import ffi

    if not isinstance(getattr(getattr(ffi.lib, "_lock", None), "_cblist", None), list):
        pytest.skip("this llvmlite keeps its lock callbacks elsewhere")
    before = list(ffi.lib._lock._cblist)
    assert before, "numba registers its llvm_lock callbacks on import"
    path = tmp_path / "warm_events.py"
    path.write_text(SOURCE)
    _import(path, "warm_events_a").twice(2.0)  # writes the cache

    counted = _LockEvents()
    try:
        again = _import(path, "warm_events_b")
        assert warm.load_cached([again.twice]) == 1
        loading = counted.starts  # (reading the cache index asks LLVM for the host: a few)
        assert ffi.lib._lock._cblist == before  # the callbacks are back, in their order
        third = _import(path, "warm_events_c")
        assert third.twice(2.0) == 4.0  # a first call's load, as without the warm thread
        first_call = counted.starts - loading
        assert first_call > 50  # ... fires them for every call into LLVM
        assert loading < first_call / 10, (loading, first_call)
    finally:
        counted.close()


def test_a_load_that_raises_puts_the_callbacks_back(tmp_path, monkeypatch):
    from llvmlite.binding import ffi

    if not isinstance(getattr(getattr(ffi.lib, "_lock", None), "_cblist", None), list):
        pytest.skip("this llvmlite keeps its lock callbacks elsewhere")
    before = list(ffi.lib._lock._cblist)
    path = tmp_path / "warm_raise.py"
    path.write_text(SOURCE)
    _import(path, "warm_raise_a").twice(2.0)  # writes the cache
    kernel = _import(path, "warm_raise_b").twice
    assert warm.cached_signatures(kernel) and not kernel.overloads
    inside = []

    def broken(sig):
        inside.append(list(ffi.lib._lock._cblist))
        ffi.register_lock_callback(*before[0])  # someone registers one meanwhile
        raise OSError("unreadable cache file")

    monkeypatch.setattr(kernel, "compile", broken)
    with pytest.raises(OSError):
        warm.load_cached([kernel])
    assert inside == [[]]  # the load ran without them
    assert ffi.lib._lock._cblist == before  # and they are back, each once


def test_uncached_names_the_kernels_without_a_cache(tmp_path, monkeypatch):
    path = tmp_path / "warm_uncached.py"
    path.write_text(SOURCE)
    module = _import(path, "warm_uncached_a")
    module.twice(2.0)  # compiles and writes the cache; never_called has none
    names = ("sample.twice", "sample.never_called")
    monkeypatch.setattr(warm, "resolve", lambda _: [module.twice, module.never_called])
    assert warm.uncached(names) == ["sample.never_called"]


def test_uncached_is_empty_when_numbas_cache_internals_are_renamed(monkeypatch):
    def renamed(dispatcher):
        raise AttributeError("'_CacheFile' object has no attribute '_load_index'")

    monkeypatch.setattr(warm, "cached_signatures", renamed)
    assert warm.uncached() == []


def test_the_slow_kernels_are_fit_kernels():
    assert set(warm.SLOW_TO_COMPILE) <= set(warm.FIT_KERNELS)
    assert all(isinstance(k, Dispatcher) for k in warm.resolve(warm.SLOW_TO_COMPILE))


def test_finish_warming_waits_for_the_loading_thread(monkeypatch):
    import time

    loading = threading.Thread(target=time.sleep, args=(0.3,), daemon=True)
    monkeypatch.setattr(warm, "_started", loading)
    loading.start()
    warm.finish_warming()
    assert not loading.is_alive()
    monkeypatch.setattr(warm, "_started", None)
    warm.finish_warming()  # no thread started: returns at once
