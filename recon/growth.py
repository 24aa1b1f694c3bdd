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

import numpy as np
from scipy.spatial import cKDTree

from .config import GrowthConfig
from .geometry import poisson_disk_thin
from .kernels.growth_rules import MAX_PER_PARTICLE, grow_kernel
from .kernels.options import query_workers
from .neighbors import PointGrid
from .surface import DataSurface, max_angular_gap

#: Candidates closer than this to a data point [r0] count as supported without the
#: surrounding test (half the rest spacing: they lie on the data).
NEAR_DATA = 0.5
#: A candidate away from the data is kept only if the widest angular gap of the data around it
#: (within ``max_gap``, in its tangent plane) is below this [deg]: growth fills holes but never
#: extends an open boundary (a point past a boundary sees a gap of 180 deg or more).
SUPPORT_ANGLE_DEG = 150.0
#: The fold rule (:func:`past_a_fold`): the other face of a thin part counts as converging
#: on a data point when it has a point within the point's sampling spacing, its distance to
#: its ``FOLD_NEIGHBOUR``-th nearest data point (the k of the fit's local density,
#: ``recon.fitting.pipeline.DENSITY_NEIGHBOURS``).
FOLD_NEIGHBOUR = 6
#: ... the other face's normal opposes the candidate's sheet: their dot product is below this
#: (more than about 105 deg apart: the faces of a thin part turn by nearly 180 deg at its rim,
#: while the two sides of a concave junction, a leg on a body, meet at about 90 deg and noisy
#: normals stray a little past it). Measured on the held-out shapes: -0.5 (120 deg) missed
#: rims where estimated normals blend both faces (eared, 5,000 points, seed 12: a part wound
#: inward, 4.5 % of the area), 0 took a leg's junction for a fold (legs, noise 0.1 %, seed 0:
#: a loop there).
FOLD_OPPOSED = -0.25
#: ... and a candidate lies past that rim when the data within this many sampling spacings
#: (6th-neighbour distances, about 2.9 nearest-neighbour spacings each on a uniform random
#: sample: the reach is about 6 of those, past the rim's own neighbourhood) lies on one side
#: of it. Measured on the held-out eared shape at 3,000 points (docs/topology-history.md,
#: "The fold rule"); not tuned further.
FOLD_REACH = 2.1
#: Candidates per block of the fold rule's neighbour gathers.
FOLD_BLOCK = 65_536
#: The stretching rule pairs only particles whose normals agree: n_i . n_j above this
#: (cos 60 deg), so that two sides of a thin part are never bridged.
STRETCH_NORMAL_AGREEMENT = 0.5


def grow_candidates(
    position: np.ndarray,
    normal: np.ndarray,
    offsets: np.ndarray,
    indices: np.ndarray,
    cfg: GrowthConfig,
    with_normals: bool = False,
    rest: np.ndarray | None = None,
) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """Candidate positions from the growing rule (one rest spacing ``rest[i]`` out when given).

    Parameters
    ----------
    position, normal : (n, 3) float64 [r0]
    offsets, indices : CSR neighbour lists within ``cfg.grow_radius``.
    with_normals : bool
        Also return each candidate's parent normal (the sheet it grows on).

    Returns
    -------
    candidates : (m, 3) float64 [r0]
    normals : (m, 3) float64, only with ``with_normals``
    """
    n = len(position)
    out = np.zeros((n, MAX_PER_PARTICLE, 3))
    count = np.zeros(n, dtype=np.int64)
    grow_kernel(
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
    cands = out[mask]
    if rest is not None:  # one rest spacing out (adaptive spacing), not one r0
        parent = np.repeat(np.arange(n), count)
        cands = position[parent] + (cands - position[parent]) * rest[parent, None]
    if with_normals:
        return cands, np.repeat(normal, count, axis=0)
    return cands


def stretch_candidates(
    position: np.ndarray,
    normal: np.ndarray,
    tree: cKDTree | PointGrid,
    frontier: np.ndarray,
    cfg: GrowthConfig,
    with_normals: bool = False,
) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """Candidate midpoints from the stretching rule, for pairs that involve a frontier particle.

    A pair (i, j) with ``stretch_min <= |x_i - x_j| <= stretch_max`` whose normals agree
    (``STRETCH_NORMAL_AGREEMENT``) and whose midpoint has no particle within
    ``stretch_min / 2`` yields the midpoint (S&T92 §6). With ``with_normals`` the pair's mean
    normal (normalised) is returned too.
    """
    empty = np.zeros((0, 3))
    idx = np.flatnonzero(frontier)
    a = b = np.zeros(0, dtype=np.int64)
    if len(idx) > 0:
        sub_tree = cKDTree(position[idx])
        pairs = sub_tree.query_pairs(cfg.stretch_max, output_type="ndarray")
        if len(pairs) > 0:
            a, b = idx[pairs[:, 0]], idx[pairs[:, 1]]
    d = np.linalg.norm(position[a] - position[b], axis=1)
    sel = d >= cfg.stretch_min
    a, b = a[sel], b[sel]
    # the two normals must agree (not two sides of a thin part)
    agree = np.einsum("ij,ij->i", normal[a], normal[b]) > STRETCH_NORMAL_AGREEMENT
    a, b = a[agree], b[agree]
    mid = 0.5 * (position[a] + position[b])
    if len(mid) > 0:
        dist, _ = tree.query(mid, k=1, workers=query_workers())
        keep = dist >= 0.5 * cfg.stretch_min
        mid, a, b = mid[keep], a[keep], b[keep]
    if not with_normals:
        return mid if len(mid) else empty
    m = normal[a] + normal[b]
    m /= np.maximum(np.linalg.norm(m, axis=1, keepdims=True), 1e-300)
    return (mid, m) if len(mid) else (empty, empty.copy())


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
    particle_tree: cKDTree | PointGrid,
    surface: DataSurface,
    seed_tree: cKDTree,
    seed_points: np.ndarray,
    cfg: GrowthConfig,
    near_data: float = NEAR_DATA,
    normals: np.ndarray | None = None,
    rest: np.ndarray | None = None,
) -> Acceptance:
    """Filter candidates: spacing from particles and each other, data support, tangent plane.

    ``normals`` (optional, (m, 3)): the normal of the sheet each candidate grows on (its
    parent's). The candidate is then projected onto the data of that sheet (data normals
    agreeing) and rejected when the data normal there is opposed to it: growth never adds a
    particle that joins two opposed sheets (the two sides of a thin part).

    A candidate is rejected when

    * a particle lies within ``reject_radius`` (before or after projection);
    * its nearest data point is farther than ``max_gap / 2`` (holes wider than ``max_gap`` stay);
    * it lies farther than ``tangent_tolerance`` from the local data plane (DESIGN §4.4);
    * it is not within ``near_data`` of the data and the data does not surround it in its
      tangent plane within ``max_gap`` (largest angular gap of the surrounding data >=
      ``SUPPORT_ANGLE_DEG`` = 150°):
      growth fills holes but never extends an open boundary;
    * it is not within ``near_data`` of the data and lies past the rim of a thin part
      (:func:`past_a_fold`; only with ``normals``): the gap beside a thin part's rim is not
      a hole of the surface, even where other data surrounds it within ``max_gap`` (the
      notch between two ears).

    Survivors are projected onto the local data plane and thinned to ``reject_radius`` among
    themselves (first come, first served, in candidate order: deterministic).
    """
    if cfg.max_gap is None:
        raise ValueError(
            "growth.max_gap must be resolved to a length before growth "
            "(recon.fitting.reconstruct does this)"
        )
    m = len(candidates)
    empty = Acceptance(np.zeros((0, 3)), np.zeros((0, 3)), m, 0, 0, 0)
    if m == 0:
        return empty
    radius = cfg.reject_radius * (np.ones(m) if rest is None else rest)
    d_part, _ = particle_tree.query(candidates, k=1, workers=query_workers())
    ok = d_part >= radius
    n_close = int((~ok).sum())
    c = candidates[ok]
    radius = radius[ok]
    cn = None if normals is None else normals[ok]
    d_data, nearest = surface.nearest(c)
    supported = d_data <= 0.5 * cfg.max_gap
    n_unsup = int((~supported).sum())
    c, d_data, radius = c[supported], d_data[supported], radius[supported]
    nearest = nearest[supported]
    cn = None if cn is None else cn[supported]
    _, pn, off = surface.project(c, cn)
    on_plane = np.abs(off) < cfg.tangent_tolerance
    if cn is not None:
        on_plane &= np.einsum("ij,ij->i", pn, cn) > 0.0
    n_off = int((~on_plane).sum())
    c, pn, off, d_data = c[on_plane], pn[on_plane], off[on_plane], d_data[on_plane]
    radius, nearest = radius[on_plane], nearest[on_plane]
    cn = None if cn is None else cn[on_plane]
    c = c - off[:, None] * pn
    far = d_data > near_data
    if far.any() and cn is not None:
        f = np.flatnonzero(far)
        fold = past_a_fold(c[f], pn[f], cn[f], nearest[f], surface)
        n_unsup += int(fold.sum())
        keep = np.ones(len(c), dtype=bool)
        keep[f[fold]] = False
        c, pn, radius, far = c[keep], pn[keep], radius[keep], far[keep]
    if far.any():
        gap = max_angular_gap(c[far], pn[far], seed_tree, seed_points, cfg.max_gap)
        inside = gap < np.deg2rad(SUPPORT_ANGLE_DEG)
        keep = np.ones(len(c), dtype=bool)
        keep[np.flatnonzero(far)[~inside]] = False
        n_unsup += int((~inside).sum())
        c, pn, radius = c[keep], pn[keep], radius[keep]
    if len(c) == 0:
        return Acceptance(c, pn, m, n_close, n_unsup, n_off)
    d_part, _ = particle_tree.query(c, k=1, workers=query_workers())
    keep = d_part >= radius
    n_close += int((~keep).sum())
    c, pn, radius = c[keep], pn[keep], radius[keep]
    if len(c) > 1:
        mutual = poisson_disk_thin(c, float(np.min(radius)))
        n_close += int((~mutual).sum())
        c, pn = c[mutual], pn[mutual]
    return Acceptance(np.ascontiguousarray(c), np.ascontiguousarray(pn), m, n_close, n_unsup, n_off)


def past_a_fold(
    candidates: np.ndarray,
    plane_normals: np.ndarray,
    sheet_normals: np.ndarray,
    nearest: np.ndarray,
    surface: DataSurface,
) -> np.ndarray:
    """The fold rule: whether each candidate off the data would extend a thin part past its
    rim (bool (m,)).

    Where the two faces of a thin part (an ear, a blade) meet at its rim, the data wraps
    round: the nearest data point to a candidate past the rim has, within its own sampling
    spacing (the distance to its ``FOLD_NEIGHBOUR``-th nearest data point), a point of the
    other face, whose normal opposes the candidate's sheet. A hole of a sheet has no such
    point at its rim. The candidate lies past the rim when, besides, the data within
    ``FOLD_REACH`` sampling spacings of it lies on one side of it in its tangent plane (an
    angular gap of pi or more; fewer than three points within that reach count as one side):
    candidates between the samples of the thin part's faces keep data all round.

    A hole *through* a thin part (a washer's) has the same rim, where the data wraps round:
    it is an opening of the shape, not missing data, and growth does not cover it either. A
    notch narrower than the reach is still taken for a hole (the data then lies on both
    sides of the candidate).

    Parameters
    ----------
    candidates : (m, 3) float64 [r0]
        Candidate positions, on the local data surface.
    plane_normals : (m, 3) float64
        The data surface's normal at each candidate (its tangent plane).
    sheet_normals : (m, 3) float64
        The normal of the sheet each candidate grows on (its parent's).
    nearest : (m,) int
        Each candidate's nearest data point.
    surface : DataSurface
        The data (normals consistently oriented).
    """
    m = len(candidates)
    fold = np.zeros(m, dtype=bool)
    spacing = np.zeros(m)
    pts = surface.points
    k = FOLD_NEIGHBOUR + 1  # the point itself and its FOLD_NEIGHBOUR nearest
    table = surface.walk_neighbors
    for lo in range(0, m, FOLD_BLOCK):  # bounded temporaries: about 0.5 kB per candidate
        hi = min(lo + FOLD_BLOCK, m)
        near = nearest[lo:hi]
        if table is not None and table.shape[1] >= k:
            rows = table[near, :k]
        else:
            rows = surface.tree.query(pts[near], k=min(k, len(pts)), workers=query_workers())[1]
            rows = np.reshape(rows, (hi - lo, -1))
        dist = np.linalg.norm(pts[rows] - pts[near][:, None, :], axis=2)
        own = dist.max(axis=1) if rows.shape[1] < k else dist[:, FOLD_NEIGHBOUR]
        opposed = (
            np.einsum("mkj,mj->mk", surface.normals[rows], sheet_normals[lo:hi]) < FOLD_OPPOSED
        )
        fold[lo:hi] = (opposed & (dist <= own[:, None])).any(axis=1)
        spacing[lo:hi] = own
    if fold.any():
        f = np.flatnonzero(fold)
        gap = max_angular_gap(
            candidates[f], plane_normals[f], surface.tree, pts, FOLD_REACH * spacing[f]
        )
        fold[f[gap < np.pi]] = False
    return fold
