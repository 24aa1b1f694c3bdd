"""End-to-end tests of the fit stage on small generated and bundled inputs."""

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

import recon
from recon.config import ReconConfig, load_config
from recon.errors import InputError, LimitExceeded
from recon.fitting import FitReport, choose_spacing, fit, fit_file, reconstruct, report_path_for
from recon.io import read_points
from recon.metrics import compare_meshes, point_to_mesh_distance
from recon.normals import choose_neighborhood_size
from recon.serialize import dumps

SAMPLE = Path(__file__).resolve().parent.parent / "sample_data"
FAST = ["seeds.min_particles=0"]


def _sphere(n=1500, seed=0, noise=0.0):
    rng = np.random.default_rng(seed)
    p = rng.normal(size=(n, 3))
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    return p + rng.normal(scale=noise, size=p.shape)


def _square_with_hole(n=2500, hole=0.2, seed=1):
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-0.5, 0.5, size=(3 * n, 2))
    xy = xy[np.linalg.norm(xy, axis=1) > hole][:n]
    return np.column_stack([xy, np.zeros(len(xy))])


def test_sphere_closes_watertight_genus_zero_and_on_the_surface():
    res = fit(_sphere(), load_config(overrides=FAST))
    topo = res.report.topology
    assert topo.watertight and topo.components == 1 and topo.genus == 0
    r = np.linalg.norm(res.mesh.vertices, axis=1)
    assert abs(np.median(r) - 1.0) < 0.01
    assert res.report.triangle_quality.min_angle_mean_deg > 50
    assert res.report.triangle_quality.min_angle_p5_deg > 30


def test_open_square_keeps_outer_boundary_and_real_hole():
    pts = _square_with_hole()
    res = fit(pts, load_config(overrides=FAST))
    topo = res.report.topology
    assert topo.boundary_loops == 2
    assert topo.non_manifold_edges == 0
    # nothing grows past the data by more than r0
    r0 = res.report.spacing
    v = res.mesh.vertices
    assert np.abs(v[:, :2]).max() < 0.5 + r0
    assert np.linalg.norm(v[:, :2], axis=1).min() > 0.2 - r0
    assert np.abs(v[:, 2]).max() < 1e-6
    assert res.report.mesh_to_input.within_r0 > 0.95
    assert res.report.mesh_to_input.within_reach >= res.report.mesh_to_input.within_r0


def test_small_hole_is_filled_large_hole_is_kept():
    cfg = load_config(overrides=FAST)
    pts = _square_with_hole(hole=0.2)
    r0, d_nn = choose_spacing(pts, cfg)
    small = fit(_square_with_hole(hole=1.2 * r0), cfg).report.topology.boundary_loops
    big = fit(pts, cfg).report.topology.boundary_loops
    assert small == 1
    assert big == 2


def test_same_input_and_seed_give_identical_meshes():
    pts = _sphere(800)
    cfg = load_config(overrides=FAST)
    a, b = fit(pts, cfg), fit(pts, cfg)
    assert np.array_equal(a.mesh.vertices, b.mesh.vertices)
    assert np.array_equal(a.mesh.faces, b.mesh.faces)


def test_scale_and_offset_invariance():
    pts = _sphere(800)
    cfg = load_config(overrides=FAST)
    base = fit(pts, cfg)
    moved = fit(pts * 1e-6 + np.array([5e6, -3e6, 10.0]) * 1e-6, cfg)
    big = fit(pts * 1e3 + np.array([5e6, 1e5, 0.0]), cfg)
    for res, scale, off in (
        (moved, 1e-6, np.array([5.0, -3.0, 1e-5])),
        (big, 1e3, np.array([5e6, 1e5, 0.0])),
    ):
        assert len(res.mesh.faces) == len(base.mesh.faces)
        assert np.allclose((res.mesh.vertices - off) / scale, base.mesh.vertices, atol=1e-6)


def test_bundled_sparse_bunny_is_interpolated():
    cloud = read_points(SAMPLE / "bunny-sparse.ply")
    res = reconstruct(cloud, ReconConfig())
    rep = res.report
    assert rep.particles > 3 * rep.input.points  # resolution floor: between samples
    assert rep.fidelity.within_r0 > 0.9
    assert rep.mesh_to_input.within_reach > 0.9  # between samples, not past them
    assert rep.triangle_quality.min_angle_mean_deg > 50
    assert rep.topology.non_manifold_edges == 0


def test_noise_raises_the_neighbourhood_size():
    assert choose_neighborhood_size(_sphere(3000), 20) == 20
    assert choose_neighborhood_size(_sphere(3000, noise=0.05), 20) > 20


def test_resolution_floor_lowers_spacing_for_sparse_data():
    pts = _sphere(500)
    dense_cfg = load_config(overrides=["seeds.min_particles=0"])
    r_plain, d_nn = choose_spacing(pts, dense_cfg)
    r_floor, _ = choose_spacing(pts, ReconConfig())
    assert r_plain == pytest.approx(2.5 * d_nn)
    assert 0.8 * d_nn <= r_floor < r_plain


def test_fidelity_zero_shrinks_more_than_default():
    pts = _sphere(1200)
    on = fit(pts, load_config(overrides=FAST))
    off = fit(
        pts,
        load_config(
            overrides=FAST
            + [
                "dynamics.fidelity=0",
                "dynamics.fidelity_normal=0",
                "triangulation.project_to_data=false",
            ]
        ),
    )
    d_on = point_to_mesh_distance(pts, on.mesh.vertices, on.mesh.faces).mean()
    d_off = point_to_mesh_distance(pts, off.mesh.vertices, off.mesh.faces).mean()
    assert d_on < d_off


def test_particle_cap_stops_growth_with_a_warning():
    res = fit(_sphere(1500), load_config(overrides=FAST + ["dynamics.max_particles=700"]))
    assert res.report.particles <= 700
    assert any("max_particles" in w for w in res.report.warnings)


def test_seed_cap_below_seed_count_is_an_error():
    with pytest.raises(LimitExceeded, match="max_particles"):
        fit(_sphere(1500), load_config(overrides=FAST + ["dynamics.max_particles=10"]))


def test_time_limit_is_an_error():
    with pytest.raises(LimitExceeded, match="time limit"):
        fit(_sphere(1500), load_config(overrides=FAST + ["dynamics.time_limit=0.001"]))


def test_reconstruction_matches_the_analytic_sphere():
    pts = _sphere(3000, seed=3)
    res = fit(pts, load_config(overrides=FAST))
    # an icosphere-like reference: dense samples of the unit sphere as a point reference
    ref = _sphere(20000, seed=9)
    cmp = compare_meshes((res.mesh.vertices, res.mesh.faces), (ref, ref), n_samples=20000)
    assert cmp["fscore"] > 0.99


def test_python_api_is_exported():
    """``recon.fit`` is the library's main function, :func:`recon.fitting.fit`."""
    assert recon.fit is fit
    with pytest.raises(InputError):
        recon.fit(np.zeros((4, 2)))  # the call reaches fit's input check


def test_report_round_trips_through_its_json(tmp_path):
    """to_dict() is the JSON written beside the mesh; from_dict() reads it back unchanged."""
    src = tmp_path / "s.xyz"
    np.savetxt(src, _sphere(800))
    res = fit_file(src, tmp_path / "m.ply", load_config(overrides=FAST))
    path = report_path_for(tmp_path / "m.ply")
    text = path.read_text()
    assert text == dumps(res.report.to_dict()) + "\n"
    data = json.loads(text)
    assert list(data)[:3] == ["oprecon_version", "input", "spacing"]
    # optional ones omitted; creases are on by default and a sphere has none
    assert data["creases"]["length"] == 0.0 and data["creases"]["corners"] == 0
    assert [k for k in data if k != "creases"][-3:] == ["fidelity", "mesh_to_input", "output"]
    assert data["output"] == {"mesh": str(tmp_path / "m.ply"), "report": str(path)}
    back = FitReport.from_dict(data)
    assert back.to_dict() == data
    assert back.history == res.report.history and back.topology == res.report.topology
    assert back.input.path == str(src)
    with pytest.raises(ValueError, match="unknown"):
        FitReport.from_dict({**data, "extra": 1})
    with pytest.raises(ValueError, match="missing"):
        FitReport.from_dict({k: v for k, v in data.items() if k != "fidelity"})


def test_in_memory_report_has_no_paths():
    rep = fit(_sphere(800), load_config(overrides=FAST)).report
    d = rep.to_dict()
    assert "output" not in d and "path" not in d["input"] and rep.output is None
    assert d["fidelity"] == rep.fidelity.to_dict() and "within_r0" in d["fidelity"]
    assert list(d["time_s"]) == ["normals", "setup", "grow", "release", "triangulate", "report"]
    assert d["history"]["step"] == list(rep.history.step)


def test_adaptive_spacing_uses_larger_particles_on_flat_data_and_reports_the_range():
    pts = _square_with_hole(n=3000, hole=0.0)
    uniform = fit(pts, load_config(overrides=FAST))
    adaptive = fit(pts, load_config(overrides=[*FAST, "seeds.adaptive=true"]))
    assert uniform.report.spacing_range is None
    lo, hi = adaptive.report.spacing_range
    r0 = adaptive.report.spacing
    assert r0 * 0.5 - 1e-12 <= lo <= hi <= r0 * 1.5 + 1e-12
    assert hi > 1.2 * r0  # flat, well-sampled: larger particles ...
    assert adaptive.report.particles < 0.9 * uniform.report.particles  # ... fewer of them
    back = FitReport.from_dict(json.loads(dumps(adaptive.report.to_dict())))
    assert back.spacing_range == adaptive.report.spacing_range


def test_density_scale_reuses_the_data_spacing():
    """_triangulate queries the data's k-NN once: local_density_scale given the spacings
    gives the same scales without querying the tree for them."""
    from scipy.spatial import cKDTree

    from recon.fitting.pipeline import DENSITY_NEIGHBOURS, local_density_scale

    rng = np.random.default_rng(5)
    pts = rng.uniform(0, 10, (600, 3)) * [1.0, 1.0, 0.0]
    pts[:100] *= 0.2  # a denser corner
    tree = cKDTree(pts)
    q = rng.uniform(0, 10, (50, 3)) * [1.0, 1.0, 0.0]
    local = tree.query(pts, DENSITY_NEIGHBOURS + 1)[0][:, -1]
    expected = local_density_scale(tree, pts, q, 4.0)
    calls = []

    class Spy:
        def query(self, x, *args, **kw):
            calls.append(len(x))
            return tree.query(x, *args, **kw)

    got = local_density_scale(Spy(), pts, q, 4.0, local=local)
    np.testing.assert_array_equal(got, expected)
    assert calls == [len(q)] and expected.max() > 1.0


def test_stages_share_one_neighbor_query():
    """The normals, the crease detection and the local surfaces take their neighbours from one
    k-d tree query (shared_neighbors) and give what their own queries give."""
    from recon.cloud import PointCloud
    from recon.creases import detect_creases
    from recon.fitting.pipeline import SHARED_NEIGHBORS_MAX, shared_neighbors
    from recon.normals import compute_normals
    from recon.surface import DataSurface

    rng = np.random.default_rng(6)
    p = rng.normal(size=(3000, 3))
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    p[:, 2] = np.minimum(p[:, 2], 0.4)  # a cap cut off: a crease
    p += rng.normal(0.0, 0.002, p.shape)
    cfg = ReconConfig()
    knn = shared_neighbors(p, cfg)
    assert knn is not None and knn[1].shape == (len(p), SHARED_NEIGHBORS_MAX)
    cloud = PointCloud(points=p, origin=np.zeros(3))
    own, _ = compute_normals(cloud, cfg.normals)
    shared, _ = compute_normals(cloud, cfg.normals, neighbors=knn)
    np.testing.assert_array_equal(shared, own)
    from recon.normals import estimate_normals

    narrow = (knn[0][:, :5], knn[1][:, :5])  # fewer than k columns: queried instead
    np.testing.assert_array_equal(
        estimate_normals(p, k=20, neighbors=narrow), estimate_normals(p, k=20)
    )
    a = detect_creases(p, own, angle_deg=cfg.creases.angle_deg, k=cfg.creases.k)
    b = detect_creases(p, own, angle_deg=cfg.creases.angle_deg, k=cfg.creases.k, neighbors=knn)
    assert a.n_crease_points > 0
    np.testing.assert_array_equal(a.labels, b.labels)
    np.testing.assert_array_equal(a.side_normals, b.side_normals)
    r0 = 0.05
    s1 = DataSurface.build(p / r0, own, k=cfg.normals.k)
    s2 = DataSurface.build(p / r0, own, k=cfg.normals.k, neighbors=(knn[0] / r0, knn[1]))
    for name in ("plane_points", "plane_normals", "quadrics", "walk_neighbors"):
        np.testing.assert_array_equal(getattr(s1, name), getattr(s2, name))
    # noisy data raise normals.k: the widest use no longer fits, each stage queries its own
    wide = load_config(overrides=["normals.k=40", "normals.auto_scale=false"])
    assert shared_neighbors(p, wide) is None


def test_the_mesh_does_not_depend_on_the_order_of_the_input_rows():
    """The fit puts the points in Morton order first (recon.cloud.spatial_order): the same
    points in another row order give the same mesh, vertex for vertex."""
    pts = _sphere(800)
    cfg = load_config(overrides=FAST)
    a = fit(pts, cfg)
    b = fit(pts[np.random.default_rng(3).permutation(len(pts))], cfg)
    assert np.array_equal(a.mesh.vertices, b.mesh.vertices)
    assert np.array_equal(a.mesh.faces, b.mesh.faces)


def test_the_stages_up_to_r0_share_one_kd_tree_of_the_data(monkeypatch):
    # neighbourhood size, shared neighbours, crease detection, thin-part re-signing and the
    # spacing each built a k-d tree of the same points (~10 ms each on bunny-clean's 40k):
    # the fit builds one and passes it on (same tree, same queries: the same fit)
    from scipy.spatial import cKDTree

    from recon import creases, geometry, normal_signs, normals
    from recon.fitting import pipeline, scale

    pts = _sphere()
    built = []

    class Counting(cKDTree):
        def __init__(self, data, *args, **kwargs):
            super().__init__(data, *args, **kwargs)
            built.append(np.array(data, dtype=np.float64))

    for module in (creases, geometry, normal_signs, normals, pipeline, scale):
        monkeypatch.setattr(module, "cKDTree", Counting, raising=False)
    res = fit(pts, load_config(overrides=FAST))
    data = np.sort(pts - res.origin, axis=0)
    of_data = [d for d in built if d.shape == pts.shape and np.allclose(np.sort(d, axis=0), data)]
    assert len(of_data) == 1
    assert res.report.input.normals["source"] == "estimated"


def test_polishing_raises_the_angles_and_keeps_the_surface_and_topology():
    pts = _sphere(noise=0.01)
    raw = fit(pts, load_config(overrides=FAST + ["triangulation.smooth_rounds=0"]))
    pol = fit(pts, load_config(overrides=FAST))
    assert pol.report.triangulation.polish_flips > 0
    assert raw.report.triangulation.polish_flips == 0
    q_raw, q_pol = raw.report.triangle_quality, pol.report.triangle_quality
    assert q_pol.min_angle_mean_deg > q_raw.min_angle_mean_deg + 0.5, (q_raw, q_pol)
    assert pol.report.topology.watertight and pol.report.topology.genus == 0
    # projected onto the local data surface: as close to the sphere as the particles were
    dev_raw = np.abs(np.linalg.norm(raw.mesh.vertices, axis=1) - 1.0)
    dev_pol = np.abs(np.linalg.norm(pol.mesh.vertices, axis=1) - 1.0)
    assert np.median(dev_pol) <= np.median(dev_raw) + 1e-3


def test_polishing_leaves_boundary_vertices_where_they_are():
    pts = _square_with_hole()
    raw = fit(pts, load_config(overrides=FAST + ["triangulation.smooth_rounds=0"]))
    pol = fit(pts, load_config(overrides=FAST))
    v0, f0 = raw.mesh.vertices, raw.mesh.faces
    v1 = pol.mesh.vertices
    assert len(v0) == len(v1)
    edges = np.sort(np.concatenate([f0[:, [0, 1]], f0[:, [1, 2]], f0[:, [2, 0]]]), axis=1)
    uniq, count = np.unique(edges, axis=0, return_counts=True)
    boundary = np.unique(uniq[count == 1])
    assert len(boundary) > 20
    np.testing.assert_array_equal(v1[boundary], v0[boundary])
    inner = np.setdiff1d(np.arange(len(v0)), boundary)
    assert np.abs(v1[inner] - v0[inner]).max() > 1e-3  # the inside was polished
    assert np.abs(v1[:, 2]).max() < 1e-6  # and stayed on the plane
    assert pol.report.topology.boundary_loops == 2


def test_an_r0_far_below_the_data_spacing_is_refused_by_the_spacing():
    """Regression: ``--spacing 3e-4`` on data 0.037 apart stopped with "growth.max_gap: 1233.9
    is out of range", a key the user never set; the message now names the spacing and the
    smallest one the default gap allows (10 data spacings within growth.max_gap's 1000 r0)."""
    from recon.fitting.scale import with_max_gap

    with pytest.raises(InputError, match=r"r0 = 0.0003 is 123 times below .* 0\.037.*--spacing"):
        with_max_gap(ReconConfig(), r0=3e-4, median_spacing=0.037)
    assert with_max_gap(ReconConfig(), r0=3.7e-4, median_spacing=0.037).growth.max_gap == 1000
    assert with_max_gap(ReconConfig(), r0=1.0, median_spacing=0.4).growth.max_gap == 4.0


def test_a_closed_mesh_the_polish_leaves_inside_out_is_turned_outward(monkeypatch):
    """Regression: a sphere scanned twice, the copies 2 spacings apart, came out closed and
    inside out (the winding turned it by its inward normals while it was open; the polish
    closed it). The polish here turns its mesh and normals over, as that fit's were."""
    import recon.fitting.pipeline as pipeline
    from recon.topology import closed_orientation

    polish = pipeline.polish_and_untangle

    def inside_out(result, *args, **kwargs):
        polished, found, left = polish(result, *args, **kwargs)
        turned = replace(polished, faces=polished.faces[:, ::-1].copy())
        return replace(turned, normals=-polished.normals), found, left

    monkeypatch.setattr(pipeline, "polish_and_untangle", inside_out)
    res = fit(_sphere(800), {"seeds.min_particles": 0})
    assert closed_orientation(res.mesh.vertices, res.mesh.faces) == {
        "closed_components": 1,
        "closed_components_inward": 0,
    }
    assert res.report.triangulation.closed_turned_outward == len(res.mesh.vertices)
    # the vertex normals turned with the faces: outward on a unit sphere
    assert np.all(np.einsum("ij,ij->i", res.mesh.normals, res.mesh.vertices) > 0)
