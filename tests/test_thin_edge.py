"""The edge of a part thinner than a spacing, closed again by a strip between its two faces'
rims (#11: the held-out knife's handles ran through the band of opposed faces at its edge)."""

from __future__ import annotations

import numpy as np
import open3d as o3d
import pytest

from recon.holes import loft_loops, loft_nearest_loops
from recon.intersections import self_intersections
from recon.mesh import boundary_loops, capped_volume, count_edge_faces, handle_count
from recon.topology import mesh_topology
from recon.triangulate import TriangulationResult, _sheets_thickened, orient_consistently


def _grid(n: int, step: float, z: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """An n x n vertex grid centred on the z axis at height z (jittered) and its faces."""
    s = (np.arange(n) - (n - 1) / 2) * step
    x, y = np.meshgrid(s, s, indexing="ij")
    v = np.stack([x.ravel(), y.ravel(), np.full(n * n, z)], axis=1)
    v += rng.normal(scale=0.05 * step, size=v.shape)
    i, j = np.meshgrid(np.arange(n - 1), np.arange(n - 1), indexing="ij")
    a = (i * n + j).ravel()
    f = np.concatenate([np.stack([a, a + n, a + n + 1], 1), np.stack([a, a + n + 1, a + 1], 1)])
    return v, f


def _two_faces(notch: bool) -> tuple[np.ndarray, np.ndarray]:
    """The two faces of a thin slab 0.8 apart without the faces across its edge: a 12 x 12
    grid above, an 11 x 11 grid of another step below (rims of other lengths); with ``notch``
    the upper rim turns inward round two missing cells."""
    rng = np.random.default_rng(3)
    vt, ft = _grid(12, 1.0, 0.4, rng)
    vb, fb = _grid(11, 1.1, -0.4, rng)
    if notch:  # drop the two faces of rim cells (0, 4) and (0, 5)
        ft = np.delete(ft, [4, 5, 121 + 4, 121 + 5], axis=0)
    return np.concatenate([vt, vb]), np.concatenate([ft, fb[:, ::-1] + len(vt)])


def test_a_strip_between_two_loops_is_an_annulus_that_does_not_cross_itself():
    v, f = _two_faces(notch=True)
    top, bottom = sorted(boundary_loops(f), key=len, reverse=True)
    strip = loft_loops(v, top, bottom)
    assert len(strip) == len(top) + len(bottom)
    assert handle_count(strip, len(v)) == (1, 2, 0)
    assert len(self_intersections(v, strip)) == 0
    assert len(self_intersections(v, np.concatenate([f, strip]))) == 0


def test_the_two_faces_of_a_thin_edge_are_joined_into_one_closed_surface():
    for notch in (False, True):
        v, f = _two_faces(notch)
        closed = loft_nearest_loops(v, f, max_gap=2.0)
        normals = np.zeros_like(v)
        normals[:, 2] = np.sign(v[:, 2])
        closed = orient_consistently(v, normals, closed)
        topo = mesh_topology(v, closed)
        assert topo["watertight"] and topo["components"] == 1 and topo["genus"] == 0, topo
        mesh = o3d.geometry.TriangleMesh(
            o3d.utility.Vector3dVector(v), o3d.utility.Vector3iVector(closed)
        )
        assert mesh.is_watertight() and mesh.is_orientable()


def test_loops_farther_apart_than_the_gap_stay_open():
    v, f = _two_faces(notch=False)
    v[v[:, 2] < 0, 2] -= 5.0  # the faces 5.8 apart: two sheets, not one thin part
    assert len(loft_nearest_loops(v, f, max_gap=2.0)) == len(f)


def test_a_strip_between_two_small_loops_stays_manifold():
    # the cheapest path along the grid of vertex pairs may run along one loop first; it must
    # not come back to its first edge (two triangles 0.5 apart used to be capped by fans)
    rng = np.random.default_rng(0)
    for m, n in ((3, 3), (3, 5), (4, 3), (7, 10)):
        for _ in range(20):
            v = rng.normal(size=(m + n, 3))
            v[m:, 2] += 0.5
            b = np.arange(m, m + n)[:: rng.choice([1, -1])]
            strip = loft_loops(v, np.arange(m), b)
            assert handle_count(strip, m + n) == (1, 2, 0)
            assert count_edge_faces(strip)[1].max() == 2


def _body_and_sheet(gap: float) -> TriangulationResult:
    """A closed sphere (radius 5) and, ``gap`` beyond its equator, a one-sided open 5 x 5
    sheet in z = 0: the merged faces of a part thinner than a spacing, continuing the body."""
    sphere = o3d.geometry.TriangleMesh.create_sphere(radius=5.0, resolution=20)
    bv, bf = np.asarray(sphere.vertices), np.asarray(sphere.triangles)
    sv, sf = _grid(6, 1.0, 0.0, np.random.default_rng(0))
    sv[:, 0] += 5.0 + gap + 2.5
    v = np.concatenate([bv, sv])
    normals = np.concatenate([bv / 5.0, np.tile([0.0, 0.0, 1.0], (len(sv), 1))])
    return TriangulationResult(v, np.concatenate([bf, sf + len(bv)]), normals, {})


def test_a_one_sided_sheet_at_a_closed_body_becomes_part_of_it():
    result = _body_and_sheet(gap=0.5)
    assert handle_count(result.faces, len(result.vertices)) == (2, 1, 0)
    thick = _sheets_thickened(result)
    assert thick is not None
    topo = mesh_topology(thick.vertices, thick.faces)
    assert topo["watertight"] and topo["components"] == 1 and topo["genus"] == 0, topo
    assert len(self_intersections(thick.vertices, thick.faces)) == 0
    mesh = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(thick.vertices), o3d.utility.Vector3iVector(thick.faces)
    )
    assert mesh.is_watertight() and mesh.is_orientable()


def test_a_sheet_away_from_the_body_stays():
    assert _sheets_thickened(_body_and_sheet(gap=3.0)) is None


def test_a_sheet_that_continues_a_joined_sheet_joins_too():
    # regression (held-out knife, seed 2): the edge's last stretch was a second one-sided sheet
    # 1.1 r0 from the body but 0.95 r0 from the first sheet, which had joined it: it was
    # judged against the body without the first sheet and stayed open (2 components, 1 loop)
    first = _body_and_sheet(gap=0.5)
    sv, sf = _grid(6, 1.0, 0.0, np.random.default_rng(1))
    sv[:, 0] += 5.0 + 0.5 + 5.0 + 0.5 + 2.5  # 0.5 beyond the first sheet, 6 from the body
    v = np.concatenate([first.vertices, sv])
    normals = np.concatenate([first.normals, np.tile([0.0, 0.0, 1.0], (len(sv), 1))])
    faces = np.concatenate([first.faces, sf + len(first.vertices)])
    assert handle_count(faces, len(v)) == (3, 2, 0)
    thick = _sheets_thickened(TriangulationResult(v, faces, normals, {}))
    assert thick is not None
    topo = mesh_topology(thick.vertices, thick.faces)
    assert topo["watertight"] and topo["components"] == 1 and topo["genus"] == 0, topo
    assert len(self_intersections(thick.vertices, thick.faces)) == 0


def _edge_open_in_places() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vertices, normals and ball-pivoted faces of a thin slab's two faces (0.8 apart) whose
    band of faces across the edge leaves two stretches of three edges open."""
    rng = np.random.default_rng(0)
    vt, ft = _grid(10, 1.0, 0.4, rng)
    vb, fb = _grid(10, 1.0, -0.4, rng)
    v = np.concatenate([vt, vb])
    normals = np.zeros_like(v)
    normals[:, 2] = np.sign(v[:, 2])
    (rim,) = boundary_loops(ft)
    band = []
    for k, (a, b) in enumerate(zip(rim, np.roll(rim, -1), strict=True)):
        if k % 18 in (4, 5, 6):  # two stretches of three edges stay open
            continue
        band += [[a, b, b + len(vt)], [a, b + len(vt), a + len(vt)]]
    return v, normals, np.concatenate([ft, fb + len(vt), np.array(band)])


def test_a_thin_edge_left_open_in_places_without_a_handle_is_closed(monkeypatch):
    # regression (held-out knife, seed 1): the band of opposed faces across a blade's edge
    # closed most of it but left two stretches open; with no handle the first repair was
    # returned as it was (1 component, 2 loops), although dropping the band and joining the
    # two faces' rims by a strip closes it
    import recon.triangulate as tri
    from recon.config import TriangulationConfig

    v, normals, faces = _edge_open_in_places()
    monkeypatch.setattr(tri, "ball_pivoting", lambda *_: faces)
    result = tri.triangulate_particles(v, normals, TriangulationConfig(), 1.0, resign=False)
    topo = mesh_topology(result.vertices, result.faces)
    assert topo["watertight"] and topo["components"] == 1 and topo["genus"] == 0, topo
    mesh = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(result.vertices), o3d.utility.Vector3iVector(result.faces)
    )
    assert mesh.is_watertight() and mesh.is_orientable()


@pytest.mark.parametrize("inward", [False, True])
def test_a_sheet_beside_a_body_left_open_at_its_edge_joins_it_only_when_asked(inward):
    # regression (held-out knife, seed 0): after the opposed band was dropped and the two
    # faces' rims joined, the body kept one loop at the blade's tip, beside the one-sided
    # sheets that continue the edge; sheets were taken only by a closed body (4 components).
    # There the particle normals pointed inward, and the open body followed them inside out
    result = _body_and_sheet(gap=0.5)
    v, f, normals = result.vertices, result.faces, result.normals
    cap = np.flatnonzero(v[f[: len(f) - 50]].mean(axis=1)[:, 2] < -4.5)  # open the south pole
    f = np.delete(f, cap, axis=0)
    if inward:
        f, normals = f[:, ::-1], -normals
    result = TriangulationResult(v, f, normals, {})
    assert handle_count(result.faces, len(v)) == (2, 2, 0)
    assert _sheets_thickened(result) is None  # an open scan's patch stays one-sided
    thick = _sheets_thickened(result, open_body=True)
    assert thick is not None
    assert handle_count(thick.faces, len(thick.vertices)) == (1, 1, 0)
    assert len(self_intersections(thick.vertices, thick.faces)) == 0
    assert capped_volume(thick.vertices, thick.faces) > 0  # outward


def _body_open_beside_sheet() -> TriangulationResult:
    """``_body_and_sheet(0.5)`` with the sphere open at a patch that reaches the sheet's side
    (above the equator, y > 1, x > 3): the rest of a thin edge left open beside the one-sided
    sheet that continues it."""
    result = _body_and_sheet(gap=0.5)
    v, f = result.vertices, result.faces
    c = v[f].mean(axis=1)
    on_body = np.arange(len(f)) < len(f) - 50
    hole = on_body & (c[:, 0] > 3.0) & (c[:, 1] > 1.0) & (c[:, 2] > 0.0)
    return TriangulationResult(v, f[~hole], result.normals, {})


@pytest.mark.parametrize("data", [True, False])
def test_the_body_loop_beside_a_joined_sheet_is_zipped_where_data_lies_across_it(data):
    # regression (held-out knife, seed 0): after the edge's one-sided sheets joined the open
    # body, the body kept one loop at the tip beside them (52 edges, 103 r0 round, 4.3 r0
    # wide: neither a small hole nor a seam), with data all across it
    from recon.triangulate import _rest_zipped

    strip = _body_open_beside_sheet()
    thick = _sheets_thickened(strip, open_body=True)
    assert thick is not None and handle_count(thick.faces, len(thick.vertices)) == (1, 1, 0)
    covered = lambda p, across=False: np.full(len(p), data)  # noqa: E731
    zipped = _rest_zipped(thick, strip, strip.vertices, 1.0, (None, 4.0, covered, None, None))
    if not data:
        assert zipped is None  # no data across the loop: a real boundary, kept
        return
    assert zipped is not None
    topo = mesh_topology(zipped.vertices, zipped.faces)
    assert topo["watertight"] and topo["components"] == 1 and topo["genus"] == 0, topo
    assert len(self_intersections(zipped.vertices, zipped.faces)) == 0
    assert capped_volume(zipped.vertices, zipped.faces) > 0  # outward
    mesh = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(zipped.vertices), o3d.utility.Vector3iVector(zipped.faces)
    )
    assert mesh.is_watertight() and mesh.is_orientable()


def _edge_reach() -> float:
    """The thin-edge reach of :func:`recon.triangulate.triangulate_particles` at defaults."""
    from recon.config import TriangulationConfig
    from recon.triangulate import EDGE_REACH

    return EDGE_REACH * 2.0 * max(TriangulationConfig().radii)


def test_the_two_faces_of_a_thin_edge_join_within_the_largest_balls_diameter():
    # regression (held-out knife, seed 5): the blade's two faces stayed two open discs (2
    # components, 2 loops) because their rims lay 2.02 and 2.01 spacings apart in median,
    # beyond the strip's old limit of 2; ball pivoting spans up to its largest ball's diameter
    v, f = _two_faces(notch=False)
    v[v[:, 2] < 0, 2] -= 1.6  # the faces 2.4 apart
    assert len(loft_nearest_loops(v, f, max_gap=2.0)) == len(f)
    closed = loft_nearest_loops(v, f, max_gap=_edge_reach())
    normals = np.zeros_like(v)
    normals[:, 2] = np.sign(v[:, 2])
    topo = mesh_topology(v, orient_consistently(v, normals, closed))
    assert topo["watertight"] and topo["components"] == 1 and topo["genus"] == 0, topo


def test_a_sheet_two_spacings_from_an_open_body_at_a_thin_edge_joins_it():
    # regression (held-out knife, seed 6): two of the tip's one-sided sheets lay 1.14 and
    # 2.04 r0 from the body, beyond the 1 r0 a sheet joins a closed body from (3 components)
    result = _body_and_sheet(gap=2.0)
    assert _sheets_thickened(result) is None
    thick = _sheets_thickened(result, _edge_reach(), open_body=True)
    assert thick is not None
    assert handle_count(thick.faces, len(thick.vertices)) == (1, 0, 0)
    assert len(self_intersections(thick.vertices, thick.faces)) == 0


def test_the_nearest_rims_are_joined_first(monkeypatch):
    # regression (held-out knife, seed 7): strips up to the largest ball's diameter, tried
    # first, joined rims that are not the edge's two faces (2 components, 29 crossing pairs);
    # the wide strips are for when those within LOFT_GAP close nothing
    import recon.triangulate as tri
    from recon.config import TriangulationConfig

    v, normals, faces = _edge_open_in_places()
    gaps = []
    relofted = tri._relofted

    def spy(alt, positions, gap, args):
        gaps.append(gap)
        return relofted(alt, positions, gap, args)

    monkeypatch.setattr(tri, "ball_pivoting", lambda *_: faces)
    monkeypatch.setattr(tri, "_relofted", spy)
    result = tri.triangulate_particles(v, normals, TriangulationConfig(), 1.0, resign=False)
    assert gaps == [tri.LOFT_GAP]  # closed by the nearest rims' strip: the wide one not tried
    assert handle_count(result.faces, len(result.vertices)) == (1, 0, 0)
