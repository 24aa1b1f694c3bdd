"""Normal signs of a closed scan read from its exterior: which side of a point a ball from
far away reaches first.

Hoppe's propagation (:func:`recon.normals.orient_normals`) and the re-signing across thin
parts (:mod:`recon.normal_signs`) both carry signs from neighbour to neighbour. Where a
part is only a few point spacings thick (the ears, tail and legs of ``bench_thin_parts.py``
at 3,000 points: 2-5 spacings), a neighbourhood holds both of its faces and the PCA normals
round its rim or round a leg are poor, so whole faces or whole ears come out inside out
(eared seed 0: 254 of 338 ear points; legs seed 0: 126 of 320 on two legs).

A closed surface also tells the sign globally: the outward normal points to the side from
which the outside is reached. Here the outside is the free space a ball of radius
``BALL_RADIUS`` voxels reaches from beyond the data (a ball, not a point, so that gaps
between sparse samples do not let it in), in a grid of about one median point spacing.
Random samples leave gaps of every size, and one gap wide enough lets the ball into the
whole inside: then both sides of most points are reached alike and the votes do not look
closed (below). The next ball of ``BALL_RADII`` is tried then: the first ball whose votes
look closed reads the data (looking closed stands in for sealed; the smallest ball reaches
farthest into narrow concave places). A point whose search reaches the outside on neither
side does not vote.
For each point, steps along ``+n`` and ``-n`` find the first outside voxel on each side;
the side reached at least ``MARGIN`` voxels sooner wins. Across a thin part the far side
is reached only after crossing the part; on a thick body the inside is never reached.
Where both sides are reached alike (an open scan, a part thinner than a voxel, a hole that
lets the ball in) there is no vote.

The votes are used only when the data looks closed: at least ``MIN_DECIDED`` of the points
vote and at least ``MIN_AGREE`` of the votes agree with the signs already found. Then a point
whose vote disagrees is turned over when most of its ``PATCH_K`` nearest points' votes
disagree too (a patch inside out); directions never change.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

__all__ = [
    "BALL_RADII",
    "BALL_RADIUS",
    "MAX_CELLS",
    "PATCH_K",
    "exterior_votes",
    "resign_by_exterior",
]

log = logging.getLogger(__name__)

#: Radius [voxels] of the ball whose reach from outside is the exterior: gaps in the
#: occupied shell narrower than its diameter do not let it in (1.5 leaked into the bodies
#: of the held-out eared and legs shapes at 3,000 points; 2.5 kept both sealed).
BALL_RADIUS = 2.5
#: The balls tried in turn [voxels] until the votes look closed: a leak floods the inside at
#: once (the ears body of ``tests/test_exterior_signs.py`` at 5,000 and 6,000 points, 5 of 12
#: samples: 21-22 % of the points vote right with the true normals at 2.5 voxels, 99-100 %
#: at 3.5; at 4,000 points none leaks). Up to 4.5: a gap that lets that in is a hole.
BALL_RADII = (BALL_RADIUS, 3.5, 4.5)
#: The grid's longest side [voxels] at one point spacing a voxel. A scan longer than this
#: many spacings (dense or large: bunny-clean's 40,000 points span 277) gets no vote: its
#: thin parts are many spacings thick, which the orientation's thin-part pairs already sign
#: (the held-out thin shapes at 40,000 points are watertight without votes), while the
#: distance transforms would cost seconds (3.1M voxels on bunny-clean at a coarser voxel:
#: 1.7-2.5 s on a loaded 2-core machine). Sparse scans, where the votes matter, span far
#: fewer (eared and legs at 3,000 points: about 67; bunny-sparse 63).
MAX_CELLS = 160
#: Search along each side of a point [voxels], in half-voxel steps.
REACH = 8.0
#: A side wins when its first outside voxel is at least this much nearer [voxels].
MARGIN = 1.0
#: The votes are used when at least this fraction of the points vote ...
MIN_DECIDED = 0.5
#: ... and at least this fraction of the votes agree with the signs already found.
MIN_AGREE = 0.8
#: A point is turned over when at least half of its this many nearest points (itself among
#: them) vote against their normals: a patch inside out (held-out eared and legs at 3,000
#: points: no point turned over wrongly, against 4 and 5 turning over every point voted against).
PATCH_K = 7
#: Points per block of the steps along the normals (memory: block x 2 x 16 x 3 ints).
BLOCK = 65_536


def exterior_votes(
    points: np.ndarray, normals: np.ndarray, spacing: float, ball: float = BALL_RADIUS
) -> np.ndarray:
    """Per point: +1 when the outside is nearer along ``+n``, -1 when nearer along ``-n``,
    0 when neither side wins (see the module docstring), the outside being what a ball of
    radius ``ball`` [voxels] reaches.

    Parameters
    ----------
    points : (n, 3) float64 [length]
    normals : (n, 3) float64, unit
    spacing : float [length]
        The data's median nearest-neighbour distance: the voxel. No point votes when the
        data spans more than ``MAX_CELLS`` voxels (less the padding).
    """
    return next(_votes_by_ball(points, normals, spacing, (ball,)))


def _votes_by_ball(
    points: np.ndarray, normals: np.ndarray, spacing: float, balls: tuple[float, ...]
) -> Iterator[np.ndarray]:
    """:func:`exterior_votes` for each of ``balls`` in turn, computed when asked for. The
    occupancy grid and the distance transform of its free space do not depend on the ball:
    they are built once, padded for the largest ball that passes the size test (more
    padding adds free space far outside only, so every ball's votes are as on its own
    grid)."""
    n = len(points)
    pads = [int(np.ceil(ball)) + 3 for ball in balls]  # each ball fits round the data
    if n == 0 or not np.isfinite(spacing) or spacing <= 0.0:
        fits = [False] * len(balls)
    else:
        lo = points.min(axis=0)
        extent = points.max(axis=0) - lo
        h = float(spacing)
        # dense or large: no vote (``MAX_CELLS``)
        fits = [float(extent.max()) <= h * (MAX_CELLS - 2 * pad) for pad in pads]
    if not any(fits):
        for _ in balls:
            yield np.zeros(n, dtype=np.int8)
        return
    pad = max(p for p, ok in zip(pads, fits, strict=True) if ok)
    shape = np.ceil(extent / h).astype(np.int64) + 2 * pad + 1
    occupied = np.zeros(tuple(shape), dtype=bool)
    cells = np.floor((points - lo) / h).astype(np.int64) + pad
    occupied[cells[:, 0], cells[:, 1], cells[:, 2]] = True
    occupied = ndimage.binary_dilation(occupied, structure=np.ones((3, 3, 3), dtype=bool))
    free = ~occupied
    del occupied
    clearance = ndimage.distance_transform_edt(free)
    for ball, ok in zip(balls, fits, strict=True):
        if not ok:
            yield np.zeros(n, dtype=np.int8)
            continue
        labels, _ = ndimage.label(clearance > ball)
        outer = labels[0, 0, 0]  # the padded corner is always far outside
        if outer == 0:
            yield np.zeros(n, dtype=np.int8)
            continue
        outside = (ndimage.distance_transform_edt(labels != outer) <= ball + 0.5) & free
        del labels
        yield _first_outside(points, normals, outside, lo, h, pad)


def _first_outside(
    points: np.ndarray,
    normals: np.ndarray,
    outside: np.ndarray,
    lo: np.ndarray,
    h: float,
    pad: int,
) -> np.ndarray:
    """The votes of :func:`exterior_votes` from the grid's ``outside`` voxels (``h`` a
    voxel, the data's lower corner ``lo`` at voxel ``pad``)."""
    n = len(points)
    steps = np.arange(0.5, REACH + 1e-9, 0.5)
    top = np.asarray(outside.shape) - 1
    votes = np.zeros(n, dtype=np.int8)
    for a in range(0, n, BLOCK):
        b = min(a + BLOCK, n)
        first = []
        for sign in (1.0, -1.0):
            q = points[a:b, None, :] + (sign * h) * steps[None, :, None] * normals[a:b, None, :]
            c = np.clip(np.floor((q - lo) / h).astype(np.int64) + pad, 0, top)
            hit = outside[c[..., 0], c[..., 1], c[..., 2]]
            first.append(np.where(hit.any(axis=1), steps[np.argmax(hit, axis=1)], np.inf))
        front, back = first
        # a side wins only when it reaches the outside (two sides that never do tie: no vote)
        up = np.isfinite(front) & (front + MARGIN <= back)
        down = np.isfinite(back) & (back + MARGIN <= front)
        votes[a:b] = np.where(up, 1, np.where(down, -1, 0))
    return votes


def resign_by_exterior(
    points: np.ndarray, normals: np.ndarray, spacing: float, tree: cKDTree | None = None
) -> tuple[np.ndarray, int]:
    """Normals turned over where the exterior votes against them, when the data looks
    closed (``MIN_DECIDED``, ``MIN_AGREE``) to one of the balls ``BALL_RADII`` (the first
    that does); and how many were turned over. ``tree``: a k-d tree of ``points`` (the
    fit's shared one; built here when None)."""
    for ball, votes in zip(
        BALL_RADII, _votes_by_ball(points, normals, spacing, BALL_RADII), strict=True
    ):
        decided = int(np.count_nonzero(votes))
        n_for = int(np.count_nonzero(votes > 0))
        if decided >= MIN_DECIDED * len(points) and n_for >= MIN_AGREE * decided:
            break
        log.debug(
            "exterior signs: ball %.1f not used (%d of %d vote, %d for)",
            ball,
            decided,
            len(votes),
            n_for,
        )
    else:
        return normals, 0
    # a patch turned inside out, not a lone point: its neighbours vote against it too (a lone
    # wrong vote near a thin part's rim is as likely as a lone wrong sign, which later stages
    # outvote; a body with one ear at 2,000 points lost its watertightness to one such flip)
    k = min(PATCH_K, len(points))
    _, idx = (cKDTree(points) if tree is None else tree).query(points, k=k)
    flip = (votes < 0) & (np.mean(votes[idx.reshape(len(points), k)] < 0, axis=1) >= 0.5)
    n_flip = int(np.count_nonzero(flip))
    log.debug("exterior signs: %d of %d normals turned over", n_flip, len(votes))
    return np.where(flip[:, None], -normals, normals), n_flip
