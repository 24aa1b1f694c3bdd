"""Peer benchmark: oprecon against the tools a user would pick instead, on the dev data set.

For every case of the development data (``../shared/data`` beside the checkout by default, or
``--data DIR``) and every method, runs the reconstruction in a fresh worker process (so the peak
memory is that method's), compares the result with the ground-truth mesh and writes a Markdown
table (and JSON with ``--json-out``):

    Chamfer-L1 and Hausdorff95 (÷ GT bbox diagonal), F-score at 1 %, normal consistency,
    boundary loops, components, non-manifold vertices, genus, watertight (the standard
    definition: every edge in two faces, every vertex one fan; ``recon.topology``) and Open3D's
    ``is_watertight()`` (which also rejects self-intersections, and wrongly counts disjoint
    coplanar faces as such: Open3D issues #5117, #6462), the crossing face pairs by
    ``recon.intersections`` (exact, coplanar overlaps included), mean minimum triangle angle,
    wall time, peak memory.

Methods: ``oprecon`` (defaults), Open3D screened Poisson depth 8 and 9 (normals estimated by
PCA and oriented by Open3D's MST propagation on a k-NN graph, 2 % lowest-density vertices
trimmed), Open3D ball pivoting (radii 1, 2, 4 x median spacing), Open3D alpha shape
(alpha = 4 x median spacing), and ``spsr``: MeshLab's screened Poisson through pymeshlab
(``pip install -e ".[bench]"``) with its own normal estimation (k = 10), depth 8, the peer of
issue 13's speed goal.

Time: ``seconds`` is the reconstruction alone (the input read and the imports excluded, for
every method alike), the median over ``--repeats`` runs; the methods of a case run alternately
(A B A B ...) so that a change of machine load hits both. The package's byte code is compiled
first (:func:`compile_sources`), as an installed package has it: with
``PYTHONDONTWRITEBYTECODE`` set and an editable install, every worker would otherwise compile
oprecon's modules from source inside the timed region (``--source-imports`` measures that).
When ``oprecon`` and ``spsr`` both run, the last lines print the time ratio oprecon / spsr per
case (goal for bunny-clean: <= 1).

Examples::

    python benchmarks/bench_quality.py                      # every case, every method
    python benchmarks/bench_quality.py --cases bunny-clean sphere-clean --methods oprecon poisson8
    python benchmarks/bench_quality.py --out bench_output/quality.md --json-out bench_output/q.json
    python benchmarks/bench_quality.py --methods oprecon --preset closed_scan --cases torus-missing
    python benchmarks/bench_quality.py --methods oprecon --cases bone-clean --set seeds.adaptive=yes
    python benchmarks/bench_quality.py --methods oprecon ball_pivoting \\
        --cases lblock-clean lblock-noise025 --set creases.enabled=true
    python benchmarks/bench_quality.py --methods oprecon spsr --cases bunny-clean --repeats 3

On machined ground truths (``CREASE_SHAPES``) a second table gives the distance from points
every 0.1 % of the diagonal along the GT's sharp edges (dihedral turn > 30 deg) to the mesh.
"""

from __future__ import annotations

import argparse
import compileall
import json
import os
import resource
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parent.parent

if str(Path(__file__).resolve().parent) not in sys.path:  # the benchmarks' shared options
    sys.path.insert(0, str(Path(__file__).resolve().parent))
from shared_options import add_overrides, override_values  # noqa: E402

METHODS = ("oprecon", "poisson8", "poisson9", "ball_pivoting", "alpha_shape", "spsr")
#: Screened Poisson depth of the ``spsr`` method (MeshLab's default is 8).
SPSR_DEPTH = 8


def _peer_normals(o3d: Any, pcd: Any) -> None:
    pcd.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(20))
    try:
        pcd.orient_normals_consistent_tangent_plane(10)
    except RuntimeError:  # Qhull failure on planar input (documented peer limitation)
        pcd.orient_normals_towards_camera_location(np.asarray(pcd.get_center()) + [0, 0, 1e3])


def run_method(
    method: str,
    input_path: str,
    preset: str | None = None,
    seed: int = 0,
    overrides: tuple[str, ...] = (),
) -> dict[str, Any]:
    """Reconstruct one input with one method (runs in a worker process)."""
    import open3d as o3d

    from recon.config import ReconConfig
    from recon.geometry import SPACING_SAMPLE_SEED, median_nearest_neighbor_distance
    from recon.io import read_points

    if method == "oprecon":
        from recon.heap import keep_freed_memory

        keep_freed_memory()  # as `oprecon fit` does (this process runs one fit)
    cloud = read_points(input_path)
    pts = cloud.points
    t0 = time.perf_counter()
    if method == "oprecon":
        from recon.config import apply_overrides, load_config
        from recon.fitting import reconstruct

        cfg = load_config(ROOT / "configs" / f"{preset}.yaml") if preset else ReconConfig()
        cfg = apply_overrides(cfg, {"seed": seed, **override_values(list(overrides))})
        res = reconstruct(cloud, cfg)
        v, f = res.mesh.vertices - cloud.origin, res.mesh.faces
    elif method == "spsr":
        import pymeshlab  # the [bench] extra; never a runtime dependency

        ms = pymeshlab.MeshSet()
        ms.add_mesh(pymeshlab.Mesh(vertex_matrix=np.ascontiguousarray(pts, dtype=np.float64)))
        ms.compute_normal_for_point_clouds(k=10)
        ms.generate_surface_reconstruction_screened_poisson(depth=SPSR_DEPTH)
        m = ms.current_mesh()
        v, f = m.vertex_matrix(), m.face_matrix().astype(np.int64)
    else:
        o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
        spacing = median_nearest_neighbor_distance(
            pts, rng=np.random.default_rng(SPACING_SAMPLE_SEED)
        )
        pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
        if method.startswith("poisson"):
            _peer_normals(o3d, pcd)
            mesh, dens = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(
                pcd, depth=int(method[-1])
            )
            dens = np.asarray(dens)
            mesh.remove_vertices_by_mask(dens < np.quantile(dens, 0.02))
        elif method == "ball_pivoting":
            _peer_normals(o3d, pcd)
            radii = o3d.utility.DoubleVector([spacing, 2 * spacing, 4 * spacing])
            mesh = o3d.geometry.TriangleMesh.create_from_point_cloud_ball_pivoting(pcd, radii)
        elif method == "alpha_shape":
            mesh = o3d.geometry.TriangleMesh.create_from_point_cloud_alpha_shape(pcd, 4 * spacing)
        else:
            raise ValueError(method)
        v = np.asarray(mesh.vertices)
        f = np.asarray(mesh.triangles, dtype=np.int64)
    seconds = time.perf_counter() - t0
    peak_mb = _own_peak_mb()
    return {
        "v": np.asarray(v + cloud.origin),
        "f": np.asarray(f),
        "seconds": seconds,
        "peak_mb": peak_mb,
    }


def _own_peak_mb() -> float:
    """This process's peak resident memory [MB]: ``VmHWM`` of ``/proc/self/status`` where there
    is one (``ru_maxrss`` survives exec on Linux, so a spawned worker would report its parent's
    peak when that was higher), else ``ru_maxrss``."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return float(line.split()[1]) / 1024.0
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def compile_sources(package: Path = ROOT / "recon") -> bool:
    """Write the byte code of ``package``'s modules to ``__pycache__`` (what a non-editable
    install and any first import do, unless ``PYTHONDONTWRITEBYTECODE`` is set; up-to-date
    files are skipped). True when every module compiled."""
    return bool(compileall.compile_dir(str(package), quiet=1))


def reconstruct_once(
    case_dir: Path, method: str, preset: str | None = None, overrides: tuple[str, ...] = ()
) -> dict[str, Any]:
    """One run of ``method`` on a case in a fresh worker process (or ``error``).

    Spawned, not forked: this process has numba's thread pool running once a case is
    judged, and a forked child of a threaded process can die on its first parallel kernel.
    """
    with ProcessPoolExecutor(max_workers=1, mp_context=get_context("spawn")) as pool:
        try:
            inp = str(case_dir / "input.ply")
            return pool.submit(run_method, method, inp, preset, 0, overrides).result()
        except Exception as exc:  # a peer crashing is a result too
            return {"error": f"{type(exc).__name__}: {exc}"[:200]}


def evaluate(
    case_dir: Path,
    gt_path: Path,
    method: str,
    n_samples: int,
    preset: str | None = None,
    overrides: tuple[str, ...] = (),
    runs: list[dict[str, Any]] | None = None,
) -> dict[str, Any]:
    """Quality row of one method on one case; ``runs``: results of :func:`reconstruct_once`
    already made (the median time is reported, the first run's mesh is measured)."""
    from recon.intersections import self_intersections
    from recon.io import read_mesh
    from recon.metrics import compare_meshes
    from recon.topology import mesh_topology, triangle_quality

    if not runs:
        runs = [reconstruct_once(case_dir, method, preset, overrides)]
    out = runs[0]
    if "error" in out:
        return {"method": method, "error": out["error"]}
    v, f = out["v"], out["f"]
    times = [r["seconds"] for r in runs if "seconds" in r]
    row: dict[str, Any] = {
        "method": method,
        "seconds": float(np.median(times)),
        "runs": len(times),
        "seconds_per_run": [round(t, 3) for t in times],
        "peak_mb": max(r["peak_mb"] for r in runs if "peak_mb" in r),
    }
    if len(f) == 0:
        row["error"] = "no faces"
        return row
    gv, gf = read_mesh(gt_path)
    cmp = compare_meshes((v, f), (gv, gf), n_samples=n_samples, seed=0)
    topo = mesh_topology(v, f)
    qual = triangle_quality(v, f)
    o3d_mesh = _open3d_mesh(v, f)
    row.update(
        {
            "chamfer_l1": cmp["chamfer_l1_relative"],
            "fscore": cmp["fscore"],
            "normal_consistency": cmp.get("normal_consistency"),
            "hausdorff95": cmp["hausdorff95_relative"],
            "boundary_loops": topo["boundary_loops"],
            "components": topo["components"],
            "watertight": topo["watertight"],
            "o3d_watertight": bool(o3d_mesh.is_watertight()),
            "o3d_vertex_manifold": bool(o3d_mesh.is_vertex_manifold()),
            "self_intersections": int(len(self_intersections(v, f))),
            "non_manifold_edges": topo["non_manifold_edges"],
            "non_manifold_vertices": topo["non_manifold_vertices"],
            "genus": topo["genus"],
            "consistently_oriented": topo["consistently_oriented"],
            "min_angle_mean": qual["min_angle_mean_deg"],
            "faces": int(len(f)),
        }
    )
    if gt_path.stem in CREASE_SHAPES:
        row.update(crease_reproduction(v, f, gv, gf) or {})
    return row


#: Two GT faces whose normals turn by more than this share a sharp edge (a crease) [deg].
SHARP_EDGE_DEG = 30.0
#: Ground truths whose sharp edges are real creases (machined shapes, exact polyhedra): the
#: crease-line metric is measured on them (other GT meshes are fine triangulations of smooth
#: shapes whose coarse facets would count as edges).
CREASE_SHAPES = ("lblock",)


def gt_crease_points(gv: np.ndarray, gf: np.ndarray, step: float) -> np.ndarray:
    """Points every ``step`` along the sharp edges of a ground-truth mesh (edges whose two
    faces' normals turn by more than ``SHARP_EDGE_DEG``); empty for a smooth GT."""
    from recon.mesh import face_normals

    fn = face_normals(gv, gf)
    edges = np.sort(np.concatenate([gf[:, [0, 1]], gf[:, [1, 2]], gf[:, [2, 0]]]), axis=1)
    owner = np.tile(np.arange(len(gf)), 3)
    order = np.lexsort((edges[:, 1], edges[:, 0]))
    edges, owner = edges[order], owner[order]
    same = np.all(edges[1:] == edges[:-1], axis=1)
    a, b = owner[:-1][same], owner[1:][same]
    cos = np.einsum("ij,ij->i", fn[a], fn[b])
    sharp = edges[:-1][same][cos < np.cos(np.radians(SHARP_EDGE_DEG))]
    out = []
    for i, j in sharp:
        p, q = gv[i], gv[j]
        m = max(2, int(np.ceil(np.linalg.norm(q - p) / step)) + 1)
        out.append(p + np.linspace(0.0, 1.0, m)[:, None] * (q - p))
    return np.concatenate(out) if out else np.zeros((0, 3))


def crease_reproduction(
    v: np.ndarray, f: np.ndarray, gv: np.ndarray, gf: np.ndarray
) -> dict[str, float] | None:
    """Distance from points on the GT's sharp edges to the mesh, ÷ the GT bbox diagonal: the
    largest, the 95th percentile and the share within 0.25 % (None when the GT is smooth)."""
    from recon.metrics import point_to_mesh_distance

    diag = float(np.linalg.norm(gv.max(axis=0) - gv.min(axis=0)))
    pts = gt_crease_points(gv, gf, 1e-3 * diag)
    if len(pts) == 0:
        return None
    d = point_to_mesh_distance(pts, v, f) / diag
    return {
        "crease_max": float(d.max()),
        "crease_p95": float(np.percentile(d, 95)),
        "crease_within": float(np.mean(d <= 0.0025)),
    }


def _open3d_mesh(v: np.ndarray, f: np.ndarray) -> Any:
    import open3d as o3d

    return o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(np.asarray(v, dtype=np.float64)),
        o3d.utility.Vector3iVector(np.asarray(f, dtype=np.int32)),
    )


def _fmt(v: Any, spec: str) -> str:
    if v is None:
        return "–"
    if isinstance(v, bool):
        return "yes" if v else "no"
    return format(v, spec)


def markdown(results: dict[str, list[dict[str, Any]]]) -> str:
    head = (
        "| case | method | CD-L1 | F@1% | NC | H95 | loops | comps | nm verts | genus | "
        "watertight | O3D watertight | crossings | min angle | time s | peak MB |"
    )
    lines = [head, "|" + "---|" * 16]
    for case, rows in results.items():
        for r in rows:
            if "error" in r and "chamfer_l1" not in r:
                lines.append(f"| {case} | {r['method']} | failed: {r['error']} |" + " |" * 13)
                continue
            lines.append(
                f"| {case} | {r['method']} | {_fmt(r['chamfer_l1'], '.5f')} | "
                f"{_fmt(r['fscore'], '.3f')} | {_fmt(r['normal_consistency'], '.3f')} | "
                f"{_fmt(r['hausdorff95'], '.4f')} | {r['boundary_loops']} | {r['components']} | "
                f"{r['non_manifold_vertices']} | {_fmt(r['genus'], 'd')} | "
                f"{_fmt(r['watertight'], '')} | {_fmt(r['o3d_watertight'], '')} | "
                f"{r.get('self_intersections', '–')} | {_fmt(r['min_angle_mean'], '.1f')} | "
                f"{_fmt(r['seconds'], '.2f')} | {_fmt(r['peak_mb'], '.0f')} |"
            )
    creases = [(case, r) for case, rows in results.items() for r in rows if "crease_max" in r]
    if creases:
        lines += [
            "",
            "GT crease lines → mesh (÷ GT bbox diagonal; target: every point within 0.0025):",
            "",
            "| case | method | CD-L1 | NC | crease max | crease p95 | share within 0.25 % |",
            "|---|---|---|---|---|---|---|",
        ]
        lines += [
            f"| {case} | {r['method']} | {_fmt(r['chamfer_l1'], '.6f')} | "
            f"{_fmt(r['normal_consistency'], '.4f')} | {_fmt(r['crease_max'], '.5f')} | "
            f"{_fmt(r['crease_p95'], '.5f')} | {_fmt(r['crease_within'], '.3f')} |"
            for case, r in creases
        ]
    return "\n".join(lines) + "\n"


def time_ratios(results: dict[str, list[dict[str, Any]]]) -> list[str]:
    """Lines "case: oprecon X s / spsr Y s = ratio" for the cases where both ran."""
    import datetime as dt

    lines = []
    for case, rows in results.items():
        by = {r["method"]: r for r in rows if "seconds" in r and "error" not in r}
        if "oprecon" in by and "spsr" in by:
            a, b = by["oprecon"], by["spsr"]
            lines.append(
                f"time ratio {case}: oprecon {a['seconds']:.2f} s / screened Poisson (pymeshlab, "
                f"depth {SPSR_DEPTH}) {b['seconds']:.2f} s = {a['seconds'] / b['seconds']:.2f} "
                f"(medians of {a['runs']} and {b['runs']} alternating runs)"
            )
    if lines:
        load = "/".join(f"{v:.2f}" for v in os.getloadavg())
        when = dt.datetime.now(dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
        policy = os.environ.get("OMP_WAIT_POLICY", "the runtime's default")
        lines.append(
            f"({when}, load average {load} (1/5/15 min) at the end, OMP_WAIT_POLICY {policy})"
        )
    return lines


def _wait_policy_default() -> str:
    """``--omp-wait-policy``'s default: the environment's PASSIVE/ACTIVE, else ``default``
    (``OMP_WAIT_POLICY=DEFAULT`` is no value libgomp knows: it warns and ignores it)."""
    value = os.environ.get("OMP_WAIT_POLICY", "").strip().upper()
    return value if value in ("PASSIVE", "ACTIVE") else "default"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data")
    ap.add_argument("--cases", nargs="*", help="case ids (default: all in the manifest)")
    ap.add_argument("--methods", nargs="*", default=list(METHODS), choices=METHODS)
    ap.add_argument("--samples", type=int, default=100_000)
    ap.add_argument("--preset", help="run oprecon with configs/PRESET.yaml instead of defaults")
    add_overrides(ap)
    ap.add_argument(
        "--repeats",
        type=int,
        default=1,
        help="runs per method and case, alternating between the methods; median time",
    )
    ap.add_argument(
        "--omp-wait-policy",
        choices=("default", "PASSIVE", "ACTIVE"),
        default=_wait_policy_default(),
        help="OMP_WAIT_POLICY for every method (default: the OpenMP runtime's own, spinning, "
        "fastest on a quiet machine; PASSIVE helps on a loaded one)",
    )
    ap.add_argument(
        "--source-imports",
        action="store_true",
        help="do not compile oprecon's byte code first (with PYTHONDONTWRITEBYTECODE set, each "
        "worker then compiles the modules it imports from source, in the timed region)",
    )
    ap.add_argument("--out", type=Path, help="write the Markdown table here too")
    ap.add_argument("--json-out", type=Path)
    args = ap.parse_args(argv)
    # OpenMP threads (MeshLab's, Open3D's, numba's) spin while they wait by default. On a quiet
    # machine that is fastest (bunny-clean screened Poisson, 2026-11-23, load 0.6: 2.2 s by
    # default, 9.4 s PASSIVE); on a loaded one spinning can cost 10x. The workers inherit it.
    if args.omp_wait_policy != "default":
        os.environ["OMP_WAIT_POLICY"] = args.omp_wait_policy
    if not args.source_imports:
        compile_sources()
    manifest = json.loads((args.data / "manifest.json").read_text())
    cases = [c for c in manifest["cases"] if not args.cases or c["id"] in args.cases]
    if not cases:
        print(f"no cases found in {args.data}", file=sys.stderr)
        return 2
    results: dict[str, list[dict[str, Any]]] = {}
    for case in cases:
        rows = []
        case_dir = args.data / "cases" / case["id"]
        runs: dict[str, list[dict[str, Any]]] = {m: [] for m in args.methods}
        for _ in range(max(1, args.repeats)):  # A B A B: load drift hits every method
            for method in args.methods:
                runs[method].append(
                    reconstruct_once(case_dir, method, args.preset, tuple(args.overrides))
                )
        for method in args.methods:
            row = evaluate(
                case_dir,
                args.data / case["gt"],
                method,
                args.samples,
                args.preset,
                tuple(args.overrides),
                runs=runs[method],
            )
            rows.append(row)
            print(
                f"{case['id']:<24} {method:<14} "
                + json.dumps(
                    {
                        k: (round(v, 5) if isinstance(v, float) else v)
                        for k, v in row.items()
                        if k != "method"
                    }
                ),
                file=sys.stderr,
                flush=True,
            )
        results[case["id"]] = rows
    table = markdown(results)
    print(table)
    for line in time_ratios(results):
        print(line)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(table)
    if args.json_out:
        args.json_out.parent.mkdir(parents=True, exist_ok=True)
        args.json_out.write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
