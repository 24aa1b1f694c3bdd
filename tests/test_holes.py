"""Hole filling's re-zip of crossing patches: local search, same result as over the whole mesh."""

from __future__ import annotations

import numpy as np
import pytest

import recon.holes as holes
from recon.holes import loft_nearest_loops, rezip_crossing_loops, zip_loop
from recon.intersections import self_intersections
from recon.mesh import boundary_loops

SHEET = 14 * 14  # the sheet's vertices come first


def _grid(n: int) -> tuple[np.ndarray, np.ndarray]:
    """An n x n vertex grid in z = 0 (unit spacing) and its faces, two per cell."""
    x, y = np.meshgrid(np.arange(n, dtype=float), np.arange(n, dtype=float), indexing="ij")
    vertices = np.stack([x.ravel(), y.ravel(), np.zeros(n * n)], axis=1)
    i, j = np.meshgrid(np.arange(n - 1), np.arange(n - 1), indexing="ij")
    a = (i * n + j).ravel()
    faces = np.concatenate([np.stack([a, a + n, a + n + 1], 1), np.stack([a, a + n + 1, a + 1], 1)])
    return vertices, faces


def _scene() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A sheet with two holes, a wall standing through the larger one (its zip crosses the
    wall), and, far away, two triangles crossing each other: an unrelated crossing."""
    n = 14
    v, f = _grid(n)
    centre = v[f].mean(axis=1)
    big = (centre[:, 0] > 4) & (centre[:, 0] < 9) & (centre[:, 1] > 4) & (centre[:, 1] < 8)
    small = (centre[:, 0] > 1) & (centre[:, 0] < 3) & (centre[:, 1] > 1) & (centre[:, 1] < 3)
    f = f[~(big | small)]
    wall_y, wall_z = np.meshgrid([3.6, 5.1, 6.3, 8.4], [-1.0, 0.35, 1.0], indexing="ij")
    wall = np.stack([np.full(wall_y.size, 6.45), wall_y.ravel(), wall_z.ravel()], axis=1)
    w = len(v) + np.arange(len(wall)).reshape(4, 3)
    wall_faces = np.concatenate(
        [
            np.stack([w[:-1, :-1].ravel(), w[1:, :-1].ravel(), w[1:, 1:].ravel()], 1),
            np.stack([w[:-1, :-1].ravel(), w[1:, 1:].ravel(), w[:-1, 1:].ravel()], 1),
        ]
    )
    far = np.array([[1000, 1000, 0], [1002, 1000, 0], [1000, 1002, 0]], dtype=float)
    far = np.vstack([far, [[1000.5, 1000.5, -1], [1000.5, 1000.5, 1], [1001.5, 1001.5, 0]]])
    o = len(v) + len(wall)
    vertices = np.vstack([v, wall, far])
    faces = np.vstack([f, wall_faces, [[o, o + 1, o + 2], [o + 3, o + 4, o + 5]]])
    normals = np.tile([0.0, 0.0, 1.0], (len(vertices), 1))
    normals[len(v) :] = [1.0, 0.0, 0.0]
    return vertices, normals, faces, o + np.arange(6)


def _zipped(vertices, faces):
    """The holes' loops in the patches' winding, their plain zips and the edge set, as
    :func:`recon.holes.fill_small_holes` hands them over."""
    he = faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    edges = set(map(tuple, np.sort(he, axis=1).tolist()))
    inner = [loop for loop in boundary_loops(faces) if loop.max() < SHEET and len(loop) <= 20]
    loops = [loop[::-1] for loop in inner]
    return loops, [zip_loop(vertices, loop, edges) for loop in loops], edges


def _rezip_over_the_whole_mesh(vertices, normals, faces, loops, patches, edges):
    """The re-zip as it was, searching every face of the mesh (the reference)."""
    owner = np.repeat(np.arange(len(patches)), [len(p) for p in patches])
    every = np.vstack([faces, *patches])
    pairs = self_intersections(vertices, every, np.arange(len(faces), len(every)))
    hit = pairs[pairs >= len(faces)] - len(faces)
    crossings = np.bincount(owner[hit], minlength=len(patches))
    patches = list(patches)
    for k in np.flatnonzero(crossings):
        rim = normals[loops[k]]
        if np.min(rim @ rim.sum(axis=0)) >= 0:
            continue
        ring = set(int(x) for x in loops[k])
        own = {
            (min(a, b), max(a, b))
            for a, b in patches[k][:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
            if not ({int(a), int(b)} <= ring and abs(holes._ring_step(loops[k], a, b)) == 1)
        }
        alt = zip_loop(vertices, loops[k], edges - own, normals)
        others = np.vstack([faces, *patches[:k], *patches[k + 1 :]])
        if holes._left_after_untangle(vertices, others, alt) < holes._left_after_untangle(
            vertices, others, patches[k]
        ):
            edges -= own
            edges |= {(min(a, b), max(a, b)) for a, b in alt[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)}
            patches[k] = alt
    return patches


@pytest.mark.parametrize("flip", [0, 3, 7])
def test_rezip_is_local_and_equals_the_search_over_the_whole_mesh(monkeypatch, flip):
    vertices, normals, faces, far = _scene()
    loops, patches, edges = _zipped(vertices, faces)
    assert len(loops) == 2
    big = int(np.argmax([len(loop) for loop in loops]))
    normals[loops[big][flip : flip + 4]] *= -1.0  # the rim normals disagree: a thin part's rim
    every = np.vstack([faces, *patches])
    assert len(self_intersections(vertices, every, np.arange(len(faces), len(every))))
    assert len(self_intersections(vertices, faces[-2:]))  # the unrelated crossing
    want_edges = set(edges)
    want = _rezip_over_the_whole_mesh(vertices, normals, faces, loops, patches, want_edges)

    seen: list[np.ndarray] = []

    def spy_crossings(v, f, subset=None):
        seen.append(v[np.unique(f)])
        return self_intersections(v, f, subset)

    def spy_untangle(v, f, **kwargs):
        seen.append(v)
        return untangle(v, f, **kwargs)

    untangle = holes.untangle
    monkeypatch.setattr(holes, "self_intersections", spy_crossings)
    monkeypatch.setattr(holes, "untangle", spy_untangle)
    got = rezip_crossing_loops(vertices, normals, faces, loops, patches, edges)
    assert len(got) == len(want)
    for a, b in zip(got, want, strict=True):
        np.testing.assert_array_equal(a, b)
    assert edges == want_edges
    assert len(seen) >= 3  # the crossing search and both untangling tests ran
    # the unrelated crossing far away took no part in any search
    assert not any(np.isin(vertices[far], s).all(axis=1).any() for s in seen)


def test_every_loop_left_open_is_logged_with_the_rule_that_keeps_it(caplog):
    """Which rule keeps a loop open (the knife's one-sided sheets: the open-sheet rule and
    ``max_hole``) is in the debug log, with the loop's perimeter, width and seam support."""
    import logging

    v, f = _grid(6)
    normals = np.tile([0.0, 0.0, 1.0], (len(v), 1))
    with caplog.at_level(logging.DEBUG, logger="recon.holes"):
        # data everywhere: the rim would be filled but is the outer rim of a small sheet
        holes.fill_small_holes(v, normals, f, 4.0, lambda p: np.ones(len(p), bool), 100.0)
        # no data test: a rim of perimeter 20 over a limit of 4
        holes.fill_small_holes(v, normals, f, 4.0)
    messages = [r.getMessage() for r in caplog.records if r.name == "recon.holes"]
    assert messages == [
        "loop of 20 edges left open: the outer rim of a small open sheet",
        "loop of 20 edges left open: perimeter 20.0, width 5.00, seam support untested",
    ]


def _loft_all_pairs(vertices, faces, max_gap, spacing=None):
    """The strips of loft_nearest_loops with every pair of loops measured (its old form)."""
    from scipy.spatial import cKDTree

    from recon.holes import loft_loops

    loops = [loop for loop in boundary_loops(faces) if len(loop) >= 3]
    trees = [cKDTree(vertices[loop]) for loop in loops]
    gap = np.full((len(loops), len(loops)), np.inf)
    for i, j in zip(*np.triu_indices(len(loops), 1), strict=True):
        gap[i, j] = gap[j, i] = max(
            np.median(trees[j].query(vertices[loops[i]])[0]),
            np.median(trees[i].query(vertices[loops[j]])[0]),
        )
    nearest = np.argmin(gap, axis=1)
    strips = []
    for i, j in enumerate(nearest):
        if i >= j or nearest[j] != i:
            continue
        here = 1.0 if spacing is None else float(np.median(spacing[np.append(loops[i], loops[j])]))
        if gap[i, j] <= max_gap * here:
            strips.append(loft_loops(vertices, loops[i], loops[j]))
    return np.concatenate([faces, *strips]) if strips else faces


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_nearest_loops_are_lofted_as_with_every_pair_measured(seed):
    """Many small discs (fans) scattered in pairs and alone: only pairs that come within reach
    are measured, and the strips are exactly those of measuring every pair."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0, 2 * np.pi, 7, endpoint=False)
    ring = np.stack([np.cos(t), np.sin(t), np.zeros(7)], axis=1)
    k = np.arange(7)
    vertices, faces = [], []
    for d in range(60):
        centre = rng.uniform(0, 40, 3)
        centre[2] = rng.choice([0.0, 0.5 + rng.uniform(0, 3)]) + 10 * (d % 3)
        base = sum(len(v) for v in vertices)
        vertices.append(np.concatenate([ring * rng.uniform(0.8, 1.2) + centre, centre[None]]))
        faces.append(np.stack([np.full(7, base + 7), base + (k + 1) % 7, base + k], 1))
    v, f = np.concatenate(vertices), np.concatenate(faces)
    spacing = rng.uniform(0.5, 1.5, len(v))
    for gap, s in ((2.0, None), (2.0, spacing), (6.0, spacing)):
        expected = _loft_all_pairs(v, f, gap, s)
        assert np.array_equal(loft_nearest_loops(v, f, gap, s), expected)
    assert len(_loft_all_pairs(v, f, 6.0, spacing)) > len(f)  # some pairs are joined


def _ring_fan(radius, z, normal_of, k=12):
    """A fan round a centre: ring ``radius`` at height ``z`` (vertices 0..k-1, centre k) and
    each vertex's normal ``normal_of(radial unit vector)``."""
    t = np.linspace(0, 2 * np.pi, k, endpoint=False)
    radial = np.stack([np.cos(t), np.sin(t), np.zeros(k)], axis=1)
    v = np.concatenate([radial * radius + [0, 0, z], [[0, 0, z]]])
    n = np.concatenate([normal_of(radial), normal_of(np.zeros((1, 3)))])
    i = np.arange(k)
    return v, n, np.stack([np.full(k, k), (i + 1) % k, i], axis=1)


@pytest.mark.parametrize("b_first", [False, True])
def test_a_thin_parts_two_rims_are_judged_the_same_from_either_loop(b_first):
    """The rims of a thin part's two faces face apart and each lies behind the other, seen
    from either loop: a pair that passes from one side only (B's normals lean over A's rim,
    so A is in front of B) is not lofted, whichever loop comes first."""

    def up(radial):
        return np.tile([0.0, 0.0, 1.0], (len(radial), 1))

    def down(radial):
        return -up(radial)

    def leaning(radial):  # 30 deg from -z, inwards over A's rim
        n = -0.5 * radial + [0.0, 0.0, -np.sqrt(0.75)]
        return n / np.linalg.norm(n, axis=1, keepdims=True)

    for b_normal, joined in ((down, True), (leaning, False)):
        parts = [_ring_fan(1.0, 0.0, up), _ring_fan(2.0, -0.2, b_normal)]
        if b_first:
            parts = parts[::-1]
        (va, na, fa), (vb, nb, fb) = parts
        v, n = np.concatenate([va, vb]), np.concatenate([na, nb])
        f = np.concatenate([fa, fb + len(va)])
        lofted = loft_nearest_loops(v, f, 4.0, None, n)
        assert (len(lofted) > len(f)) == joined


def test_the_points_across_a_slit_are_each_pairs_midpoint_once():
    """A slit 1 wide and 9 long: away from its ends each rim vertex's nearest across is the
    one facing it, and each facing pair gives one midpoint, not one per vertex (the seam
    rule's support is a share of distinct points)."""
    x = np.arange(10.0)
    top = np.stack([x, np.full(10, 0.5), np.zeros(10)], axis=1)
    ring = np.vstack([top, top[::-1] * [1.0, -1.0, 1.0]])  # round the slit
    pts = holes.across_points(ring)
    assert len(pts) < len(ring) + 1  # one per vertex and the centroid: 21
    for xi in range(3, 8):  # the facing pairs' midpoints on the slit's axis, once each
        assert np.sum(np.all(np.isclose(pts, [xi, 0.0, 0.0]), axis=1)) == 1


@pytest.mark.parametrize("block", [7, 4096])
def test_the_owner_pairs_within_the_reach_are_those_of_every_point_pair(monkeypatch, block):
    monkeypatch.setattr(holes, "PAIR_BLOCK", block)
    rng = np.random.default_rng(3)
    points = rng.random((300, 3))
    owner = np.sort(rng.integers(0, 25, 300))
    d = np.linalg.norm(points[:, None] - points[None], axis=2)
    i, j = np.nonzero(d <= 0.12)
    a, b = owner[i], owner[j]
    expected = np.unique(np.stack([a[a < b], b[a < b]], axis=1), axis=0)
    got = holes._close_owner_pairs(points, owner, 0.12)
    assert got.dtype == np.int64 and np.array_equal(got, expected)
    assert holes._close_owner_pairs(points[:1], owner[:1], 0.5).shape == (0, 2)


def test_the_loop_pair_search_holds_one_blocks_point_pairs_at_a_time():
    """Regression: the rims of a sheet that stopped at the particle cap (a 1,000-point sphere
    at --spacing 1e-3: 2,000,000 particles) met in 75 million point pairs within the reach,
    all held at once: the process grew to 24 GB and was killed. Here two discs (fans) whose
    dense rims touch at one point: about 5.7 million point pairs within the reach, nearly all
    along each rim, and no strip (the rims are far apart in median)."""
    import tracemalloc

    n = 12_000
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    ring = np.stack([np.cos(t), np.sin(t), np.zeros_like(t)], axis=1) * 40.0
    k = np.arange(n)
    fan = np.stack([np.full(n, n), k, (k + 1) % n], axis=1)
    disc = np.vstack([ring, [[0.0, 0.0, 0.0]]])
    v = np.vstack([disc, disc + [80.3, 0.0, 0.0]])
    f = np.vstack([fan, fan + len(disc)])
    tracemalloc.start()
    try:
        out = loft_nearest_loops(v, f, 5.0)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert np.array_equal(out, f)
    # all the pairs at once: their owners alone are 5.7e6 x 16 bytes (91 MB), sorted twice
    assert peak < 80 * 2**20, peak


@pytest.mark.parametrize("block", [1, 4096])  # 1: the k-d tree's rows, a few at a time
def test_the_closest_pair_of_two_loops_is_the_first_of_the_distance_matrix_on_ties(
    monkeypatch, block
):
    monkeypatch.setattr(holes, "PAIR_BLOCK", block)
    rng = np.random.default_rng(1)
    for _ in range(200):
        m, n = rng.integers(1, 40, 2)
        pa = rng.integers(0, 4, (m, 3)) * 0.5  # a coarse lattice: many equal distances
        pb = rng.integers(0, 4, (n, 3)) * 0.5 + rng.choice([0.0, 0.25])
        d = np.linalg.norm(pa[:, None] - pb[None], axis=2)
        i, j = np.unravel_index(np.argmin(d), d.shape)
        assert holes._closest_pair(pa, pb) == (i, j)


def test_a_strip_between_two_long_rims_holds_one_byte_per_vertex_pair():
    """Regression: the strip between two rims of m and n vertices held their m x n distance
    matrix (with its differences, 7 x 8 bytes a pair) and the path's m x n costs (8 bytes):
    2.2 GB for two rims of 6,000 vertices, which two long rims of a thin plate's faces
    multiply. Now the path's moves only, one byte a pair."""
    import tracemalloc

    n = 2000
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    ring = np.stack([np.cos(t), np.sin(t), np.zeros_like(t)], axis=1) * 20.0
    v = np.vstack([ring, ring + [0.05, 0.0, 0.3]])
    a, b = np.arange(n), np.arange(n, 2 * n)
    tracemalloc.start()
    try:
        strip = holes.loft_loops(v, a, b[::-1])
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert strip.shape == (2 * n, 3)
    # every face joins the rims: two corners on one, one on the other, side by side
    on_a = (strip < n).sum(axis=1)
    assert np.all((on_a == 1) | (on_a == 2))
    assert peak < 3 * n * n // 2, peak  # the moves (n^2 bytes) and a little
