"""A synthetic LiDAR scene with exact ground truth: terrain, box buildings and tree crowns.

The scene spreads over a square whose side follows the point count at a fixed density
(``density`` points per m^2 of surface), so a larger scene is a larger area, as a larger
survey is. It holds:

* terrain: a height field of gentle waves, open at the square's edge (the true boundary),
  with the buildings' footprints cut out;
* box buildings: a flat roof and four walls standing on the terrain (no floor);
* trees: spherical crowns floating above the ground (closed surfaces).

Points are sampled area-uniformly over all surfaces (with optional Gaussian noise along the
surface normal); :func:`ground_truth` samples the same surfaces without noise, as densely as
asked, for Chamfer and F-score. Coordinates can be offset (georeferenced, e.g. x, y ~ 5e6).

Used by ``benchmarks/bench_tiles.py``::

    from scenes import Scene
    scene = Scene.for_points(1_000_000, seed=0)
    pts, cls = scene.sample(1_000_000, seed=1)
    truth = scene.ground_truth(3_000_000)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Surface points per square metre.
DENSITY = 4.0
#: Terrain relief [m] and its wavelengths [m].
RELIEF = 2.0
WAVES = (37.0, 53.0)
#: LAS classes.
GROUND, BUILDING, VEGETATION = 2, 6, 5


def terrain(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return RELIEF * np.sin(x / WAVES[0]) * np.cos(y / WAVES[1]) + 0.01 * x


@dataclass
class Scene:
    side: float  # [m]
    buildings: np.ndarray  # (B, 5): x0, y0, width, depth, height
    trees: np.ndarray  # (T, 4): cx, cy, cz, radius
    offset: np.ndarray  # (3,)

    @classmethod
    def for_points(
        cls,
        n: int,
        seed: int = 0,
        density: float = DENSITY,
        offset: tuple[float, float, float] = (0.0, 0.0, 0.0),
    ) -> Scene:
        """A scene whose surface holds about ``n`` points at ``density``: one building per
        2500 m^2 of ground and two trees per building."""
        rng = np.random.default_rng(seed)
        side = float(np.sqrt(n / density / 1.25))  # walls, roofs and crowns add ~25 %
        n_b = max(1, int(side * side / 2500))
        buildings = []
        tries = 0
        while len(buildings) < n_b and tries < 100 * n_b:
            tries += 1
            w, d = rng.uniform(10, 24), rng.uniform(8, 18)
            x0, y0 = rng.uniform(5, side - w - 5), rng.uniform(5, side - d - 5)
            box = np.array([x0, y0, w, d, rng.uniform(6, 15)])
            if all(
                x0 > b[0] + b[2] + 6
                or b[0] > x0 + w + 6
                or y0 > b[1] + b[3] + 6
                or b[1] > y0 + d + 6
                for b in buildings
            ):
                buildings.append(box)
        trees = []
        tries = 0
        while len(trees) < 2 * n_b and tries < 100 * n_b:
            tries += 1
            r = rng.uniform(2.0, 4.0)
            cx, cy = rng.uniform(r + 3, side - r - 3, 2)
            if any(
                b[0] - r - 3 < cx < b[0] + b[2] + r + 3 and b[1] - r - 3 < cy < b[1] + b[3] + r + 3
                for b in buildings
            ) or any(np.hypot(cx - t[0], cy - t[1]) < r + t[3] + 2 for t in trees):
                continue
            cz = float(terrain(np.array([cx]), np.array([cy]))[0]) + r + rng.uniform(2.0, 4.0)
            trees.append(np.array([cx, cy, cz, r]))
        return cls(
            side,
            np.array(buildings).reshape(-1, 5),
            np.array(trees).reshape(-1, 4),
            np.asarray(offset, dtype=float),
        )

    # -- sampling ----------------------------------------------------------------------------

    def _areas(self) -> dict[str, float]:
        b, t = self.buildings, self.trees
        footprint = float((b[:, 2] * b[:, 3]).sum())
        return {
            "ground": self.side**2 - footprint,  # the waves add < 1 % of area
            "roofs": footprint,
            "walls": float((2 * (b[:, 2] + b[:, 3]) * b[:, 4]).sum()),
            "crowns": float((4 * np.pi * t[:, 3] ** 2).sum()),
        }

    def _inside_buildings(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        out = np.zeros(len(x), dtype=bool)
        for x0, y0, w, d, _ in self.buildings:
            out |= (x > x0) & (x < x0 + w) & (y > y0) & (y < y0 + d)
        return out

    def sample(self, n: int, seed: int = 1, noise: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """``n`` points (absolute, offset added) and their LAS classes, area-uniform.

        ``noise`` [m]: standard deviation of a displacement along the surface normal.
        """
        rng = np.random.default_rng(seed)
        areas = self._areas()
        total = sum(areas.values())
        counts = {k: int(round(n * a / total)) for k, a in areas.items()}
        counts["ground"] += n - sum(counts.values())
        parts, classes, normals = [], [], []
        # ground: rejection outside the footprints
        m = counts["ground"]
        g = np.zeros((0, 2))
        while len(g) < m:
            c = rng.uniform(0, self.side, (int(1.3 * (m - len(g))) + 16, 2))
            g = np.vstack([g, c[~self._inside_buildings(c[:, 0], c[:, 1])]])
        g = g[:m]
        z = terrain(g[:, 0], g[:, 1])
        parts.append(np.column_stack([g, z]))
        classes.append(np.full(m, GROUND))
        eps = 1e-4
        gx = (terrain(g[:, 0] + eps, g[:, 1]) - z) / eps
        gy = (terrain(g[:, 0], g[:, 1] + eps) - z) / eps
        nrm = np.column_stack([-gx, -gy, np.ones(m)])
        normals.append(nrm / np.linalg.norm(nrm, axis=1, keepdims=True))
        b = self.buildings
        if len(b):
            # roofs
            w = b[:, 2] * b[:, 3]
            k = rng.choice(len(b), counts["roofs"], p=w / w.sum())
            u = rng.random((len(k), 2))
            base = terrain(b[:, 0] + b[:, 2] / 2, b[:, 1] + b[:, 3] / 2)
            roof = np.column_stack(
                [b[k, 0] + u[:, 0] * b[k, 2], b[k, 1] + u[:, 1] * b[k, 3], base[k] + b[k, 4]]
            )
            parts.append(roof)
            classes.append(np.full(len(k), BUILDING))
            normals.append(np.tile([0.0, 0.0, 1.0], (len(k), 1)))
            # walls (down to the terrain: the wall meets the ground at its footprint)
            per = 2 * (b[:, 2] + b[:, 3]) * b[:, 4]
            k = rng.choice(len(b), counts["walls"], p=per / per.sum())
            s = rng.random(len(k)) * 2 * (b[k, 2] + b[k, 3])
            h = rng.random(len(k))
            wx, wy, nx, ny = self._walk(b[k], s)
            ground_z = terrain(wx, wy)
            top = base[k] + b[k, 4]
            wz = ground_z + h * (top - ground_z)
            parts.append(np.column_stack([wx, wy, wz]))
            classes.append(np.full(len(k), BUILDING))
            normals.append(np.column_stack([nx, ny, np.zeros(len(k))]))
        t = self.trees
        if len(t):
            a = t[:, 3] ** 2
            k = rng.choice(len(t), counts["crowns"], p=a / a.sum())
            v = rng.normal(size=(len(k), 3))
            v /= np.linalg.norm(v, axis=1, keepdims=True)
            parts.append(t[k, :3] + v * t[k, 3:4])
            classes.append(np.full(len(k), VEGETATION))
            normals.append(v)
        pts = np.concatenate(parts)
        if noise > 0:
            pts = pts + rng.normal(0, noise, (len(pts), 1)) * np.concatenate(normals)
        return pts + self.offset, np.concatenate(classes).astype(np.uint8)

    @staticmethod
    def _walk(b: np.ndarray, s: np.ndarray):
        """Points at arc length ``s`` around each building's footprint, and the outward normal."""
        x0, y0, w, d = b[:, 0], b[:, 1], b[:, 2], b[:, 3]
        x = np.empty(len(s))
        y = np.empty(len(s))
        nx = np.zeros(len(s))
        ny = np.zeros(len(s))
        e1 = s < w
        e2 = (s >= w) & (s < w + d)
        e3 = (s >= w + d) & (s < 2 * w + d)
        e4 = s >= 2 * w + d
        x[e1], y[e1], ny[e1] = x0[e1] + s[e1], y0[e1], -1
        x[e2], y[e2], nx[e2] = x0[e2] + w[e2], y0[e2] + s[e2] - w[e2], 1
        x[e3], y[e3], ny[e3] = x0[e3] + w[e3] - (s[e3] - w[e3] - d[e3]), y0[e3] + d[e3], 1
        x[e4], y[e4], nx[e4] = x0[e4], y0[e4] + d[e4] - (s[e4] - 2 * w[e4] - d[e4]), -1
        return x, y, nx, ny

    def ground_truth(self, n: int, seed: int = 99) -> np.ndarray:
        """``n`` noise-free points on the true surfaces (absolute), for Chamfer and F-score."""
        return self.sample(n, seed=seed, noise=0.0)[0]


def write_laz(path, pts: np.ndarray, cls: np.ndarray, scale: float = 0.001) -> None:
    """Write points as LAZ (LAS 1.2, point format 1) through laspy, in chunks."""
    import laspy

    header = laspy.LasHeader(point_format=1, version="1.2")
    header.scales = np.array([scale] * 3)
    header.offsets = np.floor(pts.min(axis=0))
    with laspy.open(str(path), mode="w", header=header) as writer:
        step = 1_000_000
        for i in range(0, len(pts), step):
            rec = laspy.ScaleAwarePointRecord.zeros(min(step, len(pts) - i), header=header)
            rec.x, rec.y, rec.z = pts[i : i + step, 0], pts[i : i + step, 1], pts[i : i + step, 2]
            rec.classification = cls[i : i + step]
            writer.write_points(rec)
