"""Thin parts and uneven density on shapes that are not in the dev set (generalisation check).

The dev set's thin parts are the bunny's ears and one plate; the defaults must hold on other
shapes too. This generates, from exact implicit surfaces (unions of ellipsoids, capsules and
tori, so the ground truth and the genus are known), scans with:

- ``blade``: a flat blade with round edges, 0.8 % of its diagonal thick (the plate: 2 %);
- ``knife``: an ellipsoidal blade whose edge thins to nothing (1.2 % thick at the middle);
- ``eared``: a round body with two thin ears (2 % of the size) and a thin tail (a capsule);
- ``ring``: a thin ring (torus, tube radius 5 % of the ring's), genus 1;
- ``legs``: a body on four thin legs (capsules);
- ``gradient``: an ellipsoid whose sampling density falls 20x from one end to the other.

Each is fitted with ``oprecon`` defaults and judged against the implicit surface: loops,
components, genus (and the expected genus), watertight by the standard definition, crossing
face pairs, Chamfer-L1 and F@1 % (÷ diagonal) from dense samples of the true surface. ``handles``
counts handles also on an open mesh (``(2 c - b - chi) / 2``), where the genus is undefined.
``inward %`` is the share of the mesh's area whose faces point into the shape (against the
implicit function's gradient at the face's centroid): a part turned inside out keeps a mesh
watertight with the right genus, so a fit that comes out right has it near 0 (a few faces at a
rim that thins to nothing, where the centroid lies off the surface, can point either way).

Example::

    python benchmarks/bench_thin_parts.py                 # all shapes, 40k points each
    python benchmarks/bench_thin_parts.py --shapes blade ring --points 20000 --noise 0.001
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

if str(Path(__file__).resolve().parent) not in sys.path:  # the benchmarks' shared options
    sys.path.insert(0, str(Path(__file__).resolve().parent))
from shared_options import add_overrides, override_values  # noqa: E402

Sdf = Callable[[np.ndarray], np.ndarray]


def ellipsoid(centre, axes) -> Sdf:
    c, a = np.asarray(centre, float), np.asarray(axes, float)

    def f(p: np.ndarray) -> np.ndarray:
        # first-order distance: (|q/a| - 1) * |q/a| / |grad| (exact on spheres, good enough
        # near the surface for rejection sampling and for the ground truth's sign)
        q = (p - c) / a
        k0 = np.linalg.norm(q, axis=1)
        k1 = np.linalg.norm(q / a, axis=1)
        return k0 * (k0 - 1.0) / np.maximum(k1, 1e-12)

    return f


def capsule(p0, p1, radius: float) -> Sdf:
    a, b = np.asarray(p0, float), np.asarray(p1, float)

    def f(p: np.ndarray) -> np.ndarray:
        ab = b - a
        t = np.clip((p - a) @ ab / (ab @ ab), 0.0, 1.0)
        return np.linalg.norm(p - (a + t[:, None] * ab), axis=1) - radius

    return f


def torus(major: float, minor: float) -> Sdf:
    def f(p: np.ndarray) -> np.ndarray:
        q = np.stack([np.linalg.norm(p[:, :2], axis=1) - major, p[:, 2]], axis=1)
        return np.linalg.norm(q, axis=1) - minor

    return f


def slab(half_extents, rounding: float) -> Sdf:
    """A box with rounded edges (exact distance), ``2 * rounding`` thick where flat."""
    b = np.asarray(half_extents, float)

    def f(p: np.ndarray) -> np.ndarray:
        q = np.abs(p) - b
        return (
            np.linalg.norm(np.maximum(q, 0.0), axis=1) + np.minimum(q.max(axis=1), 0.0) - rounding
        )

    return f


def union(*parts: Sdf) -> Sdf:
    return lambda p: np.min([g(p) for g in parts], axis=0)


#: name -> (implicit surface, bounding half-size, genus)
SHAPES: dict[str, tuple[Sdf, float, int]] = {
    "blade": (slab([0.9, 0.3, 0.0], 0.008), 1.0, 0),
    "knife": (ellipsoid([0, 0, 0], [1.0, 0.3, 0.012]), 1.05, 0),
    "eared": (
        union(
            ellipsoid([0, 0, 0], [0.5, 0.4, 0.4]),
            ellipsoid([0.15, 0.55, 0.1], [0.08, 0.35, 0.02]),
            ellipsoid([-0.15, 0.55, 0.1], [0.08, 0.35, 0.02]),
            capsule([0.4, 0, 0], [0.85, -0.1, 0], 0.025),
        ),
        1.0,
        0,
    ),
    "ring": (torus(0.6, 0.03), 0.7, 1),
    "legs": (
        union(
            ellipsoid([0, 0, 0.3], [0.6, 0.3, 0.2]),
            *(
                capsule([sx * 0.4, sy * 0.15, 0.25], [sx * 0.45, sy * 0.2, -0.4], 0.03)
                for sx in (-1, 1)
                for sy in (-1, 1)
            ),
        ),
        0.8,
        0,
    ),
    "gradient": (ellipsoid([0, 0, 0], [1.0, 0.5, 0.4]), 1.05, 0),
}


def surface_samples(sdf: Sdf, half: float, n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` points on the zero set, about area-uniform: random points of a thin shell around
    it (found by rejection), projected onto the surface by Newton steps on the implicit
    function. The shell's thickness follows the implicit function's gradient, which is
    nearly 1 on these shapes, so the density is uniform to within a few per cent."""
    out: list[np.ndarray] = []
    got = 0
    eps = 1e-5
    while got < n:
        p = rng.uniform(-half, half, (400_000, 3))
        d = sdf(p)
        shell = 0.004 * half
        p = p[np.abs(d) < shell]
        for _ in range(6):
            d = sdf(p)
            g = np.stack(
                [(sdf(p + eps * e) - sdf(p - eps * e)) / (2 * eps) for e in np.eye(3)], axis=1
            )
            g2 = np.maximum(np.einsum("ij,ij->i", g, g), 1e-12)
            p = p - (d / g2)[:, None] * g
        p = p[np.abs(sdf(p)) < 1e-6 * half]
        out.append(p)
        got += len(p)
    pts = np.vstack(out)
    return pts[rng.permutation(len(pts))[:n]]


def make_scan(name: str, n: int, noise: float, seed: int) -> tuple[np.ndarray, np.ndarray, int]:
    """(input points, dense ground-truth samples, genus) of one shape."""
    sdf, half, genus = SHAPES[name]
    rng = np.random.default_rng(seed)
    truth = surface_samples(sdf, half, 200_000, rng)
    if name == "gradient":
        # keep a point with probability falling 20x along x: density 20:1 end to end
        x = (truth[:, 0] - truth[:, 0].min()) / np.ptp(truth[:, 0])
        keep = rng.uniform(size=len(truth)) < 0.05**x
        pool = truth[keep]
    else:
        pool = truth
    pts = pool[rng.choice(len(pool), min(n, len(pool)), replace=False)]
    diag = float(np.linalg.norm(np.ptp(truth, axis=0)))
    pts = pts + rng.normal(scale=noise * diag, size=pts.shape)
    return pts, truth, genus


def inward_share(vertices: np.ndarray, faces: np.ndarray, sdf: Sdf) -> float:
    """Share of the area of ``faces`` whose normal points against ``sdf``'s gradient (central
    differences at each face's centroid): 0 for a mesh wound outward, 1 inside out."""
    tri = vertices[faces]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])  # twice the area
    centre = tri.mean(axis=1)
    step = 1e-5 * float(np.linalg.norm(np.ptp(vertices, axis=0)))
    grad = np.stack([sdf(centre + step * e) - sdf(centre - step * e) for e in np.eye(3)], axis=1)
    area = np.linalg.norm(normal, axis=1)
    inward = np.einsum("ij,ij->i", grad, normal) < 0
    return float(area[inward].sum() / max(area.sum(), 1e-300))


def judge(
    vertices: np.ndarray, faces: np.ndarray, truth: np.ndarray, sdf: Sdf | None = None
) -> dict:
    """Topology and accuracy of a mesh against dense samples ``truth`` of the true surface
    (and, given its implicit function ``sdf``, the share of its area wound inward)."""
    from recon.intersections import self_intersections
    from recon.mesh import handle_count
    from recon.topology import mesh_topology

    topo = mesh_topology(vertices, faces)
    diag = float(np.linalg.norm(np.ptp(truth, axis=0)))
    rng = np.random.default_rng(0)
    tri = vertices[faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    pick = rng.choice(len(faces), 200_000, p=area / area.sum())
    uv = rng.uniform(size=(200_000, 2))
    flip = uv.sum(axis=1) > 1
    uv[flip] = 1 - uv[flip]
    t = tri[pick]
    mesh_pts = t[:, 0] + uv[:, :1] * (t[:, 1] - t[:, 0]) + uv[:, 1:] * (t[:, 2] - t[:, 0])
    d_mt = cKDTree(truth).query(mesh_pts)[0] / diag
    d_tm = cKDTree(mesh_pts).query(truth)[0] / diag
    precision, recall = np.mean(d_mt < 0.01), np.mean(d_tm < 0.01)
    return {
        "loops": topo["boundary_loops"],
        "components": topo["components"],
        "genus": topo["genus"],
        # handles also of an open mesh, where the report's genus is undefined
        "handles": handle_count(faces, len(vertices))[2],
        "watertight": topo["watertight"],
        "crossings": int(len(self_intersections(vertices, faces))),
        "chamfer_l1": 0.5 * (d_mt.mean() + d_tm.mean()),
        "fscore": 2 * precision * recall / max(precision + recall, 1e-12),
        "inward": None if sdf is None else inward_share(vertices, faces, sdf),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--shapes", nargs="*", default=list(SHAPES), choices=list(SHAPES))
    ap.add_argument("--points", type=int, default=40_000)
    ap.add_argument("--noise", type=float, default=0.0005, help="noise sigma ÷ diagonal")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--save", type=Path, help="write SHAPE.input.ply and SHAPE.ply here")
    add_overrides(ap)
    args = ap.parse_args()

    import recon
    from recon.config import ReconConfig, apply_overrides

    cfg = apply_overrides(ReconConfig(), override_values(args.overrides))

    print(
        "| shape | points | loops | comps | genus (true) | handles | watertight | crossings | "
        "inward % | CD-L1 | F@1% | particles | time s |"
    )
    print("|" + "---|" * 13)
    for name in args.shapes:
        pts, truth, genus = make_scan(name, args.points, args.noise, args.seed)
        t0 = time.perf_counter()
        res = recon.fit(pts, cfg)
        seconds = time.perf_counter() - t0
        if args.save:
            from recon.io import write_mesh, write_points

            args.save.mkdir(parents=True, exist_ok=True)
            write_points(args.save / f"{name}.input.ply", pts)
            write_mesh(args.save / f"{name}.ply", res.mesh.vertices, res.mesh.faces)
        r = judge(res.mesh.vertices, res.mesh.faces, truth, SHAPES[name][0])
        print(
            f"| {name} | {len(pts):,} | {r['loops']} | {r['components']} | {r['genus']} "
            f"({genus}) | {r['handles']} | {'yes' if r['watertight'] else 'no'} | "
            f"{r['crossings']} | {100 * r['inward']:.1f} | {r['chamfer_l1']:.5f} | "
            f"{r['fscore']:.3f} | "
            f"{res.report.particles:,} | {seconds:.1f} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
