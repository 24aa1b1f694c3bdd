"""remesh's Embree queries (Open3D's RaycastingScene, float32) run at the power of two nearest
the mesh's size, as the fit's closest-point query does: far from the origin, tiny or huge
meshes give the answers of the unit-sized one.

Before: a self-intersecting mesh 1e-16 or 1e16 across passed the input check (no crossing
found), ray casts from a mesh 1e-14 across were off by 3 % of its size (1e14: no hit at all),
and the closest points of far queries were off by 2e-4 (1e-10) and 3.5e-3 (1e12) of the
distance.
"""

import numpy as np
import pytest

from recon.errors import InputError
from recon.remesh import RemeshOptions, remesh
from recon.remesh.mesh_check import check_mesh, crossing_pairs
from recon.remesh.surface import MeshSurface, edge_faces
from tests.mesh_shapes import icosphere

SCALES = [1e-8, 1e8, 1e-10, 1e12, 1e-16, 1e16]


def _placed(v: np.ndarray, scale: float) -> np.ndarray:
    """``v`` a million of its sizes away from the origin, then scaled."""
    return (v + 1e6) * scale


@pytest.mark.parametrize("scale", SCALES)
def test_far_closest_points_and_ray_casts_do_not_depend_on_the_scale(scale):
    v, f = icosphere(2)
    rng = np.random.default_rng(0)
    far = rng.normal(size=(100, 3)) * 5.0  # past the closest-point grid: Embree answers
    origin = rng.normal(size=(100, 3)) * 0.2
    direction = rng.normal(size=(100, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    unit = MeshSurface(v, f)
    d_ref = np.linalg.norm(far - unit.closest(far)[0], axis=1)
    hit_ref = unit.first_hit(np.hstack([origin, direction]))
    scaled = MeshSurface(_placed(v, scale), f)
    q = _placed(far, scale)
    d = np.linalg.norm(q - scaled.closest(q)[0], axis=1) / scale
    np.testing.assert_allclose(d, d_ref, rtol=1e-6)
    hit = scaled.first_hit(np.hstack([_placed(origin, scale), direction])) / scale
    assert np.isfinite(hit_ref).all()
    np.testing.assert_allclose(hit, hit_ref, rtol=0, atol=1e-5)


@pytest.mark.parametrize("scale", SCALES)
def test_self_intersections_are_found_at_any_scale(scale):
    v, f = icosphere(2)
    v2 = np.vstack([v, v + [0.5, 0.1, 0.05]])  # two overlapping spheres
    f2 = np.vstack([f, f + len(v)])
    edges, _, f0, f1 = edge_faces(f2, len(v2))
    expected = len(crossing_pairs(v2, f2, edges, f0, f1))
    assert expected > 0
    assert len(crossing_pairs(_placed(v2, scale), f2, edges, f0, f1)) == expected
    with pytest.raises(InputError, match="self-intersecting"):
        check_mesh(_placed(v2, scale), f2, "two.ply")


@pytest.mark.parametrize("scale", [1e-8, 1e8, 1e-16, 1e16])
def test_a_remesh_far_away_tiny_or_huge_is_like_the_unit_ones(scale):
    v, f = icosphere(3)
    v = v * [1.0, 0.7, 0.5]
    opts = RemeshOptions(spacing_relative=0.08)
    ref = remesh(v, f, opts)
    out = remesh(_placed(v, scale), f, opts)
    assert out.report["topology_preserved"]
    # the same mesh up to the rounding of the placement (the relaxation drifts apart from
    # differences in the last bits): as many faces, every vertex on the input
    assert abs(len(out.faces) - len(ref.faces)) <= 0.02 * len(ref.faces)
    back = out.vertices / scale - 1e6
    foot, _, _ = MeshSurface(v, f).closest(back)
    assert np.linalg.norm(back - foot, axis=1).max() < 1e-6
    for key in ("hausdorff95_relative", "mean_to_input_relative"):
        assert out.report["distance"][key] == pytest.approx(ref.report["distance"][key], 0.2)
