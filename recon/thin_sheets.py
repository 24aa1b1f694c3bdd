"""One-sided sheets beside a closed body, made thin closed parts of it.

Where a part is thinner than the normals' orientation resolves (the last spacings of a
knife's edge), both faces' particles merge into one sheet, meshed as one open layer beside
the closed body whose edge it continues. :func:`thicken_sheets` makes each such disc two
copies off it joined round its rim (:func:`recon.holes.thicken_sheet`) and joins that to the
body by a short tube (:func:`recon.holes.neck_between`); the triangulation
(:mod:`recon.triangulate`) decides whether the result is kept.

A joined sheet is part of the body, and a sheet that continues it (the edge's next stretch)
is judged against the body with it, so every sheet is tried again after each join, in its
order. A sheet's trial depends only on the body near it, though: a sheet that failed is
tried again only once a join changed the body within the reach of what its trial read
(:class:`recon.holes.FailedTrials`). The sheets joined and their order are those of trying
every sheet again after each join; a mesh shattered into 1,600 pieces no longer pays a
crossing search per sheet and join.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from .holes import FailedTrials, thicken_sheet
from .intersections import face_spheres, self_intersections
from .mesh import face_components, handle_count

__all__ = ["thicken_sheets"]


def thicken_sheets(
    vertices: np.ndarray,
    normals: np.ndarray,
    faces: np.ndarray,
    reach: float,
    half_thickness: float,
    open_body: bool = False,
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """``(vertices, normals, faces)`` with each one-sided open disc within ``reach`` of the
    main body (the largest component) made a closed part ``half_thickness`` either side of
    it and joined to the body; None when none is.

    The new vertices follow the old ones (their normals: the sheet's, then negated); the
    faces are the body's, then the sheets left as they were, unoriented. A sheet whose thick
    copy would cross the body, or that no tube joins without crossing, stays. ``open_body``:
    the body may have boundary loops; else only a closed body (no loop) takes sheets.
    """
    v, f = vertices, faces
    n, label = face_components(f, len(v))
    if n < 2:
        return None
    body = int(np.argmax(np.bincount(label)))
    if not open_body and handle_count(f[label == body], len(v))[1] != 0:
        return None
    sheets = [f[label == k] for k in range(n) if k != body]
    discs = [handle_count(sheet, len(v)) == (1, 1, 0) for sheet in sheets]
    parts_v, parts_n, body_faces = [v], [normals], f[label == body]
    count, joined_any = len(v), True
    failed = FailedTrials()
    while joined_any:
        joined_any = False
        all_v = np.concatenate(parts_v)
        tree = cKDTree(all_v[np.unique(body_faces)])
        largest_face = float(face_spheres(all_v, body_faces)[1].max())  # bounding radius
        for k, sheet in enumerate(sheets):
            if sheet is None or not discs[k] or k in failed:
                continue
            own = v[np.unique(sheet)]
            if tree.query(own)[0].min() > reach:
                failed.add(k, own, reach)  # no body vertex within reach of it
                continue
            new_v, new_f = thicken_sheet(v, sheet, half_thickness)
            trial_v = np.concatenate([all_v, new_v])
            trial_f = np.concatenate([body_faces, new_f + count])
            old = np.arange(len(body_faces))
            new = np.arange(len(body_faces), len(trial_f))
            if len(self_intersections(trial_v, trial_f, new)):
                # a body face crossing the copy meets it inside its box
                failed.add(k, new_v, 2.0 * largest_face)
                continue
            joined = failed.neck(k, trial_v, trial_f, old, new, new_v, largest_face)
            if joined is None:
                continue
            up = normals[np.unique(sheet)]
            parts_v.append(new_v)
            parts_n.append(np.concatenate([up, -up]))
            count += len(new_v)
            body_faces, sheets[k], joined_any = joined, None, True
            break  # the body grew: measure the other sheets' distances to it again
    if count == len(v):
        return None
    faces_all = np.concatenate([body_faces, *(s for s in sheets if s is not None)])
    return np.concatenate(parts_v), np.concatenate(parts_n), faces_all
