"""Held-out machined shapes: do sharp creases generalise beyond the dev set's L-block?

Builds four exact machined parts as triangle meshes (no dev data is read), samples points on
them area-uniformly (clean, and with isotropic Gaussian noise of 0.25 % of the bounding-box
diagonal, the dev set's ``noise025``), fits each at defaults (or with ``--set`` overrides) and
prints one Markdown row per case:

    Chamfer-L1 and normal consistency (``recon.metrics.compare_meshes``, ÷ GT diagonal),
    watertight, genus, the share of points on the GT's sharp edges within 0.25 % of the
    diagonal of the mesh (as in ``bench_quality.py``), the detected crease length ÷ the GT's
    sharp-edge length and the corners detected / in the GT.

Shapes (edges turn by the angle between the face normals):

- ``block_hole``: a 1.0 x 0.8 x 0.4 block with a vertical through hole of radius 0.2 (90 deg
  convex edges; the hole's rims are circles, its wall a 96-gon);
- ``hexprism``: a regular hexagonal prism, circumradius 0.5, height 0.6 (60 deg side edges =
  120 deg interior, 90 deg rims), 12 corners;
- ``boss``: a 1.0 x 0.8 x 0.3 block with a cylinder of radius 0.2, height 0.25 on top (a convex
  90 deg rim, a concave 90 deg rim at its foot);
- ``wedge``: a prism over a 30-60-90 triangle (legs 1.0 and 0.577), height 0.5: turns of 90,
  120 and 150 deg, 6 corners.

Example::

    python benchmarks/bench_machined.py                         # 8 fits at defaults
    python benchmarks/bench_machined.py --shapes wedge --set creases.enabled=false
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parent
sys.path.insert(0, str(ROOT))
from shared_options import add_overrides, override_values  # noqa: E402

#: Sides of the polygons standing in for circles (a 3.75 deg turn between wall facets).
CIRCLE_SIDES = 96
N_POINTS = 20000
NOISE = 0.0025


def _circle(cx: float, cy: float, r: float) -> np.ndarray:
    a = np.linspace(0.0, 2.0 * np.pi, CIRCLE_SIDES, endpoint=False)
    return np.c_[cx + r * np.cos(a), cy + r * np.sin(a)]


def _subdivide(poly: np.ndarray, step: float) -> np.ndarray:
    out = []
    for a, b in zip(poly, np.roll(poly, -1, axis=0), strict=True):
        m = max(1, int(np.ceil(np.linalg.norm(b - a) / step)))
        out.append(a + np.linspace(0.0, 1.0, m, endpoint=False)[:, None] * (b - a))
    return np.concatenate(out)


def _ring(poly: np.ndarray) -> np.ndarray:
    """A straight-sided polygon with its sides cut at about the circles' side length (caps and
    walls share these vertices: no T-junction, so the GT's sharp edges are shared edges)."""
    return _subdivide(poly, 2.0 * np.pi * 0.2 / CIRCLE_SIDES)


def _cap(outer: np.ndarray, holes: list[np.ndarray], z: float, up: bool) -> list[np.ndarray]:
    """Triangles of a planar polygon (convex ``outer`` minus convex ``holes``) at height z."""
    from matplotlib.path import Path as MPath
    from scipy.spatial import Delaunay

    ring = _ring(outer)
    pts = np.concatenate([ring, *holes]) if holes else ring
    tri = Delaunay(pts).simplices
    cen = pts[tri].mean(axis=1)
    keep = MPath(outer).contains_points(cen)
    for h in holes:
        keep &= ~MPath(h).contains_points(cen)
    out = []
    for t in tri[keep]:
        p = np.c_[pts[t], np.full(3, z)]
        n = np.cross(p[1] - p[0], p[2] - p[0])[2]
        if (n > 0) != up:
            p = p[::-1]
        out.append(p)
    return out


def _wall(poly: np.ndarray, z0: float, z1: float, outward: bool) -> list[np.ndarray]:
    """Quads (two triangles each) of the vertical wall over a closed counter-clockwise
    polygon; ``outward``: normals point away from the polygon's inside."""
    out = []
    for a, b in zip(poly, np.roll(poly, -1, axis=0), strict=True):
        p = [np.r_[a, z0], np.r_[b, z0], np.r_[b, z1], np.r_[a, z1]]
        t1, t2 = np.array([p[0], p[1], p[2]]), np.array([p[0], p[2], p[3]])
        if not outward:
            t1, t2 = t1[::-1], t2[::-1]
        out += [t1, t2]
    return out


def _weld(tris: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    allv = np.concatenate(tris)
    key = np.round(allv, 9)
    v, inv = np.unique(key, axis=0, return_inverse=True)
    return v, inv.reshape(-1, 3).astype(np.int64)


def _rect(x0: float, y0: float, x1: float, y1: float) -> np.ndarray:
    return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], float)


def block_hole() -> tuple[np.ndarray, np.ndarray]:
    outer, hole = _rect(0, 0, 1.0, 0.8), _circle(0.5, 0.4, 0.2)
    tris = _cap(outer, [hole], 0.0, False) + _cap(outer, [hole], 0.4, True)
    tris += _wall(_ring(outer), 0.0, 0.4, True) + _wall(hole, 0.0, 0.4, False)
    return _weld(tris)


def hexprism() -> tuple[np.ndarray, np.ndarray]:
    a = np.radians(np.arange(6) * 60.0)
    hexagon = 0.5 * np.c_[np.cos(a), np.sin(a)]
    tris = _cap(hexagon, [], 0.0, False) + _cap(hexagon, [], 0.6, True)
    return _weld(tris + _wall(_ring(hexagon), 0.0, 0.6, True))


def boss() -> tuple[np.ndarray, np.ndarray]:
    outer, disk = _rect(0, 0, 1.0, 0.8), _circle(0.5, 0.4, 0.2)
    tris = _cap(outer, [], 0.0, False) + _cap(outer, [disk], 0.3, True)
    tris += _wall(_ring(outer), 0.0, 0.3, True) + _wall(disk, 0.3, 0.55, True)
    tris += _cap(disk, [], 0.55, True)
    return _weld(tris)


def wedge() -> tuple[np.ndarray, np.ndarray]:
    tri = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, np.tan(np.radians(30.0))]])
    tris = _cap(tri, [], 0.0, False) + _cap(tri, [], 0.5, True)
    return _weld(tris + _wall(_ring(tri), 0.0, 0.5, True))


SHAPES = {"block_hole": block_hole, "hexprism": hexprism, "boss": boss, "wedge": wedge}
#: Corners of each part (vertices where three planar faces meet; circles have none).
GT_CORNERS = {"block_hole": 8, "hexprism": 12, "boss": 8, "wedge": 6}


def sharp_length(gv: np.ndarray, gf: np.ndarray) -> float:
    """Total length of the GT's sharp edges (faces turning by more than 30 deg)."""
    from bench_quality import gt_crease_points

    pts = gt_crease_points(gv, gf, 1e9)  # every sharp edge as its two end points
    return float(np.sum(np.linalg.norm(pts[1::2] - pts[0::2], axis=1)))


def run_case(name: str, noisy: bool, overrides: dict[str, Any]) -> dict[str, Any]:
    from bench_quality import crease_reproduction

    from recon.config import ReconConfig, apply_overrides
    from recon.fitting import reconstruct
    from recon.io import cloud_from_arrays
    from recon.metrics import compare_meshes, sample_surface
    from recon.topology import mesh_topology

    gv, gf = SHAPES[name]()
    diag = float(np.linalg.norm(gv.max(axis=0) - gv.min(axis=0)))
    pts, _ = sample_surface(gv, gf, N_POINTS, seed=1)
    if noisy:
        pts = pts + np.random.default_rng(2).normal(scale=NOISE * diag, size=pts.shape)
    cfg = apply_overrides(ReconConfig(), overrides)
    t = time.perf_counter()
    res = reconstruct(cloud_from_arrays(pts), cfg)
    sec = time.perf_counter() - t
    v, f = np.asarray(res.mesh.vertices), np.asarray(res.mesh.faces)
    cmp = compare_meshes((v, f), (gv, gf), n_samples=100_000, seed=0)
    topo = mesh_topology(v, f)
    cr = crease_reproduction(v, f, gv, gf) or {}
    found = res.report.creases
    return {
        "case": f"{name}-{'noise025' if noisy else 'clean'}",
        "cd": cmp["chamfer_l1_relative"],
        "nc": cmp.get("normal_consistency"),
        "watertight": topo["watertight"],
        "genus": topo["genus"],
        "within": cr.get("crease_within"),
        "length": (found.length / sharp_length(gv, gf)) if found is not None else None,
        "corners": (found.corners if found is not None else None),
        "gt_corners": GT_CORNERS[name],
        "seconds": sec,
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--shapes", nargs="*", default=list(SHAPES), choices=list(SHAPES))
    ap.add_argument("--noise", choices=("both", "clean", "noisy"), default="both")
    add_overrides(ap)
    args = ap.parse_args(argv)
    overrides = override_values(args.overrides)
    variants = {"both": (False, True), "clean": (False,), "noisy": (True,)}[args.noise]
    print(
        "| case | CD-L1 | NC | watertight / genus | crease share within 0.25 % | "
        "detected length ÷ GT | corners detected / GT | time s |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for name in args.shapes:
        for noisy in variants:
            r = run_case(name, noisy, overrides)

            def fmt(x: Any, spec: str) -> str:
                return "–" if x is None else format(x, spec)

            print(
                f"| {r['case']} | {r['cd']:.6f} | {fmt(r['nc'], '.4f')} | "
                f"{'yes' if r['watertight'] else 'no'} / {fmt(r['genus'], 'd')} | "
                f"{fmt(r['within'], '.3f')} | {fmt(r['length'], '.2f')} | "
                f"{fmt(r['corners'], 'd')} / {r['gt_corners']} | {r['seconds']:.1f} |",
                flush=True,
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
