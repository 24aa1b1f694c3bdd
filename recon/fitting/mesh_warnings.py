"""Warnings about a poor mesh, from the measures the fit report already has.

A fit that completes can still write a mesh that downstream tools reject or that does not
represent the data. :func:`mesh_warnings` reads the report's figures (no new computation) and
returns one sentence per defect, naming the figure and what to try:

- **crossings**: self-crossing face pairs left after untangling
  (``triangulation.self_intersections_left`` > 0);
- **fragments**: the mesh falls apart. Either its components are debris-sized on average
  (at least :data:`FRAGMENT_COMPONENTS` components holding fewer than
  :data:`recon.winding.MIN_COMPONENT_FACES` faces each on average, the size below which the
  triangulation drops a component as debris next to a real part), or the triangulation kept
  fewer than :data:`MIN_VERTEX_SHARE` of the fitted particles as vertices (it meshes every
  particle of a connected sheet, so most of the sheet became debris or was never joined);
- **far data**: at least 5 % of the input points lie farther than :data:`FAR_DATA_R0` r0
  from the mesh (the fidelity's 95th percentile): the particles interact over a few r0, so
  data that far is not represented by the surface.

Several separate objects give several components each with a real share of the faces: the
mean component size then stays far above the debris limit and no warning is given. At their
values here the rules are quiet on all 27 dev cases and on the held-out shapes of
``benchmarks/bench_thin_parts.py`` (3k and 40k points) at the defaults. A tiled fit has no
fidelity and no crossing count of the stitched mesh (its tiles' counts include their halos):
it gets the fragments warning only.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, is_dataclass
from typing import TYPE_CHECKING, Any

from ..winding import MIN_COMPONENT_FACES

if TYPE_CHECKING:
    from .report import Fidelity, MeshMeasures, Topology, TriangulationStats

__all__ = [
    "FAR_DATA_R0",
    "FIT_HINT",
    "FRAGMENT_COMPONENTS",
    "MIN_VERTEX_SHARE",
    "crossing_warning",
    "far_data_warning",
    "fit_warnings",
    "fragment_warning",
    "mesh_warnings",
]

#: A mesh of at least this many components whose mean component has fewer than
#: ``MIN_COMPONENT_FACES`` faces has fallen apart (one or two small parts are a small mesh).
FRAGMENT_COMPONENTS = 3
#: The triangulation meshes every particle of a connected sheet (dev set: 99-100 % of them
#: become vertices); a mesh with fewer vertices than this share of the particles lost most of
#: the sheet.
MIN_VERTEX_SHARE = 0.5
#: Input points farther than this many r0 from the mesh are not represented by it; a warning
#: when at least 5 % of them are (the fidelity's p95; dev set at most 1.5 r0, the 1 %-noise
#: bunny).
FAR_DATA_R0 = 3.0
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


def fragment_warning(components: int, faces: int, vertices: int, particles: int) -> str | None:
    """The warning for a mesh that fell apart (None when it did not).

    Parameters
    ----------
    components, faces, vertices : int
        The mesh's connected components, faces and vertices.
    particles : int
        The fitted particles the mesh was triangulated from (0: not known, that test skipped).
    """
    parts = []
    if components >= FRAGMENT_COMPONENTS and faces < MIN_COMPONENT_FACES * components:
        parts.append(
            f"falls apart into {components:,} components of {faces / components:.0f} faces "
            f"on average (the triangulation's debris size is {MIN_COMPONENT_FACES})"
        )
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


def mesh_warnings(
    topology: Topology | Mapping[str, Any],
    triangulation: TriangulationStats | Mapping[str, Any],
    *,
    particles: int,
    r0: float,
    fidelity: Fidelity | Mapping[str, Any] | None = None,
) -> tuple[str, ...]:
    """The warnings about a poor mesh, in the order crossings, fragments, far data.

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

    Returns
    -------
    tuple of str
        One sentence per defect found; empty for a sound mesh.
    """
    topo, tri, fid = _section(topology), _section(triangulation), _section(fidelity)
    found = tri.get("self_intersections_found")
    out = (
        crossing_warning(
            int(tri.get("self_intersections_left", 0)), None if found is None else int(found)
        ),
        fragment_warning(
            int(topo["components"]), int(topo["n_faces"]), int(topo["n_vertices"]), particles
        ),
        far_data_warning(fid.get("p95"), fid.get("within_r0"), r0),
    )
    return tuple(w for w in out if w is not None)


def fit_warnings(
    measures: MeshMeasures, triangulation: Mapping[str, Any], particles: int, r0: float
) -> tuple[str, ...]:
    """:func:`mesh_warnings` of an untiled fit: its measures and triangulation stats.

    Parameters
    ----------
    measures : MeshMeasures
        :func:`recon.fitting.report.measure_mesh` of the mesh.
    triangulation : mapping
        The triangulation's ``stats`` (with the self-intersection counts).
    particles : int
        The fitted particles.
    r0 : float [length]
        The rest spacing.
    """
    return mesh_warnings(
        measures.topology,
        triangulation,
        particles=int(particles),
        r0=r0,
        fidelity=measures.fidelity,
    )
