"""recon.fitting.collector: the garbage collector skips the objects alive before a fit."""

from __future__ import annotations

import gc
import weakref

import numpy as np
import pytest

import recon
from recon.fitting.collector import survivors_frozen


@pytest.fixture
def sphere_points() -> np.ndarray:
    p = np.random.default_rng(0).normal(size=(600, 3))
    return p / np.linalg.norm(p, axis=1, keepdims=True)


def test_a_fit_runs_with_the_survivors_frozen_and_unfreezes_them(sphere_points):
    seen = []
    recon.fit(sphere_points, on_progress=lambda phase, info: seen.append(gc.get_freeze_count()))
    assert seen and min(seen) > 0  # frozen during every phase that reported
    assert gc.get_freeze_count() == 0  # nothing left frozen


def test_the_freeze_is_undone_when_the_fit_fails():
    with pytest.raises(ValueError), survivors_frozen():
        assert gc.get_freeze_count() > 0
        raise ValueError("a failing fit")
    assert gc.get_freeze_count() == 0


def test_a_callers_own_freeze_is_left_alone():
    gc.freeze()
    try:
        frozen = gc.get_freeze_count()
        with survivors_frozen():
            assert gc.get_freeze_count() == frozen
        assert gc.get_freeze_count() == frozen  # not unfrozen by the fit
    finally:
        gc.unfreeze()


def test_nothing_is_frozen_with_the_collector_disabled():
    gc.disable()
    try:
        with survivors_frozen():
            assert gc.get_freeze_count() == 0
    finally:
        gc.enable()


def test_garbage_made_before_the_fit_waits_for_its_end():
    """What was alive when the block began is frozen: a reference cycle dropped just before
    survives a full collection inside the block and is collected after it."""

    class Node:
        pass

    gc.collect()  # counts reset: no automatic collection before the block
    a, b = Node(), Node()
    a.other, b.other = b, a
    alive = weakref.ref(a)
    del a, b  # unreachable now, but not yet collected
    with survivors_frozen():
        gc.collect()
        assert alive() is not None
    gc.collect()
    assert alive() is None
