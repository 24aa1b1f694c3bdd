"""Benchmark ``oprecon remesh`` against isotropic remeshers on the same inputs.

Inputs: the dev bunny (``gt/bunny.ply``) and a marching-cubes mesh made here (Open3D's
screened Poisson reconstruction of 200k area samples of the bunny: its triangles come from
marching cubes, with slivers down to ~0 degrees). Target edge = the input's mean edge length.

For every tool and input, runs alternate (ours, anchors, ours, ...) and the medians are printed:
wall time (ours with its input checks but without the measurements of its report: distances
and triangle quality,
which the anchors do not do),
worst / mean min angle, Hausdorff-95 / diagonal (100k samples each way, exact point-to-surface,
``recon.metrics.compare_meshes``), topology before and after, and the time ratio against
gpytoolbox ``remesh_botsch`` (10 iterations). Anchors are run where installed
(``pip install -e .[bench]``): gpytoolbox, pymeshlab (isotropic explicit remeshing, 10
iterations); CGAL and pyacvd are not packaged here and are reported as not installed.

Both tools run in this one process, so under the same OpenMP wait policy: the runtime's
default unless ``OMP_WAIT_POLICY`` is set (printed; PASSIVE slows OpenMP code ~4x on a quiet
machine). Run the timing part without ``nice``.

Then: ``--adaptive`` face saving at equal Hausdorff-95 on the bunny, the marching-cubes bunny
and a generated blob (an ellipsoid with a sharp bump and waves; uniform runs at several
spacings, interpolated in log-log) and the bound on that saving for any spacing that is a
function of the curvature (:func:`band_bound`), ``--faces N`` accuracy, and the crease deviation on
``gt/lblock.ply``.

    .venv/bin/python benchmarks/bench_remesh.py --skip adaptive faces      # timings
    nice -n 10 .venv/bin/python benchmarks/bench_remesh.py --skip compare  # the rest
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import time
from pathlib import Path

import numpy as np

from recon.io import read_mesh
from recon.metrics import compare_meshes, sample_surface
from recon.remesh import RemeshOptions, remesh
from recon.remesh.pipeline import spacing_field
from recon.remesh.surface import MeshSurface
from recon.topology import mesh_topology, triangle_quality

ITERATIONS = 10


def marching_cubes_bunny(v: np.ndarray, f: np.ndarray, depth: int) -> tuple[np.ndarray, ...]:
    import open3d as o3d

    p, n = sample_surface(v, f, 200_000, 0)
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(p))
    pc.normals = o3d.utility.Vector3dVector(n)
    m, _ = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(pc, depth=depth)
    m.remove_degenerate_triangles()
    m.remove_unreferenced_vertices()
    return np.asarray(m.vertices).copy(), np.asarray(m.triangles).astype(np.int64)


def blob() -> tuple[np.ndarray, np.ndarray]:
    """An ellipsoid (1 x 0.7 x 0.5) with a sharp bump and low waves: 81,920 faces of a
    subdivided icosahedron, deformed."""
    import open3d as o3d

    m = o3d.geometry.TriangleMesh.create_icosahedron(1.0).subdivide_midpoint(6)
    v = np.asarray(m.vertices).copy()
    u = v / np.linalg.norm(v, axis=1, keepdims=True)
    r = 1.0 + 0.25 * np.exp(-((u - [0.0, 0.0, 1.0]) ** 2).sum(axis=1) / 0.05)
    r += 0.12 * np.sin(5 * u[:, 0]) * np.cos(4 * u[:, 1])
    return u * r[:, None] * [1.0, 0.7, 0.5], np.asarray(m.triangles).astype(np.int64)


def mean_edge(v: np.ndarray, f: np.ndarray) -> float:
    return float(np.linalg.norm(v[f] - v[np.roll(f, -1, axis=1)], axis=2).mean())


def measure(v_in, f_in, v, f) -> dict:
    q = triangle_quality(v, f)
    t = mesh_topology(v, f)
    c = compare_meshes((v, f), (v_in, f_in), n_samples=100_000, seed=0)
    return {
        "faces": len(f),
        "worst": q["min_angle_min_deg"],
        "mean": q["min_angle_mean_deg"],
        "h95": c["hausdorff95_relative"],
        "h": c["hausdorff_relative"],
        "topo": (t["components"], t["boundary_loops"], t["genus"]),
    }


def run_ours(v, f, h, **kw):
    t = time.perf_counter()
    r = remesh(v, f, RemeshOptions(spacing=h, **kw))
    wall = time.perf_counter() - t - r.report["timings"]["measure"]
    return r.vertices, r.faces, wall


def run_gpytoolbox(v, f, h):
    import gpytoolbox as gpy

    t = time.perf_counter()
    V, F = gpy.remesh_botsch(v.astype(np.float64), f.astype(np.int32), i=ITERATIONS, h=h)
    return V, np.asarray(F, dtype=np.int64), time.perf_counter() - t


def run_pymeshlab(v, f, h):
    import pymeshlab

    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(v, f.astype(np.int32)))
    t = time.perf_counter()
    ms.meshing_isotropic_explicit_remeshing(iterations=ITERATIONS, targetlen=pymeshlab.PureValue(h))
    wall = time.perf_counter() - t
    m = ms.current_mesh()
    return m.vertex_matrix(), m.face_matrix().astype(np.int64), wall


def available() -> dict:
    tools = {"oprecon remesh": run_ours}
    for name, module, fn in (
        ("gpytoolbox remesh_botsch", "gpytoolbox", run_gpytoolbox),
        ("pymeshlab isotropic", "pymeshlab", run_pymeshlab),
    ):
        try:
            __import__(module)
            tools[name] = fn
        except ImportError:
            print(f"  {name}: not installed (pip install -e .[bench])")
    for name in ("CGAL isotropic_remeshing", "pyacvd"):
        print(f"  {name}: not installed (no package in this environment)")
    return tools


def compare_tools(name, v, f, runs, tools) -> None:
    h = mean_edge(v, f)
    q_in = triangle_quality(v, f)
    t_in = mesh_topology(v, f)
    topo_in = (t_in["components"], t_in["boundary_loops"], t_in["genus"])
    print(
        f"\n## {name}: {len(f):,} faces, target edge {h:.5g}; input worst "
        f"{q_in['min_angle_min_deg']:.4f} deg, mean {q_in['min_angle_mean_deg']:.1f} deg, "
        f"topology (components, loops, genus) {topo_in}"
    )
    times: dict[str, list[float]] = {k: [] for k in tools}
    last: dict[str, tuple] = {}
    for _ in range(runs):
        for tool, fn in tools.items():  # alternate the tools within every run
            V, F, wall = fn(v, f, h)
            times[tool].append(wall)
            last[tool] = (V, F)
    base = statistics.median(times.get("gpytoolbox remesh_botsch", [float("nan")]))
    print(
        "| tool | time (median) | ratio to gpytoolbox | faces | worst min angle | mean min "
        "angle | Hausdorff-95 / diag | topology after |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for tool in tools:
        m = measure(v, f, *last[tool])
        med = statistics.median(times[tool])
        print(
            f"| {tool} | {med:.2f} s | {med / base:.2f}x | {m['faces']:,} | {m['worst']:.1f} | "
            f"{m['mean']:.1f} | {m['h95']:.2e} | {m['topo']} |"
        )


BOUND_BANDS = 12
BOUND_SAMPLES = 100_000


def band_errors(v, f, V, F, rng) -> tuple[np.ndarray, np.ndarray]:
    """Distances of area samples both ways (output -> input, input -> output) and the input
    face under each sample."""
    surf_in, surf_out = MeshSurface(v, f), MeshSurface(V, F)
    p_out, _ = surf_out.sample(BOUND_SAMPLES, rng)
    foot, face_out, _ = surf_in.closest(p_out)
    p_in, face_in = surf_in.sample(BOUND_SAMPLES, rng)
    d = np.concatenate([np.linalg.norm(p_out - foot, axis=1), surf_out.distance(p_in)])
    return d, np.concatenate([face_out, face_in])


def band_bound(v, f, runs, target: float, lo: float = 0.5, hi: float = 3.0) -> tuple:
    """The largest face saving at the uniform run's Hausdorff-95 (``target`` x mean edge) that
    any spacing that is a function of the curvature field can reach, if every region's error
    at a spacing is that of a uniform mesh there.

    The input is cut into :data:`BOUND_BANDS` bands of equal area by the spacing field (i.e.
    by curvature); the uniform runs give each band's distance samples at their spacings (in
    between: the nearest run's samples scaled by (h / k)^p, p the band's measured order of the
    error in h). Faces go as sum A_b / h_b^2, and the pooled 95th percentile must stay at the
    target's: a Lagrange multiplier on the pooled exceedance picks every band's h_b in
    [lo, hi] x mean edge. Returns (saving, h per band, p per band)."""
    h = mean_edge(v, f)
    centre = 0.5 * (v.min(axis=0) + v.max(axis=0))
    surf = MeshSurface((v - centre) / h, f)
    x = spacing_field(surf, 1.0, 0.01, 100.0)[f].mean(axis=1)
    order = np.argsort(x)
    cum = np.cumsum(surf.face_area[order]) / surf.face_area.sum()
    band = np.empty(len(f), dtype=np.int64)
    band[order] = np.minimum((cum * BOUND_BANDS).astype(np.int64), BOUND_BANDS - 1)
    area = np.bincount(band, surf.face_area, BOUND_BANDS) / surf.face_area.sum()
    ks = np.array([k for k, _, _ in runs])
    by = {k: [np.sort(d[band[fc] == b]) for b in range(BOUND_BANDS)] for k, d, fc in runs}
    limit = np.percentile(next(d for k, d, _ in runs if k == target), 95)
    hs = np.exp(np.linspace(np.log(lo), np.log(hi), 120))
    exceed = np.zeros((BOUND_BANDS, len(hs)))
    p = np.zeros(BOUND_BANDS)
    for b in range(BOUND_BANDS):
        q95 = [np.percentile(by[k][b], 95) for k in ks]
        p[b] = np.polyfit(np.log(ks), np.log(q95), 1)[0]
        for j, hh in enumerate(hs):
            k = ks[np.argmin(np.abs(np.log(ks / hh)))]
            d = by[k][b] * (hh / k) ** p[b]
            exceed[b, j] = 1.0 - np.searchsorted(d, limit, side="right") / len(d)

    def pick(lam: float) -> tuple[np.ndarray, float]:
        j = ((1.0 / hs**2)[None, :] + lam * exceed).argmin(axis=1)
        return hs[j], float((area * exceed[np.arange(BOUND_BANDS), j]).sum())

    a, b_ = 1e-3, 1e7
    for _ in range(80):
        mid = math.sqrt(a * b_)
        a, b_ = (mid, b_) if pick(mid)[1] > 0.05 else (a, mid)
    hb, _ = pick(b_)
    return 1.0 - float((area / hb**2).sum()) * target**2, hb, p


def adaptive_saving(name, v, f) -> None:
    h = mean_edge(v, f)
    print(f"\n## --adaptive on the {name}: faces at equal Hausdorff and Hausdorff-95")
    uniform = []
    runs = []
    rng = np.random.default_rng(0)
    for k in (0.8, 1.0, 1.25, 1.6, 2.0):
        V, F, _ = run_ours(v, f, k * h)
        m = measure(v, f, V, F)
        uniform.append((m["faces"], m["h95"], m["h"]))
        runs.append((k, *band_errors(v, f, V, F, rng)))
        print(
            f"  uniform spacing {k:.2f} h: {m['faces']:,} faces, Hausdorff {m['h']:.2e}, "
            f"H95 {m['h95']:.2e}"
        )
    logf = np.log([u[0] for u in uniform])
    fits = {
        key: np.polyfit(np.log([u[i] for u in uniform]), logf, 1)
        for key, i in (("h95", 1), ("h", 2))
    }
    for k in (1.0, 1.5, 2.0):
        V, F, _ = run_ours(v, f, k * h, adaptive=True)
        m = measure(v, f, V, F)
        text = []
        for key, i, label in (("h", 2, "Hausdorff"), ("h95", 1, "H95")):
            slope, icpt = fits[key]
            need = float(np.exp(icpt + slope * np.log(m[key])))
            seen = [u[i] for u in uniform]
            note = "" if min(seen) <= m[key] <= max(seen) else " (extrapolated)"
            text.append(
                f"at equal {label} ({m[key]:.2e}) uniform needs ~{need:,.0f}{note}: "
                f"{100 * (1 - m['faces'] / need):.0f} % fewer"
            )
        print(
            f"  adaptive spacing {k:.2f} h: {m['faces']:,} faces, worst {m['worst']:.1f} mean "
            f"{m['mean']:.1f} deg, topology {m['topo']}; " + "; ".join(text)
        )
    for target in (1.0, 1.6):
        saving, hb, p = band_bound(v, f, runs, target)
        print(
            f"  bound at the uniform {target:.2f} h run's H95, spacing any function of the "
            f"curvature ({BOUND_BANDS} bands, 0.5-3 h): {100 * saving:.0f} % fewer; h per band "
            f"{np.round(hb, 2).tolist()}; order of the error in h per band "
            f"{np.round(p, 2).tolist()}"
        )


def faces_accuracy(v, f) -> None:
    print("\n## --faces N on the bunny")
    for n in (10_000, 30_000, 60_000):
        r = remesh(v, f, RemeshOptions(faces=n, check_intersections=False))
        got = len(r.faces)
        print(f"  N = {n:,}: {got:,} faces ({100 * (got - n) / n:+.2f} %)")


def creases(path: Path) -> None:
    v, f = read_mesh(path)
    r = remesh(v, f, RemeshOptions(crease_angle=40.0))
    rep = r.report
    q = rep["output"]["triangle_quality"]
    print(
        f"\n## lblock --crease-angle 40: {rep['features']['crease_edges']} crease edges, "
        f"{rep['features']['corners']} corners; largest crease deviation "
        f"{100 * rep['features']['deviation_max_relative']:.2e} % of the diagonal; worst "
        f"{q['min_angle_min_deg']:.1f} mean {q['min_angle_mean_deg']:.1f} deg; topology "
        f"{'preserved' if rep['topology_preserved'] else 'CHANGED'}"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", type=Path, default=Path(__file__).parents[2] / "shared" / "data")
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--mc-depth", type=int, default=7)
    ap.add_argument(
        "--skip", nargs="*", default=[], help="parts to skip: compare adaptive faces creases"
    )
    args = ap.parse_args()
    policy = os.environ.get("OMP_WAIT_POLICY")
    print(f"OMP_WAIT_POLICY: {policy or 'not set (the OpenMP runtime default)'}; both tools alike")
    v, f = read_mesh(args.data / "gt" / "bunny.ply")
    # warm up the compiled kernels (numba caches) outside the timings
    remesh(v, f, RemeshOptions(spacing=4 * mean_edge(v, f), check_intersections=False))
    vm, fm = marching_cubes_bunny(v, f, args.mc_depth)
    mc_name = f"marching-cubes bunny (Poisson depth {args.mc_depth})"
    if "compare" not in args.skip:
        tools = available()
        compare_tools("bunny", v, f, args.runs, tools)
        compare_tools(mc_name, vm, fm, args.runs, tools)
    if "adaptive" not in args.skip:
        adaptive_saving("bunny", v, f)
        adaptive_saving(mc_name, vm, fm)
        adaptive_saving("blob", *blob())
    if "faces" not in args.skip:
        faces_accuracy(v, f)
    if "creases" not in args.skip:
        creases(args.data / "gt" / "lblock.ply")


if __name__ == "__main__":
    main()
