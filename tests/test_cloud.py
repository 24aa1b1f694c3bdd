"""The point-cloud type: rows taken in a new order, the Morton order of the points, and the
checks of arrays given as input (numbers, colours)."""

import numpy as np
import pytest

from recon.cloud import PointCloud, numeric_array, spatial_order, unit_colors
from recon.errors import InputError


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


def test_integer_colours_are_scaled_by_their_type_not_clipped():
    """uint8 200 is 200/255 (it was clipped to white); 16-bit channels are on 0-65535 (as
    in LAS and PLY ``ushort``), other integer types on 0-255."""
    c8 = np.array([[200, 0, 255], [1, 2, 3]], dtype=np.uint8)
    np.testing.assert_array_equal(unit_colors(c8), c8 / 255.0)
    c16 = np.array([[65535, 32768, 0]], dtype=np.uint16)
    np.testing.assert_array_equal(unit_colors(c16), c16 / 65535.0)
    c64 = np.array([[255, 128, 0]], dtype=np.int64)
    np.testing.assert_array_equal(unit_colors(c64), c64 / 255.0)
    assert unit_colors(c8).dtype == np.float64


def test_float_colours_in_the_unit_range_are_kept_as_given():
    c = np.random.default_rng(0).random((50, 3))
    c[0] = [0.0, 1.0, 0.5]
    out = unit_colors(c.astype(np.float32))
    np.testing.assert_array_equal(out, c.astype(np.float32).astype(np.float64))


@pytest.mark.parametrize(
    "colors, what",
    [
        (np.array([[0.5, 1.5, 0.0]]), r"row 0 .*\[0, 1\]"),
        (np.array([[0.5, 0.5, 0.5], [0.1, -0.2, 0.0]]), r"row 1 .*\[0, 1\]"),
        (np.array([[0.5, 0.5, 0.5], [np.nan, 0.2, 0.0]]), "row 1 .*not finite"),
        (np.array([[np.inf, 0.2, 0.0]]), "row 0 .*not finite"),
        (np.array([[-1, 0, 0]], dtype=np.int16), r"row 0 .*0-255"),
        (np.array([[300, 0, 0]], dtype=np.int32), r"row 0 .*0-255"),
    ],
)
def test_colours_out_of_range_or_not_finite_are_refused_naming_the_row(colors, what):
    with pytest.raises(InputError, match=f"colors: {what}"):
        unit_colors(colors)


def test_colours_on_a_0_255_float_scale_are_refused_with_a_hint():
    with pytest.raises(InputError, match="divide by 255"):
        unit_colors(np.array([[200.0, 10.0, 0.0]]))


def test_complex_or_textual_colours_are_refused():
    with pytest.raises(InputError, match="colors: .*complex"):
        unit_colors(np.full((2, 3), 0.5 + 0j))
    with pytest.raises(InputError, match="colors: .*numbers"):
        unit_colors([["red", "green", "blue"]])


def test_numeric_array_takes_numbers_of_any_real_type_unchanged():
    ints = np.arange(6, dtype=np.int32).reshape(2, 3)
    assert numeric_array(ints, "points") is ints
    np.testing.assert_array_equal(numeric_array([[1, 2.5, 3]], "points"), [[1, 2.5, 3]])
    objects = np.array([[1, 2, 3]], dtype=object)
    assert numeric_array(objects, "points").dtype == np.float64


@pytest.mark.parametrize(
    "given, said",
    [
        (None, "got None"),
        ("x", "numbers, got str"),
        ([["a", "b", "c"]], "numbers, got .*str"),
        ({"x": 1}, "numbers, got dict"),
        (np.ones((4, 3)) * (1 + 2j), "complex"),
        (np.array([[1, 2, 1j]], dtype=object), "numbers"),
        ([[0.0, 0.0, 1.0], [1.0, 0.0]], "rows of different lengths"),
    ],
)
def test_numeric_array_refuses_what_is_not_an_array_of_real_numbers(given, said):
    with pytest.raises(InputError, match=f"input array: normals: .*{said}"):
        numeric_array(given, "normals")
