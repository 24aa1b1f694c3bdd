"""The global sign of each consistently oriented component of normals: the votes of
:func:`recon.normals.orient_normals`'s rules (``viewpoint``, ``outward``, ``up``).

Each rule sums one signed quantity over a component; the component is flipped when the sum
is negative, and ``|sum| / sum|.|`` says how decisive the vote was (see the docstring of
:mod:`recon.normals` for the rules).
"""

from __future__ import annotations

import logging

import numpy as np

__all__ = ["CLOSED_CONFIDENCE", "component_votes"]

logger = logging.getLogger("recon.normals")

#: Outward votes at least this decisive make ``auto`` treat a component as closed; scanner
#: positions whose vote is less decisive are not used (``scanners``).
CLOSED_CONFIDENCE = 0.5
#: Extreme points per direction for the outward vote: this fraction of the component ...
_EXTREME_FRACTION = 0.01
#: ... but at most this many.
_EXTREME_MAX = 200


def _fibonacci_directions(m: int = 25) -> np.ndarray:
    """``m`` near-uniform unit vectors and their opposites, (2m, 3)."""
    i = np.arange(m) + 0.5
    z = 1.0 - 2.0 * i / m
    phi = np.pi * (1.0 + 5.0**0.5) * i
    r = np.sqrt(1.0 - z * z)
    d = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)
    return np.concatenate([d, -d])


_DIRECTIONS = _fibonacci_directions()


def _component_sums(labels: np.ndarray, values: np.ndarray, n_comp: int) -> np.ndarray:
    return np.bincount(labels, weights=values, minlength=n_comp)


def _outward_votes(
    points: np.ndarray, normals: np.ndarray, labels: np.ndarray, n_comp: int
) -> tuple[np.ndarray, np.ndarray]:
    """Per component: (sum of n . d over extreme points, sum of |n . d|)."""
    score = np.zeros(n_comp)
    weight = np.zeros(n_comp)
    order = np.argsort(labels, kind="stable")
    bounds = np.searchsorted(labels[order], np.arange(n_comp + 1))
    for c in range(n_comp):
        members = order[bounds[c] : bounds[c + 1]]
        m = members.size
        if m < 4:
            continue
        p = points[members]
        nrm = normals[members]
        t = int(np.clip(np.ceil(_EXTREME_FRACTION * m), 1, _EXTREME_MAX))
        for d in _DIRECTIONS:
            top = np.argpartition(-(p @ d), t - 1)[:t]
            votes = nrm[top] @ d
            score[c] += votes.sum()
            weight[c] += np.abs(votes).sum()
    return score, weight


def _up_axes(points: np.ndarray, labels: np.ndarray, n_comp: int) -> np.ndarray:
    """Per component the least-variance axis, signed toward +z (else +y, else +x)."""
    count = np.bincount(labels, minlength=n_comp).astype(np.float64)
    mean = np.stack([_component_sums(labels, points[:, i], n_comp) for i in range(3)], 1)
    mean /= np.maximum(count, 1.0)[:, None]
    centred = points - mean[labels]
    cov = np.zeros((n_comp, 3, 3))
    for i in range(3):
        for j in range(i, 3):
            cov[:, i, j] = cov[:, j, i] = _component_sums(
                labels, centred[:, i] * centred[:, j], n_comp
            )
    _, vecs = np.linalg.eigh(cov)
    axes = vecs[:, :, 0]
    for c in range(n_comp):
        a = axes[c]
        ref = next((i for i in (2, 1, 0) if abs(a[i]) > 0.1), 2)
        if a[ref] < 0:
            axes[c] = -a
    return axes


def component_votes(
    points: np.ndarray,
    oriented: np.ndarray,
    labels: np.ndarray,
    n_comp: int,
    orientation: str,
    viewpoint: np.ndarray | None,
    scanners: bool,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per component: the vote's sum, the sum of its magnitudes and the rule that voted.

    Parameters
    ----------
    points : (n, 3) float64 [length]
    oriented : (n, 3) float64
        Normals signed consistently within each component.
    labels : (n,) int
        Each point's component, ``0 .. n_comp - 1``.
    orientation : {'auto', 'outward', 'viewpoint', 'none'}
    viewpoint : (3,) or (n, 3) float64 [length] or None
    scanners : bool
        ``viewpoint`` holds the scanner positions a file gave: with ``auto``, components whose
        normals do not face them as one (the vote under ``CLOSED_CONFIDENCE``) take the
        ``outward`` or ``up`` vote instead.

    Returns
    -------
    score, weight : (n_comp,) float64
    rule : (n_comp,) object
        ``'viewpoint'``, ``'outward'``, ``'up'`` or ``'none'``.
    """
    rule = np.full(n_comp, "none", dtype=object)
    score = np.zeros(n_comp)
    weight = np.zeros(n_comp)
    todo = np.ones(n_comp, dtype=bool)  # the components no viewpoint signs
    if orientation == "viewpoint" or (orientation == "auto" and viewpoint is not None):
        to_view = viewpoint - points
        dist = np.linalg.norm(to_view, axis=1)
        s = np.einsum("ij,ij->i", oriented, to_view) / np.maximum(dist, 1e-300)
        score = _component_sums(labels, s, n_comp)
        weight = _component_sums(labels, np.abs(s), n_comp)
        rule[:] = "viewpoint"
        todo[:] = False
        if scanners and orientation == "auto":  # only where they face the surface as one
            todo = np.abs(score) < CLOSED_CONFIDENCE * weight
            if todo.any():
                logger.info(
                    "normal orientation: the scanner positions do not face %d of %d "
                    "component(s) consistently (a pose that is not where the scan was made "
                    "from); those are signed as without them",
                    int(np.count_nonzero(todo)),
                    n_comp,
                )
    if orientation == "outward" or (orientation == "auto" and todo.any()):
        o_score, o_weight = _outward_votes(points, oriented, labels, n_comp)
        o_rule = np.full(n_comp, "outward", dtype=object)
        if orientation == "auto":
            conf = np.abs(o_score) / np.maximum(o_weight, 1e-300)
            open_c = conf < CLOSED_CONFIDENCE
            if open_c.any():
                axes = _up_axes(points, labels, n_comp)
                s = np.einsum("ij,ij->i", oriented, axes[labels])
                up_score = _component_sums(labels, s, n_comp)
                up_weight = _component_sums(labels, np.abs(s), n_comp)
                o_score = np.where(open_c, up_score, o_score)
                o_weight = np.where(open_c, up_weight, o_weight)
                o_rule[open_c] = "up"
        score = np.where(todo, o_score, score)
        weight = np.where(todo, o_weight, weight)
        rule[todo] = o_rule[todo]
    return score, weight, rule
