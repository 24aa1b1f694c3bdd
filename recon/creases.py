"""Sharp creases and corners in the data, by Gauss-map clustering (issue 12, step 1).

Each point looks at the unoriented normals of its ``k`` nearest data points (a wide
neighbourhood, 48 by default, about twice the normal-estimation one) and clusters them as axes
(:mod:`recon.kernels.gauss_map`):

- **crease**: two tight clusters, each holding at least 25 % of the neighbourhood, whose
  planes turn by more than ``angle_deg`` (the angle between the two face normals: 0 on a
  plane, 90 deg on a box edge, 180 deg on a knife edge; measured from the point positions, so
  the normals' signs do not matter and a 270 deg concave edge counts as a 90 deg turn);
- **corner**: three such clusters, pairwise turning by more than ``angle_deg``, the smallest
  holding at least 10 %.

Past ``180 - angle_deg`` (a knife edge: a 150 deg turn has axes 30 deg apart) the normals near
the edge are all blends and do not split; there two planes refitted to the neighbourhood's
points decide (``KNIFE_RATIO``, :mod:`recon.kernels.gauss_map` eq. K1).

A cheap screen comes first: a point is clustered only when one of its neighbours is as
curved (PCA surface variation) as half of what the edge point of the weakest counting fold
shows (:func:`_edge_variation`); on a clean smooth surface most points are not.

Three filters follow. The data must *reach the line*: some neighbour lies within ``0.3 h`` of the
crease line, which a sharp crease satisfies (median 0.08 h on the clean L-block, 0.15 h with
0.25 % noise) and a rounded edge does not (a fillet of radius rho stays about 0.4 rho off the
planes' intersection at 90 deg). And the crease must be *coherent*: feature points near its line
must span at least 1.2 neighbourhood radii along it. Last, only *long folds* are kept
(:func:`_long_folds`): crease points linked into lines at least ``MIN_LINE_RADII``
neighbourhood radii long whose sides two planes fit down to the data's noise floor while one
quadric misses them about as much as it misses the exact fold of those planes. This keeps
smooth shapes untouched: tight bends of scans (bunny, face) gave short or curved-sided
fragments.

"Tight" is the noise floor: the angle between the two cluster axes must exceed three times the
sum of their spreads (median angle of members to their axis). A smooth surface splits its
continuous spread of normals into halves only about two spreads apart, and noise widens the
spreads with the separation, so neither a curved nor a noisy smooth surface passes.

Crease *length* is measured along the crease lines: each crease point has a foot, the point
of its crease line (the intersection of its two side planes) closest to it. The feet of a
crease band fall on the line, so each stands for ``2 h / m`` of it, ``m`` being the number of
feet within the local sample spacing ``h = sqrt(pi r_k**2 / k)`` (``r_k``: distance to the
k-th neighbour). This does not depend on how wide the detected band is. Corner zones (about
half a neighbourhood radius around each corner) are not counted: on the exact L-block the
measured length is about 9 % short of the true edge length. Corners are groups of at least
three corner points whose three-plane intersections lie within ``3 h`` of each other (corner
points in smaller groups become smooth); each is placed at the median of its group.

Detection feeds the fit report and, with ``creases.fit``, the fit itself
(:mod:`recon.crease_surface`, :mod:`recon.crease_mesh`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse
from scipy.sparse import csgraph
from scipy.spatial import cKDTree

from .geometry import as_points
from .kernels.gauss_map import gauss_map_kernel
from .kernels.options import query_workers
from .kernels.pca import scatter_matrices
from .row_blocks import for_row_blocks

__all__ = ["SMOOTH", "CREASE", "CORNER", "Creases", "detect_creases"]

SMOOTH, CREASE, CORNER = 0, 1, 2
CREASE_SHARE = 0.25
CORNER_SHARE = 0.15
CORNER_MIN_DET = 0.5
SEPARATION_RATIO = 3.0
KEEP_FRACTION = 0.5
COHERENCE = 1.2
GAP = 0.3
MIN_CORNER_POINTS = 3
GROUP_RADIUS = 3.0
#: A crease line must be at least this many neighbourhood radii long (its crease and corner
#: points linked within LINK_RADIUS radii, crease points only to parallel ones).
MIN_LINE_RADII = 5.0
LINK_RADIUS = 1.5
LINE_LINK = 2.5
LINE_OFFSET = 0.25
LINK_ANGLE_DEG = 20.0
#: ... and its neighbourhoods must be a fold: two planes fit them at least this many times
#: better (RMS distance, median over the line) than one quadric.
FOLD_RATIO = 1.25
#: ... and the two planes must explain them down to the noise: RMS distance at most
#: NOISE_RATIO times the noise floor (the NOISE_QUANTILE of the one-quadric RMS residuals of
#: NOISE_SAMPLE points of the whole cloud: the flat and smooth parts' scatter).
NOISE_RATIO = 1.5
NOISE_QUANTILE = 25.0
NOISE_SAMPLE = 2000
NOISE_MIN = 0.01
#: ... and one quadric must miss them (beyond the noise: sqrt(res_quadric**2 - res_sides**2))
#: by at least SHARPNESS times what it misses on the exact fold of the same two planes (the
#: neighbours moved onto them): a tight smooth bend of the same turn is easier to fit.
SHARPNESS = 0.9
#: Points whose neighbours are all flatter (PCA surface variation) than this fraction of that
#: of the sharpest-counting fold's edge point (:func:`_edge_variation`) are smooth without
#: clustering (a cheap first screen; most of a smooth clean surface).
SCREEN_FRACTION = 0.5
#: Knife edges (turns past 180 deg - angle_deg, whose faces' normal axes lie closer than
#: angle_deg): where the normals do not split, two planes refitted to the neighbourhood's
#: points (:mod:`recon.kernels.gauss_map`, eq. K1) must leave at most this fraction of the
#: RMS distance to one plane (0 turns the test off).
KNIFE_RATIO = 0.5


@dataclass(frozen=True)
class Creases:
    """Sharp features of a point set.

    Attributes
    ----------
    labels : (n,) int8
        ``SMOOTH`` (0), ``CREASE`` (1) or ``CORNER`` (2) per point.
    side_normals : (n, 3, 3) float64
        Unit side normals: rows 0 and 1 for a crease, 0-2 for a corner, zero otherwise. Signed
        by the majority of the input normals, so oriented input gives oriented sides.
    direction : (n, 3) float64
        Unit crease direction ``n1 x n2`` at crease points; zero elsewhere.
    turn_deg : (n,) float64 [deg]
        Angle between the side normals (the smallest pair at a corner); 0 when smooth.
    corners : (m, 3) float64 [length]
        One point per detected corner.
    length : float [length]
        Detected crease length (band integral, see the module docstring).
    foot : (n, 3) float64 [length], optional
        At crease points the point of their crease line closest to them; NaN elsewhere.
    """

    labels: np.ndarray
    side_normals: np.ndarray
    direction: np.ndarray
    turn_deg: np.ndarray
    corners: np.ndarray
    length: float
    foot: np.ndarray | None = None

    @property
    def n_crease_points(self) -> int:
        return int(np.count_nonzero(self.labels == CREASE))

    @property
    def n_corner_points(self) -> int:
        return int(np.count_nonzero(self.labels == CORNER))

    def take(self, rows: np.ndarray) -> Creases:
        """The detection at the points ``rows`` (indices into the points it labels, in that
        order); ``corners`` and ``length`` are the whole detection's."""
        rows = np.asarray(rows)
        return Creases(
            labels=self.labels[rows],
            side_normals=self.side_normals[rows],
            direction=self.direction[rows],
            turn_deg=self.turn_deg[rows],
            corners=self.corners,
            length=self.length,
            foot=None if self.foot is None else self.foot[rows],
        )


def detect_creases(
    points: np.ndarray,
    normals: np.ndarray | None = None,
    *,
    angle_deg: float = 40.0,
    k: int = 48,
    normals_k: int = 20,
    neighbors: tuple[np.ndarray, np.ndarray] | None = None,
    tree: cKDTree | None = None,
) -> Creases:
    """Label every point smooth, crease or corner (see the module docstring).

    Parameters
    ----------
    points : (n, 3) float64 [length]
    normals : (n, 3) float64, optional
        Unit normals, oriented or not; estimated by PCA of ``normals_k`` neighbours if None.
    angle_deg : float [deg]
        Smallest angle between the two side normals that counts as a crease.
    k : int
        Neighbourhood size of the clustering (capped at n).
    neighbors : (distances (n, m), indices (n, m)), optional
        Each point's m >= k nearest points, nearest first (a shared k-d tree query of
        ``points``); queried here when None or narrower.
    tree : scipy.spatial.cKDTree, optional
        A k-d tree of ``points`` (the fit's shared one); built here when None.
    """
    pts = as_points(points)
    n = len(pts)
    kk = int(min(k, n))
    if kk < 8:
        return _empty(n)
    tree = cKDTree(pts) if tree is None else tree
    if neighbors is not None and neighbors[1].shape[1] >= kk:
        dist, idx = neighbors[0][:, :kk], neighbors[1][:, :kk]
    else:
        dist, idx = tree.query(pts, k=kk, workers=query_workers())
    # (the shared query's int32 indices are used as they are: an int64 copy was 384 MB at 1M)
    # the normal-estimation neighbours are the first of these (sorted by distance)
    own, variation = _pca(pts, tree, min(normals_k, n), idx if normals_k <= kk else None)
    if normals is None:
        normals = own
    nrm = np.ascontiguousarray(normals, dtype=np.float64)
    # screen: a crease within a neighbourhood puts a point of it on the edge, whose PCA
    # neighbourhood straddles both faces; where every neighbour is flatter than half of that
    # (the fold of angle_deg), the Gauss map is not clustered (all smooth)
    # (a gather of the flags: a neighbour's variation >= screen iff the max is; 1/8 the bytes)
    curved = variation >= SCREEN_FRACTION * _edge_variation(angle_deg)
    cand = np.flatnonzero(np.concatenate([curved[idx[b]].any(axis=1) for b in _blocks(n)]))
    label = np.zeros(n, np.int8)
    side = np.zeros((n, 3, 3))
    direction = np.zeros((n, 3))
    turn = np.zeros(n)
    corner = np.full((n, 3), np.nan)
    foot = np.full((n, 3), np.nan)
    out = gauss_map_kernel(
        pts,
        nrm,
        variation,
        np.ascontiguousarray(pts[cand]),
        np.ascontiguousarray(idx[cand], dtype=np.int64),
        max(8, int(round(KEEP_FRACTION * kk))),
        np.radians(angle_deg),
        SEPARATION_RATIO,
        CREASE_SHARE,
        CORNER_SHARE,
        CORNER_MIN_DET,
        KNIFE_RATIO,
    )
    label[cand], side[cand], direction[cand], turn[cand], _, corner[cand], _, foot[cand] = out
    h = np.sqrt(np.pi * dist[:, -1] ** 2 / kk)
    label = _reach_line(pts, tree, label, direction, foot, h, kk)
    label = _coherent(pts, label, direction, idx, dist[:, -1])
    label = _long_folds(pts, label, side, direction, foot, idx, dist[:, -1], h)
    corners, lone = _group_corners(label, corner, float(np.median(h)))
    label[lone] = SMOOTH
    length = _line_length(foot[label == CREASE], h[label == CREASE])
    return Creases(
        labels=label,
        side_normals=side,
        direction=direction,
        turn_deg=np.degrees(turn),
        corners=corners,
        length=length,
        foot=foot,
    )


def _edge_variation(angle_deg: float) -> float:
    """Surface variation ``l3 / (l1 + l2 + l3)`` of a disc folded along a diameter, for the
    folds whose normal axes are at least ``angle_deg`` apart (turns from ``angle_deg`` to
    ``180 - angle_deg``; the least at either end): each half-disc tilted by ``phi = turn / 2``
    from the bisector plane has second moments 1/4 along the fold, ``cos(phi)**2 / 4`` across
    it and ``sin(phi)**2 (1/4 - (4 / (3 pi))**2)`` out of the plane (radius 1)."""

    def fold(turn: float) -> float:
        phi = np.radians(turn) / 2.0
        m = sorted(
            [0.25, np.cos(phi) ** 2 / 4.0, np.sin(phi) ** 2 * (0.25 - (4.0 / (3.0 * np.pi)) ** 2)]
        )
        return float(m[0] / sum(m))

    return min(fold(angle_deg), fold(max(180.0 - angle_deg, angle_deg)))


def _line_length(foot: np.ndarray, h: np.ndarray) -> float:
    """Length of the 1-D set of crease feet: each stands for ``2 h / m`` of line, ``m`` being
    the number of feet within ``h`` of it (itself included)."""
    if len(foot) == 0:
        return 0.0
    tree = cKDTree(foot)
    counts = np.array([len(x) for x in tree.query_ball_point(foot, h)], dtype=np.float64)
    return float(np.sum(2.0 * h / counts))


def _reach_line(
    pts: np.ndarray,
    tree: cKDTree,
    label: np.ndarray,
    direction: np.ndarray,
    foot: np.ndarray,
    h: np.ndarray,
    k: int,
) -> np.ndarray:
    """Keep crease points whose line the data reach: one of the ``k`` data points nearest to
    the point's foot on the line lies within ``GAP * h`` of the line (the foot, not the point:
    near a knife edge the wide neighbourhood of a crease point may not reach the edge).
    A rounded edge (fillet of radius rho) keeps its data ``(1/cos(turn/2) - 1) rho`` off the
    planes' intersection, about 0.4 rho at 90 deg; a sharp crease has data on the line."""
    sel = np.flatnonzero(label == CREASE)
    if len(sel) == 0:
        return label
    _, near = tree.query(foot[sel], k=k)
    rel = pts[near] - foot[sel][:, None, :]
    d = direction[sel][:, None, :]
    t = np.einsum("nkj,nkj->nk", rel, d)
    gap = np.linalg.norm(rel - t[..., None] * d, axis=2).min(axis=1)
    out = label.copy()
    out[sel[gap > GAP * h[sel]]] = SMOOTH
    return out


def _coherent(
    pts: np.ndarray, label: np.ndarray, direction: np.ndarray, idx: np.ndarray, radius: np.ndarray
) -> np.ndarray:
    """Keep crease points whose line continues: feature neighbours near the line through the
    point along its direction ``d`` (crease neighbours also parallel to it) must span at least
    ``COHERENCE`` neighbourhood radii along ``d``. Facets of a coarse mesh and kinks of a
    scan give short, scattered fragments; a crease runs through the whole neighbourhood."""
    sel = np.flatnonzero(label == CREASE)
    if len(sel) == 0:
        return label
    nb = idx[sel]
    d = direction[sel][:, None, :]
    rel = pts[nb] - pts[sel][:, None, :]
    t = np.einsum("nkj,nkj->nk", rel, d)
    off = np.linalg.norm(rel - t[..., None] * d, axis=2)
    lab = label[nb]
    par = np.abs(np.einsum("nkj,nkj->nk", direction[nb], d)) > np.cos(np.radians(20.0))
    ok = ((lab == CORNER) | ((lab == CREASE) & par)) & (off < 0.5 * radius[sel][:, None])
    t_max = np.where(ok, t, -np.inf).max(axis=1)
    t_min = np.where(ok, t, np.inf).min(axis=1)
    out = label.copy()
    out[sel[t_max - t_min < COHERENCE * radius[sel]]] = SMOOTH
    return out


def _long_folds(
    pts: np.ndarray,
    label: np.ndarray,
    side: np.ndarray,
    direction: np.ndarray,
    foot: np.ndarray,
    idx: np.ndarray,
    radius: np.ndarray,
    h: np.ndarray,
) -> np.ndarray:
    """Keep the feature points of long folds only. Crease and corner points are linked into
    lines (within ``LINK_RADIUS`` neighbourhood radii; two crease points only when their
    directions agree to ``LINK_ANGLE_DEG``; corner points link to any), and a line is kept when

    - it is at least ``MIN_LINE_RADII`` neighbourhood radii long (measured along the feet,
      :func:`_line_length`): a tight bend or a kink of a scan gives short fragments, a
      machined edge runs on, through its corners, into the next edge;
    - its neighbourhoods are folds, not bends (medians over the line's crease points): one
      quadric height field misses the neighbours by at least ``FOLD_RATIO`` times the RMS
      distance to the two sides (each a plane that may bend along the line); the sides fit down
      to the noise floor (:func:`_noise_floor`, ``NOISE_RATIO``); and the quadric's miss beyond
      the noise is at least ``SHARPNESS`` times its miss on the exact fold of the same two
      planes. A quadric fits a smooth bend as well as two planes do, or better, and a tight
      bend of the same turn better than the sharp fold; across a sharp crease it misses by a
      fraction of the radius while the two planes are exact up to the noise.
    """
    feat = np.flatnonzero(label != SMOOTH)
    if len(feat) == 0:
        return label
    is_crease = label[feat] == CREASE
    rad = float(np.median(radius[feat]))
    # crease points: feet on one line (parallel, the other's foot near the line)
    cr = feat[is_crease]
    pos = np.where(is_crease[:, None], np.nan_to_num(foot[feat]), pts[feat])
    pairs = cKDTree(pos).query_pairs(LINE_LINK * rad, output_type="ndarray")
    a, b = pairs[:, 0], pairs[:, 1]
    dirs = direction[feat]
    cos = np.abs(np.einsum("ij,ij->i", dirs[a], dirs[b]))
    rel = pos[b] - pos[a]
    t = np.einsum("ij,ij->i", rel, dirs[a])
    off = np.linalg.norm(rel - t[:, None] * dirs[a], axis=1)
    both = is_crease[a] & is_crease[b]
    line = both & (cos > np.cos(np.radians(LINK_ANGLE_DEG))) & (off < LINE_OFFSET * rad)
    # corner points: any feature point near them
    near = ~both & (np.linalg.norm(pts[feat[a]] - pts[feat[b]], axis=1) < LINK_RADIUS * rad)
    keep = line | near
    graph = sparse.coo_matrix(
        (np.ones(int(keep.sum())), (a[keep], b[keep])), shape=(len(feat), len(feat))
    )
    n_comp, comp = csgraph.connected_components(graph, directed=False)
    # a line is kept only when long enough: lengths first; when no line of crease points is,
    # every feature point turns smooth and no fold residual is needed (smooth scans)
    long_enough = [_long_enough(comp == c, is_crease, foot, h, feat, radius) for c in range(n_comp)]
    out = label.copy()
    if not any(long_enough):
        out[feat] = SMOOTH
        return out
    ratio, plane_res, sharpness = np.full((3, len(feat)), np.nan)
    if len(cr):
        res_q, res_p, res_i = _fold_residuals(pts, idx[cr], side[cr, :2], foot[cr], radius[cr])
        ratio[is_crease] = res_q / np.maximum(res_p, 1e-12)
        plane_res[is_crease] = res_p
        sharpness[is_crease] = np.sqrt(np.maximum(res_q**2 - res_p**2, 0.0)) / np.maximum(
            res_i, 1e-300
        )
    floor = None  # the noise floor, measured when a line first needs it (not on smooth scans)
    for c, long_line in enumerate(long_enough):
        m = comp == c
        mc = m & is_crease  # not empty on a long line
        # (the three tests are pure: their order does not change the verdict, and the one
        # that needs the floor comes last)
        fold = (
            long_line
            and float(np.median(ratio[mc])) >= FOLD_RATIO
            and float(np.median(sharpness[mc])) >= SHARPNESS
        )
        if fold and floor is None:
            floor = _noise_floor(pts, idx, radius)
        fold = fold and float(np.median(plane_res[mc])) <= NOISE_RATIO * floor
        if not fold:
            out[feat[m]] = SMOOTH
    return out


def _long_enough(
    m: np.ndarray, is_crease: np.ndarray, foot: np.ndarray, h: np.ndarray, feat: np.ndarray, radius
) -> bool:
    """Is the line of feature points ``m`` (a mask over ``feat``; ``is_crease`` marks the
    crease points) at least ``MIN_LINE_RADII`` neighbourhood radii long, measured along its
    crease points' feet (False without a crease point)?"""
    mc = m & is_crease
    if not mc.any():
        return False
    length = _line_length(foot[feat[mc]], h[feat[mc]])
    return bool(length >= MIN_LINE_RADII * float(np.median(radius[feat[m]])))


def _quadric_residual(nb: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """RMS residual [length] of one quadric height field fitted to each row of points ``nb``
    (m, k, 3) over their PCA plane (``scale``: (m, 1, 1) lengths for the conditioning)."""
    rel = (nb - nb.mean(axis=1, keepdims=True)) / scale
    _, vec = np.linalg.eigh(np.einsum("mki,mkj->mij", rel, rel))
    x = np.einsum("mki,mi->mk", rel, vec[:, :, 2])
    y = np.einsum("mki,mi->mk", rel, vec[:, :, 1])
    z = np.einsum("mki,mi->mk", rel, vec[:, :, 0])
    basis = np.stack([np.ones_like(x), x, y, x * x, x * y, y * y], axis=-1)
    gram = np.einsum("mki,mkj->mij", basis, basis) + 1e-9 * np.eye(6)
    coef = np.linalg.solve(gram, np.einsum("mki,mk->mi", basis, z)[..., None])[..., 0]
    res = np.sqrt(np.mean((np.einsum("mki,mi->mk", basis, coef) - z) ** 2, axis=1))
    return res * scale[:, 0, 0]


def _noise_floor(pts: np.ndarray, idx: np.ndarray, radius: np.ndarray) -> float:
    """The data's scatter [length]: the ``NOISE_QUANTILE`` percentile of the one-quadric RMS
    residuals of ``NOISE_SAMPLE`` evenly spread points (most of a surface is smooth there), at
    least ``NOISE_MIN`` neighbourhood radii."""
    step = max(1, len(pts) // NOISE_SAMPLE)
    s = np.arange(0, len(pts), step)
    res = _quadric_residual(pts[idx[s]], np.maximum(radius[s], 1e-300)[:, None, None])
    # exact data: rounding only (float32 input quantises at ~1e-7 of the coordinates)
    return max(float(np.percentile(res, NOISE_QUANTILE)), NOISE_MIN * float(np.median(radius)))


def _fold_residuals(
    pts: np.ndarray, idx: np.ndarray, side: np.ndarray, foot: np.ndarray, radius: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Per crease point: RMS residual [length] of one quadric height field fitted to its
    neighbours ``idx`` over their PCA plane, and the RMS distance to the nearer of its two side
    planes (refitted to the neighbours by PCA, each neighbour assigned to the nearer one), each
    side allowed to bend along the crease line (a quadratic in the along-line coordinate: the
    wall of a hole or boss meets its face along a circle) but not across it."""
    nb = pts[idx]  # (m, k, 3)
    scale = np.maximum(radius, 1e-300)[:, None, None]
    res_quadric = _quadric_residual(nb, scale)
    local = (nb - foot[:, None]) / scale
    na, nb_ = side[:, 0].copy(), side[:, 1].copy()
    ca = np.zeros_like(na)
    cb = np.zeros_like(nb_)
    for _ in range(6):
        da = np.abs(np.einsum("mkj,mj->mk", local - ca[:, None], na))
        db = np.abs(np.einsum("mkj,mj->mk", local - cb[:, None], nb_))
        for mask, n, c in ((da <= db, na, ca), (da > db, nb_, cb)):
            w = mask.astype(np.float64)
            cnt = w.sum(axis=1)
            cen = np.einsum("mk,mkj->mj", w, local) / np.maximum(cnt, 1.0)[:, None]
            r = (local - cen[:, None]) * w[..., None]
            _, v = np.linalg.eigh(np.einsum("mki,mkj->mij", r, r))
            ok = cnt >= 3
            n[ok] = v[ok, :, 0]
            c[ok] = cen[ok]
    sa = np.einsum("mkj,mj->mk", local - ca[:, None], na)
    sb = np.einsum("mkj,mj->mk", local - cb[:, None], nb_)
    on_a = np.abs(sa) <= np.abs(sb)
    d = np.cross(na, nb_)
    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-300)
    t = np.einsum("mkj,mj->mk", local, d)
    sq = np.zeros(len(idx))
    for mask, dist, n in ((on_a, sa, na), (~on_a, sb, nb_)):
        # each side may bend along the line (a hole's or a boss's wall), not across it
        across = np.cross(d, n)
        u = np.einsum("mkj,mj->mk", local, across)
        w = mask.astype(np.float64)
        basis = np.stack([np.ones_like(t), u, t, t * t], axis=-1) * w[..., None]
        gram = np.einsum("mki,mkj->mij", basis, basis) + 1e-9 * np.eye(4)
        coef = np.linalg.solve(gram, np.einsum("mki,mk->mi", basis, dist * w)[..., None])[..., 0]
        sq += np.sum(w * (np.einsum("mki,mi->mk", basis, coef) - dist * w) ** 2, axis=1)
    res_sides = np.sqrt(sq / idx.shape[1]) * scale[:, 0, 0]
    # the same neighbours moved onto the sharp fold of the two planes: what one quadric
    # misses on an exact crease of this turn and extent
    ideal = local - np.where(
        on_a[..., None], sa[..., None] * na[:, None], sb[..., None] * nb_[:, None]
    )
    res_ideal = _quadric_residual(ideal * scale, scale)
    return res_quadric, res_sides, res_ideal


def _pca(
    pts: np.ndarray, tree: cKDTree, k: int, nearest: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """PCA normals and surface variation ``l3 / (l1 + l2 + l3)`` of ``k`` neighbours (the
    first ``k`` columns of ``nearest``, the neighbours by distance, when given)."""
    normals, variation = np.empty((len(pts), 3)), np.empty(len(pts))
    workers = query_workers()

    def rows(b: slice) -> None:  # a (block, k, 3) gather at a time
        idx = nearest[b, :k] if nearest is not None else tree.query(pts[b], k, workers=workers)[1]
        idx = idx.reshape(b.stop - b.start, k)
        cov = np.empty((len(idx), 3, 3))
        scatter_matrices(pts, idx, pts[b], False, cov)  # about the mean, as numpy: one sweep
        w, v = np.linalg.eigh(cov)
        total = w.sum(axis=1)
        variation[b] = np.where(total > 0, w[:, 0] / np.where(total > 0, total, 1.0), 0.0)
        normals[b] = v[:, :, 0]

    if nearest is None:  # the k-d tree query is threaded itself
        for b in _blocks(len(pts)):
            rows(b)
    else:  # numpy without the GIL: blocks in threads
        for_row_blocks(rows, len(pts), BLOCK)
    return normals, variation


#: Rows per block of the per-point neighbourhood work (a (block, k, 3) float64 gather is
#: 75 MB at k = 48).
BLOCK = 65536


def _blocks(n: int) -> list[slice]:
    """Row slices of ``BLOCK`` rows covering ``range(n)``."""
    return [slice(lo, min(lo + BLOCK, n)) for lo in range(0, n, BLOCK)]


def _group_corners(
    label: np.ndarray, corner: np.ndarray, h: float
) -> tuple[np.ndarray, np.ndarray]:
    """Corners: groups of corner estimates within ``GROUP_RADIUS * h`` of each other, at least
    ``MIN_CORNER_POINTS`` strong, each placed at the median; and the indices of the corner
    points left alone (returned so that the caller can unlabel them)."""
    sel = np.flatnonzero(label == CORNER)
    if len(sel) == 0:
        return np.zeros((0, 3)), sel
    est = corner[sel]
    pairs = cKDTree(est).query_pairs(GROUP_RADIUS * h, output_type="ndarray")
    graph = sparse.coo_matrix(
        (np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(sel), len(sel))
    )
    n_comp, comp = csgraph.connected_components(graph, directed=False)
    sizes = np.bincount(comp, minlength=n_comp)
    big = np.flatnonzero(sizes >= MIN_CORNER_POINTS)
    out = np.array([np.median(est[comp == c], axis=0) for c in big]).reshape(-1, 3)
    return out, sel[sizes[comp] < MIN_CORNER_POINTS]


def _empty(n: int) -> Creases:
    return Creases(
        labels=np.zeros(n, np.int8),
        side_normals=np.zeros((n, 3, 3)),
        direction=np.zeros((n, 3)),
        turn_deg=np.zeros(n),
        corners=np.zeros((0, 3)),
        length=0.0,
        foot=np.full((n, 3), np.nan),
    )
