import numpy as np
import pytest
from scipy.spatial import cKDTree

import recon.growth as growth
from recon.config import GrowthConfig
from recon.growth import (
    accept_candidates,
    grow_candidates,
    past_a_fold,
    stretch_candidates,
)
from recon.neighbors import build_neighbor_list
from recon.surface import DataSurface


def _only_first_row(offsets):
    """CSR offsets with every row but the first emptied (so only particle 0 can grow when
    ``min_neighbors >= 1``), keeping the arrays in bounds for the kernel."""
    out = np.full_like(offsets, offsets[1])
    out[0] = 0
    return out


def test_isolated_particle_grows_a_hexagon_in_its_tangent_plane():
    pos = np.array([[0.0, 0.0, 0.0]])
    nrm = np.array([[0.0, 0.0, 1.0]])
    off, idx = build_neighbor_list(pos, 1.5)
    c = grow_candidates(pos, nrm, off, idx, GrowthConfig())
    assert len(c) == 6
    assert np.allclose(np.linalg.norm(c, axis=1), 1.0)
    assert np.allclose(c[:, 2], 0.0)
    d = np.linalg.norm(c[:, None] - c[None], axis=2)
    assert np.isclose(np.sort(d, axis=1)[:, 1].min(), 1.0)  # hexagon: neighbours 1 apart


def test_boundary_particle_fills_only_the_open_side():
    # particle at origin with neighbours on the -x half plane
    ang = np.deg2rad([90, 150, 210, 270])
    nb = np.column_stack([np.cos(ang), np.sin(ang), np.zeros(4)])
    pos = np.vstack([[0.0, 0, 0], nb])
    nrm = np.tile([0.0, 0, 1], (5, 1))
    off, idx = build_neighbor_list(pos, 1.5)
    cfg = GrowthConfig(min_neighbors=1, max_neighbors=5)
    c = grow_candidates(pos, nrm, _only_first_row(off), idx, cfg)
    # gap of 180 degrees on the +x side: 2 candidates at 330 and 30 degrees
    assert len(c) == 2
    assert np.all(c[:, 0] > 0.8)


def test_full_ring_does_not_grow():
    ang = np.deg2rad(np.arange(0, 360, 60))
    pos = np.vstack([[0.0, 0, 0], np.column_stack([np.cos(ang), np.sin(ang), np.zeros(6)])])
    nrm = np.tile([0.0, 0, 1], (7, 1))
    off, idx = build_neighbor_list(pos, 1.5)
    cfg = GrowthConfig(min_neighbors=1, max_neighbors=6)
    c = grow_candidates(pos, nrm, _only_first_row(off), idx, cfg)
    assert len(c) == 0


def test_stretch_adds_midpoint_of_distant_pair():
    pos = np.array([[0.0, 0, 0], [2.2, 0, 0]])
    nrm = np.tile([0.0, 0, 1], (2, 1))
    c = stretch_candidates(pos, nrm, cKDTree(pos), np.array([True, True]), GrowthConfig())
    assert np.allclose(c, [[1.1, 0, 0]])
    far = np.array([[0.0, 0, 0], [3.0, 0, 0]])
    assert (
        len(stretch_candidates(far, nrm, cKDTree(far), np.array([True, True]), GrowthConfig())) == 0
    )


def _plane_with_hole(hole_radius, spacing=0.5, half=8.0):
    g = np.arange(-half, half + 1e-9, spacing)
    xy = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    xy = xy[np.linalg.norm(xy, axis=1) >= hole_radius]
    pts = np.column_stack([xy, np.zeros(len(xy))])
    return DataSurface.build(pts, np.tile([0.0, 0, 1], (len(pts), 1)), k=12)


GAP4 = GrowthConfig(max_gap=4.0)


def _accept(surface, cands, particles, cfg=GAP4):
    return accept_candidates(
        cands, cKDTree(particles), surface, cKDTree(surface.points), surface.points, cfg
    )


def test_candidate_in_small_hole_is_accepted_and_projected():
    s = _plane_with_hole(1.5)  # hole diameter 3 < max_gap 4
    particles = s.points[::3]
    acc = _accept(s, np.array([[0.0, 0.0, 0.3]]), particles)
    assert len(acc.positions) == 1
    assert abs(acc.positions[0, 2]) < 1e-9


def test_candidate_in_large_hole_is_rejected():
    s = _plane_with_hole(3.0)  # diameter 6 > max_gap 4
    acc = _accept(s, np.array([[0.0, 0.0, 0.0]]), s.points[::3])
    assert len(acc.positions) == 0
    assert acc.n_unsupported == 1


def test_candidate_past_open_boundary_is_rejected():
    s = _plane_with_hole(0.0)
    acc = _accept(s, np.array([[9.5, 0.0, 0.0]]), s.points[::3])
    assert len(acc.positions) == 0


def test_candidate_off_the_tangent_plane_is_rejected():
    s = _plane_with_hole(1.5)
    acc = _accept(s, np.array([[0.0, 0.0, 1.2]]), s.points[::3])
    assert len(acc.positions) == 0
    assert acc.n_off_plane == 1


def test_candidates_too_close_to_particles_or_each_other_are_thinned():
    s = _plane_with_hole(2.0)
    particles = s.points
    cands = np.array([[0.0, 0.0, 0.0], [0.3, 0.0, 0.0], [1.99, 0.0, 0.0]])
    acc = _accept(s, cands, particles)
    assert len(acc.positions) == 1  # second is too close to the first, third to a particle


def test_growth_never_joins_two_opposed_sheets():
    """A candidate grown from the top sheet of a thin slab, nearest to the bottom sheet's data,
    lands on the top sheet (data of its own sheet) or nowhere, never on the bottom sheet."""
    g = np.arange(-6.0, 6.0 + 1e-9, 0.5)
    xy = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    top = np.column_stack([xy, np.full(len(xy), 0.6)])
    bottom = np.column_stack([xy, np.full(len(xy), -0.6)])
    pts = np.vstack([top, bottom])
    nrm = np.vstack([np.tile([0.0, 0, 1], (len(xy), 1)), np.tile([0.0, 0, -1], (len(xy), 1))])
    s = DataSurface.build(pts, nrm, k=12)
    cand = np.array([[0.1, 0.1, -0.1]])
    particles = np.array([[3.0, 3.0, 0.6], [3.0, 3.0, -0.6]])
    cfg = GrowthConfig(max_gap=4.0, tangent_tolerance=1.0)
    tree = cKDTree(s.points)
    acc = accept_candidates(
        cand, cKDTree(particles), s, tree, s.points, cfg, normals=np.array([[0.0, 0, 1]])
    )
    assert len(acc.positions) == 1
    assert acc.positions[0, 2] == pytest.approx(0.6) and acc.normals[0, 2] > 0.99
    # without the parent normal the nearest (opposed) sheet takes it
    acc = accept_candidates(cand, cKDTree(particles), s, tree, s.points, cfg)
    assert acc.positions[0, 2] == pytest.approx(-0.6)
    # deep in the other sheet's data (no agreeing data nearby): rejected, not joined
    deep = np.array([[0.1, 0.1, -0.5]])
    acc = accept_candidates(
        deep, cKDTree(particles), s, tree, s.points, cfg, normals=np.array([[0.0, 0, 1]])
    )
    assert len(acc.positions) == 0 and acc.n_off_plane == 1


def test_candidates_carry_their_parent_normals():
    pos = np.array([[0.0, 0.0, 0.0], [10.0, 0.0, 0.0]])
    nrm = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0]])
    offsets = np.zeros(3, dtype=np.int64)
    cands, normals = grow_candidates(
        pos, nrm, offsets, np.zeros(0, dtype=np.int32), GrowthConfig(), with_normals=True
    )
    assert (
        len(cands) == 12 and np.allclose(normals[:6], nrm[0]) and np.allclose(normals[6:], nrm[1])
    )
    pair = np.array([[0.0, 0.0, 0.0], [2.2, 0.0, 0.0]])
    both = np.array([[0.0, 0.0, 1.0], [0.0, 0.6, 0.8]])
    mid, mid_n = stretch_candidates(
        pair, both, cKDTree(pair), np.array([True, True]), GrowthConfig(), with_normals=True
    )
    assert len(mid) == 1 and np.allclose(
        mid_n[0], (both[0] + both[1]) / np.linalg.norm(both[0] + both[1])
    )


def _two_ears(thickness=0.3, spacing=0.5, notch=1.5):
    """Two thin plates side by side in the plane z = 0 (x < -notch and x > notch), joined
    below y = -3 (a U-shaped notch 2 ``notch`` wide between them), each sampled on both
    faces: the top face at z = +thickness / 2 with normal +z, the bottom face at
    -thickness / 2 with normal -z (the faces meet at the rims, as an ear's do)."""
    g = np.arange(-6.0, 6.0 + 1e-9, spacing)
    xy = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    xy = xy[(np.abs(xy[:, 0]) >= notch) | (xy[:, 1] <= -3.0)]
    pts = np.vstack(
        [
            np.column_stack([xy, np.full(len(xy), 0.5 * thickness)]),
            np.column_stack([xy, np.full(len(xy), -0.5 * thickness)]),
        ]
    )
    nrm = np.vstack([np.tile([0.0, 0, 1], (len(xy), 1)), np.tile([0.0, 0, -1], (len(xy), 1))])
    return DataSurface.build(pts, nrm, k=12)


def test_the_notch_beside_a_thin_parts_rim_is_not_a_hole():
    """Regression (held-out eared shape, 3,000 points, seeds 2 and 3): the top face of an ear
    grew into the notch between the ears, which the data surrounds within ``max_gap`` (ear,
    head, ear), and the mesh kept a web there with holes, back faces and 5-6 handles."""
    s = _two_ears()
    up = np.array([[0.0, 0, 1]])
    cand = np.array([[0.0, 0.0, 0.15]])  # mid-notch, 1.5 from either rim (3 < max_gap 4)
    far = np.array([[5.0, 5.0, 0.0]])
    # the data surrounds it: without its sheet's normal (no fold rule) it is taken
    assert len(_accept(s, cand, far).positions) == 1
    acc = accept_candidates(cand, cKDTree(far), s, cKDTree(s.points), s.points, GAP4, normals=up)
    assert len(acc.positions) == 0 and acc.n_unsupported == 1
    # a notch narrower than the rule's reach keeps data on both sides: still taken for a hole
    s = _two_ears(notch=0.75)
    acc = accept_candidates(cand, cKDTree(far), s, cKDTree(s.points), s.points, GAP4, normals=up)
    assert len(acc.positions) == 1


def test_an_opening_through_a_thin_part_is_not_grown_over():
    """A hole through a thin plate (a washer's) has the notch's rim: the data wraps round it.
    It is an opening of the shape, not missing data."""
    g = np.arange(-6.0, 6.0 + 1e-9, 0.5)
    xy = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    xy = xy[np.linalg.norm(xy, axis=1) >= 1.5]
    pts = np.vstack([np.column_stack([xy, np.full(len(xy), z)]) for z in (0.15, -0.15)])
    nrm = np.vstack([np.tile([0.0, 0, z], (len(xy), 1)) for z in (1.0, -1.0)])
    s = DataSurface.build(pts, nrm, k=12)
    cand, far = np.array([[0.0, 0.0, 0.15]]), np.array([[5.0, 5.0, 0.0]])
    assert len(_accept(s, cand, far).positions) == 1  # within max_gap 4: a hole, without it
    acc = accept_candidates(
        cand, cKDTree(far), s, cKDTree(s.points), s.points, GAP4, normals=np.array([[0.0, 0, 1]])
    )
    assert len(acc.positions) == 0


def test_a_hole_in_a_sheet_is_still_filled_with_the_fold_rule():
    """The fold rule asks for the other face at the rim: a hole in a single sheet has none."""
    s = _plane_with_hole(1.5)
    far = np.array([[5.0, 5.0, 0.0]])
    acc = accept_candidates(
        np.array([[0.0, 0.0, 0.3]]),
        cKDTree(far),
        s,
        cKDTree(s.points),
        s.points,
        GAP4,
        normals=np.array([[0.0, 0, 1]]),
    )
    assert len(acc.positions) == 1


def test_past_a_fold_needs_the_opposed_face_and_data_on_one_side(monkeypatch):
    s = _two_ears()
    up = np.array([[0.0, 0, 1]] * 3)
    cands = np.array(
        [
            [0.8, 0.0, 0.15],  # 0.7 past the right ear's inner rim
            [3.0, 0.0, 0.15],  # on the ear's top face
            [0.8, 0.0, 0.15],  # the same as the first, on a sheet facing down
        ]
    )
    sheet = np.array([[0.0, 0, 1], [0.0, 0, 1], [0.0, 0, -1]])
    nearest = s.tree.query(cands)[1]
    fold = past_a_fold(cands, up, sheet, nearest, s)
    # the first: the rim's bottom face opposes its sheet and the data lies on one side; the
    # second is among the face's samples; the third's own sheet faces down, where the
    # rim's top face opposes it
    assert fold.tolist() == [True, False, True]
    monkeypatch.setattr(growth, "FOLD_BLOCK", 2)  # in blocks: the same answer
    assert past_a_fold(cands, up, sheet, nearest, s).tolist() == [True, False, True]
    # a single sheet's open edge is no fold (the support test, not this rule, judges it)
    plane = _plane_with_hole(0.0)
    edge = np.array([[8.7, 0.0, 0.0]])
    assert not past_a_fold(edge, up[:1], up[:1], plane.tree.query(edge)[1], plane)[0]


def _folded_sheet(turn_deg, spacing=0.5, half=6.0):
    """The sheet z = 0, x <= 0 (normal +z) and a second sheet leaving its edge (the y axis)
    turned by ``turn_deg``: along (cos t, 0, -sin t), normal (sin t, 0, cos t), so the two
    normals are ``turn_deg`` apart (0: one plane; near 180: the two faces of a knife)."""
    t = np.radians(turn_deg)
    g = np.arange(-half, half + 1e-9, spacing)
    steps = np.arange(spacing, half + 1e-9, spacing)
    a = np.stack(np.meshgrid(-steps[::-1], g), -1).reshape(-1, 2)
    a = np.vstack([a, np.column_stack([np.zeros(len(g)), g])])  # the edge belongs to it
    s, y = (m.ravel() for m in np.meshgrid(steps, g))
    b = np.column_stack([s * np.cos(t), y, -s * np.sin(t)])
    pts = np.vstack([np.column_stack([a, np.zeros(len(a))]), b])
    nrm = np.vstack(
        [np.tile([0.0, 0, 1], (len(a), 1)), np.tile([np.sin(t), 0, np.cos(t)], (len(b), 1))]
    )
    return DataSurface.build(pts, nrm, k=12)


@pytest.mark.parametrize(("turn_deg", "fold"), [(100.0, False), (150.0, True)])
def test_a_fold_is_a_turn_well_past_a_right_angle(turn_deg, fold):
    """Past the edge of a sheet whose data turns back under it: a turn of 150 deg is the rim
    of a thin part; one of 100 deg (a box's edge, a leg's junction with a body, where noisy
    normals stray past 90 deg) is not, though its normals oppose the sheet's (dot -0.17;
    the rule asks for less than ``FOLD_OPPOSED`` = -0.25, about 105 deg)."""
    s = _folded_sheet(turn_deg)
    cand, up = np.array([[0.7, 0.0, 0.0]]), np.array([[0.0, 0, 1]])
    assert past_a_fold(cand, up, up, s.tree.query(cand)[1], s)[0] == fold
