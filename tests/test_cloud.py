"""The point-cloud type: rows taken in a new order, and the Morton order of the points."""

import numpy as np

from recon.cloud import PointCloud, spatial_order


def test_the_corners_of_a_cube_follow_the_z_curve():
    """Hand case: the Morton code of a corner is its bits z y x, so the corners of the unit
    cube come out in the order of the binary numbers zyx."""
    corners = np.array([[x, y, z] for z in (1, 0) for y in (0, 1) for x in (1, 0)], float)
    order = spatial_order(corners)
    codes = corners[:, 0] + 2 * corners[:, 1] + 4 * corners[:, 2]
    assert codes[order].tolist() == list(range(8))


def test_the_order_is_a_permutation_that_keeps_ties_in_input_order():
    rng = np.random.default_rng(0)
    pts = rng.random((1000, 3))
    pts[500:] = pts[:500]  # every point twice: ties
    order = spatial_order(pts)
    assert np.array_equal(np.sort(order), np.arange(1000))
    first = {}
    for k in order:
        key = pts[k].tobytes()
        assert first.setdefault(key, k) <= k  # the earlier row of a tie comes first
    assert len(spatial_order(np.zeros((0, 3)))) == 0
    assert spatial_order(np.ones((3, 3))).tolist() == [0, 1, 2]  # one cell: input order


def test_points_close_in_the_order_are_close_in_space():
    """Consecutive points of a shuffled surface sample are far apart; in Morton order they
    are a few spacings apart on average."""
    rng = np.random.default_rng(1)
    u, v = rng.uniform(0, 2 * np.pi, (2, 20000))
    pts = np.stack([(1 + 0.35 * np.cos(v)) * np.cos(u), (1 + 0.35 * np.cos(v)) * np.sin(u)], 1)
    pts = np.column_stack([pts, 0.35 * np.sin(v)])
    step = np.linalg.norm(np.diff(pts, axis=0), axis=1).mean()
    ordered = pts[spatial_order(pts)]
    step_ordered = np.linalg.norm(np.diff(ordered, axis=0), axis=1).mean()
    spacing = np.sqrt(4 * np.pi**2 * 0.35 / len(pts))  # torus area / n
    assert step > 50 * spacing
    assert step_ordered < 5 * spacing


def test_take_keeps_every_row_aligned():
    pts = np.arange(12.0).reshape(4, 3)
    cloud = PointCloud(
        pts,
        np.array([1.0, 2.0, 3.0]),
        normals=pts / 10,
        colors=pts / 12,
        info={"n_points": 4},
        attributes={"intensity": np.arange(4.0)},
    )
    order = np.array([2, 0, 3, 1])
    moved = cloud.take(order)
    assert np.array_equal(moved.points, pts[order])
    assert np.array_equal(moved.normals, pts[order] / 10)
    assert np.array_equal(moved.colors, pts[order] / 12)
    assert moved.attributes["intensity"].tolist() == [2.0, 0.0, 3.0, 1.0]
    assert np.array_equal(moved.origin, cloud.origin) and moved.info == cloud.info
    assert PointCloud(pts, np.zeros(3)).take(order).normals is None
