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
    # after a block that raised its one interrupt, a late repeat is ignored
    after = signal.SIG_IGN if once else signal.default_int_handler
    assert signal.getsignal(signal.SIGINT) is after
    assert not guard.active


def test_term_takes_sigterm_over_a_handler_of_its_own_and_puts_it_back(default_sigint):
    def own(signum, frame):  # the handler outside the block
        raise AssertionError("SIGTERM reached the outer handler inside the block")

    old = signal.signal(signal.SIGTERM, own)
    try:
        guard = deferred_interrupts(once=True, term=True)
        with pytest.raises(KeyboardInterrupt), guard:
            signal.pthread_kill(threading.main_thread().ident, signal.SIGTERM)
            time.sleep(0.01)
        assert guard.raised.is_set()
        assert signal.getsignal(signal.SIGTERM) is own
        with deferred_interrupts():  # without term: the block leaves it alone
            assert signal.getsignal(signal.SIGTERM) is own
    finally:
        signal.signal(signal.SIGTERM, old)


def test_the_exit_hook_ignores_interrupts_and_is_registered_once(default_sigint, monkeypatch):
    """:func:`ignore_interrupts_at_exit` (every command calls it) registers one ``atexit``
    hook, which ignores SIGINT, and SIGTERM where it has its default action, for the
    interpreter's teardown (tests/test_interrupt.py checks it in a real exit)."""
    from recon import interrupts

    hooks = []
    monkeypatch.setattr(interrupts.atexit, "register", hooks.append)
    monkeypatch.setattr(interrupts, "_exit_hook_registered", False)
    interrupts.ignore_interrupts_at_exit()
    interrupts.ignore_interrupts_at_exit()
    assert len(hooks) == 1
    old_term = signal.getsignal(signal.SIGTERM)
    try:
        hooks[0]()
        assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
        term = signal.SIG_IGN if old_term == signal.SIG_DFL else old_term
        assert signal.getsignal(signal.SIGTERM) == term
    finally:
        signal.signal(signal.SIGTERM, old_term)


def test_with_ctrl_c_ignored_sigterm_still_raises_and_ctrl_c_stays_ignored(default_sigint):
    """A process started in the background of a script ignores SIGINT: SIGTERM must still
    clean up (before, the block took nothing and SIGTERM killed the process on the spot)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    old_term = signal.signal(signal.SIGTERM, signal.SIG_DFL)
    try:
        guard = deferred_interrupts()
        with pytest.raises(KeyboardInterrupt), guard:
            assert guard.term_only and not guard.active
            assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
            signal.pthread_kill(threading.main_thread().ident, signal.SIGTERM)
            time.sleep(0.01)
        assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
        assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL
        assert not guard.term_only
    finally:
        signal.signal(signal.SIGTERM, old_term)
