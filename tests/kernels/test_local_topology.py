"""Handles inside geodesic balls (recon.kernels.local_topology), through recon.small_handles."""

import numpy as np
import pytest

from recon.small_handles import small_handles
from tests.mesh_shapes import icosphere, sphere_with_tunnel, torus


def _edge(v, f):
    return float(np.median(np.linalg.norm(v[f[:, 0]] - v[f[:, 1]], axis=1)))


def test_a_sphere_has_no_small_handle():
    v, f = icosphere(3, 6.0)
    hits, sizes = small_handles(v, f, 3 * _edge(v, f))
    assert len(hits) == 0 and len(sizes) == 0


def test_a_tunnel_a_few_edges_across_is_found_where_it_is():
    v, f = sphere_with_tunnel()
    hits, sizes = small_handles(v, f, 3 * _edge(v, f))
    assert len(hits) > 0 and np.all(sizes > 0)
    tube = np.unique(f[-6:])  # the tube's corners
    # every ball that holds the handle is centred within the reach of the tube
    gap = np.linalg.norm(v[hits][:, None, :] - v[tube][None, :, :], axis=2).min(axis=1)
    assert gap.max() <= 3 * _edge(v, f)
    # a smaller ball cannot hold it
    assert len(small_handles(v, f, 0.8 * _edge(v, f))[0]) == 0


@pytest.mark.parametrize(
    ("shape", "found"),
    [((64, 20, 10.0, 3.0), False), ((8, 6, 1.2, 0.5), True)],
    ids=["ring-of-the-true-surface", "torus-a-few-edges-round"],
)
def test_a_handle_counts_only_when_both_its_cycles_fit_in_the_ball(shape, found):
    v, f = torus(*shape)
    hits, _ = small_handles(v, f, 3 * _edge(v, f))
    assert (len(hits) > 0) == found
