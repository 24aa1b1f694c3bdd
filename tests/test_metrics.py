"""recon.metrics on analytic cases: spheres, shifted planes, a mesh against itself."""

from __future__ import annotations

import json

import numpy as np
import pytest
from mesh_shapes import grid, icosphere, tetrahedron

from recon.errors import InputError
from recon.metrics import (
    SurfaceError,
    check_comparison,
    compare_meshes,
    fidelity,
    point_to_mesh_distance,
    quality_report,
    sample_surface,
)

N = 20_000


@pytest.fixture(scope="module")
def sphere():
    return icosphere(4)  # 5120 faces; its face planes sit within 0.1 % of the radius


# ---------------------------------------------------------------------------- distances


def test_point_to_mesh_distance_hand_cases():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)
    q = np.array([[0.2, 0.2, 0.5], [0.2, 0.2, -0.3], [2, 0, 0], [-1, -1, 0], [0.5, 0.5, 0]])
    d = point_to_mesh_distance(q, v, [[0, 1, 2]])
    np.testing.assert_allclose(d, [0.5, 0.3, 1.0, 2**0.5, 0.0], atol=1e-6)


def test_point_to_mesh_distance_is_precise_far_from_the_origin():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float) + 1e6
    d = point_to_mesh_distance([[1e6 + 0.2, 1e6 + 0.2, 1e6 + 1e-3]], v, [[0, 1, 2]])
    assert d[0] == pytest.approx(1e-3, rel=1e-4)


@pytest.mark.parametrize("scale", [1e-10, 1e12, 1e20])
def test_point_to_mesh_distance_does_not_depend_on_the_units(sphere, scale):
    """Regression: Embree's float32 query with its own tolerances put a sphere's fit 1e-10
    or 1e12 across 30-60x farther from its data than at unit size, and found no face at all
    1e20 across; the mean distance over the diagonal must not depend on the units."""
    v, f = sphere
    rng = np.random.default_rng(0)
    q = rng.normal(size=(2000, 3))
    q *= (1.0 + 0.01 * rng.random((2000, 1))) / np.linalg.norm(q, axis=1, keepdims=True)
    unit = point_to_mesh_distance(q, v, f)
    scaled = point_to_mesh_distance(q * scale, v * scale, f) / scale
    np.testing.assert_allclose(scaled, unit, rtol=1e-3, atol=1e-6)
    same = compare_meshes((v * scale, f), (v * scale, f), n_samples=2000)
    assert same["chamfer_l1_relative"] < 1e-6, same["chamfer_l1_relative"]


def test_point_to_mesh_distance_needs_faces():
    with pytest.raises(InputError, match="no faces"):
        point_to_mesh_distance(np.zeros((2, 3)), np.zeros((3, 3)), np.zeros((0, 3), int))


# ---------------------------------------------------------------------------- sampling


def test_sample_surface_is_deterministic_and_on_the_surface(sphere):
    v, f = sphere
    p1, n1 = sample_surface(v, f, 5000, seed=3)
    p2, n2 = sample_surface(v, f, 5000, seed=3)
    p3, _ = sample_surface(v, f, 5000, seed=4)
    np.testing.assert_array_equal(p1, p2)
    np.testing.assert_array_equal(n1, n2)
    assert not np.array_equal(p1, p3)
    assert point_to_mesh_distance(p1, v, f).max() < 1e-6
    np.testing.assert_allclose(np.linalg.norm(n1, axis=1), 1.0)
    # Outward face normals on a sphere point along the position.
    assert np.min(np.einsum("ij,ij->i", n1, p1 / np.linalg.norm(p1, axis=1, keepdims=True))) > 0.99


def test_sample_surface_is_area_uniform():
    # Left half of a 2 x 1 strip in 2 triangles, right half in 200: samples still split 50/50.
    v1, f1 = grid(1, 1)
    v2, f2 = grid(10, 10)
    v = np.concatenate([v1, v2 + [1, 0, 0]])
    f = np.concatenate([f1, f2 + len(v1)])
    p, _ = sample_surface(v, f, 40_000, seed=0)
    assert np.mean(p[:, 0] < 1) == pytest.approx(0.5, abs=0.01)
    # and uniform inside a triangle: mean of the samples = centroid
    p, _ = sample_surface(v1, f1[:1], 40_000, seed=1)
    np.testing.assert_allclose(p.mean(axis=0), v1[f1[0]].mean(axis=0), atol=5e-3)


def test_sample_surface_rejects_zero_area():
    with pytest.raises(InputError, match="zero surface area"):
        sample_surface(np.zeros((3, 3)), [[0, 1, 2]], 10)


# ---------------------------------------------------------------------------- comparison


@pytest.mark.parametrize("delta", [0.01, 0.05])
def test_sphere_against_scaled_sphere(sphere, delta):
    v, f = sphere
    r = compare_meshes((v, f), (v * (1 + delta), f), n_samples=N)
    # Exact answer for the spheres: delta * r. The icosphere's faces sit slightly inside the
    # sphere, which shrinks the gap by < 0.1 %.
    assert r["chamfer_l1"] == pytest.approx(delta, rel=2e-3)
    assert r["chamfer_l2"] == pytest.approx(delta**2, rel=4e-3)
    assert r["hausdorff"] == pytest.approx(delta, rel=2e-3)
    diag = 2 * np.sqrt(3) * (1 + delta) * np.abs(v).max()
    assert r["diag"] == pytest.approx(diag)
    assert r["chamfer_l1_relative"] == pytest.approx(r["chamfer_l1"] / diag)
    assert r["chamfer_l2_relative"] == pytest.approx(r["chamfer_l2"] / diag**2)
    assert r["normal_consistency"] > 0.9999
    # tau = 1 % of the diagonal ~ 0.035: below the gap of 0.05, above 0.01
    assert r["fscore"] == (1.0 if delta * 1.01 < r["tau"] else 0.0)


def test_mesh_against_itself_is_zero(sphere):
    v, f = sphere
    r = compare_meshes((v, f), (v, f), n_samples=N, seed=1)
    assert r["chamfer_l1"] < 1e-6 and r["hausdorff"] < 1e-6
    assert r["fscore"] == 1.0 and r["precision"] == 1.0 and r["recall"] == 1.0
    assert r["normal_consistency"] == pytest.approx(1.0)
    assert r["normal_consistency_signed"] == pytest.approx(1.0)
    assert r["topology"]["mesh"] == r["topology"]["reference"]
    assert r["reference_kind"] == "mesh" and r["notes"] == []


def test_plane_against_shifted_plane():
    v, f = grid(8, 8)
    shift = 0.05
    r = compare_meshes((v + [0, 0, shift], f), (v, f), n_samples=N)
    assert r["chamfer_l1"] == pytest.approx(shift, rel=1e-6)
    assert r["chamfer_l2"] == pytest.approx(shift**2, rel=1e-6)
    assert r["hausdorff"] == pytest.approx(shift, rel=1e-6)
    assert r["hausdorff95"] == pytest.approx(shift, rel=1e-6)
    assert r["mesh_to_reference"]["mean"] == pytest.approx(shift, rel=1e-6)
    assert r["reference_to_mesh"]["max"] == pytest.approx(shift, rel=1e-6)
    assert r["fscore"] == 0.0  # tau = 1 % of sqrt(2) < shift
    assert compare_meshes((v + [0, 0, shift], f), (v, f), n_samples=N, tau=0.06)["fscore"] == 1.0
    r = compare_meshes((v + [0, 0, shift], f), (v, f), n_samples=N, tau_relative=0.04)
    assert r["tau"] == pytest.approx(0.04 * 2**0.5) and r["fscore"] == 1.0


def test_plane_shift_far_from_origin_keeps_precision():
    v, f = grid(4, 4)
    r = compare_meshes((v + [1e4, 1e4, 1e4 + 0.05], f), (v + 1e4, f), n_samples=5000)
    assert r["chamfer_l1"] == pytest.approx(0.05, rel=1e-5)


def test_partial_overlap_gives_precision_and_recall():
    # The mesh covers the left half of the reference: precision 1, recall 1/2.
    v, f = grid(4, 4)
    half = v * [0.5, 1, 1]
    r = compare_meshes((half, f), (v, f), n_samples=N, tau=1e-3)
    assert r["precision"] == 1.0
    assert r["recall"] == pytest.approx(0.5, abs=0.02)
    assert r["fscore"] == pytest.approx(2 * 0.5 / 1.5, abs=0.02)
    # Reference samples on the right half lie on average 0.25 from the mesh.
    assert r["reference_to_mesh"]["mean"] == pytest.approx(0.5 * 0.25, rel=0.03)
    assert r["hausdorff"] == pytest.approx(0.5, abs=0.01)


def test_flipped_mesh_has_negative_signed_normal_consistency(sphere):
    v, f = sphere
    r = compare_meshes((v, f[:, ::-1]), (v, f), n_samples=5000)
    assert r["normal_consistency"] == pytest.approx(1.0)
    assert r["normal_consistency_signed"] == pytest.approx(-1.0)


def test_point_cloud_reference(sphere):
    v, f = sphere
    pts, nrm = sample_surface(v * 1.01, f, 50_000, seed=7)
    r = compare_meshes((v, f), (pts, nrm), n_samples=N)
    assert r["reference_kind"] == "points"
    assert any("only point-based metrics" in note for note in r["notes"])
    assert any("thinned" in note for note in r["notes"])
    assert r["n_samples"]["reference"] == N
    assert r["topology"]["reference"] is None
    # reference->mesh is exact; mesh->points adds the point spacing (~0.01 here)
    assert r["reference_to_mesh"]["mean"] == pytest.approx(0.01, rel=5e-3)
    assert 0.01 < r["mesh_to_reference"]["mean"] < 0.02
    assert r["normal_consistency"] > 0.99
    r = compare_meshes((v, f), (pts, None), n_samples=N)
    assert r["normal_consistency"] is None
    assert any("no normals" in note for note in r["notes"])


def test_compare_is_deterministic_and_json_ready(sphere):
    v, f = sphere
    a = compare_meshes((v, f), (v * 1.02, f), n_samples=5000, seed=5)
    b = compare_meshes((v, f), (v * 1.02, f), n_samples=5000, seed=5)
    assert a == b
    assert json.loads(json.dumps(a, allow_nan=False)) == a


def test_compare_rejects_bad_input():
    v, f = tetrahedron()
    with pytest.raises(InputError, match="mesh has no faces"):
        compare_meshes((v, np.zeros((0, 3), int)), (v, f))
    with pytest.raises(InputError, match="tau must be > 0"):
        compare_meshes((v, f), (v, f), tau=0.0, n_samples=100)
    with pytest.raises(InputError, match="reference must be"):
        compare_meshes((v, f), v)


def test_compare_says_which_surface_has_zero_area():
    """Regression: a zero-area mesh or reference both gave "mesh has zero surface area"."""
    v, f = tetrahedron()
    flat = (np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0]]), np.array([[0, 1, 2]]))
    with pytest.raises(SurfaceError, match="^mesh has zero surface area") as err:
        compare_meshes(flat, (v, f), n_samples=100)
    assert err.value.side == "mesh"
    with pytest.raises(SurfaceError, match="^reference mesh has zero surface area") as err:
        compare_meshes((v, f), flat, n_samples=100)
    assert err.value.side == "reference"
    with pytest.raises(SurfaceError, match="zero-size bounding box") as err:
        compare_meshes((v, f), (np.ones((5, 3)), None), n_samples=100)
    assert err.value.side == "reference" and isinstance(err.value, InputError)


# ---------------------------------------------------------------------------- tolerances


def test_check_comparison():
    v, f = grid(4, 4)
    r = compare_meshes((v + [0, 0, 0.05], f), (v, f), n_samples=2000)
    checks = check_comparison(r, max_chamfer=0.01, max_chamfer_abs=1.0, min_fscore=0.5)
    by = {c["metric"]: c for c in checks}
    assert by["chamfer_l1_relative"]["passed"] is False
    assert by["chamfer_l1_relative"]["excess"] == pytest.approx(0.05 / 2**0.5 - 0.01, rel=1e-5)
    assert by["chamfer_l1"]["passed"] is True and by["chamfer_l1"]["excess"] < 0
    assert by["fscore"]["passed"] is False and by["fscore"]["excess"] == pytest.approx(0.5)
    assert check_comparison(r) == []
    topo = check_comparison(r, same_topology=True)
    assert [c["metric"] for c in topo] == [
        "topology.components",
        "topology.boundary_loops",
        "topology.genus",
        "topology.watertight",
    ]
    assert all(c["passed"] for c in topo)


def test_check_same_topology_needs_a_mesh_reference():
    v, f = grid(2, 2)
    r = compare_meshes((v, f), (v, None), n_samples=100)
    with pytest.raises(InputError, match="reference mesh"):
        check_comparison(r, same_topology=True)


# ---------------------------------------------------------------------------- reports


def test_fidelity_of_points_off_a_plane():
    v, f = grid(2, 2)
    rng = np.random.default_rng(0)
    pts = np.column_stack([rng.random((1000, 2)), np.full(1000, 0.02)])
    r = fidelity(pts, v, f, diag=2.0)
    assert r["n"] == 1000 and r["diag"] == 2.0
    for key in ("mean", "rms", "p95", "max"):
        assert r[key] == pytest.approx(0.02, rel=1e-6)
        assert r[f"{key}_relative"] == pytest.approx(0.01, rel=1e-6)


def test_quality_report(sphere):
    v, f = sphere
    pts, _ = sample_surface(v, f, 2000, seed=0)
    r = quality_report(pts * 1.001, v, f)
    assert set(r) == {"topology", "triangle_quality", "mesh_bbox_diag", "fidelity"}
    assert r["topology"]["genus"] == 0
    assert r["triangle_quality"]["min_angle_mean_deg"] > 50
    assert r["fidelity"]["mean"] == pytest.approx(1e-3, rel=0.01)
    assert r["fidelity"]["diag"] == pytest.approx(np.linalg.norm(np.ptp(pts * 1.001, axis=0)))
    assert quality_report(None, v, f)["fidelity"] is None
    assert quality_report(pts, v, f, diag=10.0)["fidelity"]["diag"] == 10.0
    json.dumps(r, allow_nan=False)


def test_quality_report_of_a_mesh_without_faces():
    r = quality_report(np.ones((5, 3)), np.zeros((3, 3)), np.zeros((0, 3), int))
    assert r["topology"]["n_faces"] == 0 and r["fidelity"] is None
    assert r["triangle_quality"]["n_measured"] == 0
