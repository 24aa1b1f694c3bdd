"""Sharp-crease and corner detection (recon.creases, issue 12 step 1).

Angles are *turning* angles: the angle between the two face normals (0 on a plane, 90 deg on a
box edge, 180 deg on a knife edge); the interior dihedral angle of the wedge is 180 deg minus it.
"""

import json

import numpy as np
import pytest
from click.testing import CliRunner
from mesh_shapes import wedge_points
from recon.cli.main import app

from recon import creases as creases_module
from recon.config import CreasesConfig, ReconConfig
from recon.crease_orient import orient_across_creases
from recon.creases import CORNER, CREASE, SMOOTH, detect_creases
from recon.fitting.report import FitReport
from recon.io import write_points


def _sample_faces(rects, n, rng):
    """Area-uniform samples on planar rectangles given as (origin, edge u, edge v)."""
    areas = np.array([np.linalg.norm(np.cross(u, v)) for _, u, v in rects])
    counts = rng.multinomial(n, areas / areas.sum())
    out = []
    for (o, u, v), m in zip(rects, counts, strict=True):
        s = rng.uniform(size=(m, 2))
        out.append(np.asarray(o) + s[:, :1] * np.asarray(u) + s[:, 1:] * np.asarray(v))
    return np.concatenate(out)


def _cube(n=24000, seed=0):
    e = np.eye(3)
    rects = []
    for ax in range(3):
        u, v = e[(ax + 1) % 3], e[(ax + 2) % 3]
        rects += [(np.zeros(3), u, v), (e[ax], u, v)]
    return _sample_faces(rects, n, np.random.default_rng(seed))


def _lblock(n=20000, seed=0):
    """The dev set's lblock: a 1.0 x 0.8 footprint with a 0.6 x 0.4 notch cut from the corner
    (x > 0.4, y > 0.4), extruded 0.5 in z. Its edges: the L outline at z = 0 and z = 0.5
    (2 x 3.6) and six vertical edges (6 x 0.5), 10.2 in all, one of them concave (270 deg)."""
    outline = np.array([[0, 0], [1, 0], [1, 0.4], [0.4, 0.4], [0.4, 0.8], [0, 0.8]], float)
    rects = []
    for a, b in zip(outline, np.roll(outline, -1, axis=0), strict=True):
        rects.append((np.r_[a, 0.0], np.r_[b - a, 0.0], np.array([0.0, 0.0, 0.5])))
    # top and bottom as two rectangles each: [0,1]x[0,0.4] and [0,0.4]x[0.4,0.8]
    for z in (0.0, 0.5):
        rects.append((np.array([0.0, 0.0, z]), np.array([1.0, 0, 0]), np.array([0, 0.4, 0])))
        rects.append((np.array([0.0, 0.4, z]), np.array([0.4, 0, 0]), np.array([0, 0.4, 0])))
    return _sample_faces(rects, n, np.random.default_rng(seed))


def _torus(n=20000, big=1.0, small=0.35, seed=0):
    rng = np.random.default_rng(seed)
    # rejection sampling for area-uniform samples
    u = rng.uniform(0, 2 * np.pi, 4 * n)
    v = rng.uniform(0, 2 * np.pi, 4 * n)
    keep = rng.uniform(0, big + small, 4 * n) < big + small * np.cos(v)
    u, v = u[keep][:n], v[keep][:n]
    r = big + small * np.cos(v)
    return np.c_[r * np.cos(u), r * np.sin(u), small * np.sin(v)]


def _sphere(n=20000, seed=0):
    p = np.random.default_rng(seed).normal(size=(n, 3))
    return p / np.linalg.norm(p, axis=1, keepdims=True)


def _noisy(p, rel, seed=1):
    diag = np.linalg.norm(p.max(0) - p.min(0))
    return p + np.random.default_rng(seed).normal(scale=rel * diag, size=p.shape)


@pytest.mark.parametrize("turn", [30, 60, 90, 120, 150])
def test_wedge_is_a_crease_exactly_when_it_turns_past_the_threshold(turn):
    threshold = 45.0
    p = wedge_points(turn)
    found = detect_creases(p, angle_deg=threshold)
    crease = found.labels == CREASE
    if turn < threshold:
        assert not crease.any()
        assert found.length == 0.0
        return
    assert crease.sum() > 50
    # the crease line is 1.0 long; the wedge's open ends shorten the detected band a little
    assert 0.85 < found.length < 1.1
    # direction along y to a few degrees
    err = np.degrees(np.arccos(np.clip(np.abs(found.direction[crease, 1]), 0, 1)))
    assert np.median(err) < 3.0 and np.percentile(err, 90) < 6.0
    # measured turn close to the true one (blended normals bias it low by up to ~9 deg at 120)
    assert abs(np.median(found.turn_deg[crease]) - turn) < 10.0
    # crease points sit near the edge, nothing far from it
    dist_a = np.hypot(p[:, 0], p[:, 2])  # distance to the y axis
    assert dist_a[crease].max() < 0.15
    # the side normals are unit and d = n1 x n2
    n1, n2 = found.side_normals[crease, 0], found.side_normals[crease, 1]
    assert np.allclose(np.linalg.norm(n1, axis=1), 1.0)
    assert np.allclose(
        np.cross(n1, n2) / np.linalg.norm(np.cross(n1, n2), axis=1)[:, None],
        found.direction[crease],
    )


@pytest.mark.parametrize("turn", [150, 160, 170])
def test_a_knife_edge_is_a_crease_on_its_line_at_the_default_threshold(turn):
    # regression (held-out wedge, 30 deg knife edge): past 180 deg - threshold the two faces'
    # normal axes lie closer than the threshold and the normals blended across the edge fill
    # the gap between them; the clusters' planes then missed the line (a fifth of the feet up
    # to 0.03 off it at 160 deg) or nothing was found. Two planes refitted to the points
    # (eq. K1) put the feet on the line.
    found = detect_creases(wedge_points(turn))
    crease = found.labels == CREASE
    assert crease.sum() > 100
    assert 0.85 < found.length < 1.3
    off = np.hypot(found.foot[crease, 0], found.foot[crease, 2])
    assert np.percentile(off, 95) < 1e-6
    assert abs(np.median(found.turn_deg[crease]) - turn) < 3.0
    err = np.degrees(np.arccos(np.clip(np.abs(found.direction[crease, 1]), 0, 1)))
    assert np.percentile(err, 95) < 1.0


def _filleted(radius, n=8000, seed=0):
    """The 90 deg wedge with its edge rounded by a quarter cylinder of ``radius``."""
    rng = np.random.default_rng(seed)
    arc = np.pi / 2 * radius
    lengths = np.array([1.0, arc, 1.0])
    part = rng.choice(3, size=n, p=lengths / lengths.sum())
    s = rng.uniform(0, 1, n)
    y = rng.uniform(-0.5, 0.5, n)
    a = s * np.pi / 2
    x = np.select([part == 0, part == 1], [-s, radius * np.sin(a)], radius)
    z = np.select([part == 0, part == 1], [0.0, radius * (1 - np.cos(a))], radius + s)
    return np.c_[x, y, z]


def test_rounded_edge_is_not_a_crease():
    # spacing h ~ 0.016; a fillet of 3 h keeps the data 1.2 h off the planes' intersection
    assert not (detect_creases(_filleted(0.05)).labels == CREASE).any()
    # the same sampling with a negligible fillet is a crease
    assert (detect_creases(_filleted(0.002)).labels == CREASE).sum() > 50


def _short_wedge(length, n=4000, seed=0):
    """The 90 deg wedge of ``wedge_points`` cut to a crease ``length`` long (same density)."""
    rng = np.random.default_rng(seed)
    m = int(n * length)
    u = rng.uniform(0.0, 1.0, (m, 2)) * [1.0, length] - [0.0, length / 2]
    v = rng.uniform(0.0, 1.0, (m, 2)) * [1.0, length] - [0.0, length / 2]
    return np.r_[np.c_[-u[:, 0], u[:, 1], np.zeros(m)], np.c_[np.zeros(m), v[:, 1], v[:, 0]]]


def test_a_short_fold_is_not_a_crease_a_long_one_is():
    # regression: a sharp fold only ~4 neighbourhood radii long (0.25; radius ~0.064) was a
    # crease, as were the short fragments on tight bends of smooth scans (bunny, face)
    assert not (detect_creases(_short_wedge(0.25)).labels != SMOOTH).any()
    found = detect_creases(_short_wedge(0.6))
    assert (found.labels == CREASE).sum() > 50
    assert 0.45 < found.length < 0.65


@pytest.mark.parametrize("length, fitted", [(0.25, False), (0.6, True)])
def test_the_fold_fits_run_only_for_a_line_long_enough(length, fitted, monkeypatch):
    # a short fold's crease points reach the line test and all turn smooth for being short:
    # the fold residuals and the noise floor (most of the filters' cost on smooth scans,
    # whose tight bends give short fragments) are then not computed; a long fold needs them
    calls, seen = [], []
    for name in ("_fold_residuals", "_noise_floor"):
        real = getattr(creases_module, name)

        def spy(*args, _real=real, _name=name):
            calls.append(_name)
            return _real(*args)

        monkeypatch.setattr(creases_module, name, spy)
    real_folds = creases_module._long_folds

    def folds(pts, label, *rest):
        seen.append(int(np.count_nonzero(label == CREASE)))
        return real_folds(pts, label, *rest)

    monkeypatch.setattr(creases_module, "_long_folds", folds)
    found = detect_creases(_short_wedge(length))
    assert seen[0] > 20  # the line test had crease points to judge
    assert sorted(calls) == (["_fold_residuals", "_noise_floor"] if fitted else [])
    assert ((found.labels == CREASE).sum() > 50) == fitted


def _fold_measures(radius):
    """Sharpness (the quadric's miss beyond the noise over its miss on the exact fold) and
    quadric / sides residual ratio at five feet along the 90 deg wedge rounded by ``radius``."""
    from scipy.spatial import cKDTree

    from recon.creases import _fold_residuals

    p = _filleted(radius)
    feet = np.c_[np.full(5, radius), np.linspace(-0.2, 0.2, 5), np.zeros(5)]
    dist, idx = cKDTree(p).query(feet, k=48)
    side = np.tile(np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]]), (5, 1, 1))
    res_q, res_s, res_i = _fold_residuals(p, idx, side, feet, dist[:, -1])
    return np.sqrt(np.maximum(res_q**2 - res_s**2, 0.0)) / res_i, res_q / np.maximum(res_s, 1e-300)


def test_a_fold_is_told_from_a_tight_bend():
    # exact fold: one quadric misses exactly what it misses on the ideal fold; two planes fit
    sharp, ratio = _fold_measures(1e-9)
    assert np.allclose(sharp, 1.0, atol=0.02) and np.all(ratio > 1e3)
    # a fillet of about two spacings (half the neighbourhood radius): the bend is easier
    sharp, ratio = _fold_measures(0.03)
    assert np.median(sharp) < 0.6 and np.median(ratio) < 1.5


def test_a_noisy_fold_is_still_a_crease():
    # 0.25 % of the diagonal: the sides fit to the noise floor
    found = detect_creases(_noisy(wedge_points(90), 0.0025))
    assert 0.85 < found.length < 1.1


def _can(n=12000, r=0.3, height=0.6, seed=0):
    """A closed cylinder: side wall and two flat caps (two circular 90 deg rims)."""
    rng = np.random.default_rng(seed)
    side, cap = 2 * np.pi * r * height, np.pi * r * r
    m = rng.multinomial(n, np.array([side, cap, cap]) / (side + 2 * cap))
    t = rng.uniform(0, 2 * np.pi, m[0])
    out = [np.c_[r * np.cos(t), r * np.sin(t), rng.uniform(0, height, m[0])]]
    for k, z in ((1, 0.0), (2, height)):
        rr, tt = r * np.sqrt(rng.uniform(size=m[k])), rng.uniform(0, 2 * np.pi, m[k])
        out.append(np.c_[rr * np.cos(tt), rr * np.sin(tt), np.full(m[k], z)])
    return np.concatenate(out)


def test_circular_rims_are_creases():
    # regression: the wall bends along the rim, so two planes missed it by more than the
    # (exact) data's noise floor and the rims were dropped; a side may bend along the line
    p = _can()
    found = detect_creases(p)
    assert found.length == pytest.approx(2 * 2 * np.pi * 0.3, rel=0.1)
    assert len(found.corners) == 0
    z = p[found.labels == CREASE, 2]
    assert np.all(np.minimum(z, 0.6 - z) < 0.1)


def test_threshold_above_the_turn_finds_nothing():
    found = detect_creases(wedge_points(90), angle_deg=100.0)
    assert not (found.labels != SMOOTH).any()


def test_cube_gives_eight_corners_and_twelve_edges():
    p = _cube()
    found = detect_creases(p)
    assert len(found.corners) == 8
    # each corner estimate close to a cube vertex
    assert np.all(np.abs(found.corners - np.round(found.corners)) < 0.02)
    assert (found.labels == CORNER).any()
    assert found.length == pytest.approx(12.0, rel=0.15)


def test_lblock_crease_length_and_corners():
    found = detect_creases(_lblock())
    assert found.length == pytest.approx(10.2, rel=0.15)
    # 12 corners; the three-cluster split can miss one or two under random sampling
    assert 10 <= len(found.corners) <= 12
    assert np.all(np.abs(found.corners - np.round(found.corners / 0.1) * 0.1) < 0.02)
    # the concave vertical edge x = y = 0.4 is found
    p = _lblock()
    near_concave = np.hypot(p[:, 0] - 0.4, p[:, 1] - 0.4) < 0.01
    mid = near_concave & (np.abs(p[:, 2] - 0.25) < 0.15)
    hit = mid & (found.labels == CREASE)
    assert hit.sum() > 0.7 * mid.sum()
    assert np.all(np.abs(found.direction[hit, 2]) > np.cos(np.radians(5.0)))


@pytest.mark.parametrize("shape", [_sphere, _torus])
@pytest.mark.parametrize("noise", [0.0, 0.01])
def test_smooth_shapes_have_no_creases(shape, noise):
    p = shape()
    if noise:
        p = _noisy(p, noise)
    found = detect_creases(p)
    assert not (found.labels != SMOOTH).any()
    assert found.length == 0.0 and len(found.corners) == 0


def test_detection_is_deterministic_and_orientation_free():
    p = _cube(n=8000)
    a = detect_creases(p)
    b = detect_creases(p)
    assert np.array_equal(a.labels, b.labels) and a.length == b.length
    # flipping input normals' signs changes nothing but the side normals' signs
    from recon.normals import estimate_normals

    nrm = estimate_normals(p, k=20)
    flips = np.where(np.random.default_rng(3).uniform(size=len(p)) < 0.5, -1.0, 1.0)
    c = detect_creases(p, nrm)
    d = detect_creases(p, nrm * flips[:, None])
    assert np.array_equal(c.labels, d.labels)


def test_config_and_cli(tmp_path):
    # on by default; --crease-angle sets the angle, --no-creases turns it off
    assert CreasesConfig().enabled and 0 < ReconConfig().creases.angle_deg < 90
    src = tmp_path / "lblock.ply"
    write_points(src, _lblock(n=3000))
    runner = CliRunner()
    fast = ["--set", "seeds.min_particles=0", "--quiet"]
    res = runner.invoke(
        app, ["fit", str(src), "-o", str(tmp_path / "a.ply"), "--crease-angle", "60", *fast]
    )
    assert res.exit_code == 0, res.output
    report = json.loads((tmp_path / "a.report.json").read_text())
    assert report["creases"]["angle_deg"] == 60.0
    assert report["creases"]["length"] > 0 and report["creases"]["corners"] > 0
    assert FitReport.from_dict(report).creases.angle_deg == 60.0
    res = runner.invoke(
        app, ["fit", str(src), "-o", str(tmp_path / "b.ply"), "--no-creases", *fast]
    )
    assert res.exit_code == 0, res.output
    assert "creases" not in json.loads((tmp_path / "b.report.json").read_text())
    res = runner.invoke(app, ["fit", str(src), "-o", str(tmp_path / "d.ply"), *fast])
    assert res.exit_code == 0, res.output
    # defaults detect the creases too
    assert json.loads((tmp_path / "d.report.json").read_text())["creases"]["length"] > 0
    # the creases change the mesh; with creases.fit=false detection only feeds the report
    assert (tmp_path / "a.ply").read_bytes() != (tmp_path / "b.ply").read_bytes()
    report_only = ["--crease-angle", "60", "--set", "creases.fit=false"]
    res = runner.invoke(app, ["fit", str(src), "-o", str(tmp_path / "e.ply"), *report_only, *fast])
    assert res.exit_code == 0, res.output
    assert "creases" in json.loads((tmp_path / "e.report.json").read_text())
    assert (tmp_path / "e.ply").read_bytes() == (tmp_path / "b.ply").read_bytes()
    res = runner.invoke(
        app, ["fit", str(src), "-o", str(tmp_path / "c.ply"), "--crease-angle", "0"]
    )
    assert res.exit_code == 2 and "angle_deg" in res.output


@pytest.mark.parametrize("turn", [90, 120])
def test_orientation_is_made_consistent_across_a_crease(turn):
    # regression (wedge, held-out): orientation by propagation took a whole face of a
    # 30-60-90 prism inward (a 150 deg knife edge looks like a 30 deg bend up to sign); the
    # mesh came out open or of genus 2-3. Face A (z = 0, normal +z) and face B turned up by
    # `turn`: consistent normals face the same side of the fold, A's +z means B's faces -x.
    p = wedge_points(turn)[:6000]  # A has 4000 points, B 2000: most points are on A
    a = np.radians(turn)
    b_normal = np.array([-np.sin(a), 0.0, np.cos(a)])  # B's normal consistent with A's +z
    good = np.r_[np.tile([0.0, 0.0, 1.0], (4000, 1)), np.tile(b_normal, (2000, 1))]
    bad = good * np.r_[np.ones(4000), -np.ones(2000)][:, None]
    found = detect_creases(p, bad, angle_deg=45.0)
    out, fixed, n = orient_across_creases(p, bad, found)
    assert n >= 1800  # B (2000), but for points with normals of both faces near the line
    assert np.mean(np.einsum("ij,ij->i", out, good) > 0) > 0.99
    # the side normals follow: both face the same side of the fold
    cr = fixed.labels == CREASE
    sides = fixed.side_normals[cr]
    np.testing.assert_allclose(np.median(sides[:, 0] + sides[:, 1], axis=0)[1], 0.0, atol=1e-6)
    assert np.median(np.einsum("ij,j->i", sides[:, 0] + sides[:, 1], good[0] + b_normal)) > 0
    # consistent input is returned as it is
    found = detect_creases(p, good, angle_deg=45.0)
    out, _, n = orient_across_creases(p, good, found)
    assert n == 0 and out is good


@pytest.mark.parametrize("turn", [150, 160])
def test_points_near_a_knife_edge_take_the_sign_of_the_side_they_lie_on(turn):
    # regression (held-out wedge): near the 30 deg knife edge the normals are blends of both
    # faces and the orientation signed both faces' points there alike (60 % of face B's
    # points within 0.02 of the edge inward); the particles took those signs and the
    # triangulation turned the whole face over. Here: PCA normals signed like their face,
    # but within 0.06 of the edge (a neighbourhood radius) like face A. Points on the line
    # itself (within 0.02) are blends of both faces either way and are not counted.
    from recon.normals import estimate_normals

    p = wedge_points(turn)
    a = np.radians(turn)
    b_normal = [-np.sin(a), 0.0, np.cos(a)]  # B's normal consistent with A's +z
    face = np.r_[np.tile([0.0, 0.0, 1.0], (4000, 1)), np.tile(b_normal, (4000, 1))]
    n = estimate_normals(p, k=20)
    n *= np.sign(np.einsum("ij,ij->i", n, face))[:, None]
    e = np.hypot(p[:, 0], p[:, 2])
    n[e < 0.06] *= np.sign(n[e < 0.06] @ np.array([0.0, 0.0, 1.0]))[:, None]
    band = (e > 0.02) & (e < 0.06)
    assert np.mean(np.einsum("ij,ij->i", n[band], face[band]) > 0) < 0.6
    out, _, _ = orient_across_creases(p, n, detect_creases(p, n))
    ok = np.einsum("ij,ij->i", out, face) > 0
    assert ok[band].mean() > 0.95
    assert ok[e >= 0.06].mean() > 0.98


@pytest.mark.parametrize("turn", [60, 90, 150])
@pytest.mark.parametrize("noise", [0.0, 0.003])
def test_the_flatness_screen_does_not_change_a_detection(turn, noise, monkeypatch):
    # the screen skips the Gauss-map clustering where every neighbour is flat; on folds from
    # the threshold to a knife edge, clean or noisy, the detection is the one without it
    p = wedge_points(turn) + np.random.default_rng(1).normal(scale=noise, size=(8000, 3))
    screened = detect_creases(p, angle_deg=45.0)
    monkeypatch.setattr(creases_module, "SCREEN_FRACTION", 0.0)
    full = detect_creases(p, angle_deg=45.0)
    assert screened.n_crease_points > 50
    np.testing.assert_array_equal(screened.labels, full.labels)
    cr = full.labels != SMOOTH
    for name in ("side_normals", "direction", "turn_deg", "foot"):
        np.testing.assert_array_equal(getattr(screened, name)[cr], getattr(full, name)[cr])
    np.testing.assert_array_equal(screened.corners, full.corners)
    assert screened.length == full.length
