"""Headless pictures of a mesh: three shaded views with defects marked, and the convergence plot.

:func:`render_mesh_png` draws with matplotlib's Agg canvas directly (``Figure`` +
``FigureCanvasAgg``), so it needs no display and changes no global matplotlib state. The views
are orthographic and flat-shaded, drawn back to front (painter's algorithm) as 2-D polygons,
which is much faster than ``mplot3d`` and keeps the aspect ratio exact. Big meshes are
simplified for drawing only (vertex clustering down to about ``max_faces`` triangles); the
highlighted edges always come from the full mesh.

Colours: the front side of a face (its winding makes it face the viewer) is blue-grey, the back
side tan, so an open surface seen from behind or a flipped patch stands out. Boundary edges are
red, non-manifold edges magenta, drawn over the surface (visible even when occluded).

References
----------
[Hun07] J. D. Hunter. "Matplotlib: A 2D graphics environment". Computing in Science &
        Engineering 9(3), 2007.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from .errors import InputError
from .io.files import AtomicOutputs, atomic_output
from .mesh import count_edge_faces, face_normals, vertex_fans
from .topology import degenerate_face_mask, validate_mesh

__all__ = ["check_history", "render_mesh_png"]

#: (name, direction toward the viewer, screen-up hint) of the three views.
VIEWS = (
    ("front (+z)", (0.0, 0.0, 1.0), (0.0, 1.0, 0.0)),
    ("side (+x)", (1.0, 0.0, 0.0), (0.0, 1.0, 0.0)),
    ("oblique", (1.0, 0.8, 1.2), (0.0, 1.0, 0.0)),
)
FRONT_COLOR = np.array([0.60, 0.70, 0.84])
BACK_COLOR = np.array([0.86, 0.72, 0.52])
BOUNDARY_COLOR = "red"
NON_MANIFOLD_COLOR = "magenta"
#: Mesh edges on a detected crease line (issue 12).
CREASE_COLOR = "#0057d9"
_DPI = 100
_PHASE_COLORS = {"grow": "#dde8f5", "release": "#f5e6d0"}


def _cluster_vertices(
    vertices: np.ndarray, faces: np.ndarray, cell: float
) -> tuple[np.ndarray, np.ndarray]:
    """Merge the vertices in each ``cell``-sized voxel; drop collapsed and repeated faces."""
    keys = np.floor((vertices - vertices.min(axis=0)) / cell).astype(np.int64)
    _, label = np.unique(keys, axis=0, return_inverse=True)
    label = label.ravel()
    n = int(label.max()) + 1
    counts = np.bincount(label, minlength=n).astype(np.float64)
    merged = np.stack(
        [np.bincount(label, weights=vertices[:, k], minlength=n) / counts for k in range(3)], 1
    )
    f = label[faces]
    f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 2] != f[:, 0])]
    _, first = np.unique(np.sort(f, axis=1), axis=0, return_index=True)
    return merged, f[np.sort(first)]


def _simplify_for_drawing(
    vertices: np.ndarray, faces: np.ndarray, max_faces: int
) -> tuple[np.ndarray, np.ndarray]:
    """At most ``max_faces`` triangles that look like the mesh (vertex clustering)."""
    if len(faces) <= max_faces:
        return vertices, faces
    p = vertices[faces]
    area = 0.5 * float(np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1).sum())
    # A surface of area A through voxels of size h gives ~1.5 A / h^2 vertices, 2x as many faces.
    cell = np.sqrt(3.0 * area / max_faces) if area > 0 else 1.0
    for _ in range(8):
        v, f = _cluster_vertices(vertices, faces, cell)
        if len(f) <= max_faces:
            return v, f
        cell *= 1.3
    keep = np.sort(np.random.default_rng(0).choice(len(f), max_faces, replace=False))
    return v, f[keep]


def _view_basis(direction: Sequence[float], up: Sequence[float]) -> np.ndarray:
    """Rows: screen right, screen up, toward the viewer."""
    d = np.asarray(direction, dtype=np.float64)
    d /= np.linalg.norm(d)
    u = np.asarray(up, dtype=np.float64)
    right = np.cross(u, d)
    right /= np.linalg.norm(right)
    return np.stack([right, np.cross(d, right), d])


def _draw_view(
    ax: Any,
    name: str,
    basis: np.ndarray,
    vertices: np.ndarray,
    faces: np.ndarray,
    edge_sets: list[tuple[np.ndarray, str, float]],
    all_vertices: np.ndarray,
    extent: np.ndarray,
    markers: np.ndarray | None = None,
    nothing_drawn: str | None = None,
) -> None:
    """One view: ``vertices``/``faces`` (the drawing's, maybe simplified) shaded, the
    ``edge_sets`` (vertex pairs into ``all_vertices``, the mesh's own) on top, and the view
    framed on the points ``extent`` (the vertices the faces use). ``nothing_drawn``: what the
    view says instead of drawing faces (every face degenerate)."""
    from matplotlib.collections import LineCollection, PolyCollection

    ax.set_axis_off()
    ax.set_title(name, fontsize=9)
    frame = extent @ basis.T
    lo, hi = frame[:, :2].min(axis=0), frame[:, :2].max(axis=0)
    pad = 0.04 * float(np.max(hi - lo)) if np.max(hi - lo) > 0 else 1.0
    ax.set_xlim(lo[0] - pad, hi[0] + pad)
    ax.set_ylim(lo[1] - pad, hi[1] + pad)
    ax.set_aspect("equal", adjustable="box")
    if len(faces) == 0 or nothing_drawn:
        text = nothing_drawn or "no faces"
        ax.text(0.5, 0.5, text, ha="center", va="center", transform=ax.transAxes, wrap=True)
    else:
        s = vertices @ basis.T
        tri = s[faces]
        n = face_normals(vertices, faces)
        facing = n @ basis[2]
        light = basis[2] + 0.3 * basis[1] + 0.2 * basis[0]  # a head light, up and right
        light /= np.linalg.norm(light)
        shade = 0.3 + 0.7 * np.abs(n @ light)
        base = np.where(facing[:, None] >= 0, FRONT_COLOR, BACK_COLOR)
        colors = np.clip(base * shade[:, None], 0.0, 1.0)
        order = np.argsort(tri[:, :, 2].mean(axis=1), kind="stable")  # far to near
        ax.add_collection(
            PolyCollection(
                tri[order, :, :2],
                facecolors=colors[order],
                edgecolors=colors[order],  # same colour: hides the anti-aliasing seams
                linewidths=0.3,
            )
        )
    q2 = (all_vertices @ basis.T)[:, :2]
    for edges, color, width in edge_sets:
        if len(edges):
            ax.add_collection(LineCollection(q2[edges], colors=color, linewidths=width, zorder=3))
    if markers is not None and len(markers):
        m = markers @ basis.T
        ax.scatter(m[:, 0], m[:, 1], s=40, facecolors="none", edgecolors=NON_MANIFOLD_COLOR,
                   linewidths=1.2, zorder=4)  # fmt: skip


def non_manifold_vertex_ids(faces: np.ndarray) -> np.ndarray:
    """Vertices whose faces form more than one fan (bow-ties), as in :mod:`recon.topology`."""
    f = faces[
        (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 2] != faces[:, 0])
    ]
    if len(f) == 0:
        return np.zeros(0, dtype=np.int64)
    pairs = np.unique(np.stack([f.ravel(), vertex_fans(f).ravel()], axis=1), axis=0)
    ids, n_fans = np.unique(pairs[:, 0], return_counts=True)
    return ids[n_fans > 1]


def check_history(history: Mapping[str, Any]) -> dict[str, list[Any]]:
    """The lists of a fit history as :func:`render_mesh_png` draws them (numbers as floats).

    Raises
    ------
    InputError
        Not a mapping, no ``step`` list, lists of unequal lengths or non-numbers where numbers
        belong: a caller that read the history from a file can check it first and draw the
        mesh without it (``oprecon report --png``).
    """
    if not isinstance(history, Mapping):
        raise InputError(f"history must be a mapping of lists, got {type(history).__name__}")
    h = {k: list(v) for k, v in history.items() if isinstance(v, (list, tuple, np.ndarray))}
    if "step" not in h:
        raise InputError("history has no 'step' list")
    n = len(h["step"])
    for key in ("particles", "kinetic", "coverage", "phase"):
        if key in h and len(h[key]) != n:
            raise InputError(
                f"history lists must have equal lengths: 'step' has {n}, '{key}' {len(h[key])}"
            )
    for key in ("step", "particles", "kinetic", "coverage"):
        if key in h:
            try:
                h[key] = list(np.asarray(h[key], dtype=np.float64))  # None -> NaN
            except (TypeError, ValueError):
                raise InputError(f"history '{key}' must hold numbers") from None
    return h


def _draw_history(fig: Any, spec: Any, history: dict[str, list[Any]]) -> None:
    top = fig.add_subplot(spec[0])
    bottom = fig.add_subplot(spec[1], sharex=top)
    steps = np.asarray(history["step"], dtype=np.float64)
    top.set_title("convergence", fontsize=9)
    if len(steps) == 0:
        top.text(0.5, 0.5, "empty history", ha="center", va="center", transform=top.transAxes)
    # Phases as shaded spans with their names.
    phases = [str(p) for p in history.get("phase", [])]
    if phases and len(steps):
        starts = [0] + [i for i in range(1, len(phases)) if phases[i] != phases[i - 1]]
        for j, i0 in enumerate(starts):
            i1 = starts[j + 1] if j + 1 < len(starts) else len(phases) - 1
            x0 = steps[i0 - 1] if i0 > 0 else steps[0]
            color = _PHASE_COLORS.get(phases[i0], "#eeeeee")
            for ax in (top, bottom):
                ax.axvspan(x0, steps[i1], color=color, zorder=0, lw=0)
            top.text(
                0.5 * (x0 + steps[i1]), 1.0, phases[i0], fontsize=7, ha="center", va="top",
                transform=top.get_xaxis_transform(),
            )  # fmt: skip
    if "particles" in history and len(steps):
        top.plot(steps, history["particles"], color="tab:blue", lw=1.2)
        top.set_ylabel("particles", color="tab:blue", fontsize=8)
    if "coverage" in history and len(steps):
        twin = top.twinx()
        twin.plot(steps, history["coverage"], color="tab:green", lw=1.2)
        twin.set_ylabel("coverage", color="tab:green", fontsize=8)
        twin.tick_params(labelsize=7)
    if "kinetic" in history and len(steps):
        k = np.asarray(history["kinetic"], dtype=np.float64)
        ok = np.isfinite(k) & (k > 0)
        if ok.any():
            bottom.semilogy(steps[ok], k[ok], color="tab:red", lw=1.2)
        bottom.set_ylabel("kinetic energy", color="tab:red", fontsize=8)
    bottom.set_xlabel("step", fontsize=8)
    for ax in (top, bottom):
        ax.tick_params(labelsize=7)
    top.tick_params(labelbottom=False)


def render_mesh_png(
    path: str | os.PathLike[str],
    vertices: Any,
    faces: Any,
    *,
    history: Mapping[str, Any] | None = None,
    title: str | None = None,
    size: tuple[int, int] = (1500, 500),
    max_faces: int = 60_000,
    outputs: AtomicOutputs | None = None,
    crease_vertices: Any = None,
    marks: Mapping[str, Any] | None = None,
) -> None:
    """Write a PNG of a mesh from three sides, defects marked, plus an optional convergence plot.

    Parameters
    ----------
    path : path-like
        PNG to write (atomically: a partial file never appears under this name).
    vertices : (V, 3) array_like of float [length]
        Mesh vertices.
    faces : (F, 3) array_like of int
        Mesh triangles (may be empty: the panels then say so).
    history : mapping or None
        Fit history, lists of equal length: ``step`` (required), ``particles``, ``kinetic``,
        ``coverage``, ``phase`` (strings such as 'grow' and 'release'). When given, a fourth
        panel plots particles and coverage (top) and kinetic energy on a log scale (bottom)
        per step, with the phases shaded.
    title : str or None
        Heading; a summary of the mesh (faces, boundary and non-manifold edges) follows it.
    size : (int, int)
        Image width and height in pixels.
    max_faces : int
        Draw at most this many triangles (big meshes are simplified for the picture only).
    outputs : AtomicOutputs, optional
        Write as part of this set of outputs (moved into place together when its
        :func:`recon.io.atomic_outputs` block ends) instead of on its own.
    crease_vertices : (V,) array_like of bool, optional
        Vertices on detected crease lines and corners: the mesh edges between two of them are
        drawn in blue (``CREASE_COLOR``).
    marks : mapping, optional
        When ``faces`` only draw a larger mesh (a tiled fit's, never held whole): that mesh's
        ``boundary`` and ``non_manifold`` (E, 2) edges and ``bow_ties`` vertices as indices
        into ``vertices``, and its face count ``faces``; they replace those of ``faces``.

    Raises
    ------
    InputError
        Malformed mesh or history, or a size below 100 x 100 pixels.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    v, f = validate_mesh(vertices, faces)
    referenced = np.unique(f) if len(f) else np.arange(len(v))  # they frame the views
    if len(v):  # centre: keeps precision for georeferenced coordinates (x ~ 1e6)
        v = v - 0.5 * (v[referenced].min(axis=0) + v[referenced].max(axis=0))
    width, height = (int(s) for s in size)
    if width < 100 or height < 100:
        raise InputError(f"image size must be at least 100 x 100 pixels, got {width} x {height}")
    hist = None if history is None else check_history(history)

    if marks is None:
        edges, counts = count_edge_faces(f)
        boundary, non_manifold = edges[counts == 1], edges[counts > 2]
        bow_ties = v[non_manifold_vertex_ids(f)]
        n_faces = len(f)
    else:
        boundary, non_manifold = (
            np.asarray(marks[k], dtype=np.int64).reshape(-1, 2)
            for k in ("boundary", "non_manifold")
        )
        bow_ties = v[np.asarray(marks.get("bow_ties", []), dtype=np.int64)]
        n_faces = int(marks["faces"])
    used = v[referenced] if len(v) else np.zeros((1, 3))
    if marks is not None and len(v):
        used = v  # the marked edges index every vertex (the drawing's and the marked ones)
    draw_v, draw_f = _simplify_for_drawing(v, f, max_faces)
    nothing_drawn = None
    if len(draw_f) and degenerate_face_mask(draw_v, draw_f).all():
        nothing_drawn = "no non-degenerate face to draw"

    fig = Figure(figsize=(width / _DPI, height / _DPI), dpi=_DPI, facecolor="white")
    FigureCanvasAgg(fig)
    outer = fig.add_gridspec(
        1, 1 if hist is None else 2, width_ratios=[3.0] if hist is None else [3.0, 1.25],
        left=0.01, right=0.99 if hist is None else 0.95, bottom=0.09, top=0.86, wspace=0.1,
    )  # fmt: skip
    views = outer[0].subgridspec(1, 3, wspace=0.04)
    creases = _crease_edges(f, crease_vertices, len(v))
    edge_sets = [
        (creases, CREASE_COLOR, 1.2),
        (boundary, BOUNDARY_COLOR, 1.0),
        (non_manifold, NON_MANIFOLD_COLOR, 1.6),
    ]
    for col, (name, direction, up) in enumerate(VIEWS):
        ax = fig.add_subplot(views[0, col])
        basis = _view_basis(direction, up)
        _draw_view(ax, name, basis, draw_v, draw_f, edge_sets, v, used, bow_ties, nothing_drawn)
    if hist is not None:
        panel = outer[1].subgridspec(2, 1, hspace=0.08)
        _draw_history(fig, (panel[0, 0], panel[1, 0]), hist)

    summary = (
        f"{n_faces:,} faces"
        + (f" (drawn: {len(draw_f):,})" if len(draw_f) != n_faces else "")
        + f"   boundary edges (red): {len(boundary):,}"
        + f"   non-manifold edges (magenta): {len(non_manifold):,}"
        + f"   non-manifold vertices (magenta circles): {len(bow_ties):,}"
        + (f"   crease edges (blue): {len(creases):,}" if crease_vertices is not None else "")
        + "   back side of faces: tan"
    )
    fig.suptitle(f"{title}\n{summary}" if title else summary, fontsize=10)
    with atomic_output(path, outputs) as tmp:
        fig.savefig(tmp, format="png", dpi=_DPI, facecolor="white")


def _crease_edges(faces: np.ndarray, crease_vertices: Any, n_vertices: int) -> np.ndarray:
    """(E, 2) mesh edges whose two vertices are crease vertices."""
    if crease_vertices is None or len(faces) == 0:
        return np.zeros((0, 2), dtype=np.int64)
    mask = np.asarray(crease_vertices, dtype=bool).reshape(-1)
    if mask.shape != (n_vertices,):
        raise InputError(f"crease_vertices: expected {n_vertices} flags, got {mask.shape[0]}")
    edges, _ = count_edge_faces(faces)
    return edges[mask[edges].all(axis=1)]
