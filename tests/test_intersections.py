"""Self-intersections: the finder agrees with Open3D, and untangling separates crossing sheets."""

from __future__ import annotations

import numpy as np
import open3d as o3d
import pytest
from mesh_shapes import icosphere

import recon.intersections as inter
from recon.intersections import (
    candidate_pairs,
    self_intersections,
    separate_opposed,
    untangle,
)
from recon.topology import mesh_topology


def open3d_pairs(vertices: np.ndarray, faces: np.ndarray) -> set[tuple[int, int]]:
    mesh = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(vertices), o3d.utility.Vector3iVector(faces)
    )
    return {tuple(sorted(p)) for p in np.asarray(mesh.get_self_intersecting_triangles()).tolist()}


def test_finder_agrees_with_open3d_on_random_triangles():
    rng = np.random.default_rng(3)
    n = 300
    centres = rng.uniform(0, 4, (n, 1, 3))
    vertices = (centres + rng.normal(scale=0.3, size=(n, 3, 3))).reshape(-1, 3)
    faces = np.arange(3 * n).reshape(n, 3)
    ours = {tuple(p) for p in self_intersections(vertices, faces).tolist()}
    assert len(ours) > 20  # the test means something
    assert ours == open3d_pairs(vertices, faces)


def test_subset_gives_the_pairs_touching_it():
    rng = np.random.default_rng(4)
    n = 200
    vertices = (rng.uniform(0, 3, (n, 1, 3)) + rng.normal(scale=0.3, size=(n, 3, 3))).reshape(-1, 3)
    faces = np.arange(3 * n).reshape(n, 3)
    # and one face much larger than the rest, far away
    vertices = np.vstack([vertices, [[20.0, 0, 0], [30.0, 0, 0], [20.0, 10.0, 0]]])
    faces = np.vstack([faces, [[3 * n, 3 * n + 1, 3 * n + 2]]])
    n += 1
    every = candidate_pairs(vertices, faces)
    subset = np.arange(0, n, 7)
    some = candidate_pairs(vertices, faces, subset)
    expected = every[np.isin(every, subset).any(axis=1)]
    assert sorted(map(tuple, some.tolist())) == sorted(map(tuple, expected.tolist()))


def test_a_local_subset_is_searched_among_the_faces_near_it(monkeypatch):
    """A few faces tried in a big mesh (a tube, a thickened sheet) are searched among the faces
    round them only: the same pairs as a search of the whole mesh, and the grid search is
    handed the nearby faces alone."""
    import recon.intersections as inter

    v, f = icosphere(5)  # 20,480 faces
    centroid = v[f].mean(axis=1)
    rng = np.random.default_rng(5)
    seen: list[int] = []
    overlapping = inter._overlapping

    def spy(c, r, mark, test=None):
        seen.append(len(c))
        return overlapping(c, r, mark, test)

    monkeypatch.setattr(inter, "_overlapping", spy)
    found = 0
    for _ in range(12):
        # a copy of a patch of the sphere tilted through it about a tangent axis
        centre = centroid[rng.integers(len(f))]
        near = np.linalg.norm(centroid - centre, axis=1) < 0.08
        used, local = np.unique(f[near], return_inverse=True)
        axis = np.cross(centre, rng.normal(size=3))
        axis /= np.linalg.norm(axis)
        angle = np.radians(rng.uniform(10.0, 40.0))
        d = v[used] - centre
        moved = centre + (  # Rodrigues' rotation of the patch about the axis through its centre
            d * np.cos(angle)
            + np.cross(axis, d) * np.sin(angle)
            + np.outer(d @ axis, axis) * (1.0 - np.cos(angle))
        )
        vertices = np.vstack([v, moved])
        faces = np.vstack([f, local.reshape(-1, 3) + len(v)])
        new = np.arange(len(f), len(faces))
        seen.clear()
        local_pairs = self_intersections(vertices, faces, new)
        local_candidates = candidate_pairs(vertices, faces, new)
        assert seen and max(seen) < len(faces) / 10  # the search ran near the patch
        monkeypatch.setattr(inter, "LOCAL_SHARE", -1.0)  # the search of the whole mesh
        seen.clear()
        assert np.array_equal(local_pairs, self_intersections(vertices, faces, new))
        assert np.array_equal(local_candidates, candidate_pairs(vertices, faces, new))
        assert seen == [len(faces), len(faces)]
        monkeypatch.setattr(inter, "LOCAL_SHARE", 0.5)
        found += len(local_pairs) > 0
    assert found >= 10  # the tilted patches cross the sphere


def test_a_huge_face_whose_tip_crosses_a_small_subset_is_still_found():
    # regression (second read of the local search): a face 1e9 long whose tip crosses a small
    # face by 3e-8; the exact test's sum r_i + r_j rounds to the huge radius, by more than a
    # pad relative to the small faces' coordinates alone, and the local box left it out
    h, length, x0 = 0.9216035573870036, 1.5e9, 0.9216035275846812
    far = [[-1e3, 5.0 * k, 0.0] for k in range(4)]
    far += [[-1e3, 5.0 * k + 1.0, 0.0] for k in range(4)]
    far += [[-1e3, 5.0 * k, 1.0] for k in range(4)]
    v = np.array(
        [[h, 0, 0], [h - 1.5, 0.3, 0], [h - 1.5, -0.3, 0], [x0, 0, 1e-12]]
        + [[x0 + length, 0, 1.0], [x0 + length, 0, -1.0]]
        + far,
        dtype=float,
    )
    f = np.array([[0, 1, 2], [3, 4, 5]] + [[6 + k, 10 + k, 14 + k] for k in range(4)])
    assert self_intersections(v, f[:2]).tolist() == [[0, 1]]
    assert self_intersections(v, f, [0]).tolist() == [[0, 1]]
    assert candidate_pairs(v, f, [0]).tolist() == [[0, 1]]


def test_a_face_that_is_not_finite_is_judged_by_the_search_of_the_whole_mesh():
    # regression: the local search left a far NaN face out and answered; the whole mesh's
    # search refuses it, and so does a search for a subset now
    v, f = icosphere(3)
    v = np.vstack([v, [[30.0, 0, 0], [31.0, 0, 0], [np.nan, 1.0, 0]]])
    f = np.vstack([f, [[len(v) - 3, len(v) - 2, len(v) - 1]]])
    with pytest.raises(ValueError):
        self_intersections(v, f)
    with pytest.raises(ValueError):
        self_intersections(v, f, [0])


def pinched_lens(depth: float) -> tuple[np.ndarray, np.ndarray]:
    """A flat closed lens (an icosphere squashed to 5 % thickness) whose upper sheet is pressed
    ``depth`` below the lower one inside a disc: two opposed sheets crossing each other."""
    v, f = icosphere(4)
    v = v * np.array([1.0, 1.0, 0.05])
    # upper and lower vertices share their (x, y) exactly: jitter, so that the sheets cross
    # transversally rather than edge on edge (where tests of touching faces may differ)
    v[:, :2] += np.random.default_rng(0).normal(scale=1e-3, size=(len(v), 2))
    r = np.linalg.norm(v[:, :2], axis=1)
    top = (v[:, 2] > 0) & (r < 0.4)
    bump = np.cos(r[top] / 0.4 * np.pi / 2) ** 2  # 1 at the centre, 0 on the disc's rim
    v[top, 2] -= (2 * v[top, 2] + depth) * bump  # the centre ends ``depth`` under the lower sheet
    return v, f


def test_untangle_separates_crossing_sheets():
    v, f = pinched_lens(depth=0.02)
    assert mesh_topology(v, f)["watertight"]
    before = self_intersections(v, f)
    assert len(before) > 10
    assert {tuple(p) for p in before.tolist()} == open3d_pairs(v, f)
    out, found, left = untangle(v, f)
    assert found == len(before) and left == 0
    assert len(self_intersections(out, f)) == 0
    assert not open3d_pairs(out, f)
    moved = np.linalg.norm(out - v, axis=1) > 0
    # only the pinched region moves, and the upper sheet ends above the lower one
    assert np.all(np.linalg.norm(v[moved, :2], axis=1) < 0.55)
    assert 0 < moved.sum() < 0.3 * len(v)


def test_untangle_leaves_a_clean_mesh_alone():
    v, f = icosphere(2)
    out, found, left = untangle(v, f)
    assert (found, left) == (0, 0) and np.array_equal(out, v)


def test_untangle_never_moves_fixed_vertices():
    v, f = pinched_lens(depth=0.02)
    fixed = np.zeros(len(v), dtype=bool)
    fixed[np.argsort(np.linalg.norm(v[:, :2], axis=1))[:5]] = True  # the dent's bottom
    out, found, _ = untangle(v, f, fixed=fixed)
    assert found > 0 and np.array_equal(out[fixed], v[fixed])
    assert not np.array_equal(out, v)


def test_untangle_counts_the_crossings_it_could_not_move():
    v = np.array([[0, 0, 0], [2, 0, 0], [0, 2, 0], [0.5, 0.5, -1], [0.5, 0.5, 1], [1.5, 1.5, 0]])
    f = np.array([[0, 1, 2], [3, 4, 5]])
    out, found, left = untangle(v.astype(float), f, fixed=np.ones(6, dtype=bool))
    assert (found, left) == (1, 1) and np.array_equal(out, v)


def test_candidate_pairs_equal_the_overlapping_bounding_spheres():
    """The cell-grid broad phase finds exactly the pairs whose bounding spheres overlap (brute
    force), with and without a subset, with large faces among them, sorted and unique."""
    rng = np.random.default_rng(5)
    for trial in range(12):
        nv = int(rng.integers(20, 300))
        vertices = rng.uniform(0.0, 10.0, (nv, 3))
        faces = rng.integers(0, nv, (int(rng.integers(2, 400)), 3))
        if trial % 3 == 0:
            vertices[faces[0]] *= 4.0  # a few large faces
        corners = vertices[faces]
        centroid = corners.mean(axis=1)
        radius = np.linalg.norm(corners - centroid[:, None, :], axis=2).max(axis=1)
        gap = np.linalg.norm(centroid[:, None, :] - centroid[None, :, :], axis=2)
        overlap = np.triu(gap <= radius[:, None] + radius[None, :], k=1)
        want = np.argwhere(overlap)
        np.testing.assert_array_equal(candidate_pairs(vertices, faces), want)
        subset = rng.choice(len(faces), size=max(1, len(faces) // 4), replace=False)
        mark = np.zeros(len(faces), dtype=bool)
        mark[subset] = True
        want_sub = want[mark[want[:, 0]] | mark[want[:, 1]]]
        np.testing.assert_array_equal(candidate_pairs(vertices, faces, subset), want_sub)


def test_candidate_pairs_with_faces_at_many_scales():
    """Large faces at several scales (each level more than 3x the median of the one below)
    are paired with every face they overlap, large or not, by the grid's level search: the
    pairs equal the brute-force overlaps, with and without a subset."""
    rng = np.random.default_rng(11)
    sizes = np.repeat([0.05, 0.4, 3.0, 20.0], [600, 60, 12, 3])
    centres = rng.uniform(0.0, 30.0, (len(sizes), 1, 3))
    vertices = (centres + sizes[:, None, None] * rng.normal(size=(len(sizes), 3, 3))).reshape(-1, 3)
    faces = np.arange(len(vertices)).reshape(-1, 3)
    corners = vertices[faces]
    centroid = corners.mean(axis=1)
    radius = np.linalg.norm(corners - centroid[:, None, :], axis=2).max(axis=1)
    gap = np.linalg.norm(centroid[:, None, :] - centroid[None, :, :], axis=2)
    want = np.argwhere(np.triu(gap <= radius[:, None] + radius[None, :], k=1))
    large = radius > 3.0 * np.median(radius)
    assert np.sum(large[want].all(axis=1)) > 5  # pairs of two large faces are among them
    np.testing.assert_array_equal(candidate_pairs(vertices, faces), want)
    for subset in (np.arange(0, len(faces), 9), np.flatnonzero(large)[:4]):
        mark = np.zeros(len(faces), dtype=bool)
        mark[subset] = True
        want_sub = want[mark[want[:, 0]] | mark[want[:, 1]]]
        np.testing.assert_array_equal(candidate_pairs(vertices, faces, subset), want_sub)


def test_crossing_test_fused_into_the_grid_search_equals_testing_every_candidate():
    """self_intersections tests pairs as the grid finds them: the same pairs as testing every
    candidate pair afterwards (the two-step search it replaces), with faces at several
    scales and with a subset."""
    from recon.kernels.tri_intersect import pairs_intersect

    rng = np.random.default_rng(12)
    sizes = np.repeat([0.1, 0.6, 4.0], [900, 60, 6])
    centres = rng.uniform(0.0, 6.0, (len(sizes), 1, 3))
    vertices = (centres + sizes[:, None, None] * rng.normal(size=(len(sizes), 3, 3))).reshape(-1, 3)
    faces = np.arange(len(vertices)).reshape(-1, 3)
    faces[::7, 0] = faces[1::7, 1][: len(faces[::7])]  # some pairs share a vertex
    for subset in (None, np.arange(0, len(faces), 5)):
        candidates = candidate_pairs(vertices, faces, subset)
        hit = np.zeros(len(candidates), dtype=np.bool_)
        pairs_intersect(vertices, faces, candidates, hit)
        got = self_intersections(vertices, faces, subset)
        assert len(got) > 30
        np.testing.assert_array_equal(got, candidates[hit])


@pytest.mark.parametrize("passes", [3, 5, 30])
def test_untangle_counts_what_is_left_as_a_search_of_the_whole_mesh(passes):
    """The crossings left are counted from the start's pairs where nothing moved and a search
    around the moved faces: the same as searching the whole returned mesh, also when the
    passes stop short and some crossings are held by fixed vertices."""
    v, f = pinched_lens(depth=0.1)
    fixed = np.zeros(len(v), dtype=bool)
    fixed[np.argsort(np.linalg.norm(v[:, :2], axis=1))[:3]] = True
    out, found, left = untangle(v, f, passes=passes, fixed=fixed)
    assert found > left > 0 and not np.array_equal(out, v)
    assert left == len(self_intersections(out, f))
    # and a crossing far away that nothing moves is still counted
    far = v + np.array([10.0, 0.0, 0.0])
    v2, f2 = np.vstack([v, far]), np.vstack([f, f + len(v)])
    fixed2 = np.concatenate([fixed, np.ones(len(v), dtype=bool)])
    out2, found2, left2 = untangle(v2, f2, passes=passes, fixed=fixed2)
    assert found2 == 2 * found and left2 == left + found
    assert left2 == len(self_intersections(out2, f2))


def grid_sheet(n: int, height, facing_up: bool) -> tuple[np.ndarray, np.ndarray]:
    """An n x n grid of unit spacing centred on the origin at z = height(x, y), its faces
    wound to face +z (``facing_up``) or -z."""
    xs = np.arange(n, dtype=float) - (n - 1) / 2
    x, y = (a.ravel() for a in np.meshgrid(xs, xs, indexing="ij"))
    v = np.c_[x, y, height(x, y)]
    i, j = (a.ravel() for a in np.meshgrid(np.arange(n - 1), np.arange(n - 1), indexing="ij"))
    a, b, c, d = i * n + j, (i + 1) * n + j, (i + 1) * n + j + 1, i * n + j + 1
    f = np.r_[np.c_[a, b, c], np.c_[a, c, d]]
    return v, (f if facing_up else f[:, ::-1])


def thin_part_with_a_wide_dent() -> tuple[np.ndarray, np.ndarray, int]:
    """The two sides of a thin part 0.3 apart (top facing +z at z = 0, bottom facing -z),
    the bottom bulging through the top in a wide, gentle dome (width 5 spacings): smooth
    sheets crossing at a shallow angle. Returns vertices, faces and the top's vertex count."""
    top_v, top_f = grid_sheet(13, lambda x, y: 0.0 * x, facing_up=True)
    bottom_v, bottom_f = grid_sheet(
        13, lambda x, y: -0.3 + 0.5 * np.exp(-(x**2 + y**2) / 50.0), facing_up=False
    )
    return np.vstack([top_v, bottom_v]), np.vstack([top_f, bottom_f + len(top_v)]), len(top_v)


def test_untangle_parts_opposed_sheets_that_smoothing_cannot():
    """Regression (knife seed 6 kept 4 crossing pairs): the umbrella passes alone leave most
    of the dome's crossings; pushing each side along its own normal clears them, top above
    bottom again, each vertex pushed by at most one spacing."""
    v, f, n_top = thin_part_with_a_wide_dent()
    found = len(self_intersections(v, f))
    assert found > 100
    smoothed, _, umbrella_left = untangle(v, f, separate_passes=0)
    assert umbrella_left > found // 3
    out, found_again, left = untangle(v, f)
    assert found_again == found and left == 0
    assert len(self_intersections(out, f)) == 0 and not open3d_pairs(out, f)
    centre_top, centre_bottom = n_top // 2, n_top + n_top // 2
    assert out[centre_top, 2] > out[centre_bottom, 2]
    # the push after the smoothing: at most SEPARATE_PASSES x SEPARATE_STEP = 1 spacing
    assert 0 < np.linalg.norm(out - smoothed, axis=1).max() <= 1.0 + 1e-9


def test_separate_opposed_leaves_sheets_facing_the_same_way_alone():
    """Two crossing sheets that face the same way are a fold, not the sides of a thin part:
    pushing both along +z would not part them, so nothing moves."""
    top_v, top_f = grid_sheet(7, lambda x, y: 0.0 * x, facing_up=True)
    tilted_v, tilted_f = grid_sheet(7, lambda x, y: 0.2 * x, facing_up=True)
    v, f = np.vstack([top_v, tilted_v]), np.vstack([top_f, tilted_f + len(top_v)])
    before = len(self_intersections(v, f))
    assert before > 0
    out, left = separate_opposed(v, f)
    assert left == before and np.array_equal(out, v)


def _jittered_thin_part() -> tuple[np.ndarray, np.ndarray]:
    """:func:`thin_part_with_a_wide_dent` with its grid jittered: no two faces the same size
    (on the exact grid the order-free check sends untangle to its search of every pass)."""
    v, f, _ = thin_part_with_a_wide_dent()
    v[:, :2] += np.random.default_rng(8).normal(scale=1e-3, size=(len(v), 2))
    return v, f


def test_crossings_kept_over_moves_equal_a_search_of_the_whole_mesh():
    """Every crossing pair, kept by searching again only around the faces that moved, equals
    a search of the whole mesh after each of many random moves (pairs appearing and going),
    and its pairs touching a subset equal the subset's search."""
    v, f = pinched_lens(depth=0.05)
    rng = np.random.default_rng(21)
    first = self_intersections(v, f)
    every = inter._Crossings(v, f, first)
    assert every.exact and len(first) > 10
    vertex_faces = inter._vertex_faces(f, len(v))
    dent = np.flatnonzero(np.linalg.norm(v[:, :2], axis=1) < 0.5)
    before = seen = {tuple(p) for p in first.tolist()}
    gone = 0
    for _ in range(15):
        pick = rng.choice(dent, size=int(rng.integers(1, 60)), replace=False)
        v = v.copy()
        v[pick] += rng.normal(scale=0.03, size=(len(pick), 3))
        assert every.moved(v, np.unique(vertex_faces[pick].indices))
        want = self_intersections(v, f)
        np.testing.assert_array_equal(every.touching(np.ones(len(f), dtype=bool)), want)
        mask = np.zeros(len(f), dtype=bool)
        mask[rng.choice(len(f), size=300, replace=False)] = True
        np.testing.assert_array_equal(
            every.touching(mask), self_intersections(v, f, np.flatnonzero(mask))
        )
        now = {tuple(p) for p in want.tolist()}
        gone += len(before - now)
        before, seen = now, seen | now
    assert len(seen) > len(first) + 20 and gone > 20  # pairs came and went


@pytest.mark.parametrize("case", ["lens", "fixed lens", "thin part", "umbrella only"])
def test_untangle_gives_what_searching_every_pass_gives(monkeypatch, case):
    """untangle keeps every crossing pair over its passes (and separate_opposed over its
    pushes) by searching around the faces each moves; forced to search all it asks for
    every pass instead (as when two faces' sizes may tie), it returns the same mesh and
    counts, bit for bit."""
    kwargs: dict = {}
    if case == "thin part":
        v, f = _jittered_thin_part()
    else:
        v, f = pinched_lens(depth=0.1)
    if case == "fixed lens":
        kwargs["fixed"] = np.zeros(len(v), dtype=bool)
        kwargs["fixed"][np.argsort(np.linalg.norm(v[:, :2], axis=1))[:3]] = True
    if case == "umbrella only":
        kwargs["separate_passes"] = 0
    kept = []
    moved = inter._Crossings.moved

    def spy(self, vertices, faces_moved):
        kept.append(moved(self, vertices, faces_moved))
        return kept[-1]

    monkeypatch.setattr(inter._Crossings, "moved", spy)
    got = untangle(v, f, **kwargs)
    assert len(kept) > 5 and all(kept)  # kept pairs, not searched every pass
    monkeypatch.setattr(inter, "_order_free", lambda vertices, faces: False)
    kept.clear()
    want = untangle(v, f, **kwargs)
    assert not any(kept)
    assert got[1:] == want[1:] and got[1] > got[2]
    np.testing.assert_array_equal(got[0], want[0])
    if case != "umbrella only":
        parted = separate_opposed(want[0], f, fixed=kwargs.get("fixed"))
        monkeypatch.undo()
        np.testing.assert_array_equal(
            separate_opposed(want[0], f, fixed=kwargs.get("fixed"))[0], parted[0]
        )


def test_order_free_refuses_a_flat_grid_and_accepts_a_jittered_one():
    v, f, _ = thin_part_with_a_wide_dent()
    assert not inter._order_free(v, f)  # congruent faces apart: the order could matter
    assert inter._order_free(*_jittered_thin_part())


def _sliver_through_a_wall():
    """A small grid (which sets the median edge length, 1/8) and, apart from it, a long
    sliver whose one free corner sits at the origin with its far corners 100 away, crossing a
    held wall at x = 5: each umbrella pass moves the free corner halfway toward the far
    corners, which clears the crossing by carrying it some 50 away."""
    from mesh_shapes import grid

    v, f = grid(8, 8)
    n = len(v)
    extra = np.array(
        [[0, 0, 0], [100, 0.05, 0], [100, -0.05, 0], [5, 0, -1], [5, 1, 1], [5, -1, 1]], float
    )
    v = np.vstack([v + [0, 0, 10], extra])
    f = np.vstack([f, [[n, n + 1, n + 2], [n + 3, n + 4, n + 5]]])
    fixed = np.zeros(len(v), bool)
    fixed[n + 1 :] = True
    return v, f, fixed, n


def test_untangling_moves_no_vertex_farther_than_its_reach():
    """Regression (a sphere with 5 % outliers): the umbrella passes walked a vertex beside a
    sliver hanging off a stray particle some 295 edge lengths toward the sliver's far corner
    (a spike across the scene); now each vertex stops UNTANGLE_REACH median edge lengths from
    where it was, and the crossing it could not clear within that is counted as left."""
    v, f, fixed, n = _sliver_through_a_wall()
    assert len(self_intersections(v, f)) == 1
    out, found, left = untangle(v, f, fixed=fixed)
    reach = inter.UNTANGLE_REACH * inter.median_edge(v, f)
    assert reach == pytest.approx(inter.UNTANGLE_REACH / 8)
    assert np.linalg.norm(out - v, axis=1).max() <= reach * (1 + 1e-12)
    assert (found, left) == (1, 1)
    assert left == len(self_intersections(out, f))
    # with room enough, the same passes clear it
    assert untangle(v, f, fixed=fixed, reach=1000.0)[2] == 0


def test_separation_moves_no_vertex_farther_than_its_reach():
    v = np.array([[0, 0, 0], [2, 0, 0], [0, 2, 0], [0.5, 0.5, 0.1], [0.5, 1.5, 0.1]], float)
    v = np.vstack([v, [[1.5, 0.5, -0.3]]])
    f = np.array([[0, 1, 2], [3, 4, 5]])
    parted, left = separate_opposed(v, f)
    assert left == 0  # the docstring's example: parted within its reach
    held, left = separate_opposed(v, f, origin=v, reach=0.01)
    assert np.linalg.norm(held - v, axis=1).max() <= 0.01 * (1 + 1e-12)
    assert left == 1


def test_within_reach_leaves_the_rows_within_reach_bit_for_bit():
    rng = np.random.default_rng(0)
    origin = rng.normal(size=(50, 3))
    points = origin + rng.normal(size=(50, 3)) * 0.3
    before = points.copy()
    inter.within_reach(points, origin, 0.5)
    far = np.linalg.norm(before - origin, axis=1) > 0.5
    assert far.any() and (~far).any()
    np.testing.assert_array_equal(points[~far], before[~far])
    np.testing.assert_allclose(np.linalg.norm(points[far] - origin[far], axis=1), 0.5)
