"""Creases in the fit: one plane per side near a crease, and crease particles (issue 12).

Built from the detected creases (:mod:`recon.creases`) in the fit's normalised units (r0 = 1).
Each crease data point gives a *crease sample*: a foot ``x0`` on its crease line, the line's
direction ``d`` and the two side planes through the line, with unit normals ``n_a, n_b``
(oriented like the data normals) fitted to the two Gauss-map clusters of its neighbourhood.
A sample is *convex* when its neighbourhood lies behind both planes (the centroid ``c`` of the
data around it has ``(c - x0) . (n_a + n_b) < 0``), *concave* otherwise.

**Per-side data surface** (:meth:`CreaseField.adjust`). Near a crease the data is not one
quadric: a particle within ``reach`` of a crease sample is anchored to the closest point of the
*wedge* the two side planes form, with face a restricted to its side of plane b::

    convex:   {x : (x - x0) . n_a = 0, (x - x0) . n_b <= 0}   (and a <-> b)
    concave:  {x : (x - x0) . n_a = 0, (x - x0) . n_b >= 0}

plus the line itself. The anchor normal is the face's normal, or on the line the direction
from the line to the particle (the bisector ``n_a + n_b`` when it is on the line). A particle
is thus pulled onto the face whose data it sits over, never onto a quadric bent across the
edge, and growth candidates (projected with the same anchors) land on their face's plane.

**Crease particles** (:meth:`CreaseField.constrain`). Particles within ``snap`` of a crease
line are moved onto it, and the particle nearest to a detected corner (within
``CORNER_SNAP`` spacings) onto the corner, and marked *unoriented*: they keep the spacing
interaction and neither give nor take the smoothing terms (S&T92 §6, Fig. 7). A particle is
snapped only when no other particle lies within ``SNAP_CLEARANCE`` x its spacing of its new
place, so a crease line carries particles at the local spacing, never two on one spot. Their
normal is the bisector of the side normals (it orients the triangulation; unoriented particles
keep their frame in the dynamics).

References
----------
[ST92] R. Szeliski, D. Tonnesen. "Surface Modeling with Oriented Particle Systems".
       SIGGRAPH '92, §6 (creases: unoriented particles).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from .crease_lines import (
    extend_to_corners,
    meeting_corners,
    refine_corners,
    smooth_lines,
)
from .creases import CREASE, Creases
from .state import ParticleState

__all__ = ["CreaseField", "SNAP_CLEARANCE"]

#: A particle is snapped onto a crease only when no other particle is closer than this
#: many spacings to its new place.
SNAP_CLEARANCE = 0.6
#: ... and no particle left where it was ends closer than this many spacings to a snapped one.
SNAP_MIN_GAP = 0.5
#: The wedge replaces a particle's anchor only when its foot is within this distance [r0] of
#: the data surface's foot (a quadric rounds a sharp edge by a fraction of r0; farther, the
#: wedge belongs to another crease, e.g. one meeting it at a corner).
WEDGE_TOLERANCE = 0.75
#: A particle within this many spacings of a crease line whose place on the line is taken (a
#: crease particle closer than SNAP_CLEARANCE) is removed: it would sit on the crease beside
#: it and make triangles that cut the edge.
DROP_DISTANCE = 0.3
#: The particle nearest to a corner is snapped onto it when within this many spacings (a
#: corner is a point: its nearest particle may be up to one spacing away).
CORNER_SNAP = 0.5
#: After the dynamics, a corner with no particle within CORNER_TOUCH spacings gets one: its
#: nearest particle when within CORNER_MERGE spacings, else a new one (:meth:`_occupy_corners`).
CORNER_TOUCH = 0.05
CORNER_MERGE = 0.3
#: ... then no foot of a crease sample is left farther than FILL_GAP spacings from a crease
#: particle: the nearest particle within FILL_MERGE spacings moves onto the foot, or a new one
#: is added (:meth:`_fill_lines`); feet with no particle within FILL_SHEET spacings are left.
FILL_GAP = 0.75
FILL_MERGE = 0.5
FILL_SHEET = 1.5
#: Neighbours of a crease sample's foot: their centroid decides whether it is convex, and they
#: refit its two side planes (about 2.5 r0 around the foot at the default spacing of 2.5 data
#: spacings: the fit averages sensor noise over a few spacings of line; 32 left the line
#: jittering by a tenth of r0 at 0.25 % noise).
REFINE_K = 128
#: A refit side plane needs this many member points; samples with fewer are dropped.
REFINE_MIN_MEMBERS = 6
#: Rounds of the two-plane refit (assign to the nearer plane, refit by PCA).
REFINE_ROUNDS = 8
#: Neighbours farther than 3 median residuals + REFINE_FLOOR (at most REFINE_OUTLIER) from
#: both planes are left out of a round of the refit [r0].
REFINE_FLOOR = 0.02
REFINE_OUTLIER = 0.5


@dataclass
class CreaseField:
    """Crease lines and corners of the data in normalised units (r0 = 1).

    Attributes
    ----------
    feet : (m, 3) float64 [r0]
        A point of each crease sample's line.
    direction : (m, 3) float64
        Unit line directions.
    side : (m, 2, 3) float64
        Unit side normals (outward when the data normals are).
    convex : (m,) bool
    corners : (c, 3) float64 [r0]
    reach : float [r0]
        Particles within this distance of a crease sample's foot use its side planes.
    snap : float [r0]
        Particles within this distance of a crease line (of a corner) become crease particles.
    """

    feet: np.ndarray
    direction: np.ndarray
    side: np.ndarray
    convex: np.ndarray
    corners: np.ndarray
    reach: float
    snap: float

    def __post_init__(self) -> None:
        self._tree = cKDTree(self.feet) if len(self.feet) else None
        self._corner_tree = cKDTree(self.corners) if len(self.corners) else None

    @classmethod
    def build(
        cls,
        found: Creases,
        points: np.ndarray,
        scale: float,
        reach: float = 2.5,
        snap: float = 0.5,
    ) -> CreaseField:
        """Crease samples from a detection on the input points.

        Parameters
        ----------
        found : Creases
            Detection on the input points (input units).
        points : (n, 3) float64 [r0]
            The same points in normalised units (``input / scale``).
        scale : float [length]
            r0: converts ``found``'s feet and corners to normalised units.
        """
        sel = np.flatnonzero((found.labels == CREASE) & np.isfinite(found.foot).all(axis=1))
        feet = np.ascontiguousarray(found.foot[sel] / scale)
        side = np.ascontiguousarray(found.side_normals[sel, :2])
        direction = np.ascontiguousarray(found.direction[sel])
        convex = np.zeros(len(sel), dtype=bool)
        if len(sel):
            # the neighbourhood of the foot (on the line: both sides in it) refits the planes
            k = int(min(REFINE_K, len(points)))
            _, idx = cKDTree(points).query(feet, k=k)
            idx = idx.reshape(len(sel), k)
            centroid = points[idx].mean(axis=1)
            convex = np.einsum("ij,ij->i", centroid - feet, side[:, 0] + side[:, 1]) < 0.0
            feet, side, direction, good = _refine_planes(points, sel, idx, feet, side)
            feet, direction = smooth_lines(feet, direction, good)
            feet, side, direction, convex = feet[good], side[good], direction[good], convex[good]
        corners = np.ascontiguousarray(np.asarray(found.corners, dtype=np.float64).reshape(-1, 3))
        corners = refine_corners(feet, direction, corners / scale)
        corners = np.vstack([corners, meeting_corners(feet, direction, corners)])
        feet, direction, side, convex = extend_to_corners(feet, direction, side, convex, corners)
        return cls(feet, direction, side, convex, corners, reach, snap)

    @property
    def n_samples(self) -> int:
        return len(self.feet)

    # -- the per-side data surface -------------------------------------------------------
    def nearest_sample(self, positions: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
        """Index of the nearest crease sample within ``radius`` of each position (-1: none)
        and the distance to its foot."""
        q = len(positions)
        if self._tree is None or q == 0:
            return np.full(q, -1, dtype=np.int64), np.full(q, np.inf)
        dist, idx = self._tree.query(positions, k=1, distance_upper_bound=radius)
        idx = np.where(np.isfinite(dist), idx, -1).astype(np.int64)
        return idx, dist

    def wedge(
        self, positions: np.ndarray, sample: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Closest point of each position on its sample's wedge, the normal there, and
        whether it lies on the line (the closest point is the line's)."""
        x0, d = self.feet[sample], self.direction[sample]
        na, nb = self.side[sample, 0], self.side[sample, 1]
        sign = np.where(self.convex[sample], 1.0, -1.0)
        r = positions - x0
        t = np.einsum("ij,ij->i", r, d)
        line = x0 + t[:, None] * d
        da = np.einsum("ij,ij->i", r, na)
        db = np.einsum("ij,ij->i", r, nb)
        c = np.einsum("ij,ij->i", na, nb)
        # a face foot is on the face when it is on the right side of the other plane
        ok_a = sign * (db - da * c) <= 0.0
        ok_b = sign * (da - db * c) <= 0.0
        radial = positions - line
        e = np.linalg.norm(radial, axis=1)
        # ties go to the line (a particle on it keeps the bisector as its normal)
        cost = np.stack([e, np.where(ok_a, np.abs(da), np.inf), np.where(ok_b, np.abs(db), np.inf)])
        pick = (np.argmin(cost, axis=0) + 2) % 3  # 0: face a, 1: face b, 2: the line
        foot = np.where(
            (pick == 0)[:, None],
            positions - da[:, None] * na,
            np.where((pick == 1)[:, None], positions - db[:, None] * nb, line),
        )
        bis = na + nb
        bis /= np.maximum(np.linalg.norm(bis, axis=1, keepdims=True), 1e-300)
        out = np.where(e[:, None] > 1e-9, radial / np.maximum(e, 1e-300)[:, None], bis)
        out *= np.where(np.einsum("ij,ij->i", out, bis) < 0.0, -1.0, 1.0)[:, None]
        nrm = np.where((pick == 0)[:, None], na, np.where((pick == 1)[:, None], nb, out))
        return foot, nrm, pick == 2

    def adjust(
        self,
        positions: np.ndarray,
        normals: np.ndarray | None,
        foot: np.ndarray,
        nrm: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Replace the anchors (``foot``, ``nrm``) of positions near a crease by the closest
        point of the crease's wedge (see the module docstring); others are returned as given.
        With ``normals``, only particles on the sheet the sides face (``n . (n_a + n_b) > 0``)
        are changed."""
        sample, _ = self.nearest_sample(positions, self.reach)
        use = sample >= 0
        if normals is not None and use.any():
            s = sample[use]
            agree = np.einsum("ij,ij->i", normals[use], self.side[s, 0] + self.side[s, 1]) > 0.0
            use[np.flatnonzero(use)[~agree]] = False
        if not use.any():
            return foot, nrm
        foot, nrm = foot.copy(), nrm.copy()
        sel = np.flatnonzero(use)
        f, n, _ = self.wedge(positions[sel], sample[sel])
        # a wedge far from the data's own surface is another crease's (near a corner): keep
        ok = np.linalg.norm(f - foot[sel], axis=1) <= WEDGE_TOLERANCE
        foot[sel[ok]] = f[ok]
        nrm[sel[ok]] = n[ok]
        return foot, nrm

    def line_candidates(self) -> tuple[np.ndarray, np.ndarray]:
        """Growth candidates on the crease lines: every sample's foot, with the bisector of its
        side normals (growth keeps those at least ``reject_radius`` from every particle, so
        a crease line fills at the local spacing), and the corners."""
        bis = self.side[:, 0] + self.side[:, 1]
        bis /= np.maximum(np.linalg.norm(bis, axis=1, keepdims=True), 1e-300)
        pos, nrm = self.feet, bis
        if len(self.corners) and len(self.feet):
            # a corner takes the bisector of its nearest sample's sides
            _, near = self._tree.query(self.corners, k=1)
            pos = np.vstack([self.corners, pos])
            nrm = np.vstack([bis[near], nrm])
        return np.ascontiguousarray(pos), np.ascontiguousarray(nrm)

    # -- crease particles ----------------------------------------------------------------
    def constrain(self, state: ParticleState, settle: bool = False) -> np.ndarray:
        """Snap particles near a crease line or corner onto it and mark them unoriented; every
        other particle is marked oriented; particles within ``DROP_DISTANCE`` of a line where
        a crease particle already sits are removed. Returns the mask of crease particles (over
        the particles that remain).

        ``settle``: only the particles that are crease particles already (unoriented) are put
        back onto their line or corner (a final touch with no dynamics after it: nothing jumps).
        """
        n = state.n
        current = ~np.asarray(state.is_oriented, dtype=bool)
        crease = np.zeros(n, dtype=bool)
        if n == 0 or (self._tree is None and self._corner_tree is None):
            return crease
        pos = state.position.copy()
        nrm = state.normal
        rest = np.asarray(state.rest, dtype=np.float64)
        target = pos.copy()
        new_normal = nrm.copy()
        order_key = np.full(n, np.inf)
        at_corner = np.zeros(n, dtype=bool)
        # corners first: the nearest particle to each corner, within CORNER_SNAP spacings
        if self._corner_tree is not None:
            dist, idx = cKDTree(pos).query(
                self.corners, k=1, distance_upper_bound=CORNER_SNAP * float(np.median(rest))
            )
            for c, (dc, i) in enumerate(zip(dist, idx, strict=True)):
                if np.isfinite(dc) and order_key[i] == np.inf and (current[i] or not settle):
                    target[i] = self.corners[c]
                    at_corner[i] = True
                    order_key[i] = -1.0 + dc * 1e-3
        # lines: particles within snap of their nearest sample's line
        sample, _ = self.nearest_sample(pos, self.reach)
        cand = np.flatnonzero((sample >= 0) & (order_key == np.inf))
        if len(cand):
            s = sample[cand]
            bis = self.side[s, 0] + self.side[s, 1]
            agree = np.einsum("ij,ij->i", nrm[cand], bis) > 0.0
            r = pos[cand] - self.feet[s]
            t = np.einsum("ij,ij->i", r, self.direction[s])
            line = self.feet[s] + t[:, None] * self.direction[s]
            e = np.linalg.norm(pos[cand] - line, axis=1)
            # settling puts every crease particle back on its line, however far it drifted
            near = (e < self.snap) | (settle & current[cand])
            ok = agree & near & (current[cand] | (not settle))
            cand, line, e, bis = cand[ok], line[ok], e[ok], bis[ok]
            target[cand] = line
            order_key[cand] = e
            new_normal[cand] = bis / np.linalg.norm(bis, axis=1, keepdims=True)
        chosen = np.flatnonzero(np.isfinite(order_key))
        if len(chosen) == 0 and not current.any():
            state.set_oriented(True)
            return crease
        chosen = chosen[np.argsort(order_key[chosen], kind="stable")]
        # greedy: keep a snap only if nothing else is within the clearance of its new place
        tree = cKDTree(pos)
        near = tree.query_ball_point(target[chosen], SNAP_CLEARANCE * rest[chosen])
        placed: list[int] = []
        drop = np.zeros(n, dtype=bool)
        for i, nb in zip(chosen, near, strict=True):
            clear = True
            for j in nb:
                if j != i and not crease[j]:
                    # an unsnapped particle (or a candidate not yet placed) sits there
                    if np.isfinite(order_key[j]) and order_key[j] > order_key[i]:
                        continue
                    clear = False
                    break
            if clear and placed:
                dd = np.linalg.norm(target[placed] - target[i], axis=1)
                clear = bool(np.all(dd >= SNAP_CLEARANCE * rest[i]))
                # a particle hugging the line beside a crease particle is redundant: drop it
                if not clear and not settle and order_key[i] < DROP_DISTANCE * rest[i]:
                    drop[i] = True
            if clear:
                crease[i] = True
                placed.append(int(i))
        # a candidate passed over for a later one that then stayed put may sit on a new place:
        # undo the snaps that came closer than SNAP_MIN_GAP to a particle left where it was
        for _ in range(len(chosen)):
            placed_idx = np.flatnonzero(crease)
            others = np.flatnonzero(~crease)
            if len(placed_idx) == 0 or len(others) == 0:
                break
            dist, k = cKDTree(target[placed_idx]).query(
                pos[others], k=1, distance_upper_bound=SNAP_MIN_GAP * float(np.max(rest))
            )
            close = np.isfinite(dist)
            close[close] &= dist[close] < SNAP_MIN_GAP * rest[others[close]]
            if not close.any():
                break
            crease[placed_idx[k[close]]] = False
        idx = np.flatnonzero(crease)
        moved = pos.copy()
        moved[idx] = target[idx]
        # a crease particle that found no room on its line becomes an oriented particle of the
        # face it is nearest: onto the wedge, with that face's normal (it would otherwise keep
        # the bisector wherever it drifted, e.g. inside the solid under a face)
        back = np.flatnonzero(current & ~crease)
        if len(back):
            s_back, _ = self.nearest_sample(pos[back], self.reach)
            back, s_back = back[s_back >= 0], s_back[s_back >= 0]
            foot_back, normal_back, _ = self.wedge(pos[back], s_back)
            moved[back] = foot_back
            new_normal[back] = normal_back
        state.position = moved
        if len(idx) or len(back):
            nn = state.normal
            nn[idx] = new_normal[idx]
            nn[back] = new_normal[back]
            state.normal = nn
            # keep only the velocity along the line (a snapped particle moves along it)
            vel = state.velocity.copy()
            s, _ = self.nearest_sample(moved[idx], self.reach)
            on_line = (s >= 0) & ~at_corner[idx]
            d = self.direction[np.maximum(s, 0)]
            along = np.einsum("ij,ij->i", vel[idx], d)
            vel[idx] = np.where(on_line[:, None], along[:, None] * d, 0.0)
            state.velocity = vel
        state.set_oriented(~crease)
        if drop.any():
            state.remove(~drop)
            crease = crease[~drop]
        if settle:
            crease = self._occupy_corners(state, crease)
            crease = self._fill_lines(state, crease)
        return crease

    def _fill_lines(self, state: ParticleState, crease: np.ndarray) -> np.ndarray:
        """Cover every crease line with crease particles at the local spacing (the last touch
        of :meth:`constrain`, after the corners). The dynamics can leave a stretch of line with
        no crease particle: face particles settled 0.5-0.8 spacings off it both block growth
        on the line and are too far to snap, and the mesh then cuts the edge there. While
        some sample's foot is farther than ``FILL_GAP`` spacings from every crease particle,
        the farthest such foot (the middle of the widest gap) gets one: the nearest particle
        on the sides' sheet (``n . (n_a + n_b) > 0``) is moved onto it when within
        ``FILL_MERGE`` spacings, else a new particle is added there (normal: the bisector).
        Feet with no particle within ``FILL_SHEET`` spacings (no sheet there) are skipped.
        Returns the crease mask over the particles now."""
        if self._tree is None or state.n == 0:
            return crease
        bis = self.side[:, 0] + self.side[:, 1]
        bis /= np.maximum(np.linalg.norm(bis, axis=1, keepdims=True), 1e-300)
        rest = np.asarray(state.rest, dtype=np.float64)
        d_all, near = cKDTree(state.position).query(self.feet, k=1)
        spacing = rest[near]
        live = d_all <= FILL_SHEET * spacing
        crease = crease.copy()
        d_line = np.full(len(self.feet), np.inf)
        if crease.any():
            d_line = cKDTree(state.position[crease]).query(self.feet, k=1)[0]
        for _ in range(len(self.feet)):
            gap = np.where(live, d_line / spacing, 0.0)
            s = int(np.argmax(gap))
            if gap[s] <= FILL_GAP:
                break
            foot = self.feet[s]
            pos, nrm = state.position, state.normal
            cand = cKDTree(pos).query_ball_point(foot, FILL_MERGE * spacing[s])
            cand = [j for j in cand if not crease[j] and nrm[j] @ bis[s] > 0.0]
            if cand:
                j = min(cand, key=lambda q: float(np.sum((pos[q] - foot) ** 2)))
                pos, nrm = pos.copy(), nrm.copy()
                pos[j], nrm[j] = foot, bis[s]
                state.position, state.normal = pos, nrm
                vel = state.velocity.copy()
                vel[j] = 0.0
                state.velocity = vel
                oriented = np.asarray(state.is_oriented, dtype=bool).copy()
                oriented[j] = False
                state.set_oriented(oriented)
                crease[j] = True
            else:
                state.add(foot[None], bis[s][None], oriented=False, rest=spacing[s])
                crease = np.concatenate([crease, [True]])
            d_line = np.minimum(d_line, np.linalg.norm(self.feet - foot, axis=1))
        return crease

    def _occupy_corners(self, state: ParticleState, crease: np.ndarray) -> np.ndarray:
        """Put a crease particle on every corner that has none (the last touch of
        :meth:`constrain`): a corner snaps only its nearest particle within ``CORNER_SNAP``
        spacings while the dynamics run, so a corner whose particles settled farther stays
        empty, and the mesh cuts it. The nearest particle within ``CORNER_MERGE`` spacings is
        moved onto it; otherwise a new particle is added there (normal: the bisector of the
        nearest crease sample's sides). Returns the crease mask over the particles now."""
        if self._corner_tree is None or state.n == 0:
            return crease
        dist, near = cKDTree(state.position).query(self.corners, k=1)
        rest = np.asarray(state.rest, dtype=np.float64)
        empty = dist > CORNER_TOUCH * rest[near]
        if not empty.any():
            return crease
        if self._tree is not None:
            _, s = self._tree.query(self.corners[empty], k=1)
            bis = self.side[s, 0] + self.side[s, 1]
            bis /= np.maximum(np.linalg.norm(bis, axis=1, keepdims=True), 1e-300)
        else:
            bis = state.normal[near[empty]]
        merge = dist[empty] <= CORNER_MERGE * rest[near[empty]]
        # a particle moves to one corner only, its nearest; the others get new particles
        order = np.flatnonzero(merge)[np.argsort(dist[empty][merge], kind="stable")]
        merge = np.isin(
            np.arange(len(merge)), order[np.unique(near[empty][order], return_index=True)[1]]
        )
        idx = near[empty][merge]
        if len(idx):
            pos, nrm = state.position.copy(), state.normal.copy()
            pos[idx] = self.corners[empty][merge]
            nrm[idx] = bis[merge]
            state.position, state.normal = pos, nrm
            vel = state.velocity.copy()
            vel[idx] = 0.0
            state.velocity = vel
            crease = crease.copy()
            crease[idx] = True
            oriented = np.asarray(state.is_oriented, dtype=bool).copy()
            oriented[idx] = False
            state.set_oriented(oriented)
        add = ~merge
        if add.any():
            state.add(
                self.corners[empty][add],
                bis[add],
                oriented=False,
                rest=rest[near[empty][add]],
            )
            crease = np.concatenate([crease, np.ones(int(add.sum()), dtype=bool)])
        return crease


def _refine_planes(
    points: np.ndarray, sel: np.ndarray, idx: np.ndarray, feet: np.ndarray, side: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Two-plane fit of each crease sample's neighbourhood ``idx``: starting from the detected
    side planes through the foot, assign every neighbour to the nearer plane and refit each plane
    by PCA of its members (``REFINE_ROUNDS`` times); the line is the planes' intersection, its
    foot the line point closest to the data point. The detected planes pass through the
    clusters' centroids with their mean normals, which a few blended normals tilt; the refit
    uses positions only."""
    nb = points[idx]  # (m, K, 3)
    p = points[sel]
    na, nb_ = side[:, 0].copy(), side[:, 1].copy()
    ca, cb = feet.copy(), feet.copy()
    for rnd in range(REFINE_ROUNDS):
        da = np.abs(np.einsum("mkj,mj->mk", nb - ca[:, None], na))
        db = np.abs(np.einsum("mkj,mj->mk", nb - cb[:, None], nb_))
        res = np.minimum(da, db)
        # inliers: a third face's points (near a corner) and outliers do not tilt the planes
        tol = np.minimum(REFINE_OUTLIER, 3.0 * np.median(res, axis=1) + REFINE_FLOOR)
        if rnd == 0:
            tol[:] = REFINE_OUTLIER
        inl = res <= tol[:, None]
        members = []
        for mask, n, c in ((inl & (da <= db), na, ca), (inl & (da > db), nb_, cb)):
            w = mask.astype(np.float64)
            cnt = w.sum(axis=1)
            members.append(cnt)
            ok = cnt >= REFINE_MIN_MEMBERS
            cen = np.einsum("mk,mkj->mj", w, nb) / np.maximum(cnt, 1)[:, None]
            rel = (nb - cen[:, None]) * w[..., None]
            cov = np.einsum("mki,mkj->mij", rel, rel)
            _, vec = np.linalg.eigh(cov)
            new = vec[:, :, 0]
            new *= np.where(np.einsum("ij,ij->i", new, n) < 0.0, -1.0, 1.0)[:, None]
            n[ok] = new[ok]
            c[ok] = cen[ok]
    members_a, members_b = members
    cos = np.einsum("ij,ij->i", na, nb_)
    det = 1.0 - cos * cos
    good = det > 1e-6
    ra = np.einsum("ij,ij->i", na, ca - p)
    rb = np.einsum("ij,ij->i", nb_, cb - p)
    a = (ra - cos * rb) / np.where(good, det, 1.0)
    b = (rb - cos * ra) / np.where(good, det, 1.0)
    x0 = p + a[:, None] * na + b[:, None] * nb_
    d = np.cross(na, nb_)
    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-300)
    # a sample whose refit is degenerate (a side with too few points, parallel planes, a line
    # far from the detected one) is dropped: its neighbours along the line cover it
    good &= np.linalg.norm(x0 - feet, axis=1) <= 1.0
    good &= (members_a >= REFINE_MIN_MEMBERS) & (members_b >= REFINE_MIN_MEMBERS)
    out_side = np.stack([na, nb_], axis=1)
    return (
        np.ascontiguousarray(x0),
        np.ascontiguousarray(out_side),
        np.ascontiguousarray(d),
        good,
    )
