"""The fit report: typed sections, the measurements of the mesh, and where the report is written.

A :class:`FitReport` is a frozen dataclass made of sections (:class:`InputSummary`,
:class:`StepCounts`, :class:`Timings`, :class:`History`, :class:`TriangulationStats`,
:class:`Topology`, :class:`TriangleQuality`, :class:`Fidelity`, :class:`MeshToInput`,
:class:`OutputPaths`). :meth:`FitReport.to_dict` gives the JSON-ready dictionary written to
``<mesh>.report.json`` (key order and values are part of the format: the regression references
hash it), and :meth:`FitReport.from_dict` reads one back.

:func:`measure_mesh` measures a fitted mesh with :mod:`recon.metrics`: topology, triangle
quality, fidelity (input points to mesh) and the other direction (mesh to input), and
:func:`report_path_for` names the report file of a mesh.
"""

from __future__ import annotations

import copy
from collections.abc import Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import MISSING, dataclass, field, fields
from pathlib import Path
from typing import Any, NamedTuple, TypeVar

import numpy as np

from ..kernels.options import query_workers
from ..metrics import distance_stats, fidelity, quality_report, sample_surface
from ..surface import DataSurface

__all__ = [
    "MESH_SAMPLES_MAX",
    "MESH_SAMPLES_PER_FACE",
    "SAMPLING_REACH",
    "Fidelity",
    "CreaseStats",
    "FitReport",
    "History",
    "InputSummary",
    "MeshMeasures",
    "MeshToInput",
    "OutputPaths",
    "StepCounts",
    "Timings",
    "Topology",
    "TriangleQuality",
    "TriangulationStats",
    "measure_mesh",
    "report_path_for",
]

#: On a surface sampled uniformly at random, 95 % of the surface lies within about 2.1 median
#: nearest-neighbour spacings of a sample (Poisson process: P(d > t) = exp(-pi rho t^2), with
#: rho ~ 0.22 / spacing^2). Mesh farther than max(r0, this) from every input point has grown
#: past the data rather than between samples.
SAMPLING_REACH = 2.1
#: The mesh-to-input distances are measured on this many points per triangle of the mesh ...
MESH_SAMPLES_PER_FACE = 4
#: ... and on at most this many points.
MESH_SAMPLES_MAX = 20_000
#: Meshes up to this many faces get their topology and triangle quality measured in a second
#: thread beside the distances (when the fit has 2+ threads); larger ones one after the
#: other, since the two measures' peaks add up (a 1M-point fit's 1.3M faces: 2.27 GiB
#: together against 1.72 GiB for the distances alone).
CONCURRENT_REPORT_FACES = 200_000

_S = TypeVar("_S", bound="_Section")
#: Field metadata: leave the key out of ``to_dict()`` when the value is None.
_OPTIONAL = {"omit_if_none": True}


def _plain(value: Any) -> Any:
    """The JSON-ready form of a field value: tuples as lists, mappings as independent dicts."""
    if isinstance(value, tuple):
        return list(value)
    if isinstance(value, Mapping):
        return copy.deepcopy(dict(value))
    return value


def _check_keys(
    what: str, data: Mapping[str, Any], required: list[str], optional: list[str]
) -> None:
    """Raise ValueError naming the keys of ``data`` that are missing or unknown."""
    missing = [k for k in required if k not in data]
    unknown = [str(k) for k in data if k not in required and k not in optional]
    problems = [f"missing {', '.join(missing)}"] if missing else []
    problems += [f"unknown {', '.join(unknown)}"] if unknown else []
    if problems:
        raise ValueError(f"{what}: {'; '.join(problems)}")


class _Section:
    """``to_dict``/``from_dict`` of a flat report section whose field names are its JSON keys."""

    def to_dict(self) -> dict[str, Any]:
        """The section as a dict: fields in order, tuples as lists, unset optional keys left out."""
        out: dict[str, Any] = {}
        for f in fields(self):  # type: ignore[arg-type]
            value = getattr(self, f.name)
            if value is None and f.metadata.get("omit_if_none"):
                continue
            out[f.name] = _plain(value)
        return out

    @classmethod
    def from_dict(cls: type[_S], data: Mapping[str, Any]) -> _S:
        """The section from its dict (as :meth:`to_dict` writes it); lists become tuples.

        Raises
        ------
        ValueError
            ``data`` is not a mapping, lacks a required key or has an unknown one.
        """
        if not isinstance(data, Mapping):
            raise ValueError(f"{cls.__name__}: expected a mapping, got {type(data).__name__}")
        known = fields(cls)  # type: ignore[arg-type]
        _check_keys(
            cls.__name__,
            data,
            required=[f.name for f in known if f.default is MISSING],
            optional=[f.name for f in known if f.default is not MISSING],
        )
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in data.items()})


# --------------------------------------------------------------------------------------------
# sections


@dataclass(frozen=True)
class InputSummary(_Section):
    """The input cloud.

    Attributes
    ----------
    points : int
        Number of points (after reading and merging duplicates).
    bbox_diagonal : float [length]
    median_spacing : float [length]
        Median nearest-neighbour distance.
    normals : mapping
        How the normals were obtained: the ``info`` of :func:`recon.normals.compute_normals`
        (``source``, ``n_filled``, ``time_s`` and, when estimated, ``k``, ``radius`` and the
        orientation fields).
    path : str or None
        The input file (set by :func:`recon.fitting.fit_file`; absent from in-memory fits).
    memory_estimate : mapping or None
        The peak memory estimated before the fit (``points``, ``particles``, ``peak_bytes``;
        :mod:`recon.fitting.memory`), set by :func:`recon.fitting.fit_file`.
    """

    points: int
    bbox_diagonal: float
    median_spacing: float
    normals: Mapping[str, Any]
    path: str | None = field(default=None, metadata=_OPTIONAL)
    memory_estimate: Mapping[str, Any] | None = field(default=None, metadata=_OPTIONAL)


@dataclass(frozen=True)
class StepCounts(_Section):
    """Dynamics steps run per phase."""

    grow: int
    release: int


@dataclass(frozen=True)
class Timings:
    """Wall time per phase [s], rounded to 0.1 ms, and their total (rounded from the exact sum).

    In the JSON: ``time_s`` (the phases, in this order) and ``time_total_s``.
    """

    normals: float
    setup: float
    grow: float
    release: float
    triangulate: float
    report: float
    total: float

    @classmethod
    def from_phases(cls, phases: Mapping[str, float]) -> Timings:
        """From :attr:`recon.fitting.schedule.Clock.phases` (exact seconds per phase)."""
        return cls(
            **{k: round(v, 4) for k, v in phases.items()},
            total=round(sum(phases.values()), 4),
        )

    def phases(self) -> dict[str, float]:
        """``{phase: seconds}`` in the order the phases run (the ``time_s`` of the JSON)."""
        return {f.name: getattr(self, f.name) for f in fields(self) if f.name != "total"}


@dataclass(frozen=True)
class History(_Section):
    """The fit's convergence, one entry per growth round and release chunk.

    Attributes
    ----------
    step : tuple of int
        Dynamics steps run so far.
    particles : tuple of int
    kinetic : tuple of float
        Kinetic energy per particle after the last relaxation.
    coverage : tuple of float
        Fraction of the data within ``COVER_RADIUS`` r0 of a particle.
    phase : tuple of str
        ``grow`` or ``release``.
    """

    step: tuple[int, ...]
    particles: tuple[int, ...]
    kinetic: tuple[float, ...]
    coverage: tuple[float, ...]
    phase: tuple[str, ...]


@dataclass(frozen=True)
class TriangulationStats(_Section):
    """What the triangulation did (``stats`` of :func:`recon.triangulate.triangulate_particles`)."""

    method: str
    faces_raw: int
    faces_manifold: int
    holes_filled: int
    small_components_removed: int
    vertices_split: int = 0
    #: edges flipped by the polishing rounds (``triangulation.smooth_rounds``)
    polish_flips: int = 0
    #: which mesh the polish kept: "polished", "held" (polished again with the vertices near
    #: the crossings it left held) or "unpolished" (recon.polish.polish_and_untangle)
    polish_kept: str = "polished"
    #: vertices the polish held near the crossings it left ("held")
    polish_held: int = 0
    #: crossing face pairs found after the repair, and left after untangling
    self_intersections_found: int = 0
    self_intersections_left: int = 0
    #: handles small enough for a geodesic ball of a few spacings, cut out and zipped
    #: (recon.small_handles)
    small_handles_cut: int = 0
    #: open sheets whose data lie on both their sides, made thin closed bodies
    #: (recon.two_sided)
    two_sided_closed: int = 0
    #: vertices of closed components turned outward at the end (wound inward while still
    #: open, then closed by the polish; recon.winding.turn_closed_outward)
    closed_turned_outward: int = 0


@dataclass(frozen=True)
class Topology(_Section):
    """Topology of the mesh: the counts of :func:`recon.topology.mesh_topology`.

    ``watertight`` is the standard definition: every edge in exactly two faces and every
    vertex's faces forming one fan. ``largest_hole_perimeter`` is in input units (0 when the
    mesh is closed); ``largest_hole_r0`` is that loop's diameter ``perimeter / pi`` in r0, the
    unit of ``triangulation.max_hole`` (filled holes have ``perimeter <= pi * max_hole``).
    ``orientable`` is None when not measured: a tiled fit's streamed count checks the
    winding edge by edge, which tells a consistently oriented mesh (orientable) but not
    whether an inconsistently wound one could be made consistent.
    """

    n_vertices: int
    n_faces: int
    n_edges: int
    components: int
    boundary_edges: int
    boundary_loops: int
    non_manifold_edges: int
    non_manifold_vertices: int
    watertight: bool
    orientable: bool | None
    consistently_oriented: bool
    euler_characteristic: int
    genus: int | None
    degenerate_faces: int
    duplicate_faces: int
    unreferenced_vertices: int
    largest_hole_perimeter: float = 0.0
    largest_hole_r0: float = 0.0


@dataclass(frozen=True)
class TriangleQuality(_Section):
    """Triangle shapes: :func:`recon.topology.triangle_quality` (None when nothing measured)."""

    n_measured: int
    min_angle_mean_deg: float | None
    min_angle_p5_deg: float | None
    min_angle_min_deg: float | None
    max_angle_max_deg: float | None
    aspect_ratio_mean: float | None
    aspect_ratio_p95: float | None
    aspect_ratio_max: float | None
    edge_length_mean: float | None
    edge_length_cv: float | None


@dataclass(frozen=True)
class Fidelity(_Section):
    """Distances from the input points to the mesh (:func:`recon.metrics.fidelity`).

    Lengths in input units; ``*_relative`` divided by ``diag`` (the input's bounding-box
    diagonal); ``within_r0`` is the fraction of points at most r0 from the mesh.
    """

    diag: float
    n: int
    mean: float | None
    rms: float | None
    p95: float | None
    max: float | None
    mean_relative: float | None
    rms_relative: float | None
    p95_relative: float | None
    max_relative: float | None
    within_r0: float


@dataclass(frozen=True)
class MeshToInput(_Section):
    """Distances from points sampled on the mesh to the data surface: nothing grown past it?

    Lengths in input units; ``*_relative`` divided by the input's bounding-box diagonal.
    ``within_r0`` and ``within_reach`` are the fractions of the samples at most r0 and at most
    ``reach`` (max of r0 and ``SAMPLING_REACH`` median point spacings) from the data.
    """

    n: int
    mean: float | None
    rms: float | None
    p95: float | None
    max: float | None
    mean_relative: float | None
    rms_relative: float | None
    p95_relative: float | None
    max_relative: float | None
    within_r0: float
    reach: float
    within_reach: float


@dataclass(frozen=True)
class CreaseStats(_Section):
    """Sharp features detected in the data (:mod:`recon.creases`); with ``creases.fit`` the mesh
    keeps them (:mod:`recon.crease_surface`).

    ``length`` [length] is the crease length measured along the crease lines (each crease
    point's foot on the intersection of its two side planes counts ``2 h / m``, ``m`` feet being
    within the local spacing ``h``); ``corners`` the number of corner groups.
    """

    angle_deg: float
    length: float
    length_relative: float
    corners: int
    crease_points: int
    corner_points: int


@dataclass(frozen=True)
class OutputPaths(_Section):
    """The files :func:`recon.fitting.fit_file` wrote (optional ones absent when not asked for)."""

    mesh: str
    particles: str | None = field(default=None, metadata=_OPTIONAL)
    preview: str | None = field(default=None, metadata=_OPTIONAL)
    report: str | None = field(default=None, metadata=_OPTIONAL)
    #: crease vertices duplicated in the PLY (``creases.split_ply``): the file's topology
    #: opens along the creases, the report's ``topology`` is the welded surface's
    crease_vertices_split: int | None = field(default=None, metadata=_OPTIONAL)


# --------------------------------------------------------------------------------------------
# the report


@dataclass(frozen=True)
class FitReport:
    """Everything about one fit: input, scale, schedule, timings, mesh quality, outputs.

    Attributes
    ----------
    oprecon_version : str
    input : InputSummary
    spacing : float [length]
        The rest spacing r0.
    seeds : int
        Number of seed particles.
    particles : int
        Particles left after trimming (the mesh's vertices).
    particles_trimmed : int
        Particles dropped for lying too far from the data.
    steps : StepCounts
    timings : Timings
    coverage : float or None
        Fraction of the data near a particle at the last record (None without records).
    stop_reason : str
        Why growth stopped.
    warnings : tuple of str
    triangulation : TriangulationStats
    noise_estimate : float [length]
        Median RMS residual of the local data surfaces.
    history : History
    config : mapping
        The resolved configuration (:func:`recon.config.config_to_dict`): k, max_gap and a
        halved dt as they were used.
    topology : Topology
    triangle_quality : TriangleQuality
    mesh_bbox_diag : float [length]
    fidelity : Fidelity
    mesh_to_input : MeshToInput
    output : OutputPaths or None
        Set by :func:`recon.fitting.fit_file`.
    spacing_range : (float, float) or None [length]
        Smallest and largest particle rest spacing used (adaptive spacing); None when uniform.
    creases : CreaseStats or None
        Detected sharp creases and corners; None when ``creases.enabled`` is false.
    """

    oprecon_version: str
    input: InputSummary
    spacing: float
    seeds: int
    particles: int
    particles_trimmed: int
    steps: StepCounts
    timings: Timings
    coverage: float | None
    stop_reason: str
    warnings: tuple[str, ...]
    triangulation: TriangulationStats
    noise_estimate: float
    history: History
    config: Mapping[str, Any]
    topology: Topology
    triangle_quality: TriangleQuality
    mesh_bbox_diag: float
    fidelity: Fidelity
    mesh_to_input: MeshToInput
    output: OutputPaths | None = None
    spacing_range: tuple[float, float] | None = None
    creases: CreaseStats | None = None

    def to_dict(self) -> dict[str, Any]:
        """The report as written to ``<mesh>.report.json`` (this key order is the format)."""
        out = {
            "oprecon_version": self.oprecon_version,
            "input": self.input.to_dict(),
            "spacing": self.spacing,
            "seeds": self.seeds,
            "particles": self.particles,
            "particles_trimmed": self.particles_trimmed,
            "steps": self.steps.to_dict(),
            "time_s": self.timings.phases(),
            "time_total_s": self.timings.total,
            "coverage": self.coverage,
            "stop_reason": self.stop_reason,
            "warnings": list(self.warnings),
            "triangulation": self.triangulation.to_dict(),
            "noise_estimate": self.noise_estimate,
            "history": self.history.to_dict(),
            "config": _plain(self.config),
            "topology": self.topology.to_dict(),
            "triangle_quality": self.triangle_quality.to_dict(),
            "mesh_bbox_diag": self.mesh_bbox_diag,
            "fidelity": self.fidelity.to_dict(),
            "mesh_to_input": self.mesh_to_input.to_dict(),
        }
        if self.output is not None:
            out["output"] = self.output.to_dict()
        if self.spacing_range is not None:
            out["spacing_range"] = list(self.spacing_range)
        if self.creases is not None:
            out["creases"] = self.creases.to_dict()
        return out

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> FitReport:
        """A report from its dict (e.g. a ``<mesh>.report.json`` read back).

        ``FitReport.from_dict(r.to_dict()) == r`` for every report of this version.

        Raises
        ------
        ValueError
            A section or key is missing, unknown or of the wrong kind.
        """
        if not isinstance(data, Mapping):
            raise ValueError(f"fit report: expected a mapping, got {type(data).__name__}")
        optional = ("timings", "output", "spacing_range", "creases")
        keys = [f.name for f in fields(cls) if f.name not in optional]
        _check_keys(
            "fit report",
            data,
            [*keys, "time_s", "time_total_s"],
            ["output", "spacing_range", "creases"],
        )
        times = data["time_s"]
        if not isinstance(times, Mapping):
            raise ValueError("fit report: time_s must be a mapping")
        try:
            timings = Timings(**times, total=data["time_total_s"])
        except TypeError as exc:
            raise ValueError(f"fit report: time_s: {exc}") from None
        output = data.get("output")
        return cls(
            oprecon_version=data["oprecon_version"],
            input=InputSummary.from_dict(data["input"]),
            spacing=data["spacing"],
            seeds=data["seeds"],
            particles=data["particles"],
            particles_trimmed=data["particles_trimmed"],
            steps=StepCounts.from_dict(data["steps"]),
            timings=timings,
            coverage=data["coverage"],
            stop_reason=data["stop_reason"],
            warnings=tuple(data["warnings"]),
            triangulation=TriangulationStats.from_dict(data["triangulation"]),
            noise_estimate=data["noise_estimate"],
            history=History.from_dict(data["history"]),
            config=data["config"],
            topology=Topology.from_dict(data["topology"]),
            triangle_quality=TriangleQuality.from_dict(data["triangle_quality"]),
            mesh_bbox_diag=data["mesh_bbox_diag"],
            fidelity=Fidelity.from_dict(data["fidelity"]),
            mesh_to_input=MeshToInput.from_dict(data["mesh_to_input"]),
            output=None if output is None else OutputPaths.from_dict(output),
            spacing_range=(
                None if data.get("spacing_range") is None else tuple(data["spacing_range"])
            ),
            creases=None if data.get("creases") is None else CreaseStats.from_dict(data["creases"]),
        )


# --------------------------------------------------------------------------------------------
# measuring the mesh


class MeshMeasures(NamedTuple):
    """The mesh sections of a :class:`FitReport` (see there)."""

    topology: Topology
    triangle_quality: TriangleQuality
    mesh_bbox_diag: float
    fidelity: Fidelity
    mesh_to_input: MeshToInput


def measure_mesh(
    points: np.ndarray,
    vertices: np.ndarray,
    faces: np.ndarray,
    surface: DataSurface,
    *,
    r0: float,
    median_spacing: float,
    diag: float,
    rng: np.random.Generator,
) -> MeshMeasures:
    """Topology, triangle quality and both directions of fidelity of a fitted mesh.

    Parameters
    ----------
    points : (n, 3) float64 [length]
        The input points, relative to the cloud's origin.
    vertices : (V, 3) float64 [r0]
        Mesh vertices in normalised units (relative to the origin, divided by r0).
    faces : (F, 3) int64
        At least one triangle.
    surface : DataSurface
        The data in normalised units: the mesh-to-input distances go to its nearest data point.
    r0, median_spacing, diag : float [length]
        Rest spacing, median point spacing and bounding-box diagonal of the input.
    rng : numpy.random.Generator
        Draws the points sampled on the mesh.

    Returns
    -------
    MeshMeasures
    """
    absolute = vertices * r0
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="oprecon-report") as pool:
        # topology and triangle quality (numpy and scipy only: no numba parallel region, so
        # any threading layer allows it) beside the distances, when the fit has 2+ threads
        # and the mesh is small enough for both peaks at once
        beside = query_workers() > 1 and len(faces) <= CONCURRENT_REPORT_FACES
        side = pool.submit(quality_report, None, absolute, faces) if beside else None
        fid = fidelity(points, absolute, faces, diag, within={"r0": r0})
        n_samples = min(MESH_SAMPLES_MAX, MESH_SAMPLES_PER_FACE * len(faces))
        samples, _ = sample_surface(vertices, faces, n_samples, rng)
        d_mesh, _ = surface.nearest(samples)
        quality = quality_report(None, absolute, faces) if side is None else side.result()
    reach = max(1.0, SAMPLING_REACH * median_spacing / r0)
    mesh_to_input = {
        **distance_stats(d_mesh * r0, diag),
        "within_r0": float(np.mean(d_mesh <= 1.0)),
        "reach": reach * r0,
        "within_reach": float(np.mean(d_mesh <= reach)),
    }
    return MeshMeasures(
        topology=Topology.from_dict(
            {
                **quality["topology"],
                "largest_hole_r0": quality["topology"]["largest_hole_perimeter"] / (np.pi * r0),
            }
        ),
        triangle_quality=TriangleQuality.from_dict(quality["triangle_quality"]),
        mesh_bbox_diag=quality["mesh_bbox_diag"],
        fidelity=Fidelity.from_dict(fid),
        mesh_to_input=MeshToInput.from_dict(mesh_to_input),
    )


def report_path_for(mesh_path: str | Path) -> Path:
    """``mesh.ply`` -> ``mesh.report.json``: the report that :func:`fit_file` writes beside it.

    Examples
    --------
    >>> report_path_for("out/scan.ply").as_posix()
    'out/scan.report.json'
    """
    mesh_path = Path(mesh_path)
    return mesh_path.with_name(mesh_path.stem + ".report.json")
