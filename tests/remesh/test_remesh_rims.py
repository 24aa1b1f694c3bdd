"""The rims of open meshes: a remesh keeps their boundary loops, one for one.

Ball pivoting sees particles, not the input's outline: it bridged the bays and slits of a
jagged rim (a fitted face scan's), and the pieces of rim it enclosed stayed open as loops of
their own (the fitted face-scan case, 5 loops, came out with 7, 16 and 14 at the default
spacing, --spacing-relative 0.01 and --faces 5000; exit 1). The bridges are dropped now
(:func:`recon.remesh.patches.reaching_out`), and every rim of the input keeps one loop.
"""

import numpy as np
import pytest

from recon.remesh import RemeshOptions, remesh
from recon.remesh.patches import close_gaps
from tests.mesh_shapes import grid


def _wavy_sheet(n: int = 60, amplitude: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    v, f = grid(n, n)
    v[:, 2] = amplitude * np.sin(3 * v[:, 0]) * np.cos(2 * v[:, 1])
    return v, f


def _without(v: np.ndarray, f: np.ndarray, drop: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    f = f[~drop]
    used = np.unique(f)
    remap = np.full(len(v), -1)
    remap[used] = np.arange(len(used))
    return v[used], remap[f]


def _jagged_slits(slits=((0.3, 0.02, 0.45), (0.6, 0.03, 0.3))):
    """A wavy sheet with slits cut in from its edge y = 0, (x, width, depth) each: the
    triangles whose centroids fall in them are dropped, so the slits' sides zigzag and touch
    across them at vertices (split by the input check into pinches of the rim)."""
    v, f = _wavy_sheet()
    c = v[f].mean(axis=1)
    drop = np.zeros(len(f), dtype=bool)
    for x, width, depth in slits:
        drop |= (np.abs(c[:, 0] - x) < width / 2) & (c[:, 1] < depth)
    return _without(v, f, drop)


@pytest.mark.parametrize("spacing", [0.03, 0.05])
def test_a_jagged_rim_keeps_one_loop_and_no_flat_triangles(spacing):
    """Before: 4 and 9 loops instead of 1 (exit 1); at 0.05 triangles of zero area, a rim
    vertex smoothed onto the chord of its two neighbours."""
    v, f = _jagged_slits()
    r = remesh(v, f, RemeshOptions(spacing=spacing))
    topo = r.report["output"]["topology"]
    assert r.report["topology_preserved"], r.report["warnings"]
    assert topo["boundary_loops"] == 1 and topo["components"] == 1
    assert r.report["output"]["triangle_quality"]["min_angle_min_deg"] > 5.0
    assert r.report["distance"]["hausdorff95_relative"] < 2e-4


def test_small_holes_stay_open_at_a_coarse_spacing():
    """A hole a few spacings across has few particles of its own on the loop the
    triangulation leaves around it: before, fewer than half of the loop's, so it was zipped
    as a gap (3 loops in, 1 or 2 out)."""
    v, f = _wavy_sheet(80, 0.15)
    c = v[f].mean(axis=1)
    drop = np.hypot(c[:, 0] - 0.5, c[:, 1] - 0.1) < 0.06
    drop |= np.hypot(c[:, 0] - 0.3, c[:, 1] - 0.5) < 0.04
    v, f = _without(v, f, drop)
    for spacing in (0.04, 0.06):
        r = remesh(v, f, RemeshOptions(spacing=spacing))
        assert r.report["input"]["topology"]["boundary_loops"] == 3
        assert r.report["topology_preserved"], (spacing, r.report["warnings"])


def test_a_gap_beside_a_bridged_hole_is_zipped_and_the_hole_is_not():
    """close_gaps' rule "covered": ball pivoting can bridge a small hole into pieces, none
    holding most of its particles, and leave a gap beside them that holds as many of the
    hole's particles as its own. The gap's zip lies over the input (zipped), the pieces' zips
    over the hole (kept open). By the share of outline particles both stayed open (a fitted
    face scan at --faces 5000 had its hole joined to its outer rim when the bridges went)."""
    v, f = grid(6, 6)
    n = 7  # vertex (i, j) is 7 i + j

    def square(i: int, j: int) -> list[int]:
        corners = {n * i + j, n * i + j + 1, n * (i + 1) + j, n * (i + 1) + j + 1}
        return [k for k, t in enumerate(f) if set(t.tolist()) <= corners]

    f = np.delete(f, square(1, 1) + square(4, 4), axis=0)
    i, j = np.divmod(np.arange(len(v)), n)
    rim = np.where((i % 6 == 0) | (j % 6 == 0), 1, -1)  # the outer rim: rim 1
    rim[[n * 1 + 1, n * 1 + 2]] = 0  # the gap: two of the hole's particles, two others
    rim[[n * 4 + 4, n * 4 + 5, n * 5 + 4, n * 5 + 5]] = 0  # a piece of the hole
    rim[[n * 3 + 3, n * 2 + 2]] = 0  # two more under the bridges: no loop holds most
    hole = np.array([0.75, 0.75])  # the input has no surface around the piece

    def over_surface(points: np.ndarray) -> np.ndarray:
        return np.linalg.norm(points[:, :2] - hole, axis=1) > 0.2

    normals = np.tile([0.0, 0.0, 1.0], (len(v), 1))
    for rule, zipped in (("covered", 1), ("share", 0)):
        _, _, faces, n_closed = close_gaps(v, normals, f, rim, rule, over_surface)
        assert n_closed == zipped, rule
        assert len(faces) == len(f) + 2 * zipped


def test_the_only_loop_of_a_piece_on_a_rim_stays_open():
    """close_gaps' rule "rim" keeps, for each rim, the loop with most of its particles; the
    others on it are pieces cut off it. Not the only loop of a piece of its own: a strip of a
    scan beyond a neck narrower than a spacing, cut off where the triangles across the neck
    reached out, was zipped into a closed pancake (and dropped as a stray piece: the face
    range scan lost 48 vertices' worth of surface, Hausdorff 3.7e-3 -> 3.6e-2)."""
    big_v, big_f = grid(6, 6)
    small_v, small_f = grid(2, 1, size=0.3)
    v = np.vstack([big_v, small_v + [1.5, 0.0, 0.0]])
    f = np.vstack([big_f, small_f + len(big_v)])
    on_rim = (v[:, 0] % 1.0 == 0) | (v[:, 1] % 1.0 == 0) | (v[:, 0] >= 1.5)
    on_rim |= np.isclose(v[:, 1], 0.3) & (v[:, 0] >= 1.5)
    rim = np.where(on_rim, 0, -1)  # one rim of the input: both pieces' outlines on it
    normals = np.tile([0.0, 0.0, 1.0], (len(v), 1))
    _, _, faces, n_closed = close_gaps(v, normals, f, rim, "rim")
    assert n_closed == 0 and len(faces) == len(f)
