"""Step counts follow the sheet's kinetic energy (dynamics.kinetic_tolerance), not fixed counts."""

import numpy as np
import pytest

from recon.config import load_config
from recon.fitting import fit

FAST = ["seeds.min_particles=0"]


@pytest.fixture(scope="module")
def sphere():
    rng = np.random.default_rng(0)
    p = rng.normal(size=(1500, 3))
    return p / np.linalg.norm(p, axis=1, keepdims=True)


def _fit(points, tolerance):
    cfg = load_config(overrides=FAST + [f"dynamics.kinetic_tolerance={tolerance}"])
    rep = fit(points, cfg).report
    return rep, rep.to_dict()["history"], cfg.dynamics


def test_a_sheet_at_rest_stops_before_the_caps(sphere):
    rep, hist, dyn = _fit(sphere, 0.0001)
    assert rep.steps.release < dyn.release_steps
    # it stopped because the last release chunk ended at rest, after the refills
    release = [k for k, ph in zip(hist["kinetic"], hist["phase"], strict=True) if ph == "release"]
    assert release[-1] < 1e-4
    assert len(release) > 3
    # the first growth round has only pinned seeds: nothing can move, no step is run
    assert hist["step"][0] == 0


@pytest.mark.parametrize("tolerance", [0, 1e-12])
def test_a_sheet_not_at_rest_runs_the_full_counts(sphere, tolerance):
    rep, hist, dyn = _fit(sphere, tolerance)
    assert rep.steps.release == dyn.release_steps
    rounds = [s for s, ph in zip(hist["step"], hist["phase"], strict=True) if ph == "grow"]
    if tolerance == 0:  # every growth relaxation runs relax_steps
        assert all(b - a == dyn.relax_steps for a, b in zip([0] + rounds, rounds, strict=False))
    else:  # every round but the first (only pinned seeds: no step) runs relax_steps
        assert rounds[0] == 0
        assert all(b - a == dyn.relax_steps for a, b in zip(rounds, rounds[1:], strict=False))


def test_anchors_are_refreshed_only_for_the_particles_that_moved():
    from recon.config import ReconConfig
    from recon.fitting.schedule import ANCHOR_MOVE, Clock, _Schedule
    from recon.state import ParticleState
    from recon.surface import DataSurface

    rng = np.random.default_rng(2)
    xy = rng.uniform(-10, 10, (3000, 2))
    data = np.column_stack([xy, 0.02 * (xy**2).sum(axis=1)])  # a curved cap
    surface = DataSurface.build(data, np.tile([0.0, 0.0, 1.0], (len(data), 1)), k=16)
    sched = _Schedule(surface, ReconConfig(), np.random.default_rng(0), Clock(None), None)
    pos = np.column_stack([rng.uniform(-5, 5, (50, 2)), np.full(50, 0.3)])
    state = ParticleState.from_points(pos, np.tile([0.0, 0.0, 1.0], (50, 1)))
    first = [a.copy() for a in sched.refresh_anchors(state)]
    state.position[0, 0] += ANCHOR_MOVE + 0.1
    state.position[1, 0] += ANCHOR_MOVE  # not more than ANCHOR_MOVE: keeps its anchor
    pts, nrm = sched.refresh_anchors(state)
    exact, exact_n, _ = surface.anchors(state.position, state.normal)
    assert np.allclose(pts[0], exact[0]) and not np.allclose(pts[0], first[0][0])
    assert np.array_equal(pts[1:], first[0][1:])
    assert np.array_equal(pts[2:], exact[2:])  # the ones that did not move: exact anyway
    sched.forget_anchors()
    pts, nrm = sched.refresh_anchors(state)
    assert np.array_equal(pts, exact) and np.array_equal(nrm, exact_n)


def test_anchors_follow_their_particles_through_a_growth_round():
    """Appending particles and sorting them keeps the others' anchors: the next refresh
    queries only the new particles, and gives what a full refresh would."""
    from recon.config import ReconConfig
    from recon.fitting.schedule import Clock, _Schedule
    from recon.state import ParticleState
    from recon.surface import DataSurface

    rng = np.random.default_rng(3)
    xy = rng.uniform(-10, 10, (3000, 2))
    data = np.column_stack([xy, 0.02 * (xy**2).sum(axis=1)])
    surface = DataSurface.build(data, np.tile([0.0, 0.0, 1.0], (len(data), 1)), k=16)
    sched = _Schedule(surface, ReconConfig(), np.random.default_rng(0), Clock(None), None)
    up = np.tile([0.0, 0.0, 1.0], (40, 1))
    state = ParticleState.from_points(
        np.column_stack([rng.uniform(-5, 5, (40, 2)), np.full(40, 0.3)]), up
    )
    sched.refresh_anchors(state)
    state.add(np.column_stack([rng.uniform(-5, 5, (7, 2)), np.full(7, -0.2)]), up[:7])
    order = rng.permutation(state.n)
    state.reorder(order)
    sched.reorder_anchors(7, order)
    queried = []
    anchors = surface.anchors

    def spy(positions, normals=None, **kw):
        queried.append(len(positions))
        return anchors(positions, normals, **kw)

    surface.anchors = spy
    pts, nrm = sched.refresh_anchors(state)
    exact, exact_n, _ = anchors(state.position, state.normal)
    assert queried == [7]
    assert np.array_equal(pts, exact) and np.array_equal(nrm, exact_n)


def test_when_every_particle_moved_the_anchors_equal_a_fresh_refresh():
    """A release step moves every particle: the anchors (one call over all of them, started
    from the previous anchors' data points) equal a fresh refresh's, and a later partial
    refresh still updates only the particle that moved."""
    from recon.config import ReconConfig
    from recon.fitting.schedule import ANCHOR_MOVE, Clock, _Schedule
    from recon.state import ParticleState
    from recon.surface import DataSurface

    rng = np.random.default_rng(4)
    xy = rng.uniform(-10, 10, (3000, 2))
    data = np.column_stack([xy, 0.02 * (xy**2).sum(axis=1)])
    surface = DataSurface.build(data, np.tile([0.0, 0.0, 1.0], (len(data), 1)), k=16)
    sched = _Schedule(surface, ReconConfig(), np.random.default_rng(0), Clock(None), None)
    pos = np.column_stack([rng.uniform(-5, 5, (30, 2)), np.full(30, 0.3)])
    state = ParticleState.from_points(pos, np.tile([0.0, 0.0, 1.0], (30, 1)))
    sched.refresh_anchors(state)
    state.position[:, :2] += ANCHOR_MOVE + 0.05
    calls = []
    anchors = surface.anchors

    def spy(positions, normals=None, **kw):
        calls.append((len(positions), kw.get("hint") is not None))
        return anchors(positions, normals, **kw)

    surface.anchors = spy
    pts, nrm = sched.refresh_anchors(state)
    exact, exact_n, _ = anchors(state.position, state.normal)
    assert calls == [(30, True)]
    assert np.array_equal(pts, exact) and np.array_equal(nrm, exact_n)
    state.position[5, 0] += ANCHOR_MOVE + 0.1
    pts, _ = sched.refresh_anchors(state)
    exact, _, _ = anchors(state.position, state.normal)
    assert calls[1:] == [(1, True)] and np.array_equal(pts, exact)
