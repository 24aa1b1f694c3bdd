"""One-sided sheets beside a closed body made thin parts of it (#11), tried again only where a
join changed the body (a shattered mesh's repair took a crossing search per sheet and join)."""

from __future__ import annotations

import numpy as np
import open3d as o3d
import pytest

import recon.holes as holes
import recon.thin_sheets as thin_sheets
from recon.mesh import handle_count
from recon.thin_sheets import thicken_sheets
from recon.topology import mesh_topology

HALF = 0.15


def _sheet(
    centre: np.ndarray, angle: float, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """A jittered 4 x 4 grid (3 x 3 cells of side 0.5) in the plane z = centre_z, turned by
    ``angle`` about the z axis."""
    s = (np.arange(4) - 1.5) * 0.5
    x, y = np.meshgrid(s, s, indexing="ij")
    c, t = np.cos(angle), np.sin(angle)
    x, y = c * x - t * y, t * x + c * y
    v = np.stack([x.ravel(), y.ravel(), np.zeros(16)], axis=1) + centre
    v += rng.normal(scale=0.02, size=v.shape)
    i, j = np.meshgrid(np.arange(3), np.arange(3), indexing="ij")
    a = (i * 4 + j).ravel()
    f = np.concatenate([np.stack([a, a + 4, a + 5], 1), np.stack([a, a + 5, a + 1], 1)])
    return v, f


def _body_with_sheets() -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """A closed sphere (radius 5) and 24 flat sheets round its equator: rows of three going
    outward at each of eight angles. A row's first sheet is 0.4-0.6 from the body, or 3 (too
    far), or cuts into it (its thick copy would cross it); each next sheet is 0.5 beyond the
    one before, so it can join only once that one has, and comes first in the faces, so it
    is tried before that one joins. Returns vertices, normals, faces and
    the number of sheets."""
    sphere = o3d.geometry.TriangleMesh.create_sphere(radius=5.0, resolution=24)
    v = [np.asarray(sphere.vertices)]
    normals = [v[0] / 5.0]
    faces = [np.asarray(sphere.triangles, dtype=np.int64)]
    rng = np.random.default_rng(7)
    count, sheets = len(v[0]), 0
    for k, first in enumerate([0.5, 3.0, -0.5, 0.4, 0.6, 3.0, 0.5, -0.5]):
        angle = 2.0 * np.pi * k / 8.0
        out = np.array([np.cos(angle), np.sin(angle), 0.0])
        for step in (2, 1, 0):  # outermost first: tried (and failed) before it can join
            dist = 5.0 + first + 0.75 + step * 2.0  # the sheet's centre; its half-width 0.75
            sv, sf = _sheet(dist * out, angle, rng)
            v.append(sv)
            normals.append(np.tile([0.0, 0.0, 1.0], (len(sv), 1)))
            faces.append(sf + count)
            count += len(sv)
            sheets += 1
    return np.concatenate(v), np.concatenate(normals), np.concatenate(faces), sheets


def test_a_sheet_beside_the_body_and_the_sheets_that_continue_it_join_it():
    v, n, f, sheets = _body_with_sheets()
    assert handle_count(f, len(v)) == (1 + sheets, sheets, 0)
    thick = thicken_sheets(v, n, f, 1.0, HALF)
    assert thick is not None
    tv, tn, tf = thick
    assert len(tv) == len(tn) and np.array_equal(tv[: len(v)], v)
    topo = mesh_topology(tv, tf)
    # rows at 0.4-0.6 join sheet by sheet (4 rows of 3); rows 3 away or cutting into the
    # body stay (4 rows of 3 open sheets)
    assert topo["components"] == 1 + 12, topo
    assert topo["boundary_loops"] == 12, topo


def test_a_sheet_far_from_a_closed_body_leaves_the_mesh_alone():
    v, n, f, _ = _body_with_sheets()
    assert thicken_sheets(v, n, f, 0.1, HALF) is None


@pytest.mark.parametrize("where", ["sheets", "parts"])
def test_failed_trials_are_retried_only_where_a_join_changed_the_body(monkeypatch, where):
    """With and without the memo of failed trials, the same joins in the same order (the
    same faces); with it, the sheets or parts far from each join are not tried again."""
    v, n, f, _ = _body_with_sheets()
    if where == "parts":  # each sheet thickened alone: closed parts beside the body

        def run() -> object:
            return holes.join_closed_parts(pv, pf, 1.0)

        n_body = len(o3d.geometry.TriangleMesh.create_sphere(radius=5.0, resolution=24).triangles)
        parts_v, parts_f, count = [v], [f[:n_body]], len(v)
        for sheet in np.split(f[n_body:], (len(f) - n_body) // 18):  # 18 faces a sheet
            sv, sf = holes.thicken_sheet(v, sheet, HALF)
            parts_v.append(sv)
            parts_f.append(sf + count)
            count += len(sv)
        pv, pf = np.concatenate(parts_v), np.concatenate(parts_f)
    else:

        def run() -> object:
            return thicken_sheets(v, n, f, 1.0, HALF)

    calls = {"n": 0}
    tree = holes.cKDTree

    class CountedTree(tree):  # every distance query of a trial, and the necks' own
        def query(self, *args, **kwargs):
            calls["n"] += 1
            return super().query(*args, **kwargs)

    monkeypatch.setattr(holes, "cKDTree", CountedTree)
    monkeypatch.setattr(thin_sheets, "cKDTree", CountedTree)
    with_memo = run()
    queries = calls["n"]
    calls["n"] = 0
    monkeypatch.setattr(holes.FailedTrials, "__contains__", lambda self, k: False)
    without = run()
    assert with_memo is not None and without is not None
    for a, b in zip(
        with_memo if isinstance(with_memo, tuple) else [with_memo],
        without if isinstance(without, tuple) else [without],
        strict=True,
    ):
        assert np.array_equal(a, b)
    assert queries < 0.5 * calls["n"], (queries, calls["n"])


def test_tied_neck_candidates_go_in_face_order_whatever_else_the_mesh_holds():
    """The memo relies on a join far away leaving a part's neck candidates as they were: with
    exact ties, the sort must not depend on the rest of the array (regression: the default
    sort's tie order changed when far faces were added, and a part that had failed would
    have joined on a retry)."""
    rng = np.random.default_rng(2)
    top = rng.uniform(-4.0, 4.0, size=(60, 2))
    v = np.vstack(
        [
            np.column_stack([top, np.ones(60)]),  # the body: triangles at z = 1 ...
            np.column_stack([top, -np.ones(60)]),  # ... mirrored exactly to z = -1
            [[6.0, -0.5, 0.0], [7.0, 0.5, 0.0], [6.0, 0.5, 0.0]],  # the part, at z = 0
        ]
    )
    tri = rng.integers(0, 60, size=(300, 3))
    faces = np.vstack([tri, tri + 60, [[120, 121, 122]]])  # the same corner order: exact ties
    body, part = np.arange(600), np.array([600])
    pairs, gaps = holes.neck_candidates(v, faces, body, part, candidates=600)
    assert len(np.unique(gaps)) <= len(gaps) // 2  # the test means something: ties
    for d in np.unique(gaps):  # within a tie, the body faces in their order
        assert np.all(np.diff(pairs[gaps == d, 0]) > 0)
    # far faces listed after the body change nothing among the body's
    far_v = np.vstack([v, v[:120] + [100.0, 0.0, 0.0]])
    far_f = np.vstack([faces, tri + 123, tri + 183])
    more = np.concatenate([body, np.arange(601, 1201)])
    again, gaps_again = holes.neck_candidates(far_v, far_f, more, part, candidates=600)
    assert np.array_equal(again, pairs) and np.array_equal(gaps_again, gaps)
