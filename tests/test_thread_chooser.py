"""Serial or threaded kernels by measured speed (:class:`recon.kernels.options.ThreadChooser`):
the decision rules, and states that do not depend on the decisions."""

from __future__ import annotations

import numba
import numpy as np
import pytest
from scipy.spatial import cKDTree

from recon.config import ReconConfig
from recon.dynamics import Simulation
from recon.kernels import options
from recon.kernels.options import PROBE_EVERY, TIMED_MIN_ITEMS, ThreadChooser, thread_count
from recon.neighbors import PointGrid
from recon.params import PhysicsParams
from recon.state import ParticleState
from tests.reference import hex_sheet, unit

N = 10 * TIMED_MIN_ITEMS
needs_two = pytest.mark.skipif(
    int(numba.config.NUMBA_NUM_THREADS) < 2, reason="numba has fewer than 2 threads here"
)


def _decisions(chooser: ThreadChooser, n: int, calls: int, serial_s: float, threaded_s: float):
    """Run ``calls`` fake calls that take the given seconds per mode; return the decisions."""
    out = []
    for _ in range(calls):
        parallel = chooser.parallel(n)
        chooser.record(parallel, threaded_s if parallel else serial_s, n)
        out.append(parallel)
    return out


@needs_two
@pytest.mark.parametrize("threaded_faster", [True, False])
def test_chooser_times_both_modes_then_uses_the_faster_and_probes_the_other(threaded_faster):
    with thread_count(2):
        chooser = ThreadChooser(always=10 * N)
        serial_s, threaded_s = (2.0, 1.0) if threaded_faster else (1.0, 2.0)
        got = _decisions(chooser, N, 4 * PROBE_EVERY, serial_s, threaded_s)
    assert got[:4] == [False, False, True, True]  # each mode: a warm-up call, then timed
    rest = got[4:]
    best = sum(p == threaded_faster for p in rest)
    probes = len(rest) - best
    assert 1 <= probes <= len(rest) // PROBE_EVERY + 1  # the other mode only now and then
    assert best > probes


@needs_two
def test_chooser_follows_a_change_of_load():
    with thread_count(2):
        chooser = ThreadChooser(always=10 * N)
        _decisions(chooser, N, 3 * PROBE_EVERY, 2.0, 1.0)  # threads win ...
        later = _decisions(chooser, N, 3 * PROBE_EVERY, 2.0, 8.0)  # ... then the core is busy
    switched = later[2:]  # one slow threaded call is enough to switch
    assert not all(later)
    assert sum(switched) <= len(switched) // PROBE_EVERY + 1  # threaded: only the probes


def test_chooser_limits():
    chooser = ThreadChooser(always=N)
    assert chooser.parallel(N) and chooser.parallel(N + 1)  # from ``always``: threaded
    assert not chooser.parallel(TIMED_MIN_ITEMS - 1)  # tiny: never
    assert chooser.parallel(5, always=0)
    with thread_count(1):  # one thread: nothing to choose
        assert not any(_decisions(ThreadChooser(always=10 * N), N, 5, 2.0, 1.0))


def _sheet(k: int = 48) -> ParticleState:
    rng = np.random.default_rng(1)
    position = hex_sheet(k, k) + rng.normal(scale=0.05, size=(k * k, 3))
    normal = unit(np.array([0.0, 0.0, 1.0]) + rng.normal(scale=0.1, size=(k * k, 3)))
    return ParticleState.from_points(position, normal)


@needs_two
def test_states_do_not_depend_on_the_choices(monkeypatch):
    """A chooser that flips between serial and threaded every call gives the same states as
    serial steps."""
    params = PhysicsParams.from_config(ReconConfig(), spacing=1.0)
    flips = iter(range(10**6))
    monkeypatch.setattr(
        options.ThreadChooser, "parallel", lambda self, n, always=None: next(flips) % 2 == 1
    )
    assert _sheet().n >= TIMED_MIN_ITEMS
    runs = []
    for parallel in (None, False):
        state = _sheet()
        sim = Simulation(state, params, parallel=parallel)
        sim.set_anchors(state.position.copy(), state.normal.copy(), 1.0, 0.5)
        sim.run(12)
        runs.append((state.position.copy(), state.orientation.copy(), sim.n_rebuilds))
    assert np.array_equal(runs[0][0], runs[1][0])
    assert np.array_equal(runs[0][1], runs[1][1])


@needs_two
@pytest.mark.parametrize(("threaded_s", "rare"), [(2.0, True), (1.2, False)])
def test_a_clear_loser_is_re_timed_ever_more_rarely(threaded_s, rare):
    calls = 8 * options.PROBE_EVERY_MAX
    with thread_count(2):
        got = _decisions(ThreadChooser(), N, calls, 1.0, threaded_s)
    probes = sum(got[4:])
    if rare:  # intervals 16, 32, 64, 128, 128, ...
        assert 1 <= probes <= calls // options.PROBE_EVERY_MAX + 4
    else:  # within PROBE_BACKOFF: every PROBE_EVERY calls
        assert probes >= calls // PROBE_EVERY - 2


@needs_two
def test_point_grid_queries_ask_a_chooser_and_answer_the_same_either_way(monkeypatch):
    """Grid queries of fewer than PARALLEL_MIN_PARTICLES points (a growth round's, the
    coverage test's) are timed both ways by a chooser, and the answers do not depend on it."""
    asked = []
    flips = iter(range(10**6))

    def parallel(self, n, always=None):
        asked.append(n)
        return next(flips) % 2 == 1

    monkeypatch.setattr(options.ThreadChooser, "parallel", parallel)
    rng = np.random.default_rng(3)
    points, query = rng.uniform(size=(20_000, 3)), rng.uniform(size=(5_000, 3))
    grid = PointGrid(points, 0.05)
    knn = [grid.query(query, k=4) for _ in range(2)]  # one threaded, one serial
    cover = [grid.covered(query, 0.02) for _ in range(2)]
    assert asked == [5_000] * 4
    assert np.array_equal(knn[0][0], knn[1][0]) and np.array_equal(knn[0][1], knn[1][1])
    assert np.array_equal(cover[0], cover[1])
    dist, idx = cKDTree(points).query(query, k=4)
    assert np.array_equal(knn[0][1], idx) and np.allclose(knn[0][0], dist)
    assert np.array_equal(cover[0], cKDTree(points).query(query)[0] <= 0.02)


def test_a_call_forced_threaded_is_not_timed():
    """timed_threads does not let a call that ``always`` forces threaded (more items than the
    timed calls) into the chooser's running means."""
    chooser = ThreadChooser()
    with options.timed_threads(chooser, N, always=N) as parallel:
        assert parallel
    assert chooser._per_item == [None, None] and chooser._warm == [False, False]
    with options.timed_threads(chooser, N, always=N + 1):
        pass
    assert chooser._warm != [False, False]  # a timed call is recorded (its first warms up)
