"""Warnings about a poor mesh, from the measures the fit report already has.

A fit that completes can still write a mesh that downstream tools reject or that does not
represent the data. :func:`mesh_warnings` reads the report's figures and returns one sentence
per defect, naming the figure and what to try; the one figure the report lacks, the largest
component's face count, :func:`fit_warnings` counts from the faces in one pass, and only for a
mesh of :data:`PIECES_COMPONENTS` components or more:

- **crossings**: self-crossing face pairs left after untangling
  (``triangulation.self_intersections_left`` > 0);
- **fragments**: the mesh falls apart. Either its components are debris-sized on average
  (at least :data:`FRAGMENT_COMPONENTS` components holding fewer than
  :data:`recon.winding.MIN_COMPONENT_FACES` faces each on average, the size below which the
  triangulation drops a component as debris next to a real part), or it has at least
  :data:`PIECES_COMPONENTS` components and the largest holds less than
  :data:`MIN_LARGEST_SHARE` of the faces (a third of the surface or more lies in pieces apart
  from the main one, however large they are), or the triangulation kept fewer than
  :data:`MIN_VERTEX_SHARE` of the fitted particles as vertices (it meshes every particle of a
  connected sheet, so most of the sheet became debris or was never joined);
- **far data**: at least 5 % of the input points lie farther than :data:`FAR_DATA_R0` r0
  from the mesh (the fidelity's 95th percentile): the particles interact over a few r0, so
  data that far is not represented by the surface;
- **mesh off the data**: less than :data:`MIN_ON_DATA` of the mesh surface lies within reach
  of an input point (``mesh_to_input.within_reach``, the summary's "mesh on the data"; the
  reach is max(r0, 2.1 median point spacings), beyond which a uniformly random sampling
  leaves 5 % of its surface): a third of the mesh or more bridges gaps or grows past the data;
- **facing down** (untiled fits): an open mesh whose normals the outward vote signed and whose
  mean face normal points down (:func:`facing_warning`): a valley turned inside out, unless it
  was seen from below.

Separate objects are told from pieces by their number: a scan of up to
``PIECES_COMPONENTS - 1`` objects is never warned about whatever their sizes, and several
objects each holding thousands of faces keep the mean component far above the debris limit.
A scan of :data:`PIECES_COMPONENTS` or more separate objects none of which holds
:data:`MIN_LARGEST_SHARE` of the faces is warned about (the sentence says so), since face
counts alone cannot tell it from a surface that fell into as many pieces. At their values here
the rules are quiet on all 27 dev cases and on the held-out shapes of
``benchmarks/bench_thin_parts.py`` (3k and 40k points) at the defaults. A tiled fit has no
fidelity, no mesh-to-data distances and no crossing count of the stitched mesh (its tiles'
counts include their halos): it gets the fragments warning only (its streamed topology counts
the largest component's faces: :class:`recon.tiling.measure.TopologyAccumulator`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, is_dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from ..mesh import face_area_vectors, vertex_components
from ..winding import MIN_COMPONENT_FACES

if TYPE_CHECKING:
    from ..triangulate import TriangulationResult
    from .report import Fidelity, MeshMeasures, MeshToInput, Topology, TriangulationStats

__all__ = [
    "DOWN_FACING",
    "FAR_DATA_R0",
    "FIT_HINT",
    "FRAGMENT_COMPONENTS",
    "MIN_LARGEST_SHARE",
    "MIN_ON_DATA",
    "MIN_VERTEX_SHARE",
    "PIECES_COMPONENTS",
    "crossing_warning",
    "far_data_warning",
    "facing_warning",
    "fit_warnings",
    "fragment_warning",
    "largest_component_faces",
    "mesh_warnings",
    "off_data_warning",
]

#: A mesh of at least this many components whose mean component has fewer than
#: ``MIN_COMPONENT_FACES`` faces has fallen apart (one or two small parts are a small mesh).
FRAGMENT_COMPONENTS = 3
#: A mesh of at least this many components whose largest holds less than
#: ``MIN_LARGEST_SHARE`` of the faces fell apart into pieces, even when they are not debris;
#: fewer components may be as many separate objects (dev set: 1 component, 2 on the bunny with
#: a missing part; held-out shapes: 1).
PIECES_COMPONENTS = 5
#: ... i.e. a third of the surface or more lies in other pieces than the main one (dev set and
#: held-out shapes: the largest holds at least 94 % of the faces, the bunny with a missing
#: part).
MIN_LARGEST_SHARE = 2.0 / 3.0
#: The triangulation meshes every particle of a connected sheet (dev set: 99-100 % of them
#: become vertices); a mesh with fewer vertices than this share of the particles lost most of
#: the sheet.
MIN_VERTEX_SHARE = 0.5
#: Input points farther than this many r0 from the mesh are not represented by it; a warning
#: when at least 5 % of them are (the fidelity's p95; dev set at most 1.5 r0, the 1 %-noise
#: bunny).
FAR_DATA_R0 = 3.0
#: Share of the mesh surface within reach of an input point (``mesh_to_input.within_reach``)
#: below which the mesh bridges gaps or grows past the data: a third of the surface or more
#: has no data under it. A uniformly random sampling leaves 5 % of its surface beyond the
#: reach (dev set: 0.94-1.0 on 24 of the 27 scans), but the reach follows the *median*
#: spacing, so where the density falls the share drops on a sound mesh too (dev set: 0.83 on
#: the non-uniform hemisphere, 0.84 on the non-uniform bunny, 0.88 on the sparse face; held-out:
#: 0.73 on the 20x density gradient at 3k points): a mesh a third off the data stays below.
MIN_ON_DATA = 2.0 / 3.0
#: An open mesh signed by the outward vote whose area-weighted mean face normal has a z below
#: minus this faces down (:func:`facing_warning`; dev set: the open scans' are +0.5 to +1).
DOWN_FACING = 0.5
#: What to try about crossings left by a fit.
FIT_HINT = "try a larger --spacing, or remove outliers from the input"


def _section(value: Any) -> Mapping[str, Any]:
    """A report section as a mapping (a dataclass section or an already plain dict)."""
    if value is None:
        return {}
    if is_dataclass(value) and not isinstance(value, type):
        return asdict(value)
    return value


def crossing_warning(left: int, found: int | None = None, hint: str = FIT_HINT) -> str | None:
    """The warning for ``left`` self-crossing face pairs left after untangling (None if 0).

    Parameters
    ----------
    left : int
        Crossing face pairs left in the written mesh.
    found : int, optional
        Crossing face pairs found before untangling (named in the sentence when given).
    hint : str
        What to try, ending the sentence (:data:`FIT_HINT`; ``oprecon report`` checks meshes
        of any tool).
    """
    if left <= 0:
        return None
    pairs = "pair" if left == 1 else "pairs"
    after = f" left after untangling ({found:,} found)" if found is not None else ""
    return (
        f"the mesh has {left:,} self-crossing face {pairs}{after}: slicers, CGAL booleans and "
        f"other tools that need a self-intersection-free mesh will reject it; {hint}"
    )


def fragment_warning(
    components: int, faces: int, vertices: int, particles: int, largest: int | None = None
) -> str | None:
    """The warning for a mesh that fell apart (None when it did not).

    Parameters
    ----------
    components, faces, vertices : int
        The mesh's connected components, faces and vertices.
    particles : int
        The fitted particles the mesh was triangulated from (0: not known, that test skipped).
    largest : int, optional
        Faces of the largest component (None: not known, that test skipped;
        :func:`largest_component_faces`).
    """
    parts = []
    debris = components >= FRAGMENT_COMPONENTS and faces < MIN_COMPONENT_FACES * components
    pieces = (
        largest is not None
        and components >= PIECES_COMPONENTS
        and largest < MIN_LARGEST_SHARE * faces
    )
    if debris or pieces:
        text = f"falls apart into {components:,} components"
        if debris:
            text += (
                f" of {faces / components:.0f} faces on average (the triangulation's debris "
                f"size is {MIN_COMPONENT_FACES})"
            )
        if pieces:
            text += (
                f", the largest holding only {largest / faces:.0%} of the faces (unless the "
                "scan holds that many separate objects)"
            )
        parts.append(text)
    if particles > 0 and vertices < MIN_VERTEX_SHARE * particles:
        parts.append(
            f"has {vertices:,} vertices from {particles:,} fitted particles "
            f"({vertices / particles:.0%}: the triangulation dropped most of the particle sheet)"
        )
    if not parts:
        return None
    return (
        f"the mesh {' and '.join(parts)}: try a larger --spacing or a larger --max-gap, "
        "or remove outliers from the input"
    )


def far_data_warning(p95: float | None, within_r0: float | None, r0: float) -> str | None:
    """The warning for input points far from the mesh (None when they are not).

    Parameters
    ----------
    p95 : float or None [length]
        95th percentile of the input-to-mesh distances (None: not measured).
    within_r0 : float or None
        Fraction of the input points at most r0 from the mesh (named in the sentence).
    r0 : float [length]
        The rest spacing.
    """
    if p95 is None or not r0 > 0 or not p95 > FAR_DATA_R0 * r0:
        return None
    near = f" and only {within_r0:.0%} lie within r0" if within_r0 is not None else ""
    return (
        f"5 % of the input points lie farther than {p95 / r0:.1f} r0 ({p95:.4g}) from the "
        f"mesh{near}: the mesh misses part of the data; try a larger --spacing or a larger "
        "--max-gap, or remove outliers from the input"
    )


def off_data_warning(within_reach: float | None, reach: float | None, r0: float) -> str | None:
    """The warning for a mesh that lies off the data (None when it does not).

    Parameters
    ----------
    within_reach : float or None
        Share of the mesh surface within ``reach`` of an input point (None: not measured).
    reach : float or None [length]
        That reach (named in the sentence, in r0 too).
    r0 : float [length]
        The rest spacing.
    """
    if within_reach is None or not within_reach < MIN_ON_DATA:
        return None
    where = f" ({reach:.4g}, {reach / r0:.1f} r0)" if reach is not None and r0 > 0 else ""
    return (
        f"only {within_reach:.1%} of the mesh surface lies within reach{where} of an input "
        "point (about 99 % on a sound fit of evenly sampled data): the mesh bridges gaps or "
        "grows past the data; try a smaller --max-gap or a larger --spacing, or check the "
        "normals (--viewpoint)"
    )


def largest_component_faces(faces: Any) -> int:
    """Faces of a mesh's largest connected component (faces joined through shared vertices).

    Parameters
    ----------
    faces : (F, 3) array_like of int
        The mesh's triangles.

    Returns
    -------
    int
        0 for a mesh without faces.

    Examples
    --------
    >>> largest_component_faces([[0, 1, 2], [1, 2, 3], [4, 5, 6]])
    2
    """
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    if len(f) == 0:
        return 0
    count, labels = vertex_components(f, int(f.max()) + 1)
    return int(np.bincount(labels[f[:, 0]], minlength=count).max())


def mesh_warnings(
    topology: Topology | Mapping[str, Any],
    triangulation: TriangulationStats | Mapping[str, Any],
    *,
    particles: int,
    r0: float,
    fidelity: Fidelity | Mapping[str, Any] | None = None,
    mesh_to_input: MeshToInput | Mapping[str, Any] | None = None,
    largest: int | None = None,
) -> tuple[str, ...]:
    """The warnings about a poor mesh, in the order crossings, fragments, far data, off data.

    Parameters
    ----------
    topology : Topology or mapping
        The report's ``topology`` (``n_vertices``, ``n_faces``, ``components``).
    triangulation : TriangulationStats or mapping
        Its ``triangulation`` stats (``self_intersections_left`` and ``_found``; missing keys
        count 0).
    particles : int
        The fitted particles the mesh was triangulated from.
    r0 : float [length]
        The rest spacing.
    fidelity : Fidelity or mapping, optional
        The input-to-mesh distances (``p95``, ``within_r0``); None skips that warning (a tiled
        fit does not measure them).
    mesh_to_input : MeshToInput or mapping, optional
        The mesh-to-input distances (``within_reach``, ``reach``); None skips that warning.
    largest : int, optional
        Faces of the largest component (:func:`largest_component_faces`); None skips the
        fragments warning's largest-share rule.

    Returns
    -------
    tuple of str
        One sentence per defect found; empty for a sound mesh.
    """
    topo, tri, fid = _section(topology), _section(triangulation), _section(fidelity)
    m2i = _section(mesh_to_input)
    found = tri.get("self_intersections_found")
    out = (
        crossing_warning(
            int(tri.get("self_intersections_left", 0)), None if found is None else int(found)
        ),
        fragment_warning(
            int(topo["components"]),
            int(topo["n_faces"]),
            int(topo["n_vertices"]),
            particles,
            largest,
        ),
        far_data_warning(fid.get("p95"), fid.get("within_r0"), r0),
        off_data_warning(m2i.get("within_reach"), m2i.get("reach"), r0),
    )
    return tuple(w for w in out if w is not None)


def fit_warnings(
    measures: MeshMeasures,
    triangulation: TriangulationResult,
    particles: int,
    r0: float,
    normals: Mapping[str, Any] | None = None,
) -> tuple[str, ...]:
    """:func:`mesh_warnings` of an untiled fit: its measures and triangulation, and
    :func:`facing_warning`.

    Parameters
    ----------
    measures : MeshMeasures
        :func:`recon.fitting.report.measure_mesh` of the mesh.
    triangulation : TriangulationResult
        Its ``stats`` (with the self-intersection counts), and the measured mesh's ``faces``
        and ``vertices``: the largest component's share is counted from the faces when the
        mesh has at least :data:`PIECES_COMPONENTS` components (one pass over the faces).
    particles : int
        The fitted particles.
    r0 : float [length]
        The rest spacing.
    normals : mapping, optional
        The report's ``input.normals`` (how they were oriented), for :func:`facing_warning`.
    """
    faces = triangulation.faces
    many = measures.topology.components >= PIECES_COMPONENTS
    found = mesh_warnings(
        measures.topology,
        triangulation.stats,
        particles=int(particles),
        r0=r0,
        fidelity=measures.fidelity,
        mesh_to_input=measures.mesh_to_input,
        largest=largest_component_faces(faces) if many else None,
    )
    loops = measures.topology.boundary_loops
    facing = facing_warning(triangulation.vertices, faces, loops, normals or {})
    return found if facing is None else (*found, facing)


def facing_warning(
    vertices: Any, faces: Any, boundary_loops: int, normals: Mapping[str, Any]
) -> str | None:
    """The warning for an open mesh that faces down because the outward vote signed it (None
    otherwise).

    The outward vote (``normals.orientation: auto`` without a viewpoint) is made for closed
    surfaces: it turns an open surface's convex side out, so a valley or a road in a cut,
    whose convex side is below, faces down. Nothing in the points says whether that is
    wrong (a face seen by a camera looking up the z axis faces down rightly), so the fit says
    so instead of turning it: when the mesh has a boundary, some part was signed by the
    outward vote and the area-weighted mean of the face normals points down
    (:data:`DOWN_FACING`; a closed surface's is 0). LAS/LAZ and E57 inputs say where they were
    seen from (:func:`recon.normals.scanner_positions`) and are not signed so.

    Parameters
    ----------
    vertices : (V, 3) array_like [length]
    faces : (F, 3) array_like of int
    boundary_loops : int
        The mesh's boundary loops (0: closed, never warned about).
    normals : mapping
        The report's ``input.normals``: ``orientation`` and ``component_methods``.
    """
    methods = normals.get("component_methods") or {}
    if boundary_loops == 0 or normals.get("orientation") != "auto" or "outward" not in methods:
        return None
    if len(faces) == 0:
        return None
    cross = face_area_vectors(np.asarray(vertices, dtype=np.float64), np.asarray(faces))
    area = float(np.linalg.norm(cross, axis=1).sum())
    down = float(cross[:, 2].sum()) / area if area > 0 else 0.0
    if not down < -DOWN_FACING:
        return None
    return (
        f"the open mesh faces down (the mean of its face normals has z {down:.2f}): the "
        "outward vote, made for closed shapes, turned its convex side out; if it was seen "
        "from above (terrain, a valley, a road in a cut), give a point above it: --viewpoint "
        "X,Y,Z (file coordinates), or read it from LAS/LAZ or E57, which say so"
    )
