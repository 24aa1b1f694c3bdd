"""flip_and_smooth: flips and tangential smoothing through any projection, topology kept."""

import numpy as np

from recon.remesh.improve import flip_and_smooth
from recon.topology import mesh_topology, triangle_quality
from tests.mesh_shapes import grid, icosphere


def _on_sphere(target: np.ndarray, moved: np.ndarray) -> np.ndarray:
    return target / np.linalg.norm(target, axis=1, keepdims=True)


def _jittered_sphere(seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    v, f = icosphere(3)
    rng = np.random.default_rng(seed)
    v = v + rng.normal(scale=0.03, size=v.shape)  # ~ a third of an edge
    return v / np.linalg.norm(v, axis=1, keepdims=True), f


def test_rounds_raise_the_angles_and_keep_vertices_on_the_surface_and_the_topology():
    v, f = _jittered_sphere()
    before = triangle_quality(v, f)["min_angle_mean_deg"]
    v2, f2, stats = flip_and_smooth(v, f, np.zeros(len(v), bool), _on_sphere, rounds=2, step=0.8)
    after = triangle_quality(v2, f2)["min_angle_mean_deg"]
    assert after > before + 5.0, (before, after)
    np.testing.assert_allclose(np.linalg.norm(v2, axis=1), 1.0, atol=1e-12)
    assert len(f2) == len(f) and stats["flips"] > 0
    topo = mesh_topology(v2, f2)
    assert topo["watertight"] and topo["genus"] == 0 and topo["consistently_oriented"]


def test_fixed_vertices_stay_and_projection_sees_only_the_free_ones():
    v, f = _jittered_sphere(1)
    fixed = v[:, 2] > 0.5
    seen = []

    def project(target: np.ndarray, moved: np.ndarray) -> np.ndarray:
        seen.append(moved.copy())
        return _on_sphere(target, moved)

    v2, _, _ = flip_and_smooth(v, f, fixed, project, rounds=3)
    np.testing.assert_array_equal(v2[fixed], v[fixed])
    assert len(seen) == 3
    for moved in seen:
        np.testing.assert_array_equal(moved, np.flatnonzero(~fixed))
    assert np.abs(v2[~fixed] - v[~fixed]).max() > 1e-3  # the free ones did move


def test_without_flips_the_faces_are_unchanged():
    v, f = grid(6, 6)
    rng = np.random.default_rng(2)
    v[:, :2] += rng.uniform(-0.03, 0.03, size=(len(v), 2))
    flat = lambda t, m: t * np.array([1.0, 1.0, 0.0])  # noqa: E731 - onto z = 0
    v2, f2, stats = flip_and_smooth(v, f, np.zeros(len(v), bool), flat, 2, flips=False)
    np.testing.assert_array_equal(f2, f)
    assert stats["flips"] == 0
    assert np.all(v2[:, 2] == 0.0)
