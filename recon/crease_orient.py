"""Consistent normal orientation across detected creases (issue 12, step 1).

Hoppe's propagation (:func:`recon.normals.orient_normals`) compares neighbours' normals by
``n_i . n_j``; across a sharp crease the two faces' normals turn by the crease angle, and past
90 deg the propagation carries the wrong sign over to the other face. With the creases of
:func:`recon.creases.detect_creases` known, :func:`orient_across_creases` flips whole faces
so that their crease points' side planes agree, then signs each point near a crease by the
side plane it lies on.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy import sparse
from scipy.sparse import csgraph
from scipy.spatial import cKDTree

from .creases import CREASE, SMOOTH, Creases
from .geometry import as_points

__all__ = ["orient_across_creases"]

#: Orientation across creases (:func:`orient_across_creases`): smooth points farther than a
#: neighbourhood radius from every feature point are one face with those of their
#: NORMALS_LINK_K nearest whose normals agree to FACE_LINK_DEG and that lie in their tangent
#: plane to that angle (tight: near a knife edge the blended normals turn gradually from one
#: face to the other, 15 deg per step at 150 deg); a pair of faces is decided by at least
#: MIN_VOTES crease points of which VOTE_MARGIN more agree than disagree. The points between
#: faces follow their nearest face points weighted by |cos|**ALIGN_POWER.
NORMALS_LINK_K = 10
FACE_LINK_DEG = 10.0
MIN_VOTES = 5
VOTE_MARGIN = 0.5
ALIGN_POWER = 8
#: Then the points within a neighbourhood radius of a crease point and within SIDE_PLANE_TOL
#: radii of one of its side planes take that side's sign (:func:`_sign_by_side`).
SIDE_PLANE_TOL = 0.25


def orient_across_creases(
    points: np.ndarray, normals: np.ndarray, found: Creases, k: int = 48
) -> tuple[np.ndarray, Creases, int]:
    """Make oriented normals consistent across the detected creases: whole faces are
    flipped (:func:`_orient_faces`), then each point near a crease takes the sign of the side
    it lies on (:func:`_sign_by_side`). Returns the normals, the detection with re-signed side
    normals, and the number of points flipped (0: the input is returned)."""
    nrm = np.asarray(normals, dtype=np.float64)
    out, found, _ = _orient_faces(points, nrm, found, k)
    found = _sign_sides(as_points(points), out, found, k)
    out = _sign_by_side(as_points(points), out, found, k)
    flipped = int(np.count_nonzero(np.einsum("ij,ij->i", out, nrm) < 0.0))
    return (nrm if flipped == 0 else out), found, flipped


def _sign_sides(pts: np.ndarray, nrm: np.ndarray, found: Creases, k: int) -> Creases:
    """Side normals signed by the majority of their members' normals (the ``k`` nearest
    points, each a member of the nearer side plane), and made consistent with each other:
    with ``t_a`` (``t_b``) the direction in face a (b) away from the line to its members,
    consistent sides have ``sign(n_a . t_b) == sign(n_b . t_a)``; when they do not, the side
    whose members agree less clearly is turned. Near a knife edge most members' normals are
    blends of both faces, and one side's majority alone was wrong at a fifth of the points."""
    cr = np.flatnonzero((found.labels == CREASE) & np.isfinite(found.foot).all(axis=1))
    if len(cr) == 0:
        return found
    kq = int(min(k, len(pts)))
    _, idx = cKDTree(pts).query(pts[cr], k=kq)
    idx = idx.reshape(len(cr), kq)
    rel = pts[idx] - found.foot[cr][:, None]
    na, nb = found.side_normals[cr, 0], found.side_normals[cr, 1]
    on_a = np.abs(np.einsum("mkj,mj->mk", rel, na)) <= np.abs(np.einsum("mkj,mj->mk", rel, nb))
    votes = (
        np.sign(np.einsum("mkj,mj->mk", nrm[idx], na)),
        np.sign(np.einsum("mkj,mj->mk", nrm[idx], nb)),
    )
    va = np.sum(np.where(on_a, votes[0], 0.0), axis=1)
    vb = np.sum(np.where(~on_a, votes[1], 0.0), axis=1)
    na = na * np.where(va < 0, -1.0, 1.0)[:, None]
    nb = nb * np.where(vb < 0, -1.0, 1.0)[:, None]
    d = found.direction[cr]
    ta, tb = np.cross(d, na), np.cross(d, nb)
    ta *= np.sign(np.einsum("mk,mkj,mj->m", on_a.astype(float), rel, ta))[:, None]
    tb *= np.sign(np.einsum("mk,mkj,mj->m", (~on_a).astype(float), rel, tb))[:, None]
    bad = np.sign(np.einsum("ij,ij->i", na, tb)) != np.sign(np.einsum("ij,ij->i", nb, ta))
    share_a = np.abs(va) / np.maximum(on_a.sum(axis=1), 1)
    share_b = np.abs(vb) / np.maximum((~on_a).sum(axis=1), 1)
    na[bad & (share_a < share_b)] *= -1.0
    nb[bad & (share_a >= share_b)] *= -1.0
    side = found.side_normals.copy()
    side[cr, 0], side[cr, 1] = na, nb
    return replace(found, side_normals=side)


def _sign_by_side(pts: np.ndarray, nrm: np.ndarray, found: Creases, k: int) -> np.ndarray:
    """Each point within a neighbourhood radius of a crease point takes the sign of the side
    plane (of the nearest crease point) it lies on: within ``SIDE_PLANE_TOL`` radii of that
    plane, when its normal is within 60 deg of the plane's axis (a blend of the two faces or
    the face itself; a third face's normals at a corner say nothing). Near a knife edge the
    normals are blends of both faces, and following the nearest faces' normals (the last step
    of :func:`_orient_faces`) signs the points of the two faces alike; the side they lie on
    tells them apart."""
    cr = np.flatnonzero((found.labels == CREASE) & np.isfinite(found.foot).all(axis=1))
    if len(cr) == 0:
        return nrm
    kq = int(min(k, len(pts)))
    radius = float(np.median(cKDTree(pts).query(pts[cr], k=kq)[0][:, -1]))
    dist, near = cKDTree(pts[cr]).query(pts, k=1, distance_upper_bound=radius)
    sel = np.flatnonzero(np.isfinite(dist))
    c = cr[near[sel]]
    rel = pts[sel] - found.foot[c]
    na, nb = found.side_normals[c, 0], found.side_normals[c, 1]
    da, db = np.einsum("ij,ij->i", rel, na), np.einsum("ij,ij->i", rel, nb)
    side = np.where((np.abs(da) <= np.abs(db))[:, None], na, nb)
    dot = np.einsum("ij,ij->i", nrm[sel], side)
    on = np.minimum(np.abs(da), np.abs(db)) <= SIDE_PLANE_TOL * radius
    turn = sel[on & (dot < -0.5)]
    if len(turn) == 0:
        return nrm
    out = nrm.copy()
    out[turn] *= -1.0
    return out


def _orient_faces(
    points: np.ndarray, normals: np.ndarray, found: Creases, k: int = 48
) -> tuple[np.ndarray, Creases, int]:
    """Make oriented normals consistent across the detected creases, face by face.

    Orientation by propagation (:mod:`recon.normals`) crosses a sharp edge where the normals
    of both faces look alike up to sign: across a knife edge (a 150 deg turn, |cos| = 0.87)
    it takes the far face's normals flipped. A crease decides it geometrically: with ``d`` the
    line direction and ``t_a`` (``t_b``) the direction in face a (b) away from the line to its
    data, consistently oriented side normals have ``sign(n_a . t_b) == sign(n_b . t_a)``
    (both negative on a convex edge, both positive on a concave one); flipping one side
    flips one of the two.

    The smooth points are split into faces (neighbours among the ``NORMALS_LINK_K`` nearest
    whose normals agree to ``FACE_LINK_DEG``), each crease point votes, by that test, whether
    the faces of its two sides agree, and faces are flipped so that the votes' majorities hold,
    each linked group keeping the orientation most of its points have. The points between
    faces side with the normals of their nearest face points; side normals are re-signed by
    their members.

    Returns the normals, the detection with re-signed side normals, and the number of points
    flipped (0: the input is returned).
    """
    pts = as_points(points)
    nrm = np.asarray(normals, dtype=np.float64)
    cr = np.flatnonzero((found.labels == CREASE) & np.isfinite(found.foot).all(axis=1))
    smooth = np.flatnonzero(found.labels == SMOOTH)
    if len(cr) == 0 or len(smooth) < 2:
        return nrm, found, 0
    tree = cKDTree(pts)
    # faces: smooth points beyond a neighbourhood radius of every feature point (their normals
    # do not blend two faces), linked to neighbours with agreeing normals; the points between
    # take the face of their nearest such point
    feat = np.flatnonzero(found.labels != SMOOTH)
    kq = int(min(k, len(pts)))
    radius = float(np.median(tree.query(pts[cr], k=kq)[0][:, -1]))
    gap, _ = cKDTree(pts[feat]).query(pts[smooth], k=1)
    core = smooth[gap > radius]
    if len(core) < 2:
        return nrm, found, 0
    kk = int(min(NORMALS_LINK_K + 1, len(core)))
    core_tree = cKDTree(pts[core])
    _, nb = core_tree.query(pts[core], k=kk)
    a = np.repeat(np.arange(len(core)), kk - 1)
    b = nb[:, 1:].reshape(-1)
    # same face: normals agree and the step between them lies in the tangent plane (across a
    # thin wedge the other face's points are near, but off the plane)
    step = pts[core[b]] - pts[core[a]]
    lim = np.sin(np.radians(FACE_LINK_DEG)) * np.linalg.norm(step, axis=1)
    agree = (
        np.einsum("ij,ij->i", nrm[core[a]], nrm[core[b]]) > np.cos(np.radians(FACE_LINK_DEG))
    ) & (np.abs(np.einsum("ij,ij->i", step, nrm[core[a]])) <= lim)
    graph = sparse.coo_matrix(
        (np.ones(int(agree.sum())), (a[agree], b[agree])), shape=(len(core), len(core))
    )
    n_face, face_of_core = csgraph.connected_components(graph, directed=False)
    _, nearest_core = core_tree.query(pts, k=1)
    face = face_of_core[nearest_core]  # for the votes: the points between, their nearest face
    # each crease point: its two sides' members, their faces and the consistency test
    _, idx = tree.query(pts[cr], k=kq)
    idx = idx.reshape(len(cr), kq)
    foot, d = found.foot[cr], found.direction[cr]
    na, nb_ = found.side_normals[cr, 0], found.side_normals[cr, 1]
    rel = pts[idx] - foot[:, None]
    da = np.abs(np.einsum("mkj,mj->mk", rel, na))
    db = np.abs(np.einsum("mkj,mj->mk", rel, nb_))
    on_a = da <= db
    wa, wb = on_a.astype(np.float64), (~on_a).astype(np.float64)
    sign_a = np.sign(np.einsum("mk,mkj,mj->m", wa, nrm[idx], na))
    sign_b = np.sign(np.einsum("mk,mkj,mj->m", wb, nrm[idx], nb_))
    na, nb_ = na * sign_a[:, None], nb_ * sign_b[:, None]
    ta, tb = np.cross(d, na), np.cross(d, nb_)
    ta *= np.sign(np.einsum("mk,mkj,mj->m", wa, rel, ta))[:, None]
    tb *= np.sign(np.einsum("mk,mkj,mj->m", wb, rel, tb))[:, None]
    same = np.sign(np.einsum("ij,ij->i", na, tb)) == np.sign(np.einsum("ij,ij->i", nb_, ta))
    fa, fb = _majority_face(face[idx], on_a), _majority_face(face[idx], ~on_a)
    ok = (fa >= 0) & (fb >= 0) & (fa != fb) & (sign_a != 0) & (sign_b != 0)
    if not ok.any():
        return nrm, found, 0
    # votes per pair of faces: +1 the sides agree, -1 one of them is flipped
    pair = np.minimum(fa[ok], fb[ok]) * n_face + np.maximum(fa[ok], fb[ok])
    keys, inv = np.unique(pair, return_inverse=True)
    votes = np.bincount(inv, weights=np.where(same[ok], 1.0, -1.0))
    count = np.bincount(inv)
    size = np.bincount(face_of_core, minlength=n_face)
    flip, linked = _solve_flips(keys // n_face, keys % n_face, votes, count, size)
    if not flip.any():
        return nrm, found, 0
    flipped = np.zeros(len(pts), dtype=bool)
    flipped[core] = flip[face_of_core]
    out = np.where(flipped[:, None], -nrm, nrm)
    # every other point (between faces, or on a face no crease decided: noise splits a face
    # into pieces) sides with its nearest points of decided faces, weighted by how well their
    # normals align (|cos|**ALIGN_POWER: a point of one face follows that face; a blended
    # normal near an edge, the bisector of the faces it lies between)
    anchor = core[linked[face_of_core]]
    rest = np.setdiff1d(np.arange(len(pts)), anchor)
    _, near = cKDTree(pts[anchor]).query(pts[rest], k=int(min(kq, len(anchor))))
    ref = out[anchor[near.reshape(len(rest), -1)]]
    cos = np.einsum("mkj,mj->mk", ref, out[rest])
    turn = np.sum(np.abs(cos) ** ALIGN_POWER * np.sign(cos), axis=1) < 0.0
    flipped[rest[turn]] = True
    out[rest[turn]] *= -1.0
    # side normals follow the majority of their members' new normals
    side = found.side_normals.copy()
    for j, members in ((0, wa), (1, wb)):
        s = np.sign(np.einsum("mk,mkj,mj->m", members, out[idx], side[cr, j]))
        side[cr, j] *= np.where(s == 0, 1.0, s)[:, None]
    return out, replace(found, side_normals=side), int(flipped.sum())


def _majority_face(face: np.ndarray, members: np.ndarray) -> np.ndarray:
    """Per row, the face most of the smooth ``members`` belong to (-1: none)."""
    out = np.full(len(face), -1, dtype=np.int64)
    for i in range(len(face)):
        f = face[i][members[i] & (face[i] >= 0)]
        if len(f):
            vals, cnt = np.unique(f, return_counts=True)
            out[i] = vals[np.argmax(cnt)]
    return out


def _solve_flips(
    fa: np.ndarray, fb: np.ndarray, votes: np.ndarray, count: np.ndarray, size: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Faces to flip so that the decided pairs hold (a union-find with parity, the clearest
    pairs first; a pair is decided when at least ``MIN_VOTES`` crease points voted and
    ``VOTE_MARGIN`` of them agree). In each linked group the orientation of most points is
    kept. Returns the flips and whether each face is linked to another."""
    parent = np.arange(len(size))
    parity = np.zeros(len(size), dtype=np.int64)  # relative to the parent

    def root(x: int) -> tuple[int, int]:
        p = 0
        while parent[x] != x:
            p ^= int(parity[x])
            x = int(parent[x])
        return x, p

    decided = (count >= MIN_VOTES) & (np.abs(votes) >= VOTE_MARGIN * count)
    for i in np.argsort(-np.abs(votes), kind="stable"):
        if not decided[i]:
            continue
        (ra, pa), (rb, pb) = root(int(fa[i])), root(int(fb[i]))
        want = 0 if votes[i] > 0 else 1
        if ra == rb:
            continue  # already decided by clearer votes
        parent[rb] = ra
        parity[rb] = pa ^ pb ^ want
    roots = np.array([root(x) for x in range(len(size))])
    flip = roots[:, 1].astype(bool)
    linked = np.bincount(roots[:, 0], minlength=len(size))[roots[:, 0]] > 1
    # each group keeps the orientation most of its points have (fewest flipped)
    for r in np.unique(roots[:, 0]):
        members = roots[:, 0] == r
        if 2 * size[members & flip].sum() > size[members].sum():
            flip[members] = ~flip[members]
    return flip, linked
