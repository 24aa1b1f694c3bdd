"""The relaxation schedule: the release's own damping and the growth rounds' active set."""

import numpy as np
import pytest

from recon.config import ReconConfig, apply_overrides, load_config
from recon.dynamics import Simulation
from recon.fitting import fit
from recon.fitting.schedule import Clock, _Schedule
from recon.state import ParticleState
from recon.surface import DataSurface

UP = np.array([0.0, 0.0, 1.0])


def _plane_schedule(overrides: dict) -> _Schedule:
    rng = np.random.default_rng(4)
    xy = rng.uniform(-12, 12, (4000, 2))
    data = np.column_stack([xy, np.zeros(len(xy))])
    surface = DataSurface.build(data, np.tile(UP, (len(data), 1)), k=16)
    cfg = apply_overrides(ReconConfig(), overrides)
    return _Schedule(surface, cfg, np.random.default_rng(0), Clock(None), None)


def _lattice(n_side: int) -> np.ndarray:
    """A square lattice at spacing 1 on z = 0, centred on the origin, slightly perturbed."""
    g = np.arange(n_side) - (n_side - 1) / 2.0
    x, y = np.meshgrid(g, g)
    pos = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    pos[:, :2] += np.random.default_rng(1).normal(scale=0.08, size=(len(pos), 2))
    return pos


def _seeded_lattice(overrides: dict):
    """A 15 x 15 lattice (225 particles over [-7, 7]^2) with pinned seeds within 2 of
    (-5, -5) and the last round's one addition at (5, 5), active radius 3."""
    sched = _plane_schedule({"growth.active_radius": 3.0, **overrides})
    pos = _lattice(15)
    state = ParticleState.from_points(pos, np.tile(UP, (len(pos), 1)))
    seeds = np.linalg.norm(pos[:, :2] - [-5.0, -5.0], axis=1) < 2.0
    state.set_pinned(seeds)
    sched.added_positions = np.array([[5.0, 5.0, 0.0]])
    return sched, pos, state, seeds


@pytest.mark.parametrize("beta", [None, 0.5])
def test_the_release_runs_with_its_own_damping(beta, monkeypatch):
    seen = []
    init = Simulation.__init__

    def spy(self, state, params, **kw):
        seen.append(params)
        init(self, state, params, **kw)

    monkeypatch.setattr(Simulation, "__init__", spy)
    rng = np.random.default_rng(0)
    p = rng.normal(size=(600, 3))
    cfg = load_config(
        overrides=["seeds.min_particles=0", f"dynamics.release_damping={beta or 'null'}"]
    )
    fit(p / np.linalg.norm(p, axis=1, keepdims=True), cfg)
    growth, release = seen[0], seen[-1]
    assert (growth.damping_linear, growth.damping_angular) == (2.0, 2.0)
    expected = 2.0 if beta is None else beta
    assert (release.damping_linear, release.damping_angular) == (expected, expected)


@pytest.mark.parametrize("beta", [None, 0.5])
def test_the_release_ends_with_the_heavy_damping_for_its_quench_steps(beta, monkeypatch):
    calls = []
    run = Simulation.run
    set_damping = Simulation.set_damping

    def spy_run(self, n_steps, callback=None):
        calls.append(("run", n_steps, self.params.damping_linear, self.params.damping_angular))
        return run(self, n_steps, callback)

    def spy_damping(self, linear, angular):
        calls.append(("damping", linear, angular))
        set_damping(self, linear, angular)

    monkeypatch.setattr(Simulation, "run", spy_run)
    monkeypatch.setattr(Simulation, "set_damping", spy_damping)
    rng = np.random.default_rng(0)
    p = rng.normal(size=(600, 3))
    cfg = load_config(
        overrides=[
            "seeds.min_particles=0",
            "dynamics.kinetic_tolerance=0",
            "dynamics.release_steps=45",
            "dynamics.release_quench_steps=15",
            "dynamics.damping_angular=1.5",
            f"dynamics.release_damping={beta or 'null'}",
        ]
    )
    rep = fit(p / np.linalg.norm(p, axis=1, keepdims=True), cfg).report
    assert rep.steps.release == 45
    switch = [i for i, c in enumerate(calls) if c[0] == "damping"]
    release = [c[1:] for c in calls if c[0] == "run"][-9:]  # 45 steps in chunks of 5
    if beta is None:  # no release damping, no quench
        assert switch == [] and all(c[1:] == (2.0, 1.5) for c in release)
        return
    assert len(switch) == 1 and calls[switch[0]][1:] == (2.0, 1.5)
    assert [c[1:] for c in release] == [(0.5, 0.5)] * 6 + [(2.0, 1.5)] * 3


def test_the_active_set_holds_the_particles_far_from_the_additions():
    sched, pos, state, seeds = _seeded_lattice({})
    d = np.linalg.norm(pos - sched.added_positions[0], axis=1)
    held = sched.hold_far(state, None)
    assert np.array_equal(held, (d > 3.0) & ~seeds)
    assert np.all(state.is_pinned[held]) and np.all(state.is_pinned[seeds])
    # a changed rest spacing makes a particle active wherever it is
    state.is_pinned[held] = False
    changed = np.zeros(state.n, dtype=bool)
    changed[np.flatnonzero(held)[0]] = True
    assert np.array_equal(sched.hold_far(state, changed), held & ~changed)
    state.is_pinned[held] = False
    # radius 0: every free particle moves
    sched.cfg = apply_overrides(sched.cfg, {"growth.active_radius": 0.0})
    assert sched.hold_far(state, None) is None


def test_a_growth_relaxation_moves_only_the_active_set_and_frees_it_after():
    sched, pos, state, seeds = _seeded_lattice({"dynamics.kinetic_tolerance": 0.0})
    near = np.linalg.norm(pos - sched.added_positions[0], axis=1) <= 3.0
    sim = Simulation(state, _physics(sched.cfg))
    before = state.position.copy()
    sched.relax(sim, state, sched.cfg.dynamics.relax_steps, "grow", None)
    moved = np.linalg.norm(state.position - before, axis=1) > 0.0
    assert np.array_equal(moved, near)  # the perturbed lattice relaxes where it may
    assert np.array_equal(state.is_pinned, seeds)  # the held ones are free again
    assert sched.steps["grow"] == sched.cfg.dynamics.relax_steps


@pytest.mark.parametrize("with_changed", [False, True])
def test_the_active_set_follows_a_particle_count_the_crease_hook_changes(with_changed):
    """The crease hook runs before every chunk and may drop or add particles: the held mask
    is taken per chunk (a regression: a mask taken once for the whole relaxation no longer
    matched the particles and raised an IndexError on lblock-clean)."""
    sched, pos, state, seeds = _seeded_lattice({"dynamics.kinetic_tolerance": 0.0})
    sim = Simulation(state, _physics(sched.cfg))
    calls = []

    def drop_one(sim, state, settle=False):
        calls.append(state.n)
        if len(calls) == 2:  # the second chunk starts with one particle fewer
            state.remove(np.arange(state.n) != state.n - 1)
            sim.notify_changed()

    sched.constrain_creases = drop_one
    changed = np.zeros(state.n, dtype=bool) if with_changed else None
    sched.relax(sim, state, sched.cfg.dynamics.relax_steps, "grow", changed)
    assert calls == [225, 225, 224]
    assert np.array_equal(state.is_pinned, seeds[:-1])  # the held ones are free again


def _physics(cfg: ReconConfig):
    from recon.params import PhysicsParams

    return PhysicsParams.from_config(cfg, spacing=1.0)
