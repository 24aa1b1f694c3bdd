"""Growing and stretching rules: where new particles go (S&T92 §6, T-thesis §4.7).

Both rules are pure functions: particle positions and normals in, candidate positions out. The
fit stage then accepts candidates that are far enough from existing particles and supported by
the data (:func:`accept_candidates`).

* **Growing rule.** A particle with few neighbours inside ``grow_radius`` looks at the directions
  to its neighbours in its tangent plane; every angular gap wider than ``gap_angle`` receives new
  particles, one per ``gap_step`` of gap, one rest spacing out, in the tangent plane (S&T92 §6:
  "add a particle in the largest gap"; an isolated particle grows a hexagon of six).
* **Stretching rule.** Two particles between ``stretch_min`` and ``stretch_max`` apart with no
  particle near their midpoint get a particle at the midpoint, on the mean tangent plane (S&T92
  §6 and §7: between sample points, bounded by the search range).

All lengths are in units of the rest spacing r0.

References
----------
[ST92] Szeliski & Tonnesen 1992, §6 "Adding and deleting particles", §7.
[T00]  Tonnesen, thesis, §4.7.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba as nb
import numpy as np
from scipy.spatial import cKDTree

from .config import GrowthConfig
from .seeds import poisson_disk_thin
from .surface import DataSurface, max_angular_gap, tangent_frame

MAX_PER_PARTICLE = 6


def neighbor_csr(tree: cKDTree, n: int, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Full neighbour lists within ``radius`` as CSR ``(offsets, indices)``, sorted rows."""
    pairs = tree.query_pairs(radius, output_type="ndarray")
    if len(pairs) == 0:
        return np.zeros(n + 1, dtype=np.int64), np.zeros(0, dtype=np.int64)
    src = np.concatenate([pairs[:, 0], pairs[:, 1]])
    dst = np.concatenate([pairs[:, 1], pairs[:, 0]])
    order = np.lexsort((dst, src))
    src, dst = src[order], dst[order]
    counts = np.bincount(src, minlength=n)
    offsets = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(counts, out=offsets[1:])
    return offsets, dst.astype(np.int64)


@nb.njit(cache=True)
def _grow_kernel(
    pos, nrm, offsets, indices, min_nb, max_nb, gap_angle, gap_step, out, count
):  # pragma: no cover - numba
    """Growing rule (S&T92 §6): candidates in angular gaps of sparse particles."""
    n = pos.shape[0]
    two_pi = 2.0 * np.pi
    for i in range(n):
        m = offsets[i + 1] - offsets[i]
        count[i] = 0
        if m < min_nb or m > max_nb:
            continue
        u, v = tangent_frame(nrm[i])
        c = 0
        if m == 0:
            for a in range(MAX_PER_PARTICLE):
                th = a * two_pi / MAX_PER_PARTICLE
                out[i, c] = pos[i] + np.cos(th) * u + np.sin(th) * v
                c += 1
            count[i] = c
            continue
        ang = np.empty(m)
        for a in range(m):
            d = pos[indices[offsets[i] + a]] - pos[i]
            ang[a] = np.arctan2(
                d[0] * v[0] + d[1] * v[1] + d[2] * v[2], d[0] * u[0] + d[1] * u[1] + d[2] * u[2]
            )
        ang.sort()
        for a in range(m):
            start = ang[a]
            end = ang[a + 1] if a + 1 < m else ang[0] + two_pi
            gap = end - start
            if gap <= gap_angle:
                continue
            k = max(1, int(np.floor(gap / gap_step + 0.5)) - 1)
            for b in range(1, k + 1):
                if c >= MAX_PER_PARTICLE:
                    break
                th = start + gap * b / (k + 1)
                out[i, c] = pos[i] + np.cos(th) * u + np.sin(th) * v
                c += 1
        count[i] = c


def grow_candidates(
    position: np.ndarray,
    normal: np.ndarray,
    offsets: np.ndarray,
    indices: np.ndarray,
    cfg: GrowthConfig,
) -> np.ndarray:
    """Candidate positions from the growing rule.

    Parameters
    ----------
    position, normal : (n, 3) float64 [r0]
    offsets, indices : CSR neighbour lists within ``cfg.grow_radius``.

    Returns
    -------
    candidates : (m, 3) float64 [r0]
    """
    n = len(position)
    out = np.zeros((n, MAX_PER_PARTICLE, 3))
    count = np.zeros(n, dtype=np.int64)
    _grow_kernel(
        position,
        normal,
        offsets,
        indices,
        cfg.min_neighbors,
        cfg.max_neighbors,
        np.deg2rad(cfg.gap_angle_deg),
        np.deg2rad(cfg.gap_step_deg),
        out,
        count,
    )
    mask = np.arange(MAX_PER_PARTICLE)[None, :] < count[:, None]
    return out[mask]


def stretch_candidates(
    position: np.ndarray, normal: np.ndarray, tree: cKDTree, frontier: np.ndarray, cfg: GrowthConfig
) -> np.ndarray:
    """Candidate midpoints from the stretching rule, for pairs that involve a frontier particle.

    A pair (i, j) with ``stretch_min <= |x_i - x_j| <= stretch_max`` whose midpoint has no
    particle within ``stretch_min / 2`` yields the midpoint (S&T92 §6).
    """
    idx = np.flatnonzero(frontier)
    if len(idx) == 0:
        return np.zeros((0, 3))
    sub_tree = cKDTree(position[idx])
    pairs = sub_tree.query_pairs(cfg.stretch_max, output_type="ndarray")
    if len(pairs) == 0:
        return np.zeros((0, 3))
    a, b = idx[pairs[:, 0]], idx[pairs[:, 1]]
    d = np.linalg.norm(position[a] - position[b], axis=1)
    sel = d >= cfg.stretch_min
    a, b = a[sel], b[sel]
    if len(a) == 0:
        return np.zeros((0, 3))
    # the two normals must agree (not two sides of a thin part)
    agree = np.einsum("ij,ij->i", normal[a], normal[b]) > 0.5
    a, b = a[agree], b[agree]
    mid = 0.5 * (position[a] + position[b])
    if len(mid) == 0:
        return mid
    dist, _ = tree.query(mid, k=1, workers=-1)
    return mid[dist >= 0.5 * cfg.stretch_min]


@dataclass
class Acceptance:
    """What became of one round's candidates (counts are for the report and the log)."""

    positions: np.ndarray  # (m, 3) accepted positions, projected on the data planes [r0]
    normals: np.ndarray  # (m, 3) their normals (data plane normals)
    n_candidates: int
    n_too_close: int
    n_unsupported: int
    n_off_plane: int


def accept_candidates(
    candidates: np.ndarray,
    particle_tree: cKDTree,
    surface: DataSurface,
    seed_tree: cKDTree,
    seed_points: np.ndarray,
    cfg: GrowthConfig,
    near_data: float = 0.5,
) -> Acceptance:
    """Filter candidates: spacing from particles and each other, data support, tangent plane.

    A candidate is rejected when

    * a particle lies within ``reject_radius`` (before or after projection);
    * its nearest data point is farther than ``max_gap / 2`` (holes wider than ``max_gap`` stay);
    * it lies farther than ``tangent_tolerance`` from the local data plane (DESIGN §4.4);
    * it is not within ``near_data`` of the data and the data does not surround it in its
      tangent plane within ``max_gap`` (largest angular gap of the surrounding data >= 150°):
      growth fills holes but never extends an open boundary.

    Survivors are projected onto the local data plane and thinned to ``reject_radius`` among
    themselves (first come, first served, in candidate order: deterministic).
    """
    if cfg.max_gap is None:
        raise ValueError(
            "growth.max_gap must be resolved to a length before growth "
            "(recon.pipeline.reconstruct does this)"
        )
    m = len(candidates)
    empty = Acceptance(np.zeros((0, 3)), np.zeros((0, 3)), m, 0, 0, 0)
    if m == 0:
        return empty
    d_part, _ = particle_tree.query(candidates, k=1, workers=-1)
    ok = d_part >= cfg.reject_radius
    n_close = int((~ok).sum())
    c = candidates[ok]
    d_data, nearest = surface.nearest(c)
    supported = d_data <= 0.5 * cfg.max_gap
    n_unsup = int((~supported).sum())
    c, d_data = c[supported], d_data[supported]
    _, pn, off = surface.project(c)
    on_plane = np.abs(off) < cfg.tangent_tolerance
    n_off = int((~on_plane).sum())
    c, pn, off, d_data = c[on_plane], pn[on_plane], off[on_plane], d_data[on_plane]
    c = c - off[:, None] * pn
    far = d_data > near_data
    if far.any():
        gap = max_angular_gap(c[far], pn[far], seed_tree, seed_points, cfg.max_gap)
        inside = gap < np.deg2rad(150.0)
        keep = np.ones(len(c), dtype=bool)
        keep[np.flatnonzero(far)[~inside]] = False
        n_unsup += int((~inside).sum())
        c, pn = c[keep], pn[keep]
    if len(c) == 0:
        return Acceptance(c, pn, m, n_close, n_unsup, n_off)
    d_part, _ = particle_tree.query(c, k=1, workers=-1)
    keep = d_part >= cfg.reject_radius
    n_close += int((~keep).sum())
    c, pn = c[keep], pn[keep]
    if len(c) > 1:
        mutual = poisson_disk_thin(c, cfg.reject_radius)
        n_close += int((~mutual).sum())
        c, pn = c[mutual], pn[mutual]
    return Acceptance(np.ascontiguousarray(c), np.ascontiguousarray(pn), m, n_close, n_unsup, n_off)
