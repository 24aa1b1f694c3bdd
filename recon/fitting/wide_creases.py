"""Crease detection on more points than a fit takes: a tile of a tiled fit
(:func:`recon.tiling.tasks.fit_task`) detects the creases of its core and halo on the points
around them as well, so that near its seams it sees the neighbourhoods an untiled fit sees.

The detection (:func:`recon.creases.detect_creases`) clusters the normals of each point's
``creases.k`` nearest (48: about 8 point spacings across) and then filters whole lines; a tile
that detects on its core and halo alone has the neighbourhoods of its halo's points cut at the
halo's edge, misses the creases its neighbour finds there, and its fit rounds them past the
seam. :func:`creases_around` runs the stages of the fit before the detection (Morton order,
the shared neighbour query, the normals: as :func:`recon.fitting.pipeline.fit_particles` runs
them) on the wider cloud and hands the detection at the fit's points to
:func:`~recon.fitting.pipeline.fit_particles`, whose particle sheet stays on the core and
halo.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy.spatial import cKDTree

from ..cloud import PointCloud, spatial_order
from ..config import ReconConfig
from ..creases import Creases, detect_creases
from ..kernels.options import thread_count
from ..kernels.warm import warm_fit_kernels
from ..normal_scales import per_point_k_max
from ..normals import compute_normals
from .pipeline import shared_neighbors
from .scale import with_neighborhood_size

__all__ = ["creases_around", "detect_fit_creases"]


def detect_fit_creases(
    cloud: PointCloud, cfg: ReconConfig, normals_k_max: int | None = None
) -> Creases | None:
    """The creases a fit of ``cloud`` detects (per row of ``cloud``; None when
    ``creases.enabled`` is off): the same stages as the fit's, on the same points
    (``normals_k_max`` as :func:`recon.fitting.pipeline.fit_particles` takes it)."""
    if not cfg.creases.enabled:
        return None
    warm_fit_kernels()  # (as the fit: the kernels' cached code loads beside the first stages)
    order = spatial_order(cloud.points)
    cloud = cloud.take(order)
    points = np.asarray(cloud.points, dtype=np.float64)
    k_max = normals_k_max
    if k_max is None:
        k_max = per_point_k_max(cfg.normals.k, cfg.normals.per_point_scale)
    with thread_count(cfg.threads):  # a tile's threads, as its fit's
        tree = cKDTree(points)
        cfg = with_neighborhood_size(points, cfg, tree)
        knn = shared_neighbors(points, cfg, tree)
        normals, _ = compute_normals(cloud, cfg.normals, neighbors=knn, k_max=k_max, tree=tree)
        c = cfg.creases
        found = detect_creases(
            points, normals, angle_deg=c.angle_deg, k=c.k, neighbors=knn, tree=tree
        )
    back = np.empty_like(order)
    back[order] = np.arange(len(order))
    return found.take(back)


def creases_around(
    cloud: PointCloud,
    wide: PointCloud,
    cfg: ReconConfig,
    box: tuple[np.ndarray, np.ndarray],
    normals_k_max: int | None = None,
) -> Creases | None:
    """The creases of ``cloud``'s rows as a fit of ``wide`` (a cloud holding every point of
    ``cloud`` and more around them) detects them (:func:`detect_fit_creases`); None when
    ``creases.enabled`` is off.

    Feet and corners are moved to ``cloud``'s origin; the corners kept are those in ``box``
    (lo, hi [length, absolute]: the region ``cloud`` covers, a tile's core and halo), the
    corners a fit of ``cloud`` alone could detect.
    """
    found = detect_fit_creases(wide, cfg, normals_k_max)
    if found is None:
        return None
    here = cloud.absolute_points()
    dist, rows = cKDTree(wide.absolute_points()).query(here)
    scale = max(float(np.abs(here).max()) if len(here) else 0.0, 1.0)
    if len(dist) and float(dist.max()) > 1e-9 * scale:
        raise ValueError("creases_around: cloud holds points that wide does not")
    shift = np.asarray(wide.origin, dtype=np.float64) - np.asarray(cloud.origin, dtype=np.float64)
    corners = found.corners + shift
    lo, hi = box
    inside = np.all((corners >= lo - cloud.origin) & (corners < hi - cloud.origin), axis=1)
    out = found.take(rows)
    return replace(
        out, corners=corners[inside], foot=None if out.foot is None else out.foot + shift
    )
