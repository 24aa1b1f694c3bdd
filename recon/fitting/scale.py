"""The length scales of a fit, derived from the data: rest spacing r0, neighbourhoods, max gap.

- :func:`with_neighborhood_size`: resolve ``normals.auto_scale`` (a larger k on noisy data) once,
  so the normals and the local data surfaces share it.
- :func:`choose_spacing`: the rest spacing r0 from the median point spacing, with the resolution
  floor that puts particles between the samples of sparse inputs (S&T92 §7); the point
  spacing of samples far closer along one direction than across it (scan lines) is the one
  across (:func:`sampled_spacing`).
- :func:`check_grid_size`: refuse inputs whose extent over r0 makes the neighbour grid absurd.
- :func:`with_max_gap`: resolve ``growth.max_gap`` (default: ``AUTO_GAP`` data spacings).

All lengths here are in input units; the dynamics then run in units of r0.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial import cKDTree

from ..config import ReconConfig, with_values
from ..errors import InputError
from ..geometry import (
    SPACING_SAMPLE_SEED,
    SURROUND_RATIO,
    bbox_diagonal,
    median_nearest_neighbor_distance,
    surround_distances,
)
from ..normals import choose_neighborhood_size
from ..thinning import LINE_RATIO

__all__ = [
    "AREA_PER_POINT",
    "AUTO_GAP",
    "HEX_AREA",
    "MAX_GRID_CELLS",
    "MIN_AUTO_GAP",
    "MIN_SPACING_FACTOR",
    "NOTE_SPACING_RATIO",
    "SPACING_SAMPLE_SEED",
    "SURROUND_RATIO",
    "SURROUND_SAMPLE",
    "check_grid_size",
    "choose_spacing",
    "median_surround",
    "surround_median",
    "sampled_spacing",
    "sampling_note",
    "spacing_from_median",
    "with_max_gap",
    "with_neighborhood_size",
]

#: Area per point of a uniform random sample is about AREA_PER_POINT x (median NN distance)^2,
#: and a hexagonal sheet at spacing r0 holds one particle per HEX_AREA r0^2: together they
#: predict the particle count for a given r0 (used by the resolution floor).
AREA_PER_POINT = 4.0
#: Area per particle of a hexagonal sheet at spacing 1 (sqrt(3)/2, rounded as it always was).
HEX_AREA = 0.866
#: The resolution floor never lowers r0 below this many median point spacings: closer
#: particles would resolve the sampling noise rather than the surface.
MIN_SPACING_FACTOR = 0.8
#: Largest cell grid (cells of side r0 over the data's bounding box) the neighbour search accepts.
MAX_GRID_CELLS = 2.0**60
#: The share of the points measured that must be surrounded for their median to say anything
#: (:func:`surround_median`; all but the borders on a scan, a third on three lines).
MIN_SURROUNDED = 0.1
#: Points whose surround distance is measured (a sample; the median moves by about 1 %).
SURROUND_SAMPLE = 2000
#: The fit says why r0 is what it is when the point spacing is at least this many times the
#: median nearest-neighbour distance (where scan lines are thinned: :mod:`recon.thinning`).
NOTE_SPACING_RATIO = LINE_RATIO
#: Default max_gap, in median data spacings.
AUTO_GAP = 10.0
#: The default max_gap is at least this many r0 (a gap narrower than one particle spacing is
#: no gap for the growing rule).
MIN_AUTO_GAP = 1.0


def with_neighborhood_size(
    points: np.ndarray,
    cfg: ReconConfig,
    tree: cKDTree | None = None,
    variations: dict[int, float] | None = None,
) -> ReconConfig:
    """``cfg`` with ``normals.k`` resolved when ``normals.auto_scale`` is on (else ``cfg``);
    ``tree``: a k-d tree of ``points`` when one is built already; ``variations``: a dict
    that receives the median surface variations measured on the way, by k
    (:func:`recon.normals.choose_neighborhood_size`).

    Resolved once so that the normals and the local data surfaces share the neighbourhood size.
    """
    if not cfg.normals.auto_scale:
        return cfg
    k = choose_neighborhood_size(points, cfg.normals.k, tree=tree, variations=variations)
    return with_values(cfg, normals={"k": k, "auto_scale": False})


def sampled_spacing(nearest: float, surround: float) -> float:
    """The point spacing [length] of data whose median nearest-neighbour distance is
    ``nearest`` and median surround distance ``surround``: ``nearest``, or
    ``surround / SURROUND_RATIO`` when that is larger (scan lines, clumps); ``nearest``
    when it is 0 (most points repeated: refused with that reason by
    :func:`spacing_from_median`).

    Examples
    --------
    >>> sampled_spacing(1.0, 3.4)  # random samples
    1.0
    >>> sampled_spacing(1.0, 6.0)  # lines 6 apart
    1.5
    """
    if not nearest > 0.0:
        return float(nearest)
    return float(max(nearest, surround / SURROUND_RATIO))


def sampling_note(nearest: float, spacing: float, r0: float, cfg: ReconConfig) -> str | None:
    """What a fit says when the point spacing ``spacing`` is the one across scan lines, at
    least ``NOTE_SPACING_RATIO`` times the median nearest-neighbour distance ``nearest``, and
    r0 follows it (None otherwise)."""
    s = cfg.seeds
    if s.spacing is not None or s.spacing_relative is not None:
        return None
    if not spacing >= NOTE_SPACING_RATIO * nearest:
        return None
    return (
        f"the points lie in lines or clumps about {spacing * SURROUND_RATIO:.4g} apart, "
        f"{spacing * SURROUND_RATIO / nearest:.0f} times their median spacing {nearest:.4g}: "
        f"r0 = {r0:.4g} follows the gaps between them (--spacing sets it)"
    )


def median_surround(points: np.ndarray, tree: cKDTree | None = None) -> float:
    """The median surround distance [length] (:func:`recon.geometry.surround_distances`) of
    a fixed sample of ``SURROUND_SAMPLE`` of ``points`` (all when fewer); ``tree``: a k-d tree
    of ``points`` when one is built already."""
    n = len(points)
    rows = np.arange(n)
    if n > SURROUND_SAMPLE:
        rng = np.random.default_rng(SPACING_SAMPLE_SEED)
        rows = np.sort(rng.choice(n, size=SURROUND_SAMPLE, replace=False))
    tree = cKDTree(points) if tree is None else tree
    return surround_median(surround_distances(points, rows, tree))


def surround_median(distances: np.ndarray) -> float:
    """The median of surround distances (:func:`recon.geometry.surround_distances`) over the
    points they surround; 0 (no scan lines to tell) when fewer than ``MIN_SURROUNDED`` of them
    are (a strip two rows wide, two lines)."""
    found = distances[np.isfinite(distances)]
    if len(found) == 0 or len(found) < MIN_SURROUNDED * len(distances):
        return 0.0
    return float(np.median(found))


def choose_spacing(
    points: np.ndarray,
    cfg: ReconConfig,
    tree: cKDTree | None = None,
    nearest: np.ndarray | None = None,
    notes: list[str] | None = None,
    lines: tuple[float, int] | None = None,
) -> tuple[float, float]:
    """Rest spacing r0 [length] and the point spacing of the data (:func:`sampled_spacing`:
    the median nearest-neighbour distance unless the samples lie in lines).

    By default r0 = ``spacing_factor`` x point spacing, lowered (not below
    ``MIN_SPACING_FACTOR`` x point spacing) so that the sheet gets about ``min_particles``
    particles: sparse inputs get particles between their samples (S&T92 §7) instead of a mesh
    coarser than the shape. Scan lines (and clumps) farther apart than random samples would
    be give the spacing across them: r0 from the spacing along them leaves particles lines
    of empty space apart, and the sheet falls apart between the lines.

    Parameters
    ----------
    points : (n, 3) float64 [length]
        The input points.
    cfg : ReconConfig
        ``seeds.spacing`` (absolute), ``seeds.spacing_relative`` (of the bounding-box
        diagonal) or ``seeds.spacing_factor`` with ``seeds.min_particles``.
    tree : scipy.spatial.cKDTree, optional
        A k-d tree of ``points`` (the fit's shared one).
    nearest : (n,) float64 [length], optional
        Each point's distance to its nearest other point, when known (the fit's shared
        k-nearest query; see :func:`recon.geometry.median_nearest_neighbor_distance`).
    notes : list of str, optional
        Receives :func:`sampling_note` when r0 follows scan lines.
    lines : (float, int), optional
        The median surround distance [length] and the point count measured before the lines
        were thinned (:func:`recon.thinning.line_gap`): the spacing and r0 are theirs then,
        and no note is made (the thinning's says it).

    Returns
    -------
    r0 : float [length]
    spacing : float [length]

    Raises
    ------
    InputError
        No positive finite spacing can be derived (e.g. mostly duplicate points).
    """
    rng = np.random.default_rng(SPACING_SAMPLE_SEED)
    d_nn = median_nearest_neighbor_distance(points, rng=rng, tree=tree, nearest=nearest)
    if d_nn > 0.0 and nearest is not None and not np.all(nearest > 0.0):
        d_nn = float(np.median(nearest[nearest > 0.0]))  # exact repeats kept: not lines
    if lines is None:
        spacing, n = sampled_spacing(d_nn, median_surround(points, tree)), len(points)
    else:  # the spacing across the lines (the points left along them are about as far)
        spacing, n = lines[0] / SURROUND_RATIO, lines[1]
    r0 = spacing_from_median(spacing, n, bbox_diagonal(points), cfg)
    note = None if lines is not None else sampling_note(d_nn, spacing, r0, cfg)
    if note is not None and notes is not None:
        notes.append(note)
    return r0, spacing


def spacing_from_median(d_nn: float, n_points: int, diag: float, cfg: ReconConfig) -> float:
    """r0 [length] from the median point spacing ``d_nn``, the point count and the bounding-box
    diagonal (the rule of :func:`choose_spacing`, also used by a tiled fit, which measures
    them tile by tile).

    Raises
    ------
    InputError
        No positive finite spacing can be derived.
    """
    s = cfg.seeds
    if s.spacing is not None:
        r0 = s.spacing
    elif s.spacing_relative is not None:
        r0 = s.spacing_relative * diag
    else:
        factor = s.spacing_factor
        if s.min_particles > 0:
            floor = math.sqrt(AREA_PER_POINT * n_points / (HEX_AREA * s.min_particles))
            factor = min(factor, max(floor, MIN_SPACING_FACTOR))
        r0 = factor * d_nn
    if not (r0 > 0 and math.isfinite(r0)):
        msg = f"cannot derive a rest spacing: the median point spacing is {d_nn!r}"
        if d_nn == 0.0:
            msg += " (most points are exact duplicates: set io.merge_duplicates: true)"
        raise InputError(msg + "; or give --spacing")
    return float(r0)


def check_grid_size(points: np.ndarray, r0: float) -> None:
    """Raise :class:`~recon.errors.InputError` when cells of side r0 over the data are too many.

    Far outliers (or a tiny spacing) would make the neighbour search's cell grid overflow.
    """
    span = points.max(axis=0) - points.min(axis=0)
    with np.errstate(over="ignore"):  # a spacing far below the span: inf cells, refused
        cells = float(np.prod(np.floor(span / r0) + 1.0))
    if cells > MAX_GRID_CELLS:
        raise InputError(
            f"the points span {', '.join(f'{x:.3g}' for x in span)} (x, y, z) but the rest "
            f"spacing r0 is {r0:.3g}: far too many cells for the neighbour search; remove far "
            "outliers or raise the spacing"
        )


def with_max_gap(cfg: ReconConfig, r0: float, median_spacing: float) -> ReconConfig:
    """``cfg`` with ``growth.max_gap`` [r0] resolved: ``AUTO_GAP`` data spacings when unset."""
    if cfg.growth.max_gap is not None:
        return cfg
    gap = max(AUTO_GAP * median_spacing / r0, MIN_AUTO_GAP)
    limit = type(cfg.growth).__dataclass_fields__["max_gap"].metadata["max"]
    if gap > limit:  # an r0 far below the data spacing (--spacing 3e-4 on data 0.04 apart)
        raise InputError(
            f"the rest spacing r0 = {r0:.4g} is {median_spacing / r0:.0f} times below the "
            f"data's median point spacing {median_spacing:.4g}: particles that close resolve "
            "the sampling, not the surface (the default r0 is about 2.5 point spacings); give "
            f"--spacing {AUTO_GAP * median_spacing / limit:.4g} or more (or --spacing-relative)"
        )
    return with_values(cfg, growth={"max_gap": gap})
