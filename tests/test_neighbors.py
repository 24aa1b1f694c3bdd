"""Cell-grid neighbour lists: equal to brute force, skin logic, changes between steps."""

from __future__ import annotations

import numpy as np
import pytest

from recon.errors import DivergenceError
from recon.neighbors import NeighborList, build_neighbor_list, sort_order_by_cell
from tests.reference import brute_force_neighbors, fibonacci_sphere


def _rows(offsets, indices):
    return [indices[offsets[i] : offsets[i + 1]] for i in range(len(offsets) - 1)]


@pytest.mark.parametrize("parallel", [False, True])
@pytest.mark.parametrize(
    "cloud",
    ["uniform", "dense", "sphere", "clustered", "far_outlier"],
)
def test_equals_brute_force(cloud, parallel):
    rng = np.random.default_rng(0)
    if cloud == "uniform":
        position = rng.uniform(-5, 5, size=(600, 3))
    elif cloud == "dense":  # ~80 neighbours per row: overflows the scratch rows, retried
        position = rng.uniform(0, 5, size=(500, 3))
    elif cloud == "sphere":
        position = fibonacci_sphere(800, 8.0)
    elif cloud == "clustered":
        position = np.vstack([rng.normal(scale=0.3, size=(200, 3)), rng.uniform(0, 1, (50, 3))])
        position = np.vstack([position, position[:10]])  # exact duplicates
    else:
        position = np.vstack([rng.uniform(0, 3, size=(100, 3)), [[1e5, -3e4, 2e5]]])
    radius = 1.7
    offsets, indices = build_neighbor_list(position, radius, parallel=parallel)
    assert offsets.dtype == np.int64 and indices.dtype == np.int32
    rows = _rows(offsets, indices)
    expected = brute_force_neighbors(position, radius)
    assert len(rows) == len(expected)
    for got, want in zip(rows, expected, strict=True):
        np.testing.assert_array_equal(got, want)  # rows are sorted ascending


def test_empty_and_single():
    offsets, indices = build_neighbor_list(np.zeros((0, 3)), 1.0)
    assert offsets.tolist() == [0] and indices.size == 0
    offsets, indices = build_neighbor_list(np.zeros((1, 3)), 1.0)
    assert offsets.tolist() == [0, 0]


def test_a_shorter_radius_read_from_a_covering_list_equals_a_new_build():
    """``NeighborList.within``: the pairs of a list that holds every pair within its cutoff,
    filtered to a shorter radius, are exactly the lists a build at that radius gives."""
    rng = np.random.default_rng(4)
    position = rng.uniform(0, 8, size=(700, 3))
    nl = NeighborList(cutoff=2.0, skin=0.4)
    nl.build(position)
    step = rng.normal(size=position.shape)
    step *= rng.uniform(0.0, 0.19, size=(len(position), 1)) / np.linalg.norm(step, axis=1)[:, None]
    moved = position + step  # every particle within skin/2 of its build position
    assert nl.covers(moved)
    for radius in (0.7, 1.5, 2.0):
        got = nl.within(moved, radius)
        want = build_neighbor_list(moved, radius)
        np.testing.assert_array_equal(got[0], want[0])
        np.testing.assert_array_equal(got[1], want[1])
        assert got[1].dtype == np.int32 and got[0].dtype == np.int64
    with pytest.raises(ValueError, match="exceeds the list's cutoff"):
        nl.within(moved, 2.1)


def test_rebuild_only_past_half_the_skin():
    rng = np.random.default_rng(1)
    position = rng.uniform(0, 10, size=(300, 3))
    nl = NeighborList(cutoff=2.0, skin=0.4)
    assert nl.update(position)
    moved = position.copy()
    moved[7] += [0.199, 0.0, 0.0]
    assert not nl.needs_rebuild(moved)
    assert not nl.update(moved)
    moved[7] += [0.002, 0.0, 0.0]
    assert nl.needs_rebuild(moved)
    assert nl.update(moved) and nl.n_builds == 2


def test_list_stays_valid_within_half_skin():
    """Every pair within the cutoff after moves of < skin/2 is still in the list."""
    rng = np.random.default_rng(2)
    position = rng.uniform(0, 8, size=(400, 3))
    nl = NeighborList(cutoff=2.0, skin=0.4)
    nl.build(position)
    step = rng.normal(size=position.shape)
    step *= 0.1999 / np.linalg.norm(step, axis=1)[:, None]
    moved = position + step
    assert not nl.needs_rebuild(moved)
    within = brute_force_neighbors(moved, 2.0)
    for i, row in enumerate(within):
        assert set(row) <= set(nl.neighbors_of(i).tolist())


def test_covers_is_exact_for_a_few_fast_particles():
    """A particle past skin/2 keeps the list valid until it (with a neighbour's own move)
    closes in on a particle that is not in its row: Δ_a + Δ_b > skin is needed."""
    position = np.array([[0.0, 0, 0], [2.45, 0, 0], [0.0, 5, 0], [0.0, -5, 0]])
    nl = NeighborList(cutoff=2.0, skin=0.4)
    nl.build(position)
    assert nl.neighbors_of(0).size == 0  # 2.45 > 2.4: not listed
    moved = position.copy()
    moved[0] += [0.0, 0.0, 0.3]  # fast, but away from everything
    assert nl.covers(moved)
    moved = position.copy()
    moved[0] += [0.3, 0.0, 0.0]  # 2.15 apart: still outside the cutoff
    assert nl.covers(moved)
    moved[1] -= [0.19, 0.0, 0.0]  # 1.96 apart: interacting, not listed
    assert not nl.covers(moved)
    moved = position.copy()
    moved[0] += [0.41, 0.0, 0.0]  # past the full skin, 2.04 apart: nothing new within 2.0
    assert nl.covers(moved)
    moved[0] += [0.1, 0.0, 0.0]  # 1.94 apart: interacting, not listed
    assert not nl.covers(moved)
    assert not nl.covers(position[:3])  # the count changed


def test_covers_checks_two_particles_past_the_skin_against_each_other():
    """Two particles that both moved more than the skin can meet although neither finds the
    other in the build grid around its new place: they are compared directly."""
    still = np.column_stack([np.arange(40.0), np.full(40, 9.0), np.zeros(40)])  # far off
    position = np.vstack([[[0.0, 0, 0], [6.0, 0, 0]], still])  # room for two fast ones
    nl = NeighborList(cutoff=2.0, skin=0.4)
    nl.build(position)
    moved = position.copy()
    moved[0] += [2.5, 0.0, 0.0]
    moved[1] -= [2.5, 0.0, 0.0]  # 1.0 apart now, 6.0 at the build: not listed
    assert not nl.covers(moved)
    moved[1] += [0.0, 0.0, 2.5]  # both far from the build, 2.7 apart: nothing interacts
    assert nl.covers(moved)


def test_covers_never_misses_a_pair():
    """Random builds and moves (a few fast particles, all jittered): whenever covers() says
    True, every pair within the cutoff is in the list (brute force)."""
    rng = np.random.default_rng(11)
    kept = 0
    for _ in range(60):
        n = int(rng.integers(40, 300))
        position = rng.uniform(0, 6, (n, 3)) * [1.0, 1.0, 0.2]
        nl = NeighborList(cutoff=2.0, skin=0.4)
        nl.build(position)
        moved = position + rng.normal(0.0, 0.03, position.shape)
        fast = rng.choice(n, size=2, replace=False)
        moved[fast] += rng.normal(0.0, 0.2, (2, 3))
        far = rng.choice(n, size=2, replace=False)  # past the skin
        moved[far] += rng.normal(0.0, 0.5, (2, 3))
        if not nl.covers(moved):
            continue
        kept += 1
        for i, row in enumerate(brute_force_neighbors(moved, 2.0)):
            assert set(row) <= set(nl.neighbors_of(i).tolist())
    assert kept > 10


def test_particle_count_change_forces_rebuild():
    position = np.random.default_rng(3).uniform(0, 5, size=(50, 3))
    nl = NeighborList(cutoff=1.5, skin=0.3)
    nl.build(position)
    assert nl.needs_rebuild(position[:40])
    assert nl.needs_rebuild(np.vstack([position, [[0.0, 0.0, 0.0]]]))


def test_non_finite_positions_raise_divergence():
    with pytest.raises(DivergenceError, match="particle 1"):
        build_neighbor_list(np.array([[0.0, 0, 0], [np.nan, 0, 0]]), 1.0)


def test_sort_order_groups_cells():
    rng = np.random.default_rng(4)
    position = rng.uniform(0, 20, size=(500, 3))
    order = sort_order_by_cell(position, 2.0)
    assert sorted(order.tolist()) == list(range(500))
    cells = np.floor((position[order] - position.min(axis=0)) / 2.0).astype(int)
    keys = (cells[:, 0] * 100 + cells[:, 1]) * 100 + cells[:, 2]
    assert np.all(np.diff(keys) >= 0)
