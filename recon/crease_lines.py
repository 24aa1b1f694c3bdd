"""Crease lines and corners in the fit's normalised units (r0 = 1), between the detection
(:mod:`recon.creases`) and the crease field (:mod:`recon.crease_surface`).

The crease samples each carry a foot on their line and the line's direction; this module
works on those lines only (no data points, no particles):

- :func:`smooth_lines`: each sample's line refitted along itself to its line's feet;
- :func:`refine_corners`: detected corners moved to the meeting point of their lines;
- :func:`meeting_corners`: corners added where three lines meet and one ends;
- :func:`extend_to_corners`: lines continued through their corners (samples near a corner,
  tilted by a third face, replaced).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["extend_to_corners", "meeting_corners", "refine_corners", "smooth_lines"]

#: Crease lines are continued to a corner (:func:`extend_to_corners`) from their samples
#: within EXTEND_RADIUS [r0] of it that pass within EXTEND_OFFSET [r0] of it, every
#: EXTEND_STEP [r0]; samples whose lines turn by less than EXTEND_SAME_LINE_DEG are one line.
EXTEND_RADIUS = 6.0
EXTEND_OFFSET = 0.5
EXTEND_STEP = 0.5
EXTEND_SAME_LINE_DEG = 10.0
#: Samples within CORNER_ZONE [r0] of a corner are replaced by the continued lines (about the
#: radius of the REFINE_K neighbourhood at the default spacing: nearer, it holds a third face).
CORNER_ZONE = 2.5
#: Corners are moved to the point nearest (least squares) to the lines of the crease samples
#: within EXTEND_RADIUS of them that lie at least CORNER_LINE_MIN [r0] from them along their
#: line (nearer, the third face bends the fit); when those lines run in at least two
#: directions (the smallest eigenvalue of the normal matrix at least CORNER_MIN_EIGEN per line)
#: and the move is at most CORNER_MAX_MOVE [r0] (:func:`refine_corners`).
CORNER_LINE_MIN = 1.0
CORNER_MIN_EIGEN = 0.1
CORNER_MAX_MOVE = 2.5
#: ... each line of at least CORNER_FAMILY_MIN samples, the samples' lines passing within the
#: gates [r0] of the current point, one gate per round (:func:`refine_corners`).
CORNER_FAMILY_MIN = 3
CORNER_GATES = (1.5, 0.75, 0.5)
#: Corners where crease lines meet (:func:`meeting_corners`): three lines turning pairwise by
#: more than MEET_MIN_DEG, not in one plane (MEET_MIN_SPREAD, see :func:`_line_ends_at`), at
#: least MEET_MIN_PAIRS sample pairs proposing the point, none of it within MEET_CLEARANCE
#: [r0] of a known corner.
MEET_MIN_DEG = 25.0
MEET_MIN_PAIRS = 5
MEET_CLEARANCE = 2.0
MEET_MIN_SPREAD = 0.1
#: Lines are smoothed along themselves (:func:`smooth_lines`) over the samples within
#: SMOOTH_RADIUS [r0] (at least SMOOTH_MIN of them), with a quadratic when they reach
#: SMOOTH_SIDE [r0] to both sides.
SMOOTH_RADIUS = 6.0
SMOOTH_SIDE = 1.0
SMOOTH_MIN = 4


def smooth_lines(
    feet: np.ndarray, direction: np.ndarray, good: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Each sample's line refitted to the feet of its line's samples around it (local
    polynomial regression along the line). One sample's planes come from about 2.5 r0 of data
    around its foot; under noise its foot scatters by a tenth of r0, and its neighbours along
    the line, with their own data, scatter independently once a neighbourhood apart.

    The samples (``good`` only) within ``SMOOTH_RADIUS`` of a sample whose directions are
    within ``EXTEND_SAME_LINE_DEG`` of its own and whose feet lie within ``EXTEND_OFFSET`` of
    its line give the offsets ``o(t)`` of their feet from its line against ``t`` along it;
    ``o`` is fitted by least squares with a quadratic when they reach at least
    ``SMOOTH_SIDE`` to both sides (exact on a circular rim to second order), else with a
    straight line (a line's end); the foot moves to ``o(0)`` and the direction turns by
    ``o'(0)``. Exact lines stay as they are."""
    out, out_d = feet.copy(), direction.copy()
    idx = np.flatnonzero(good)
    if len(idx) < SMOOTH_MIN:
        return out, out_d
    f, d = feet[idx], direction[idx]
    cos_same = np.cos(np.radians(EXTEND_SAME_LINE_DEG))
    for k, nb in enumerate(cKDTree(f).query_ball_point(f, SMOOTH_RADIUS)):
        nb = np.asarray(nb, dtype=np.int64)
        nb = nb[np.abs(d[nb] @ d[k]) > cos_same]
        rel = f[nb] - f[k]
        t = rel @ d[k]
        perp = rel - t[:, None] * d[k]
        on = np.linalg.norm(perp, axis=1) < EXTEND_OFFSET
        t, perp = t[on], perp[on]
        if len(t) < SMOOTH_MIN:
            continue
        degree = 2 if min(-t.min(), t.max()) >= SMOOTH_SIDE else 1
        coef, *_ = np.linalg.lstsq(np.vander(t, degree + 1), perp, rcond=None)
        out[idx[k]] = f[k] + coef[-1]
        turned = d[k] + coef[-2]
        out_d[idx[k]] = turned / np.linalg.norm(turned)
    return out, out_d


def extend_to_corners(
    feet: np.ndarray,
    direction: np.ndarray,
    side: np.ndarray,
    convex: np.ndarray,
    corners: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Continue each crease line that runs into a corner up to it, through it.

    Detection stops about half a neighbourhood short of a corner (three faces in view), and
    the samples it keeps within ``CORNER_ZONE`` of a corner have a third face in their
    neighbourhood, which can tilt their refit line by 10 deg and put their foot half a spacing
    off the edge. So the samples within ``CORNER_ZONE`` of a corner are dropped, and every line
    running into the corner (samples within ``EXTEND_RADIUS`` whose lines pass within
    ``EXTEND_OFFSET`` of it, grouped by direction within ``EXTEND_SAME_LINE_DEG`` and by the
    side of the corner they lie on, so a line through the corner is continued from both sides)
    gets samples every ``EXTEND_STEP`` from the corner (not on it) along the line's mean
    direction up to its sample nearest to the corner (with that sample's planes)."""
    if len(corners) == 0 or len(feet) == 0:
        return feet, direction, side, convex
    ctree = cKDTree(corners)
    dist, _ = ctree.query(feet, k=1)
    keep = dist >= CORNER_ZONE
    feet, direction, side, convex = feet[keep], direction[keep], side[keep], convex[keep]
    if len(feet) == 0:
        return feet, direction, side, convex
    tree = cKDTree(feet)
    add: list[int] = []
    pos: list[np.ndarray] = []
    dirs: list[np.ndarray] = []
    cos_same = np.cos(np.radians(EXTEND_SAME_LINE_DEG))
    for c in corners:
        near = np.asarray(tree.query_ball_point(c, EXTEND_RADIUS), dtype=np.int64)
        if len(near) == 0:
            continue
        rel = c - feet[near]
        t = np.einsum("ij,ij->i", rel, direction[near])
        off = np.linalg.norm(rel - t[:, None] * direction[near], axis=1)
        near = near[off < EXTEND_OFFSET]
        dist_c = np.linalg.norm(feet[near] - c, axis=1)
        near = near[np.argsort(dist_c, kind="stable")]
        free = np.ones(len(near), dtype=bool)
        for k, j in enumerate(near):
            if not free[k]:
                continue
            ahead = (feet[near] - c) @ direction[j]  # same line and side of the corner
            same = free & (np.abs(direction[near] @ direction[j]) > cos_same)
            same &= ahead * ahead[k] > 0.0
            free &= ~same
            members = near[same]
            sign = np.where(direction[members] @ direction[j] < 0.0, -1.0, 1.0)
            d = (direction[members] * sign[:, None]).sum(axis=0)
            d /= np.linalg.norm(d)
            # from the corner towards the line's samples, up to the nearest one
            reach = float((feet[j] - c) @ d)
            if reach < 0.0:
                d, reach = -d, -reach
            # (not on the corner itself: a particle past the corner would snap onto the
            # line's continuation beyond it; the corner has its own particle)
            for st in np.arange(EXTEND_STEP, reach - 0.5 * EXTEND_STEP, EXTEND_STEP):
                add.append(int(j))
                pos.append(c + st * d)
                dirs.append(d)
    if not add:
        return feet, direction, side, convex
    idx = np.asarray(add, dtype=np.int64)
    return (
        np.ascontiguousarray(np.vstack([feet, np.asarray(pos)])),
        np.ascontiguousarray(np.vstack([direction, np.asarray(dirs)])),
        np.ascontiguousarray(np.concatenate([side, side[idx]])),
        np.concatenate([convex, convex[idx]]),
    )


def _line_families(d: np.ndarray, cos_same: float):
    """Group unit line directions ``d`` (either sign) that agree within ``cos_same``, in order
    of first appearance; yields, for each group of at least ``CORNER_FAMILY_MIN``, its mask,
    the signs that align its members with its first one, and its mean unit direction."""
    free = np.ones(len(d), dtype=bool)
    for i in range(len(d)):
        if not free[i]:
            continue
        same = free & (np.abs(d @ d[i]) > cos_same)
        free &= ~same
        if np.count_nonzero(same) < CORNER_FAMILY_MIN:
            continue
        sign = np.where(d[same] @ d[i] < 0.0, -1.0, 1.0)
        dl = (d[same] * sign[:, None]).sum(axis=0)
        yield same, sign, dl / np.linalg.norm(dl)


def meeting_corners(feet: np.ndarray, direction: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """Corners the detection missed, where crease lines meet (its three-plane test misses
    corners whose faces turn by little, e.g. 60 deg, or where a thin face meets).

    Two samples whose lines turn by more than ``MEET_MIN_DEG``, pass within ``EXTEND_OFFSET``
    of each other at a point within ``EXTEND_RADIUS`` of both feet, propose that point. The
    proposals farther than ``MEET_CLEARANCE`` from every known corner are grouped (within
    ``MEET_CLEARANCE`` of a group's first), a group of at least ``MEET_MIN_PAIRS`` proposals
    gives its median, refined like a detected corner (:func:`refine_corners`), and kept when
    the refinement finds two lines there and at least one of them ends there (its samples
    near the point all on one side of it, beyond ``-EXTEND_OFFSET``): lines that only pass
    near each other make no corner. Returns ``(c, 3)`` new corners [r0]."""
    if len(feet) < 2:
        return np.zeros((0, 3))
    tree = cKDTree(feet)
    pairs = tree.query_pairs(2.0 * EXTEND_RADIUS, output_type="ndarray")
    if len(pairs) == 0:
        return np.zeros((0, 3))
    i, j = pairs[:, 0], pairs[:, 1]
    di, dj = direction[i], direction[j]
    c = np.einsum("ij,ij->i", di, dj)
    turn = np.abs(c) < np.cos(np.radians(MEET_MIN_DEG))
    i, j, di, dj, c = i[turn], j[turn], di[turn], dj[turn], c[turn]
    # closest points of the lines x_i + s d_i and x_j + u d_j
    w = feet[i] - feet[j]
    bi = np.einsum("ij,ij->i", di, w)
    bj = np.einsum("ij,ij->i", dj, w)
    det = 1.0 - c * c
    s_i = (c * bj - bi) / det
    u_j = (bj - c * bi) / det
    pi = feet[i] + s_i[:, None] * di
    pj = feet[j] + u_j[:, None] * dj
    p = 0.5 * (pi + pj)
    ok = (np.linalg.norm(pi - pj, axis=1) < EXTEND_OFFSET) & (np.abs(s_i) < EXTEND_RADIUS)
    ok &= np.abs(u_j) < EXTEND_RADIUS
    p = p[ok]
    if len(corners) and len(p):
        dist, _ = cKDTree(corners).query(p, k=1)
        p = p[dist > MEET_CLEARANCE]
    out: list[np.ndarray] = []
    free = np.ones(len(p), dtype=bool)
    for k in range(len(p)):
        if not free[k]:
            continue
        group = free & (np.linalg.norm(p - p[k], axis=1) < MEET_CLEARANCE)
        free &= ~group
        if np.count_nonzero(group) < MEET_MIN_PAIRS:
            continue
        guess = np.median(p[group], axis=0)
        if any(np.linalg.norm(q - guess) < MEET_CLEARANCE for q in out):
            continue
        x = _refine_corner(feet, direction, tree, guess)
        if x is None or not _line_ends_at(feet, direction, tree, x):
            continue
        out.append(x)
    return np.asarray(out, dtype=np.float64).reshape(-1, 3)


def _line_ends_at(feet: np.ndarray, direction: np.ndarray, tree: cKDTree, x: np.ndarray) -> bool:
    """Is ``x`` a corner of a solid, where three crease lines not in one plane meet: the
    samples within ``EXTEND_RADIUS`` whose lines pass within ``EXTEND_OFFSET`` of it, grouped
    by direction (lines of at least ``CORNER_FAMILY_MIN`` samples), make at least three lines
    that pairwise turn by more than ``MEET_MIN_DEG`` and span space (the smallest eigenvalue
    of ``sum d d^T`` at least ``MEET_MIN_SPREAD``), and one of them ends at ``x`` (its samples
    all on one side of it, none beyond ``EXTEND_OFFSET`` on the other). A curved crease with
    a gap in its detection (a hole's rim) gives lines in one plane that meet there, and lines
    that cross without ending make no corner."""
    near = np.asarray(tree.query_ball_point(x, EXTEND_RADIUS), dtype=np.int64)
    d = direction[near]
    rel = feet[near] - x
    t = np.einsum("ij,ij->i", rel, d)
    off = np.linalg.norm(rel - t[:, None] * d, axis=1)
    m = off < EXTEND_OFFSET
    d, t = d[m], t[m]
    cos_same = np.cos(np.radians(EXTEND_SAME_LINE_DEG))
    lines: list[np.ndarray] = []
    ends = False
    for same, sign, dl in _line_families(d, cos_same):
        lines.append(dl)
        ts = t[same] * sign
        ends |= bool(ts.min() > -EXTEND_OFFSET or ts.max() < EXTEND_OFFSET)
    if len(lines) < 3 or not ends:
        return False
    u = np.asarray(lines)
    cos = np.abs(u @ u.T)[np.triu_indices(len(u), 1)]
    if np.any(cos >= np.cos(np.radians(MEET_MIN_DEG))):
        return False
    # not all in one plane (lines of one face, e.g. a rim with a gap in its detection)
    return bool(np.linalg.eigvalsh(u.T @ u)[0] >= MEET_MIN_SPREAD)


def refine_corners(feet: np.ndarray, direction: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """Each corner moved to the least-squares meeting point of the crease lines running into it.

    The detection's corner is the median of three-plane intersections of single
    neighbourhoods, which can sit a spacing off under noise. The samples within
    ``EXTEND_RADIUS`` of the corner whose lines pass within a gate of it (and that lie at least
    ``CORNER_LINE_MIN`` from it along their line) are grouped into lines by direction (within
    ``EXTEND_SAME_LINE_DEG``); each line with at least ``CORNER_FAMILY_MIN`` samples is the
    line through its samples' mean foot along their mean direction (averaging the noise of
    single samples), and the corner is the point ``x`` minimising
    ``sum_lines |(I - d d^T)(x - c)|^2`` (one term per line, so a long run of samples on one
    line does not outweigh the others). This is repeated with the gates
    ``CORNER_GATES`` [r0] from the new point, so a corner detected a spacing off first finds
    its lines, then drops samples of lines that miss it. A corner keeps its place when fewer
    than two lines in different directions (the smallest eigenvalue of the normal matrix below
    ``CORNER_MIN_EIGEN`` per line) meet there, or the point is farther than
    ``CORNER_MAX_MOVE`` from the detected one."""
    if len(corners) == 0 or len(feet) == 0:
        return corners
    out = corners.copy()
    tree = cKDTree(feet)
    for c in range(len(corners)):
        x = _refine_corner(feet, direction, tree, corners[c])
        if x is not None:
            out[c] = x
    return out


def _refine_corner(
    feet: np.ndarray, direction: np.ndarray, tree: cKDTree, corner: np.ndarray
) -> np.ndarray | None:
    """One corner of :func:`refine_corners` (None: it keeps its place)."""
    cos_same = np.cos(np.radians(EXTEND_SAME_LINE_DEG))
    x, found = corner, None
    for gate in CORNER_GATES:
        near = np.asarray(tree.query_ball_point(x, EXTEND_RADIUS), dtype=np.int64)
        d = direction[near]
        rel = x - feet[near]
        t = np.einsum("ij,ij->i", rel, d)
        off = np.linalg.norm(rel - t[:, None] * d, axis=1)
        m = (off < gate) & (np.abs(t) >= CORNER_LINE_MIN)
        near, d = near[m], d[m]
        a = np.zeros((3, 3))
        b = np.zeros(3)
        lines = 0
        for same, _, dl in _line_families(d, cos_same):
            proj = np.eye(3) - np.outer(dl, dl)
            a += proj
            b += proj @ feet[near[same]].mean(axis=0)
            lines += 1
        if lines < 2 or np.linalg.eigvalsh(a)[0] < CORNER_MIN_EIGEN * lines:
            break  # one direction: the lines do not meet in a point
        new = np.linalg.solve(a, b)
        if np.linalg.norm(new - corner) > CORNER_MAX_MOVE:
            break
        x = found = new
    return found
