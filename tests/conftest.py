"""Suite-wide fixtures."""

import pytest


@pytest.fixture(autouse=True)
def _keep_the_test_process_allocator(monkeypatch):
    """The commands that run one fit make glibc keep freed memory for reuse (recon/heap.py).
    The pytest process runs them through click's runner and measures its own memory
    (tests/test_tiling.py), so in this process ``recon.heap`` finds no glibc and changes
    nothing; the processes that tests start behave as they do for users. tests/test_heap.py
    checks the policy in processes of their own and the calls through a recorder."""
    from recon import heap

    monkeypatch.setattr(heap, "_glibc", lambda: None)


@pytest.fixture
def no_kernel_loading():
    """Measurements with ``tracemalloc`` (it counts every thread's allocations) wait first for
    the thread that loads a fit's kernels (:mod:`recon.kernels.warm`), started by an earlier
    fit in this process: its 17 MB fell inside a split's measurement once, under load."""
    from recon.kernels.warm import finish_warming

    finish_warming(timeout=120.0)
