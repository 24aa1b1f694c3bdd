"""Peak memory of the stages that scale with the data (issue 13: 1M points under 2 GiB).

The large per-point and per-edge arrays are worked in blocks: each test checks that the
blocked result equals the one-block result bit for bit, and bounds the traced peak
(``tracemalloc`` sees numpy's allocations) well below what the whole-array version held.
"""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest
from scipy.spatial import cKDTree

from recon.config import ReconConfig

pytestmark = pytest.mark.usefixtures("no_kernel_loading")  # (tracemalloc: every thread)


def _traced_peak(fn, *args, **kwargs):
    """(result, peak bytes allocated by ``fn`` above the memory held at its start)."""
    tracemalloc.start()
    try:
        start, _ = tracemalloc.get_traced_memory()
        tracemalloc.reset_peak()
        out = fn(*args, **kwargs)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    return out, peak - start


def _sphere(n: int, seed: int = 0) -> np.ndarray:
    p = np.random.default_rng(seed).normal(size=(n, 3))
    return p / np.linalg.norm(p, axis=1, keepdims=True)


def _grid_mesh(n: int) -> tuple[np.ndarray, np.ndarray]:
    """An n x n grid of vertices on a gentle wave, two triangles per cell."""
    x, y = np.meshgrid(np.arange(n, dtype=float), np.arange(n, dtype=float))
    v = np.column_stack([x.ravel(), y.ravel(), 0.01 * np.sin(x.ravel() + y.ravel())])
    a = (np.arange(n - 1)[:, None] * n + np.arange(n - 1)[None, :]).ravel()
    f = np.concatenate(
        [np.column_stack([a, a + 1, a + n + 1]), np.column_stack([a, a + n + 1, a + n])]
    )
    return v, f


def test_shared_query_holds_int32_indices_and_equals_the_tree_query(monkeypatch):
    """int32 indices (12 bytes a neighbour held instead of 16), queried block by block: the
    same neighbours and distances as one query of the whole cloud."""
    from recon.fitting import pipeline

    p = _sphere(5000)
    monkeypatch.setattr(pipeline, "SHARED_QUERY_BLOCK", 1234)
    dist, idx = pipeline.shared_neighbors(p, ReconConfig())
    assert idx.dtype == np.int32 and dist.dtype == np.float64
    d_ref, i_ref = cKDTree(p).query(p, k=idx.shape[1])
    np.testing.assert_array_equal(idx, i_ref)
    np.testing.assert_array_equal(dist, d_ref)


def test_shared_query_runs_on_a_cell_grid_and_equals_the_tree_query_where_density_varies(
    monkeypatch,
):
    """The grid answers the shared query (its cell from a sample of the widest neighbour's
    distance); points far sparser than the sample's median go to the grid's k-d tree: every
    answer is the tree's."""
    from recon.fitting import pipeline
    from recon.neighbors import PointGrid

    rng = np.random.default_rng(8)
    dense = _sphere(6000)
    sparse = rng.uniform(-6.0, 6.0, (60, 3))  # far outside, ~1 point per 30 cells
    p = np.vstack([dense, sparse])
    grids = []

    class Spy(PointGrid):
        def __init__(self, *a, **k):
            super().__init__(*a, **k)
            grids.append(self)

    monkeypatch.setattr(pipeline, "PointGrid", Spy)
    dist, idx = pipeline.shared_neighbors(p, ReconConfig())
    assert len(grids) == 1 and grids[0].grid is not None
    assert grids[0]._tree is not None  # the sparse points were handed on
    d_ref, i_ref = cKDTree(p).query(p, k=idx.shape[1])
    np.testing.assert_array_equal(idx, i_ref)
    np.testing.assert_array_equal(dist, d_ref)


def test_orientation_costs_in_blocks_are_the_same_with_a_bounded_peak(monkeypatch):
    """The orientation graph's edge costs, block by block: the same oriented normals, and the
    graph's temporaries stay within 900 bytes per point (1.3 kB with the whole-graph gathers)."""
    from recon import normals, orientation_graph
    from recon.normals import estimate_normals, orient_normals

    p = _sphere(60000, seed=1)
    nrm = estimate_normals(p, k=20)
    knn = cKDTree(p).query(p, k=31)[1].astype(np.int32)
    whole, _ = orient_normals(p, nrm, k=10, across_cost=0.3, neighbors=knn)
    monkeypatch.setattr(orientation_graph, "EDGE_BLOCK", 4096)
    monkeypatch.setattr(normals, "_CHUNK", 2048)  # the thin-part split's blocks
    (blocked, _), peak = _traced_peak(orient_normals, p, nrm, k=10, across_cost=0.3, neighbors=knn)
    np.testing.assert_array_equal(blocked, whole)
    assert peak < 900 * len(p), peak / len(p)  # 1,343 bytes before the blocks, 673 after


def test_overlapping_faces_in_blocks_are_the_same_with_a_bounded_peak(monkeypatch):
    """The corner pairs of :func:`recon.mesh.overlapping_faces`, block by block: the same pairs
    (a doubled quad's overlaps found), and a peak under 450 bytes per face where the whole
    step's arrays held 817."""
    from recon import mesh

    v, f = _grid_mesh(200)
    f = np.vstack([f, [[0, 1, 200]]])  # the other diagonal of the first quad: overlaps
    whole = mesh.overlapping_faces(v, f)
    assert len(whole) >= 2
    monkeypatch.setattr(mesh, "OVERLAP_BLOCK", 2048)
    blocked, peak = _traced_peak(mesh.overlapping_faces, v, f)
    np.testing.assert_array_equal(blocked, whole)
    assert peak < 450 * len(f), peak / len(f)  # 817 bytes before the blocks, 320 after


def test_crease_detection_in_blocks_is_the_same_on_int32_neighbours(monkeypatch):
    """Crease labels from the shared int32 query, block by block, equal those of the crease
    detection's own (int64, one block) query."""
    from recon import creases

    rng = np.random.default_rng(3)
    p = _sphere(6000, seed=3)
    p[:, 2] = np.minimum(p[:, 2], 0.4)  # a cap cut off: a crease
    p += rng.normal(0.0, 0.002, p.shape)
    own = creases.detect_creases(p, k=48)
    d, i = cKDTree(p).query(p, k=48)
    monkeypatch.setattr(creases, "BLOCK", 1000)
    shared = creases.detect_creases(p, k=48, neighbors=(d, i.astype(np.int32)))
    assert own.n_crease_points > 0
    np.testing.assert_array_equal(shared.labels, own.labels)
    np.testing.assert_array_equal(shared.side_normals, own.side_normals)


def test_particle_re_signing_queries_the_particles_once(monkeypatch):
    """:func:`recon.particle_signs.consistent_normals` builds one k-d tree of the particles
    (the propagation's graph takes its columns); :func:`recon.normals.orient_normals` given
    the shared neighbours signs as with a query of its own."""
    from recon import normals, particle_signs
    from recon.normals import orient_normals

    rng = np.random.default_rng(5)
    p = _sphere(3000, seed=5) * 20.0
    n = p / 20.0
    cap = n @ np.array([0.0, 0.6, 0.8]) > 0.9
    n[cap] *= -1.0
    n += rng.normal(0.0, 0.05, n.shape)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    built = []

    class CountingTree(cKDTree):
        def __init__(self, *a, **k):
            built.append(1)
            super().__init__(*a, **k)

    monkeypatch.setattr(particle_signs, "cKDTree", CountingTree)
    monkeypatch.setattr(normals, "cKDTree", CountingTree)
    fixed = particle_signs.consistent_normals(p, n)
    assert len(built) == 1  # was 2: the propagation queried the particles again
    monkeypatch.undo()
    # the pipeline's shared query gives the propagation the same graph as a query of its own
    own, _ = orient_normals(p, n, k=6, orientation="none", across_cost=0.3)
    shared, _ = orient_normals(
        p, n, k=6, orientation="none", across_cost=0.3, neighbors=cKDTree(p).query(p, 31)[1]
    )
    np.testing.assert_array_equal(shared, own)
    assert np.all(np.einsum("ij,ij->i", fixed, p / 20.0) > 0.0)  # the cap turned back


def test_mesh_topology_frees_its_half_edges_before_the_fan_pass():
    """The report's topology count (the 1M fit's peak) holds under 550 bytes per face (817 when
    its half-edge arrays and :func:`recon.mesh.vertex_fans`' were all alive at once)."""
    from recon.topology import mesh_topology

    v, f = _grid_mesh(300)
    topo, peak = _traced_peak(mesh_topology, v, f)
    assert topo["boundary_loops"] == 1 and topo["non_manifold_vertices"] == 0
    assert topo["euler_characteristic"] == 1
    assert peak < 550 * len(f), peak / len(f)
