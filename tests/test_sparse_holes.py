"""Hole filling on sparse input (#11): bunny-sparse's mechanism on a small synthetic shape.

On sparse input the resolution floor puts r0 near one median point spacing. A test of data
"at" a point within r0 then finds data beside only about half of the surface between the
samples, so a narrow seam two growth fronts left (on a thin part: an ear) failed the seam
test and stayed open. Data now covers a hole's inside within ``SAMPLING_REACH`` median
spacings (:func:`recon.fitting.pipeline.cover_reach`); where that leaves the mesh crossing
itself the fit meshes again with the test at r0.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import open3d as o3d
import pytest

import recon
import recon.fitting.pipeline as pipeline
import recon.growth as growth
import recon.polish as polish
import recon.small_handles as small_handles
from recon.intersections import self_intersections
from recon.io import read_points
from recon.topology import mesh_topology

#: A body with one thin ear (0.1 thick: about 5 median spacings at 2,000 points), as
#: (centre, semi-axes) of two ellipsoids.
EARED = [((0.0, 0.0, 0.0), (0.5, 0.4, 0.4)), ((0.15, 0.55, 0.1), (0.1, 0.35, 0.05))]


def ellipsoid_points(centre, axes, n: int, rng: np.random.Generator) -> np.ndarray:
    """Area-uniform points on an ellipsoid: uniform directions ``u`` mapped by ``x = A u``,
    kept with probability proportional to the area element ``|A^-1 u|`` (up to ``det A``)."""
    axes = np.asarray(axes, dtype=float)
    out, got = [], 0
    while got < n:
        u = rng.normal(size=(4 * n, 3))
        u /= np.linalg.norm(u, axis=1)[:, None]
        w = np.linalg.norm(u / axes, axis=1)
        keep = rng.uniform(size=len(u)) < w / w.max()
        out.append(u[keep] * axes + np.asarray(centre))
        got += int(keep.sum())
    return np.vstack(out)[:n]


def union_points(parts, n: int, seed: int) -> np.ndarray:
    """``n`` area-uniform points on the surface of a union of ellipsoids: each surface's
    points outside the others, drawn in proportion to the area left outside."""
    rng = np.random.default_rng(seed)
    pools, areas = [], []
    for i, (c, a) in enumerate(parts):
        p = ellipsoid_points(c, a, 20_000, rng)
        inside = np.zeros(len(p), dtype=bool)
        for j, (c2, a2) in enumerate(parts):
            if j != i:
                inside |= np.sum(((p - np.asarray(c2)) / np.asarray(a2)) ** 2, axis=1) < 1.0
        pools.append(p[~inside])
        x, y, z = a  # Knud Thomsen's approximation of the ellipsoid's area (exponent 1.6075)
        q = 1.6075
        area = 4 * np.pi * (((x * y) ** q + (x * z) ** q + (y * z) ** q) / 3) ** (1 / q)
        areas.append(area * float(np.mean(~inside)))
    k = rng.multinomial(n, np.asarray(areas) / np.sum(areas))
    return np.vstack(
        [pool[rng.choice(len(pool), m, replace=False)] for pool, m in zip(pools, k, strict=True)]
    )


def _topology(res):
    return mesh_topology(res.mesh.vertices, res.mesh.faces)


# cases where the coverage test at r0 leaves one seam open (which samples do moves with the
# fit: with the Morton order of the points, 2000 points seed 4 closed without the reach too;
# with the growth's active set, the default since the night of 2026-11-28, seeds 0, 1, 2, 5
# and 12 at 1500 points show the mechanism, none of seeds 0-24 at 2000 points does; over
# seeds 0-99 at 1500 and 2000 points 178 of 200 fits closed, 183 with one k, 190 once small
# handles were cut, 192 with the active set: docs/topology-history.md; with the fold rule,
# the seventeenth round, seeds 0, 1 and 2 show it and 5 and 12 close without the reach)
@pytest.mark.parametrize(("n", "seed"), [(1500, 0), (1500, 2)])
def test_a_sparse_thin_part_comes_out_closed(n, seed, monkeypatch):
    points = union_points(EARED, n, seed)
    res = recon.fit(points)
    t = _topology(res)
    assert t["watertight"] and t["components"] == 1 and t["genus"] == 0, t
    m = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(res.mesh.vertices),
        o3d.utility.Vector3iVector(res.mesh.faces.astype(np.int32)),
    )
    assert m.is_vertex_manifold() and m.is_edge_manifold(allow_boundary_edges=False)
    assert len(self_intersections(res.mesh.vertices, res.mesh.faces)) == 0
    # the mechanism: with data covering only within r0 (about one spacing here) the seam stays
    monkeypatch.setattr(pipeline, "cover_reach", lambda median_spacing: 0.0)
    assert _topology(recon.fit(points))["boundary_loops"] >= 1


def test_cover_reach_is_below_r0_on_dense_input():
    # dense input: r0 = 2.5 median spacings (seeds.spacing_factor), the test stays at r0
    assert pipeline.cover_reach(1 / 2.5) < pipeline.HOLE_COVER_DISTANCE
    # sparse input at the resolution floor (r0 ~ one spacing): about two r0
    assert pipeline.cover_reach(1.0) == pytest.approx(2.1)


def test_a_mesh_the_reach_leaves_crossing_is_meshed_again_at_r0(monkeypatch):
    """Where the reach closes a loop through a thin part (held-out ears and legs 2-5 point
    spacings thick at 3,000 points) untangling cannot remove the crossing: the fit then
    meshes again with data covering only within r0, as before the reach. (The crossing is
    faked after the polish's own fallbacks: a crossing only the polish made is undone there,
    with the reach kept; tests/test_polish.py.)"""
    points = union_points(EARED, 2000, 4)
    real = pipeline.polish_and_untangle
    calls = []

    def first_leaves_a_crossing(result, surface, rounds, flips=True, **kwargs):
        mesh, found, left = real(result, surface, rounds, flips, **kwargs)
        calls.append(len(mesh.faces))
        return mesh, found, (left + 1 if len(calls) == 1 else left)

    monkeypatch.setattr(pipeline, "polish_and_untangle", first_leaves_a_crossing)
    res = recon.fit(points)
    assert len(calls) == 2 and res.report.triangulation.self_intersections_left == 0
    monkeypatch.setattr(pipeline, "polish_and_untangle", real)
    monkeypatch.setattr(pipeline, "cover_reach", lambda median_spacing: 0.0)
    plain = recon.fit(points)
    assert np.array_equal(res.mesh.faces, plain.mesh.faces)


@pytest.mark.parametrize(("n", "seed"), [(1500, 8)])
def test_a_tunnel_at_a_sparse_ears_base_is_cut(n, seed, monkeypatch):
    """Regression (#11): at 1,500 points, seed 8, a flap of faces at the ear's base bridges two
    sheets into a tunnel a few spacings across: watertight, but genus 1 (seed 1 before the
    growth's active set became the default). The polished
    mesh's small handles are cut (recon.small_handles); without the cut the handle stays."""
    points = union_points(EARED, n, seed)
    res = recon.fit(points)
    t = _topology(res)
    assert t["watertight"] and t["components"] == 1 and t["genus"] == 0, t
    assert res.report.triangulation.small_handles_cut == 1
    assert len(self_intersections(res.mesh.vertices, res.mesh.faces)) == 0
    monkeypatch.setattr(polish, "without_small_handles", lambda result, **kwargs: result)
    assert _topology(recon.fit(points))["genus"] == 1


def _closed_genus_0(res) -> tuple[np.ndarray, np.ndarray]:
    """The fit's mesh, checked watertight, one component, genus 0 (ours), manifold (Open3D)
    and free of crossing faces."""
    v, f = res.mesh.vertices, res.mesh.faces
    t = mesh_topology(v, f)
    assert t["watertight"] and t["components"] == 1 and t["genus"] == 0, t
    m = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(v), o3d.utility.Vector3iVector(f))
    assert m.is_vertex_manifold() and m.is_edge_manifold(allow_boundary_edges=False)
    assert len(self_intersections(v, f)) == 0
    return v, f


#: bench_thin_parts.py's eared shape (a body, two thin ears, a tail) at 5,000 points, seed 12
#: (sample_data/README.md).
EARED_STALKS = Path(__file__).resolve().parents[1] / "sample_data" / "eared-stalks.ply"


def test_an_ear_held_by_two_thin_stalks_comes_out_genus_0(monkeypatch):
    """Regression (#11, held-out eared shape, 5,000 points, seed 12): one ear met the head
    through two stalks about a triangle thick, with a window between them about 20 r0 round.
    No ball of 5 r0 holds that handle, so it stayed (watertight, genus 1). It is now cut at a
    stalk: the ball round it is an annulus, and the tunnel beside it is no longer round than
    the largest hole that hole filling closes (pi x max_gap)."""
    points = read_points(EARED_STALKS).absolute_points()
    _closed_genus_0(recon.fit(points))
    # since the fold rule (test_the_notch_between_two_ears_is_not_filled) the growth no longer
    # makes the stalks here; without that rule the cut at a stalk still closes the handle
    monkeypatch.setattr(growth, "past_a_fold", lambda c, *args: np.zeros(len(c), dtype=bool))
    res = recon.fit(points)
    _closed_genus_0(res)
    assert res.report.fidelity.within_r0 >= 0.99  # the cut took a stalk, not the data's surface
    # the mechanism: without the cut at a stalk the handle stays
    monkeypatch.setattr(small_handles, "_cut_stalk", lambda *args: None)
    assert _topology(recon.fit(points))["genus"] == 1


#: The same eared shape at 3,000 points, seed 3 (sample_data/README.md): its ears, side by
#: side in the plane z = 0.1, leave a notch 0.14 wide between them (|x| < 0.07, y > 0.4).
EARED_NOTCH = Path(__file__).resolve().parents[1] / "sample_data" / "eared-notch.ply"


def test_the_notch_between_two_ears_is_not_filled(monkeypatch):
    """Regression (#11, held-out eared shape, 3,000 points, seeds 2 and 3): the notch between
    the ears is narrower than ``max_gap`` and the data surrounds it (ear, head, ear), so the
    ears' top faces grew into it: a web with holes, back faces and 6 handles. Its rims are
    folds, where an ear's two faces meet, and the fold rule keeps growth out of it."""
    points = read_points(EARED_NOTCH).absolute_points()
    res = recon.fit(points)
    v, _ = _closed_genus_0(res)
    notch = (np.abs(v[:, 0]) < 0.05) & (v[:, 1] > 0.5)
    assert not notch.any()
    # the mechanism: without the fold rule the faces grow into the notch
    monkeypatch.setattr(growth, "past_a_fold", lambda c, *args: np.zeros(len(c), dtype=bool))
    v = recon.fit(points).mesh.vertices
    assert ((np.abs(v[:, 0]) < 0.05) & (v[:, 1] > 0.5)).sum() > 50


#: An ellipsoid (semi-axes 1, 0.5, 0.4) whose sampling density falls 20x along x, 5,000 points
#: (sample_data/README.md: ``bench_thin_parts.py --shapes gradient --points 5000 --seed 4``).
GRADIENT = Path(__file__).resolve().parents[1] / "sample_data" / "gradient-sparse.ply"
GRADIENT_AXES = np.array([1.0, 0.5, 0.4])


def test_the_points_across_a_seam_are_covered_within_the_local_sampling_reach():
    """The median reach 2 r0; a point 3 r0 from a data point twice as sparse as the median is
    beyond it (and beyond the hole-cover distance, 2 r0 there), but within the reach of the
    local sampling (4 r0). Judged alone (a hole's centroid) it is not covered; among the
    points across a seam it is. Beside a sample of median density both ask for 2 r0."""
    dist, sparser = np.array([3.0, 3.0, 1.5]), np.array([2.0, 1.0, 1.0])
    assert pipeline.covered(dist, sparser, 1.0, 2.0).tolist() == [False, False, True]
    assert pipeline.covered(dist, sparser, 1.0, 2.0, across=True).tolist() == [True, False, True]


def test_a_seam_at_the_sparse_end_of_a_density_gradient_is_closed(monkeypatch):
    """Regression (#11): at the sparse tip, where the data lie 2.5 median spacings apart, two
    growth fronts leave a seam about 6 local spacings wide. Data lay beside 16 of the 18
    points across it, short of the seam rule's ``SEAM_SUPPORT`` (0.9), so it stayed open: two
    of them sit in a gap of the random sampling, farther from every sample than the median
    spacings' reach. The points across a seam are now judged at the reach of the local
    sampling (``covered(..., across=True)``)."""
    points = read_points(GRADIENT).absolute_points()
    res = recon.fit(points)
    v, f = _closed_genus_0(res)
    # on the ellipsoid: every vertex within 1 % of the diagonal (first-order distance)
    q = v / GRADIENT_AXES
    k0, k1 = np.linalg.norm(q, axis=1), np.linalg.norm(q / GRADIENT_AXES, axis=1)
    assert np.max(np.abs(k0 * (k0 - 1.0) / k1)) < 0.01 * np.linalg.norm(2 * GRADIENT_AXES)
    # the mechanism: with the median reach across seams too, the seam stays open
    real = pipeline.covered

    def median_reach(dist, sparser, spacing, reach, across=False):
        return real(dist, sparser, spacing, reach)

    monkeypatch.setattr(pipeline, "covered", median_reach)
    assert _topology(recon.fit(points))["boundary_loops"] == 1
