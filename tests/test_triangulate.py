import numpy as np
import pytest

from recon.config import TriangulationConfig
from recon.mesh import boundary_loop_perimeters, boundary_loops, face_area_vectors
from recon.topology import mesh_topology
from recon.triangulate import (
    circumsphere_triangles,
    fill_small_holes,
    orient_faces,
    remove_non_manifold_faces,
    triangulate_particles,
    zip_loop,
)


def _hex_sheet(n=20, hole=0.0):
    pts = []
    for i in range(n):
        for j in range(n):
            pts.append([j + 0.5 * (i % 2), i * np.sqrt(3) / 2, 0.0])
    p = np.array(pts)
    p -= p.mean(axis=0)
    if hole:
        p = p[np.linalg.norm(p[:, :2], axis=1) > hole]
    return p, np.tile([0.0, 0.0, 1.0], (len(p), 1))


def _grid_faces(n):
    f = []
    for i in range(n - 1):
        for j in range(n - 1):
            a, b, c, d = i * n + j, i * n + j + 1, (i + 1) * n + j, (i + 1) * n + j + 1
            f += [[a, b, d], [a, d, c]]
    return np.array(f)


def test_hex_sheet_ball_pivoting_is_one_manifold_disk():
    p, n = _hex_sheet()
    res = triangulate_particles(p, n, TriangulationConfig(), max_hole=4.0)
    assert len(res.faces) > 600
    loops = boundary_loops(res.faces)
    assert len(loops) == 1
    fn = np.cross(
        res.vertices[res.faces[:, 1]] - res.vertices[res.faces[:, 0]],
        res.vertices[res.faces[:, 2]] - res.vertices[res.faces[:, 0]],
    )
    assert np.all(fn[:, 2] > 0)  # wound like the normals


def test_small_hole_is_filled_large_hole_stays():
    p, n = _hex_sheet(hole=1.2)
    small = triangulate_particles(p, n, TriangulationConfig(), max_hole=4.0)
    assert len(boundary_loops(small.faces)) == 1
    p, n = _hex_sheet(hole=3.5)
    large = triangulate_particles(p, n, TriangulationConfig(), max_hole=4.0)
    assert len(boundary_loops(large.faces)) == 2


def test_boundary_loops_of_grid_with_one_missing_face_pair():
    faces = _grid_faces(5)
    assert len(boundary_loops(faces)) == 1
    inner = faces[[i for i in range(len(faces)) if i not in (10, 11)]]
    loops = boundary_loops(inner)
    assert sorted(len(lp) for lp in loops) == [4, 16]


def test_fill_keeps_orientation_consistent():
    n = 6
    faces = _grid_faces(n)
    xy = np.stack(np.meshgrid(np.arange(n), np.arange(n)), -1).reshape(-1, 2)[:, ::-1]
    v = np.column_stack([xy, np.zeros(len(xy))]).astype(float)
    drop = [12, 13, 14, 15]
    faces = faces[[i for i in range(len(faces)) if i not in drop]]
    nrm = np.tile([0.0, 0, -1], (len(v), 1))  # _grid_faces winds this layout toward -z
    v2, n2, f2, filled = fill_small_holes(v, nrm, faces, max_perimeter=8.0)
    assert filled == 1
    assert len(boundary_loops(f2)) == 1
    # every interior edge is used once in each direction
    he = f2[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    s = {tuple(e) for e in he}
    assert len(s) == len(he)


def test_non_manifold_edge_faces_are_removed():
    faces = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4], [0, 1, 2]])
    out = remove_non_manifold_faces(faces, 5)
    assert out.tolist() == [[0, 1, 2], [1, 0, 3]]


def test_orient_faces_follows_normals():
    v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    f = np.array([[0, 2, 1]])
    out = orient_faces(v, np.tile([0.0, 0, 1], (3, 1)), f)
    assert out.tolist() == [[0, 1, 2]]


def test_circumsphere_test_on_hex_sheet_gives_equilateral_triangles():
    p, n = _hex_sheet(8)
    f = circumsphere_triangles(p, n, radius=1.5)
    assert len(f) > 50
    e = np.linalg.norm(p[f] - p[np.roll(f, 1, axis=1)], axis=2)
    assert np.allclose(e, 1.0, atol=1e-9)


def test_bow_tie_vertex_keeps_its_larger_fan():
    from recon.triangulate import non_manifold_vertex_faces

    # vertex 0 shared by a fan of two triangles and a lone triangle
    faces = np.array([[0, 1, 2], [0, 2, 3], [0, 4, 5]])
    drop = non_manifold_vertex_faces(faces, 6)
    assert drop.tolist() == [False, False, True]
    assert not non_manifold_vertex_faces(faces[:2], 6).any()


def _octahedron(center):
    v = np.array(
        [[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float
    ) + np.asarray(center, float)
    f = np.array(
        [[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]]
    )
    return v, f


def test_bow_tie_vertex_of_two_closed_surfaces_is_split():
    # two octahedra touching at one vertex: each fan is closed, so dropping a fan would open a
    # hole; the repair splits the vertex instead and both stay closed
    from recon.triangulate import repair_non_manifold

    va, fa = _octahedron([0, 0, 0])
    vb, fb = _octahedron([2, 0, 0])
    fb = fb + len(va)
    fb[fb == len(va) + 1] = 0  # b's vertex -x (at x = 1) is a's vertex +x
    v = np.vstack([va, vb])
    f = np.vstack([fa, fb])
    assert mesh_topology(v, f)["non_manifold_vertices"] == 1
    nrm = v / np.linalg.norm(v, axis=1, keepdims=True)
    v2, n2, f2 = repair_non_manifold(v, nrm, f)
    t = mesh_topology(v2, f2)
    assert t["non_manifold_vertices"] == 0 and t["non_manifold_edges"] == 0
    assert t["watertight"] and t["components"] == 2 and t["genus"] == 0
    assert len(f2) == len(f) and len(v2) == len(n2)


def test_figure_eight_boundary_is_split_into_two_simple_loops():
    from recon.triangulate import repair_non_manifold

    # two fans of two triangles each, meeting tip to tip at vertex 0: their boundaries form a
    # figure of eight through 0
    v = np.array(
        [[0, 0, 0], [1, -1, 0], [2, 0, 0], [1, 1, 0], [-1, 1, 0], [-2, 0, 0], [-1, -1, 0]], float
    )
    f = np.array([[0, 1, 2], [0, 2, 3], [0, 4, 5], [0, 5, 6]])
    nrm = np.tile([0.0, 0.0, 1.0], (len(v), 1))
    assert len(boundary_loops(f)) == 0  # the walk cannot follow a figure of eight
    v2, _, f2 = repair_non_manifold(v, nrm, f)
    assert mesh_topology(v2, f2)["non_manifold_vertices"] == 0
    assert len(boundary_loops(f2)) == 2


def _two_density_sheet(coarse=4.0):
    """A flat hex sheet: spacing 1 for x < 0, spacing ``coarse`` for x >= 0 (about 20 x 40)."""
    pts, spacing = [], []
    for step, x0, x1 in ((1.0, -20.0, -0.5), (coarse, 0.0, 20.0 + coarse / 2)):
        h = step * np.sqrt(3) / 2
        for i in range(int(40 / h) + 1):
            y = -20 + i * h
            for x in np.arange(x0 + 0.5 * step * (i % 2), x1, step):
                pts.append([x, y, 0.0])
                spacing.append(step)
    p = np.array(pts)
    return p, np.tile([0.0, 0.0, 1.0], (len(p), 1)), np.array(spacing)


def test_local_spacing_meshes_a_coarse_half_that_uniform_radii_cannot():
    pts, nrm, spacing = _two_density_sheet()
    cfg = TriangulationConfig(fill_holes=False)
    coarse = pts[:, 0] > 1.0
    uniform = triangulate_particles(pts, nrm, cfg, max_hole=4.0)
    local = triangulate_particles(pts, nrm, cfg, max_hole=4.0, local_spacing=spacing)

    def coarse_area(res):
        c = res.vertices[res.faces].mean(axis=1)
        a = 0.5 * np.linalg.norm(face_area_vectors(res.vertices, res.faces), axis=1)
        return a[c[:, 0] > 1.0].sum()

    half = 20.0 * 40.0
    assert coarse_area(uniform) < 0.1 * half  # balls of <= 2 r0 cannot span 4 r0 triangles
    assert coarse_area(local) > 0.8 * half
    t = mesh_topology(local.vertices, local.faces)
    assert t["non_manifold_edges"] == 0 and t["non_manifold_vertices"] == 0
    assert t["consistently_oriented"]
    assert coarse.sum() > 20  # the sheet really has a coarse half


def test_local_spacing_scales_the_hole_size_test():
    # six particles missing in the coarse half (spacing 4): a hole about 3 spacings across,
    # far wider than max_hole = 4 in r0 but narrower than 4 local spacings
    pts, nrm, spacing = _two_density_sheet()
    keep = np.linalg.norm(pts[:, :2] - [10.0, 0.0], axis=1) > 5.0
    pts, nrm, spacing = pts[keep], nrm[keep], spacing[keep]

    def mesh(fill):
        cfg = TriangulationConfig(fill_holes=fill)
        res = triangulate_particles(pts, nrm, cfg, max_hole=4.0, local_spacing=spacing)
        return res.vertices, res.faces

    perimeters = boundary_loop_perimeters(*mesh(False))
    assert len(perimeters) == 2 and perimeters[1] > np.pi * 4.0 * 2
    assert mesh_topology(*mesh(True))["boundary_loops"] == 1  # only the outer rim is left


def test_local_spacing_must_match_the_particles():
    pts, nrm = _hex_sheet(5)
    with pytest.raises(ValueError, match="local_spacing"):
        triangulate_particles(pts, nrm, TriangulationConfig(), 4.0, local_spacing=np.ones(3))
    with pytest.raises(ValueError, match="local_spacing"):
        triangulate_particles(
            pts, nrm, TriangulationConfig(), 4.0, local_spacing=np.zeros(len(pts))
        )


def test_seam_between_two_fronts_is_zipped_and_a_real_hole_stays():
    # a sheet with a long slit 4 spacings wide, 24 long (a seam two fronts left open: too wide
    # for the balls) and a round hole 12 spacings across; data covers the slit, not the hole
    pts, nrm = _hex_sheet(40)
    slit = (np.abs(pts[:, 1]) < 1.8) & (np.abs(pts[:, 0]) < 12)
    hole = np.linalg.norm(pts[:, :2] - [0.0, -10.0], axis=1) < 6.0
    keep = ~slit & ~hole

    def is_covered(c):
        return ~(np.linalg.norm(c[:, :2] - [0.0, -10.0], axis=1) < 5.5)

    def loops(fill):
        res = triangulate_particles(
            pts[keep], nrm[keep], TriangulationConfig(fill_holes=fill), 8.0, is_covered
        )
        return res, mesh_topology(res.vertices, res.faces)

    assert loops(False)[1]["boundary_loops"] == 3  # rim, slit, hole
    res, t = loops(True)
    assert t["boundary_loops"] == 2  # the rim and the round hole
    assert t["non_manifold_vertices"] == 0 and t["consistently_oriented"]
    c = res.vertices[res.faces].mean(axis=1)
    assert not (np.linalg.norm(c[:, :2] - [0.0, -10.0], axis=1) < 5.0).any()


def notched_loop():
    """A flat loop (counter-clockwise seen from +z) with a narrow notch down to a reflex corner:
    that corner has the shortest diagonal, but its triangle faces -z, folded over the patch."""
    xy = np.array([[0, 0], [4, 0], [4, 3], [2.1, 3], [2.0, 1.0], [1.9, 3], [0, 3]], dtype=float)
    vertices = np.c_[xy, np.zeros(len(xy))]
    normals = np.tile([0.0, 0.0, 1.0], (len(xy), 1))
    area = 0.5 * float(np.sum(xy[:, 0] * np.roll(xy[:, 1], -1) - np.roll(xy[:, 0], -1) * xy[:, 1]))
    return vertices, normals, np.arange(len(xy)), area


def test_zip_never_cuts_a_corner_whose_triangle_folds_against_the_normals():
    """Regression (bunny-nonuniform, issue 11): on a loop that wraps round the rim of a thin ear
    the shortest diagonals fold the patch back through the ear's other face (crossing faces
    untangle cannot separate). With the normals, the zipper cuts only corners whose triangle
    faces the way the normals do, so the patch covers the hole once."""
    vertices, normals, loop, area = notched_loop()
    old = zip_loop(vertices, loop)  # the shortest diagonal first: the reflex corner folds
    assert (face_area_vectors(vertices, old)[:, 2] < 0).any()
    faces = zip_loop(vertices, loop, normals=normals)
    assert len(faces) == len(loop) - 2
    up = face_area_vectors(vertices, faces)[:, 2]
    assert (up > 0).all()
    assert 0.5 * up.sum() == pytest.approx(area)  # no overlap: the areas add up to the hole's
