r"""How good is a mesh: distances to data or to a reference surface, and the quality report.

- :func:`point_to_mesh_distance`: exact unsigned distance from points to a triangle surface.
- :func:`sample_surface`: area-uniform random points (with face normals) on a mesh.
- :func:`fidelity`: how far input points lie from a mesh (mean, p95, max; absolute and relative).
- :func:`compare_meshes`: Chamfer-L1/L2, Hausdorff, F-score, normal consistency and topology of a
  mesh against a reference mesh or a reference point cloud.
- :func:`check_comparison`: the pass/fail test of a comparison against tolerances.
- :func:`quality_report`: topology + triangle quality + fidelity in one dict.

:func:`~recon.topology.mesh_topology` and :func:`~recon.topology.triangle_quality` live in
:mod:`recon.topology` and are re-exported here.

Notes
-----
**How distances are estimated.** Every comparison samples points on one surface and measures
their *exact* distance to the other surface (closest point on its triangles, with Open3D's
``RaycastingScene``; Embree works in float32, so coordinates are shifted by the common
bounding-box centre and divided by the power of two nearest the mesh's size first, and the
distance is taken in float64 from the returned closest point: error ~1e-7 of the diagonal, in
any units). The usual alternative, nearest neighbours between two dense sample
sets, has a floor: two independent 100k samplings of the same bunny are 1.5e-3 of the diagonal
apart (DESIGN §5), as large as the errors we want to rank. Point-to-surface has no such floor
(a mesh against itself gives 0 up to float32 round-off) and converges to the surface integrals
at the Monte-Carlo rate.

With ``d_mr`` the distances of points sampled on the mesh to the reference surface
("accuracy", drives precision) and ``d_rm`` those of reference samples to the mesh
("completeness", drives recall):

.. math::

    \mathrm{CD}_1 = \tfrac12(\overline{d_{mr}} + \overline{d_{rm}}), \quad
    \mathrm{CD}_2 = \tfrac12(\overline{d_{mr}^2} + \overline{d_{rm}^2}), \quad
    H = \max(\max d_{mr}, \max d_{rm}), \quad
    H_{95} = \max(P_{95}(d_{mr}), P_{95}(d_{rm}))

    P = \Pr[d_{mr} < \tau], \quad R = \Pr[d_{rm} < \tau], \quad F = 2PR / (P + R)

Relative values (``*_relative``) divide lengths by the reference's bounding-box diagonal and
``chamfer_l2`` by its square. When the reference is a point cloud its surface is unknown: the
mesh-to-reference distances go to the nearest reference *point* (an upper bound of the distance
to the sampled surface, inflated by the point spacing), the reference's own points are used as
its samples, and the result says so in ``notes``.

References
----------
[Knap17] A. Knapitsch, J. Park, Q.-Y. Zhou, V. Koltun. "Tanks and Temples: Benchmarking
         Large-Scale Scene Reconstruction". ACM TOG 36(4), 2017 (precision, recall, F-score).
[Berg13] M. Berger et al. "A benchmark for surface reconstruction". ACM TOG 32(2), 2013.
[Mesc19] L. Mescheder et al. "Occupancy Networks". CVPR 2019 (Chamfer-L1, normal consistency).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .errors import InputError
from .geometry import as_points
from .mesh import face_area_vectors, face_normals
from .topology import (
    mesh_topology,
    power_of_two_near,
    topology_and_quality,
    triangle_quality,
    validate_mesh,
)

__all__ = [
    "SurfaceError",
    "check_closest_found",
    "check_comparison",
    "compare_meshes",
    "fidelity",
    "mesh_topology",
    "point_to_mesh_distance",
    "quality_report",
    "sample_surface",
    "triangle_quality",
]


class SurfaceError(InputError):
    """An :class:`~recon.errors.InputError` of :func:`compare_meshes` about one of its two
    surfaces (zero area, an empty or zero-size reference cloud): ``side`` is ``"mesh"`` or
    ``"reference"``, so a caller that read them from files can name the file."""

    def __init__(self, message: str, side: str) -> None:
        super().__init__(message)
        self.side = side


#: Topology fields that ``same_topology`` compares.
TOPOLOGY_KEYS = ("components", "boundary_loops", "genus", "watertight")


# --------------------------------------------------------------------------------------------
# helpers


def _require_faces(vertices: np.ndarray, faces: np.ndarray, name: str = "mesh") -> None:
    if len(faces) == 0:
        raise InputError(f"{name} has no faces")


def _bbox_diag(points: np.ndarray) -> float:
    if len(points) == 0:
        return 0.0
    return float(np.linalg.norm(points.max(axis=0) - points.min(axis=0)))


def _closest_on_mesh(
    points: np.ndarray, vertices: np.ndarray, faces: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Distances ``(n,)`` float64 and closest face indices ``(n,)`` int64 (Embree, float32)."""
    import open3d as o3d  # imported here: ~1 s, only needed for distances

    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    centre = 0.5 * (lo + hi)
    # Embree works in float32 with tolerances of its own: a sphere 1e-10 or 1e12 across had
    # its mean distance off 30-60x. At the power of two nearest the mesh's size the query
    # sees a unit-sized mesh (a power of two changes no bit of the coordinates).
    unit = power_of_two_near(float(np.max(hi - lo)))
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(
        o3d.core.Tensor(np.ascontiguousarray((vertices - centre) / unit, dtype=np.float32)),
        o3d.core.Tensor(np.ascontiguousarray(faces, dtype=np.uint32)),
    )
    query = o3d.core.Tensor(np.ascontiguousarray((points - centre) / unit, dtype=np.float32))
    ans = scene.compute_closest_points(query)
    closest = ans["points"].numpy().astype(np.float64) * unit + centre
    face_idx = ans["primitive_ids"].numpy().astype(np.int64)
    check_closest_found(face_idx, len(faces), points, vertices)
    return np.linalg.norm(points - closest, axis=1), face_idx


def check_closest_found(face_idx: np.ndarray, n_faces: int, *coordinates: np.ndarray) -> None:
    """Raise :class:`~recon.errors.InputError` when Embree's closest-point query (float32)
    returned no face for some points (its invalid id): distances past what it resolves even
    at the mesh's own scale (:func:`_closest_on_mesh`; before that scale, surfaces 1e12
    apart or spans near 1e19 failed). ``coordinates``: the query points and the mesh's
    vertices, for the span the message gives."""
    missed = int(np.count_nonzero((face_idx < 0) | (face_idx >= n_faces)))
    if missed:
        lo = np.min([c.min(axis=0) for c in coordinates if len(c)], axis=0)
        hi = np.max([c.max(axis=0) for c in coordinates if len(c)], axis=0)
        span = float(np.max(hi - lo))
        raise InputError(
            f"the closest-point query found no face for {missed:,} of {len(face_idx):,} points "
            f"(the surfaces span {span:.3g} units together, past what its float32 resolves); "
            "rescale the data or bring the surfaces together"
        )


def distance_stats(d: np.ndarray, diag: float) -> dict[str, float | int | None]:
    """mean, rms, p95, max of distances ``d`` [length], and the same divided by ``diag``."""
    if len(d) == 0:
        stats: dict[str, float | None] = dict.fromkeys(("mean", "rms", "p95", "max"))
    else:
        stats = {
            "mean": float(d.mean()),
            "rms": float(np.sqrt(np.mean(d**2))),
            "p95": float(np.percentile(d, 95)),
            "max": float(d.max()),
        }
    rel = {
        f"{k}_relative": (None if v is None or diag <= 0 else v / diag) for k, v in stats.items()
    }
    return {"n": len(d), **stats, **rel}


# --------------------------------------------------------------------------------------------
# public API


def point_to_mesh_distance(points: Any, vertices: Any, faces: Any) -> np.ndarray:
    """Unsigned distance from each point to the closest point of a triangle surface.

    Parameters
    ----------
    points : (n, 3) array_like of float [length]
        Query points, in the same frame as ``vertices``.
    vertices : (V, 3) array_like of float [length]
        Mesh vertices.
    faces : (F, 3) array_like of int
        Mesh triangles, ``F >= 1``.

    Returns
    -------
    (n,) float64 [length]
        Exact point-to-triangle distances (Open3D ``RaycastingScene``, float32 internally after
        centring, so accurate to ~1e-7 of the mesh's extent).

    Raises
    ------
    InputError
        Malformed arrays or a mesh with no faces.

    Examples
    --------
    >>> import numpy as np
    >>> v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)
    >>> point_to_mesh_distance([[0.2, 0.2, 0.5], [2, 0, 0]], v, [[0, 1, 2]]).round(6)
    array([0.5, 1. ])
    """
    p = as_points(points, finite=True, error=InputError)
    v, f = validate_mesh(vertices, faces)
    _require_faces(v, f)
    if len(p) == 0:
        return np.zeros(0)
    return _closest_on_mesh(p, v, f)[0]


def sample_surface(
    vertices: Any, faces: Any, n: int, seed: int | np.random.Generator | None = 0
) -> tuple[np.ndarray, np.ndarray]:
    """Draw points uniformly by area on a triangle mesh.

    A face is picked with probability proportional to its area, then a point uniformly inside
    it: with ``u, v ~ U(0, 1)``, ``p = (1 - sqrt(u)) a + sqrt(u) (1 - v) b + sqrt(u) v c``
    (Osada et al. 2002, Eq. 1).

    Parameters
    ----------
    vertices : (V, 3) array_like of float [length]
        Mesh vertices.
    faces : (F, 3) array_like of int
        Mesh triangles with positive total area.
    n : int
        Number of samples.
    seed : int or numpy.random.Generator
        The same seed gives the same samples.

    Returns
    -------
    points : (n, 3) float64 [length]
        Samples on the surface.
    normals : (n, 3) float64
        Unit normal of the face each sample lies on (orientation from the face winding).

    Raises
    ------
    InputError
        Malformed arrays, ``n < 0`` or a mesh without area.

    References
    ----------
    R. Osada, T. Funkhouser, B. Chazelle, D. Dobkin. "Shape distributions". ACM TOG 21(4), 2002.
    """
    v, f = validate_mesh(vertices, faces)
    n = int(n)
    if n < 0:
        raise InputError(f"number of samples must be >= 0, got {n}")
    _require_faces(v, f)
    p = v[f]
    cross = face_area_vectors(v, f)
    area2 = np.linalg.norm(cross, axis=1)
    total = float(area2.sum())
    if not total > 0:
        raise InputError("mesh has zero surface area; cannot sample it")
    rng = np.random.default_rng(seed)
    cdf = np.cumsum(area2) / total
    face_idx = np.minimum(np.searchsorted(cdf, rng.random(n), side="right"), len(f) - 1)
    u = np.sqrt(rng.random((n, 1)))
    w = rng.random((n, 1))
    a, b, c = p[face_idx, 0], p[face_idx, 1], p[face_idx, 2]
    points = (1.0 - u) * a + u * (1.0 - w) * b + u * w * c
    normals = cross[face_idx] / area2[face_idx, None]
    return points, normals


def fidelity(
    points: Any, vertices: Any, faces: Any, diag: float, *, within: dict[str, float] | None = None
) -> dict[str, Any]:
    """How far input points lie from a mesh.

    Parameters
    ----------
    points : (n, 3) array_like of float [length]
        Input points (e.g. the point cloud a mesh was fitted to), same frame as ``vertices``.
    vertices : (V, 3) array_like of float [length]
        Mesh vertices.
    faces : (F, 3) array_like of int
        Mesh triangles, ``F >= 1``.
    diag : float [length]
        Normalising length, usually the bounding-box diagonal of ``points``.
    within : dict of str to float [length], optional
        For each ``name: distance``, also ``within_<name>``: the fraction of the points at most
        ``distance`` from the mesh.

    Returns
    -------
    dict
        ``n`` (number of points), ``diag``, and the point-to-surface distance ``mean``, ``rms``,
        ``p95``, ``max`` [length], each also as ``*_relative`` (divided by ``diag``), then the
        ``within_<name>`` fractions.
    """
    p = as_points(points, finite=True, error=InputError)
    diag = float(diag)
    if not np.isfinite(diag) or diag < 0:
        raise InputError(f"diag must be a finite length >= 0, got {diag}")
    d = point_to_mesh_distance(p, vertices, faces)
    result = {"diag": diag, **distance_stats(d, diag)}
    for name, distance in (within or {}).items():
        result[f"within_{name}"] = float(np.mean(d <= distance))
    return result


def _split_reference(reference: Any) -> tuple[str, np.ndarray, np.ndarray | None]:
    """('mesh', V, F) or ('points', P, N|None) from the forms compare_meshes accepts."""
    if hasattr(reference, "absolute_points"):  # recon.io.PointCloud
        return "points", reference.absolute_points(), getattr(reference, "normals", None)
    if not isinstance(reference, (tuple, list)) or len(reference) != 2:
        raise InputError(
            "reference must be a (vertices, faces) mesh or a (points, normals|None) cloud, "
            f"got {type(reference).__name__}"
        )
    first, second = reference
    if second is None:
        return "points", np.asarray(first), None
    second = np.asarray(second)
    if second.size == 0 or np.issubdtype(second.dtype, np.integer):
        return "mesh", np.asarray(first), second
    return "points", np.asarray(first), second


def compare_meshes(
    mesh: tuple[Any, Any],
    reference: Any,
    *,
    n_samples: int = 100_000,
    tau: float | None = None,
    tau_relative: float = 0.01,
    seed: int = 0,
) -> dict[str, Any]:
    """Compare a mesh with a reference surface: Chamfer, Hausdorff, F-score, normals, topology.

    The formulas are in the module docstring. Samples on the mesh are measured against the
    exact reference surface and vice versa (no sample-to-sample floor).

    Parameters
    ----------
    mesh : (vertices (V, 3) float, faces (F, 3) int)
        The mesh under test.
    reference : (vertices, faces), (points (m, 3) float, normals (m, 3) float or None), or a
        ``recon.io.PointCloud``
        The reference. A pair whose second array has an integer dtype is a mesh; otherwise it is
        a point cloud, and only point-based metrics apply (see ``notes`` in the result).
    n_samples : int
        Points sampled on each mesh (a point-cloud reference uses its own points, at most
        ``n_samples`` of them, drawn at random when there are more).
    tau : float or None [length]
        F-score threshold; ``None`` means ``tau_relative`` times the reference diagonal.
    tau_relative : float
        F-score threshold relative to the reference's bounding-box diagonal (default 1 %).
    seed : int
        Seed of the sampling; the same seed gives the same numbers.

    Returns
    -------
    dict
        ``reference_kind`` ('mesh' or 'points'), ``notes`` (list of str), ``n_samples``,
        ``seed``, ``diag`` (reference bounding-box diagonal), ``tau``, ``tau_relative``;
        ``chamfer_l1``, ``chamfer_l2``, ``hausdorff``, ``hausdorff95`` [length or length²] and
        their ``*_relative``; ``precision``, ``recall``, ``fscore`` in [0, 1];
        ``normal_consistency`` (mean ``|n_a . n_b|`` over both directions; ``None`` without
        reference normals) and ``normal_consistency_signed`` (the same without the absolute
        value: negative when orientations disagree); ``mesh_to_reference`` and
        ``reference_to_mesh`` (directed distance statistics, see :func:`fidelity`);
        ``topology`` with ``mesh`` and ``reference`` (``None`` for a point cloud).

    Raises
    ------
    InputError
        Malformed inputs, a mesh without faces, a non-positive threshold.
    SurfaceError
        One of the two surfaces has no area (or the reference cloud no extent); its ``side``
        says which.

    Examples
    --------
    >>> import numpy as np
    >>> v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    >>> f = np.array([[0, 1, 2], [0, 2, 3]])
    >>> r = compare_meshes((v, f), (v + [0, 0, 0.01], f), n_samples=1000)
    >>> round(r["chamfer_l1"], 6), r["fscore"]
    (0.01, 1.0)
    """
    if not isinstance(mesh, (tuple, list)) or len(mesh) != 2:
        raise InputError(f"mesh must be a (vertices, faces) pair, got {type(mesh).__name__}")
    v_m, f_m = validate_mesh(*mesh)
    _require_faces(v_m, f_m, "mesh")
    kind, ref_a, ref_b = _split_reference(reference)
    n_samples = int(n_samples)
    if n_samples < 1:
        raise InputError(f"n_samples must be >= 1, got {n_samples}")
    if int(seed) < 0:
        raise InputError(f"seed must be >= 0, got {seed}")
    seq_mesh, seq_ref = np.random.SeedSequence(int(seed)).spawn(2)
    notes: list[str] = []

    try:
        pts_m, nrm_m = sample_surface(v_m, f_m, n_samples, np.random.default_rng(seq_mesh))
    except InputError as exc:  # zero area
        raise SurfaceError(str(exc), "mesh") from None
    fn_m = face_normals(v_m, f_m)

    if kind == "mesh":
        v_r, f_r = validate_mesh(ref_a, ref_b)
        _require_faces(v_r, f_r, "reference mesh")
        diag = _bbox_diag(v_r[np.unique(f_r)])
        try:
            pts_r, nrm_r = sample_surface(v_r, f_r, n_samples, np.random.default_rng(seq_ref))
        except InputError as exc:  # zero area
            raise SurfaceError(f"reference {exc}", "reference") from None
        d_mr, face_r = _closest_on_mesh(pts_m, v_r, f_r)
        d_rm, face_m = _closest_on_mesh(pts_r, v_m, f_m)
        dots = np.concatenate(
            [
                np.einsum("ij,ij->i", nrm_m, face_normals(v_r, f_r)[face_r]),
                np.einsum("ij,ij->i", nrm_r, fn_m[face_m]),
            ]
        )
        topo_ref: dict[str, Any] | None = mesh_topology(v_r, f_r)
    else:
        from scipy.spatial import cKDTree

        pts_r = as_points(ref_a, "reference points", finite=True, error=InputError)
        if len(pts_r) == 0:
            raise SurfaceError("reference point cloud is empty", "reference")
        nrm_r = None if ref_b is None else np.asarray(ref_b, dtype=np.float64)
        if nrm_r is not None and nrm_r.shape != pts_r.shape:
            raise InputError(
                f"reference normals must have the points' shape {pts_r.shape}, got {nrm_r.shape}"
            )
        diag = _bbox_diag(pts_r)
        if len(pts_r) > n_samples:
            keep = np.sort(np.random.default_rng(seq_ref).choice(len(pts_r), n_samples, False))
            notes.append(f"reference thinned at random from {len(pts_r)} to {n_samples} points")
            pts_r = pts_r[keep]
            nrm_r = None if nrm_r is None else nrm_r[keep]
        d_mr, near_r = cKDTree(pts_r).query(pts_m, workers=1)
        d_rm, face_m = _closest_on_mesh(pts_r, v_m, f_m)
        notes.append(
            "reference is a point cloud: only point-based metrics apply (mesh-to-reference "
            "distances go to the nearest reference point, so they include the point spacing; "
            "no reference topology)"
        )
        if nrm_r is None:
            dots = None
            notes.append("reference has no normals: normal consistency not measured")
        else:
            # Rows without a valid normal (NaN or zero, see recon.io) are left out.
            length = np.linalg.norm(nrm_r, axis=1, keepdims=True)
            valid = np.isfinite(length[:, 0]) & (length[:, 0] > 0)
            unit = np.where(valid[:, None], nrm_r / np.where(valid[:, None], length, 1.0), 0.0)
            dots = np.concatenate(
                [
                    np.einsum("ij,ij->i", nrm_m, unit[near_r])[valid[near_r]],
                    np.einsum("ij,ij->i", unit, fn_m[face_m])[valid],
                ]
            )
            if len(dots) == 0:
                dots = None
                notes.append("reference normals are all invalid: normal consistency not measured")
        topo_ref = None

    if diag <= 0:
        raise SurfaceError("reference has a zero-size bounding box", "reference")
    tau_abs = float(tau) if tau is not None else float(tau_relative) * diag
    if not (np.isfinite(tau_abs) and tau_abs > 0):
        raise InputError(f"F-score threshold tau must be > 0, got {tau_abs}")

    precision = float(np.mean(d_mr < tau_abs))
    recall = float(np.mean(d_rm < tau_abs))
    fscore = 0.0 if precision + recall == 0 else 2 * precision * recall / (precision + recall)
    cd1 = 0.5 * (float(d_mr.mean()) + float(d_rm.mean()))
    cd2 = 0.5 * (float(np.mean(d_mr**2)) + float(np.mean(d_rm**2)))
    haus = max(float(d_mr.max()), float(d_rm.max()))
    haus95 = max(float(np.percentile(d_mr, 95)), float(np.percentile(d_rm, 95)))

    return {
        "reference_kind": kind,
        "notes": notes,
        "n_samples": {"mesh": len(pts_m), "reference": len(pts_r)},
        "seed": int(seed),
        "diag": diag,
        "tau": tau_abs,
        "tau_relative": tau_abs / diag,
        "chamfer_l1": cd1,
        "chamfer_l1_relative": cd1 / diag,
        "chamfer_l2": cd2,
        "chamfer_l2_relative": cd2 / diag**2,
        "hausdorff": haus,
        "hausdorff_relative": haus / diag,
        "hausdorff95": haus95,
        "hausdorff95_relative": haus95 / diag,
        "precision": precision,
        "recall": recall,
        "fscore": float(fscore),
        "normal_consistency": None if dots is None else float(np.mean(np.abs(dots))),
        "normal_consistency_signed": None if dots is None else float(np.mean(dots)),
        "mesh_to_reference": distance_stats(d_mr, diag),
        "reference_to_mesh": distance_stats(d_rm, diag),
        "topology": {"mesh": mesh_topology(v_m, f_m), "reference": topo_ref},
    }


def check_comparison(
    result: dict[str, Any],
    *,
    max_chamfer: float | None = None,
    max_chamfer_abs: float | None = None,
    min_fscore: float | None = None,
    max_hausdorff95: float | None = None,
    same_topology: bool = False,
) -> list[dict[str, Any]]:
    """Test a :func:`compare_meshes` result against tolerances.

    Parameters
    ----------
    result : dict
        Output of :func:`compare_meshes`.
    max_chamfer : float or None
        Upper limit of Chamfer-L1 relative to the reference diagonal (``chamfer_l1_relative``).
    max_chamfer_abs : float or None [length]
        Upper limit of Chamfer-L1 in input units (``chamfer_l1``).
    min_fscore : float or None
        Lower limit of the F-score at the result's ``tau``.
    max_hausdorff95 : float or None
        Upper limit of the 95 % Hausdorff distance relative to the diagonal.
    same_topology : bool
        Require equal ``components``, ``boundary_loops``, ``genus`` and ``watertight``.

    Returns
    -------
    list of dict
        One entry per test: ``metric``, ``value``, ``op`` ('<=', '>=' or '=='), ``limit``,
        ``passed`` (bool) and ``excess`` (how far past the limit, > 0 only when failing;
        ``None`` for topology fields).

    Raises
    ------
    InputError
        ``same_topology`` with a point-cloud reference (it has no topology).
    """
    checks: list[dict[str, Any]] = []

    def bound(metric: str, value: float, op: str, limit: float | None) -> None:
        if limit is None:
            return
        excess = value - limit if op == "<=" else limit - value
        checks.append(
            {
                "metric": metric,
                "value": value,
                "op": op,
                "limit": float(limit),
                "passed": bool(excess <= 0),
                "excess": float(excess),
            }
        )

    bound("chamfer_l1_relative", result["chamfer_l1_relative"], "<=", max_chamfer)
    bound("chamfer_l1", result["chamfer_l1"], "<=", max_chamfer_abs)
    bound("fscore", result["fscore"], ">=", min_fscore)
    bound("hausdorff95_relative", result["hausdorff95_relative"], "<=", max_hausdorff95)
    if same_topology:
        ref = result["topology"]["reference"]
        if ref is None:
            raise InputError("same-topology needs a reference mesh, not a point cloud")
        mine = result["topology"]["mesh"]
        for key in TOPOLOGY_KEYS:
            checks.append(
                {
                    "metric": f"topology.{key}",
                    "value": mine[key],
                    "op": "==",
                    "limit": ref[key],
                    "passed": mine[key] == ref[key],
                    "excess": None,
                }
            )
    return checks


def quality_report(
    points: Any | None,
    vertices: Any,
    faces: Any,
    *,
    diag: float | None = None,
    intersections: bool = False,
    orientation: bool = False,
) -> dict[str, Any]:
    """Topology, triangle quality and (with points) fidelity of a mesh, in one JSON-ready dict.

    Parameters
    ----------
    points : (n, 3) array_like of float [length] or None
        The input points the mesh should represent, same frame as ``vertices``; ``None`` skips
        the fidelity section.
    vertices : (V, 3) array_like of float [length]
        Mesh vertices.
    faces : (F, 3) array_like of int
        Mesh triangles (``F`` may be 0: the counts are then zero and ``fidelity`` None).
    diag : float or None [length]
        Normalising length of the relative distances; default: the bounding-box diagonal of
        ``points``.
    intersections : bool
        Also count the crossing face pairs (``self_intersections``,
        :func:`recon.intersections.self_intersections`).
    orientation : bool
        Also count the closed components and those facing inward (``topology``'s
        ``closed_components`` and ``closed_components_inward``,
        :func:`recon.topology.closed_orientation`).

    Returns
    -------
    dict
        ``topology`` (:func:`~recon.topology.mesh_topology`), ``triangle_quality``
        (:func:`~recon.topology.triangle_quality`), ``mesh_bbox_diag`` [length],
        ``fidelity`` (:func:`fidelity`; ``None`` without points or without faces) and, with
        ``intersections``, ``self_intersections``.
    """
    v, f = validate_mesh(vertices, faces)
    topology, quality = topology_and_quality(v, f, orientation=orientation)
    report: dict[str, Any] = {
        "topology": topology,
        "triangle_quality": quality,
        # the used vertices (np.unique(f), without its sort)
        "mesh_bbox_diag": (
            _bbox_diag(v[np.bincount(f.ravel(), minlength=len(v)) > 0]) if len(f) else _bbox_diag(v)
        ),
        "fidelity": None,
    }
    if intersections:
        from .intersections import self_intersections

        report["self_intersections"] = int(len(self_intersections(v, f)))
    if points is not None and len(f):
        p = as_points(points, finite=True, error=InputError)
        report["fidelity"] = fidelity(p, v, f, _bbox_diag(p) if diag is None else diag)
    return report
