"""Tests of recon.interrupts: Ctrl-C held back from fragile code, raised once when asked."""

from __future__ import annotations

import signal
import threading
import time

import pytest

from recon.interrupts import deferred_interrupts


@pytest.fixture
def default_sigint():
    """Python's own SIGINT handler (a test runner's worker may have replaced it)."""
    if threading.current_thread() is not threading.main_thread():
        pytest.skip("signals are handled in the main thread only")
    old = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, old)


def interrupt() -> None:
    """SIGINT to the main thread, handled before this returns to the caller's next line."""
    signal.pthread_kill(threading.main_thread().ident, signal.SIGINT)
    time.sleep(0.01)


@pytest.mark.parametrize("once", [False, True])
def test_a_repeated_interrupt_breaks_the_clean_up_unless_once(default_sigint, once):
    guard = deferred_interrupts(once=once)
    cleaned = False
    with pytest.raises(KeyboardInterrupt), guard:
        try:
            assert not guard.raised.is_set()
            interrupt()
        finally:
            interrupt()  # the sender repeats itself while the first one is handled
            cleaned = True
    assert guard.raised.is_set()
    assert cleaned is once
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
