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


def test_the_sources_are_the_same_however_the_vertices_are_split(monkeypatch):
    """The scan runs one block of sources per thread (at least MIN_BLOCK_VERTICES each), each
    with its own scratch marks: any split gives the same sources, in vertex order. (Blocks of
    half a copy here, so that four blocks need three copies, not 4 x 2048 vertices: the
    pure-Python pass of `make test` took 51 s over those.)"""
    from recon.kernels import local_topology

    v, f = sphere_with_tunnel()
    monkeypatch.setattr(local_topology, "MIN_BLOCK_VERTICES", len(v) // 2)
    copies = 4 * local_topology.MIN_BLOCK_VERTICES // len(v) + 1  # enough for four blocks
    assert local_topology.source_blocks(copies * len(v), 4) == 4
    verts = np.vstack([v + [20.0 * k, 0.0, 0.0] for k in range(copies)])
    faces = np.vstack([f + k * len(v) for k in range(copies)])
    reach = 3 * _edge(v, f)
    one = small_handles(verts, faces, reach, threads=1)
    assert len(one[0]) == copies * len(small_handles(v, f, reach)[0])  # each copy's tunnel
    assert np.all(np.diff(one[0]) > 0)
    for threads in (2, 3, 4, 16):  # 16: capped at MAX_BLOCKS
        split = small_handles(verts, faces, reach, threads=threads)
        assert np.array_equal(one[0], split[0]) and np.array_equal(one[1], split[1])


def _grid_with_hole(n: int = 30, hole: int = 2):
    """A flat n x n grid of unit squares (two triangles each) without the hole x hole squares
    at its centre."""
    x, y = np.meshgrid(np.arange(n + 1.0), np.arange(n + 1.0), indexing="ij")
    v = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)
    faces = []
    lo = (n - hole) // 2
    for i in range(n):
        for j in range(n):
            if lo <= i < lo + hole and lo <= j < lo + hole:
                continue
            a, b, c, d = (
                i * (n + 1) + j,
                (i + 1) * (n + 1) + j,
                (i + 1) * (n + 1) + j + 1,
                i * (n + 1) + j + 1,
            )
            faces += [[a, b, c], [a, c, d]]
    return v, np.array(faces)


def test_a_ball_round_a_thin_stalk_is_a_ring_and_one_round_a_hole_is_not():
    """The stalk sources: balls that are one annulus wrapped round a part thinner than the
    ball. A ball round a small hole of the mesh is an annulus too, but its inner rim is the
    mesh's own boundary: not a stalk (it wasted the stalk cut's tries)."""
    from recon.small_handles import _sources, _Tables

    v, f = _grid_with_hole()
    hits, _, rings, _ = _sources(_Tables(v, f), 5.0)  # 6 ring sources before
    assert len(hits) == 0 and len(rings) == 0
    v, f = torus(24, 5, 2.0, 0.2)  # a tube 1.26 round
    hits, _, rings, sizes = _sources(_Tables(v, f), 1.0)
    assert len(hits) == 0 and len(rings) == len(v) and np.all(sizes > 0)
