"""--adaptive: the remeshed edges follow the spacing field, in its finest and coarsest parts."""

import numpy as np

from recon.remesh import RemeshOptions, remesh
from recon.remesh.pipeline import ADAPTIVE_MAX, ADAPTIVE_MIN, spacing_field
from recon.remesh.surface import MeshSurface
from tests.mesh_shapes import icosphere


def _vertex_edge_length(v, f):
    e = np.unique(np.sort(f[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1), axis=0)
    length = np.linalg.norm(v[e[:, 0]] - v[e[:, 1]], axis=1)
    total = np.bincount(e[:, 0], length, len(v)) + np.bincount(e[:, 1], length, len(v))
    return total / np.maximum(np.bincount(e.ravel(), minlength=len(v)), 1)


def test_adaptive_edges_follow_the_field_at_both_ends():
    # an oblate spheroid (a disc): curved rim (fine spacing), flat faces (coarse)
    v, f = icosphere(4)
    v = v * [1.0, 1.0, 0.2]
    s = 0.06
    r = remesh(v, f, RemeshOptions(spacing=s, adaptive=True, check_intersections=False))
    centre = 0.5 * (v.min(axis=0) + v.max(axis=0))
    surface = MeshSurface((v - centre) / s, f)
    field = spacing_field(surface, 1.0, ADAPTIVE_MIN, ADAPTIVE_MAX)
    out = (r.vertices - centre) / s
    _, face, _ = surface.closest(out)
    target = field[f[face]].mean(axis=1)
    ratio = _vertex_edge_length(out, r.faces) / target
    lo, hi = np.percentile(target, [20, 80])
    assert hi > 1.8 * lo  # the field is graded
    fine, coarse = np.median(ratio[target <= lo]), np.median(ratio[target >= hi])
    assert 0.85 < fine < 1.15 and 0.85 < coarse < 1.15, (fine, coarse)
    assert r.report["topology_preserved"]
