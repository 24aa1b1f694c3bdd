"""The held-out benchmark's judge: a part turned inside out must show (bench_thin_parts)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import open3d as o3d

ROOT = Path(__file__).resolve().parents[1]


def _bench():
    spec = importlib.util.spec_from_file_location(
        "bench_thin_parts", ROOT / "benchmarks" / "bench_thin_parts.py"
    )
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_inward_share_finds_a_part_turned_inside_out():
    """An outward sphere has no area wound inward, the reversed one all of it, and with one
    cap turned over (still watertight, genus 0: only the winding tells) the cap's share."""
    bench = _bench()
    m = o3d.geometry.TriangleMesh.create_sphere(radius=0.5, resolution=30)
    v = np.asarray(m.vertices) + [0.1, -0.2, 0.3]
    f = np.asarray(m.triangles, dtype=np.int64)
    sdf = bench.ellipsoid([0.1, -0.2, 0.3], [0.5, 0.5, 0.5])
    assert bench.inward_share(v, f, sdf) == 0.0
    assert bench.inward_share(v, f[:, ::-1], sdf) == 1.0
    tri = v[f]
    cap = tri.mean(axis=1)[:, 2] > 0.3 + 0.25  # the faces above z = 0.25 (about a quarter)
    turned = f.copy()
    turned[cap] = turned[cap][:, ::-1]
    area = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    expected = area[cap].sum() / area.sum()
    assert 0.1 < expected < 0.4
    assert abs(bench.inward_share(v, turned, sdf) - expected) < 1e-12
    judged = bench.judge(v, turned, tri.mean(axis=1), sdf)
    assert judged["watertight"] and judged["genus"] == 0  # the topology cannot tell
    assert judged["inward"] == bench.inward_share(v, turned, sdf)
    assert bench.judge(v, f, tri.mean(axis=1))["inward"] is None  # no implicit function
