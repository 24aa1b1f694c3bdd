"""Re-signing the particles' normals before ball pivoting (:mod:`recon.particle_signs`)
across sharp edges and thin parts, where consistent normals point more than 90 deg apart."""

import numpy as np
import pytest

from recon.config import TriangulationConfig
from recon.particle_signs import consistent_normals, reflected_dots
from recon.topology import mesh_topology
from recon.triangulate import triangulate_particles


def _hex_sheet(n=16):
    rows = [[j + 0.5 * (i % 2), i * np.sqrt(3) / 2, 0.0] for i in range(n) for j in range(n)]
    return np.array(rows)


def _knife(opening_deg, n=16, gap=0.5):
    """Two hexagonal sheets (r0 = 1) meeting at a knife edge along y through the origin:
    face A in z = 0 at x < 0, face B opened ``opening_deg`` above it; the material lies
    between them. Returns positions, outward normals and which particles are on B."""
    a = np.radians(opening_deg)
    h = _hex_sheet(n)
    s = h[:, 0] + gap  # distance from the edge
    face_a = np.c_[-s, h[:, 1], np.zeros(len(h))]
    face_b = np.c_[-s * np.cos(a), h[:, 1], s * np.sin(a)]
    normal_a = np.tile([0.0, 0.0, -1.0], (len(h), 1))
    normal_b = np.tile([np.sin(a), 0.0, np.cos(a)], (len(h), 1))
    on_b = np.r_[np.zeros(len(h), bool), np.ones(len(h), bool)]
    return np.r_[face_a, face_b], np.r_[normal_a, normal_b], on_b


def _pair(p, q, n, m):
    return reflected_dots(np.array([p, q], float), np.array([n, m], float), [0], [1])[0]


def test_reflected_dot_reads_the_sign_whatever_the_angle_between_the_normals():
    a = np.radians(30.0)
    # one sheet: the plain dot product
    assert _pair([0, 0, 0], [1, 0, 0], [0, 0, 1], [0, 0, 1]) == pytest.approx(1.0)
    assert _pair([0, 0, 0], [1, 0, 0], [0, 0, 1], [0, 0, -1]) == pytest.approx(-1.0)
    # a 30 deg knife edge, one particle on each face at the same distance from the edge:
    # the normals are 150 deg apart (dot -0.87) and consistent
    p, q = [-1.0, 0, 0], [-np.cos(a), 0, np.sin(a)]
    n, m = [0, 0, -1.0], [np.sin(a), 0, np.cos(a)]
    assert np.dot(n, m) == pytest.approx(-np.cos(a))
    assert _pair(p, q, n, m) == pytest.approx(1.0)
    assert _pair(p, q, n, -np.array(m)) == pytest.approx(-1.0)
    # the two faces of a thin plate, one above the other: opposed and consistent; offset
    # sideways by less than the thickness, still positive
    assert _pair([0, 0, 0], [0, 0, 0.5], [0, 0, -1], [0, 0, 1]) == pytest.approx(1.0)
    assert _pair([0, 0, 0], [0, 0, 0.5], [0, 0, 1], [0, 0, 1]) == pytest.approx(-1.0)
    assert _pair([0, 0, 0], [0.3, 0, 0.5], [0, 0, -1], [0, 0, 1]) > 0.4
    # a convex 90 deg crease, and the concave step whose normals do not fit together
    assert _pair([-1, 0, 0], [0, 0, -1], [0, 0, 1], [1, 0, 0]) == pytest.approx(1.0)
    assert _pair([-1, 0, 0], [0, 0, 1], [0, 0, 1], [1, 0, 0]) == pytest.approx(-1.0)
    # perpendicular normals on one flat sheet: no evidence either way
    assert abs(_pair([0, 0, 0], [1, 0, 0], [0, 0, 1], [0, 1, 0])) < 1e-12


@pytest.mark.parametrize("opening", [30.0, 45.0, 60.0])
def test_a_wrong_patch_beside_a_knife_edge_is_re_signed_and_the_other_face_kept(opening):
    """wedge-noise025 (a 30 deg knife edge): the vote on a proposed patch counted each pair
    across the edge as disagreeing (n_i . n_j = -cos(opening) < 0) and turned a whole face
    of the wedge over (2,407 of its 2,425 particles), leaving a 531-edge loop round it. Here,
    with plain dot products, a wrong patch on face B beside a 45 deg edge turned all of face B
    over. Signs now come from :func:`reflected_dots`."""
    p, n, on_b = _knife(opening)
    assert np.array_equal(consistent_normals(p, n), n)  # consistent: nothing changes
    wrong = n.copy()
    patch = on_b & (np.linalg.norm(p[:, :2] - [-3.0, 7.0], axis=1) < 2.5)
    wrong[patch] *= -1
    assert patch.sum() >= 20
    assert np.array_equal(consistent_normals(p, wrong), n)


def test_knife_edge_with_a_wrong_patch_meshes_as_one_sheet():
    """The wrong patch beside a 45 deg knife edge: with the whole of face B turned over, ball
    pivoting left face B as a second component (the two faces' normals disagreed)."""
    p, n, on_b = _knife(45.0)
    wrong = n.copy()
    wrong[on_b & (np.linalg.norm(p[:, :2] - [-3.0, 7.0], axis=1) < 2.5)] *= -1
    res = triangulate_particles(p, wrong, TriangulationConfig(), max_hole=4.0)
    t = mesh_topology(res.vertices, res.faces)
    assert t["components"] == 1 and t["boundary_loops"] == 1 and t["consistently_oriented"]


def _sphere(n=800):
    """Points on the unit sphere (Fibonacci spiral) and their outward normals."""
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    phi = np.pi * (1.0 + 5.0**0.5) * i
    r = np.sqrt(1.0 - z * z)
    p = np.c_[r * np.cos(phi), r * np.sin(phi), z]
    return p * 10.0, p.copy()


def _inputs():
    """A flat sheet, and a sphere with outward and inward normals."""
    h = _hex_sheet()
    s, m = _sphere()
    return [(h, np.tile([0.0, 0.0, 1.0], (len(h), 1))), (s, m), (s, -m)]


@pytest.mark.parametrize("case", range(3))
def test_consistent_input_skips_the_propagation(case, monkeypatch):
    """Every neighbour pair agrees (all reflected dots >= 0): the normals come back as they
    are, without the spanning tree (the screen fires on clean scans)."""
    import recon.particle_signs as ps

    p, n = _inputs()[case]

    def fail(*args, **kwargs):
        raise AssertionError("propagate_signs ran on consistent normals")

    monkeypatch.setattr(ps, "propagate_signs", fail)
    assert consistent_normals(p, n) is n


@pytest.mark.parametrize("case", range(3))
@pytest.mark.parametrize("flip_one", [False, True])
def test_the_screen_gives_what_the_full_re_signing_gives(case, flip_one, monkeypatch):
    """The screen is exact: with it switched off, the propagation and the patch vote return
    the same normals on consistent input; with one normal flipped it does not fire and that
    normal is re-signed."""
    import recon.particle_signs as ps

    p, n = _inputs()[case]
    wrong = n.copy()
    if flip_one:
        wrong[len(n) // 3] *= -1.0
    screened = consistent_normals(p, wrong)
    monkeypatch.setattr(ps, "all_agree", lambda dots: False)
    full = consistent_normals(p, wrong)
    assert np.array_equal(screened, full)
    assert np.array_equal(screened, n)
