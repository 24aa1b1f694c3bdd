"""Typed pipeline configuration: the only home of defaults.

Every YAML section maps to one frozen dataclass inside :class:`ReconConfig`. Each field carries
its documentation and its allowed range in ``dataclasses.field(metadata=...)``, so that
validation, ``oprecon config show`` and ``configs/default.yaml`` all come from one place.

Lengths in the ``seeds``, ``dynamics``, ``potentials``, ``growth`` and ``triangulation``
sections are in units of the rest spacing r0 (``spacing``) unless the key name says otherwise.
Angles end in ``_deg``.

Precedence (highest first): command-line options > ``--set section.key=value`` >
``--config file.yaml`` > the defaults below.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field, fields, is_dataclass
from pathlib import Path
from typing import Any, ClassVar

import yaml

from .errors import ConfigError, did_you_mean
from .schema import Schema, from_dict, option, range_text, to_dict
from .sizes import parse_size

CONFIG_VERSION = 1


@dataclass(frozen=True)
class IOConfig(Schema):
    PREFIX: ClassVar[str] = "io."

    ascii: bool = option(False, "Write PLY files as ASCII instead of binary little-endian.")
    merge_duplicates: bool = option(True, "Merge exactly repeated points on reading.")
    max_points: int = option(50_000_000, "Refuse inputs with more points than this.", 4, None)
    classes: list[int] = option(
        [], "Keep only the points of these LAS/LAZ classes, e.g. [2, 6]; [] keeps all.", 0, 255
    )
    max_memory: str | int | None = option(
        None,
        "Refuse fits whose estimated peak memory exceeds this: a size such as '8G', '512M' "
        "or 1000000000 (a number of bytes, or K/M/G/T, powers of 1024); null = no limit.",
    )
    outliers: str = option(
        "none",
        "none, or statistical: drop the points whose mean distance to their io.outlier_k nearest "
        "exceeds its median by io.outlier_std_ratio robust std (1.4826 MAD), before normals.",
        choices=("none", "statistical"),
    )
    outlier_k: int = option(20, "Neighbours of the mean distance io.outliers compares.", 1, 500)
    outlier_std_ratio: float = option(3.0, "Robust std over the median to drop.", 0.5, None)

    def check(self, prefix: str) -> None:
        if self.max_memory is not None:
            parse_size(self.max_memory, f"{prefix}max_memory")


@dataclass(frozen=True)
class NormalsConfig(Schema):
    PREFIX: ClassVar[str] = "normals."

    mode: str = option(
        "auto",
        "auto: use the file's normals when present and valid, else estimate; "
        "estimate: always estimate; input: require normals in the file.",
        choices=("auto", "estimate", "input"),
    )
    k: int = option(
        20, "Neighbours for the PCA normal estimate and the local data surfaces.", 3, 500
    )
    auto_scale: bool = option(
        True,
        "Raise k (up to 4x, at most 500) on noisy data until the local surfaces are "
        "thin (median surface variation below 0.05); an explicit `oprecon normals --k` "
        "turns it off.",
    )
    per_point_scale: bool = option(
        True,
        "A point whose k-neighbourhood is not thin takes the best determined of its k, 2k, 4k "
        "nearest (up to 4x the configured k; a wider one only where it is thin or splits into "
        "a thin part's two faces). Closes blades thinner than a neighbourhood on clean data "
        "(a knife edge at 1e-4 noise); false: one k for every point.",
    )
    radius: float | None = option(
        None,
        "Of each point's k nearest, only those within this distance go into its PCA [input "
        "length units]; a point with fewer than 3 within it takes its k nearest, and a radius "
        "with which more than half the points would is refused. Turns off per_point_scale. "
        "null = the k nearest.",
        0.0,
        None,
        lo_open=True,
    )
    orient_k: int = option(
        10, "Neighbours in the orientation graph (Hoppe et al. 1992 MST).", 3, 100
    )
    thin_parts: float = option(
        0.3,
        "Orientation: extra MST cost of neighbour edges that cross the surface, so the two "
        "faces of a thin part are not oriented alike (0 = off, Hoppe's plain MST; on very "
        "noisy data with wide neighbourhoods it costs a few % of correctly signed normals).",
        0.0,
        5.0,
    )
    thin_gap: float = option(
        0.5,
        "Orientation: two faces of a thin part are told apart where the offsets of a point's "
        "30 nearest along its normal split into two groups this many neighbourhood radii "
        "apart (and 5 deviations). Where a part tapers, thin_gap_taper goes further; a "
        "blade thinner than about one spacing everywhere keeps its rim better as one layer "
        "(F@1% 0.98-0.99 at 0.2 everywhere against 0.99-1.0).",
        0.05,
        1.0,
    )
    thin_gap_taper: float = option(
        0.2,
        "Orientation: where a thin part tapers to its edge, its faces are also told apart "
        "where they split only this many neighbourhood radii apart, on the rows joined "
        "(through rows that split) to a patch of 10 or more that split at thin_gap; a part "
        "thinner than thin_gap everywhere has no such patch and is meshed as one layer "
        "(a knife at 5,000 points: watertight, F@1% 0.99 against 0.97-1.0 without the rule). "
        "0, or thin_gap or more: off.",
        0.0,
        1.0,
    )
    exterior_signs: bool = option(
        True,
        "Orientation: on a closed scan, turn over the estimated normals that point away from "
        "the side from which a ball coming from outside reaches the point first (thin parts "
        "a few spacings thick whose faces the propagation got inside out).",
    )
    orientation: str = option(
        "auto",
        "Global sign: auto (outward if the surface looks closed, else "
        "toward the viewpoint or +z), outward, viewpoint, or none.",
        choices=("auto", "outward", "viewpoint", "none"),
    )
    viewpoint: list[float] | None = option(
        None,
        "Scanner position [x, y, z] for range scans "
        "(input length units); implies orientation toward it.",
    )

    def check(self, prefix: str) -> None:
        if self.viewpoint is not None and len(self.viewpoint) != 3:
            raise ConfigError(
                f"{prefix}viewpoint: expected 3 numbers [x, y, z], got {self.viewpoint}"
            )


@dataclass(frozen=True)
class SeedsConfig(Schema):
    PREFIX: ClassVar[str] = "seeds."

    spacing: float | None = option(
        None,
        "Absolute rest spacing r0 [input length units]; null = derived from the data.",
        0.0,
        None,
        lo_open=True,
    )
    spacing_relative: float | None = option(
        None,
        "Rest spacing r0 as a fraction of the bounding-box diagonal; null = derived from the data.",
        0.0,
        1.0,
        lo_open=True,
    )
    spacing_factor: float = option(
        2.5,
        "r0 = spacing_factor x median nearest-neighbour distance "
        "of the input (used when spacing and spacing_relative are null).",
        0.1,
        100.0,
    )
    min_particles: int = option(
        10_000,
        "Resolution floor: r0 shrinks (down to the data spacing x "
        "0.8) so that the sheet has about this many particles; sparse "
        "inputs are then interpolated between samples.",
        0,
        None,
    )
    thinning: float = option(1.0, "Seeds are Poisson-disk thinned to this distance [r0].", 0.3, 5.0)
    adaptive: bool = option(
        False,
        "Adaptive spacing (experimental): each particle's rest spacing follows the local "
        "feature size of the data (radius of curvature, half the thickness to the opposite "
        "sheet), not below the local data spacing, clamped to [spacing_min, spacing_max].",
    )
    spacing_min: float = option(0.5, "Adaptive spacing: smallest rest spacing [r0].", 0.1, 1.0)
    spacing_max: float = option(1.5, "Adaptive spacing: largest rest spacing [r0].", 1.0, 4.0)
    spacing_step: float = option(
        0.15, "Adaptive spacing: largest relative change of a spacing per round.", 0.01, 1.0
    )

    def check(self, prefix: str) -> None:
        if self.spacing is not None and self.spacing_relative is not None:
            raise ConfigError(
                f"{prefix}spacing and {prefix}spacing_relative are exclusive; set one"
            )


@dataclass(frozen=True)
class DynamicsConfig(Schema):
    PREFIX: ClassVar[str] = "dynamics."

    dt: float = option(0.2, "Time step [r0-units of time; m = I = 1].", 0.0, 1.0, lo_open=True)
    max_steps: int = option(3000, "Hard cap on dynamics steps over all phases.", 1, None)
    max_particles: int = option(2_000_000, "Hard cap on the particle count.", 4, None)
    damping_linear: float = option(2.0, "beta_0: linear velocity damping.", 0.0, None)
    damping_angular: float = option(2.0, "beta_2: angular velocity damping.", 0.0, None)
    damping_relative_linear: float = option(
        0.0, "beta_1: relative damping between neighbours (T-thesis eq. 4.10 sign).", 0.0, None
    )
    damping_relative_angular: float = option(0.0, "beta_3: relative angular damping.", 0.0, None)
    release_damping: float | None = option(
        None,
        "beta_0 and beta_2 during the release (the smoothing after the seeds let go); null = "
        "damping_linear and damping_angular.",
        0.0,
        None,
    )
    release_quench_steps: int = option(
        0,
        "The release's last steps run with damping_linear and damping_angular again (with "
        "release_damping set): a lightly damped release relaxes the sheet in fewer steps, "
        "the heavy damping at its end then stops the particles' jitter.",
        0,
        100_000,
    )
    max_displacement: float = option(
        0.1, "Per-step displacement cap [r0].", 0.0, 10.0, lo_open=True
    )
    max_rotation_deg: float = option(
        17.0, "Per-step rotation cap [degrees].", 0.0, 180.0, lo_open=True
    )
    skin: float = option(
        0.4,
        "Neighbour-list skin [r0]; lists are rebuilt after skin/2 motion.",
        0.0,
        5.0,
        lo_open=True,
    )
    relax_steps: int = option(15, "Relaxation steps after each growth round.", 1, 10_000)
    release_steps: int = option(100, "Steps after the seeds are released (smoothing).", 0, 100_000)
    kinetic_tolerance: float = option(
        1e-4,
        "The sheet is at rest when its kinetic energy per particle falls below this "
        "[r0^2/time^2; 1e-4: mean speed ~0.014 r0 per time unit]: a growth round's relaxation "
        "and a release chunk stop early (checked every 5 steps), and the release ends after "
        "its gap refills once a chunk ends at rest. 0 = always run relax_steps and "
        "release_steps.",
        0.0,
        1.0,
    )
    fidelity: float = option(
        5.0, "Point-to-plane pull toward the data (0 = pure smoothing).", 0.0, 100.0
    )
    fidelity_normal: float = option(
        0.5, "Torque aligning particle normals with data normals.", 0.0, 100.0
    )
    time_limit: float | None = option(
        None, "Wall-clock limit for one fit [s]; null = none.", 0.0, None, lo_open=True
    )


@dataclass(frozen=True)
class PotentialsConfig(Schema):
    PREFIX: ClassVar[str] = "potentials."

    w_lj: float = option(
        1.0, "alpha_LJ: weight of the spacing (Lennard-Jones 4-2) potential.", 0.0, None
    )
    w_planarity: float = option(1.0, "alpha_P: co-planarity weight (S&T92 eq. 3).", 0.0, None)
    w_normality: float = option(1.0, "alpha_N: co-normality weight (S&T92 eq. 4).", 0.0, None)
    w_circularity: float = option(0.0, "alpha_C: co-circularity weight (S&T92 eq. 5).", 0.0, None)
    cutoff: float = option(
        2.0, "Interaction cutoff [r0] (LJ shifted-force truncation and psi).", 1.2, 5.0
    )
    weighting: str = option(
        "poly",
        "psi: poly (1-(d/rc)^2)^2, gaussian exp(-d^2/(2 s^2)), or "
        "anisotropic (S&T92 eq. 7 in the particle frame).",
        choices=("poly", "gaussian", "anisotropic"),
    )
    influence_radius: float = option(
        1.0, "sigma of the gaussian/anisotropic weight [r0].", 0.0, 5.0, lo_open=True
    )
    anisotropy: float = option(
        2.0,
        "Anisotropic weight: normal-direction sigma divisor "
        "(sigma_n = influence_radius / anisotropy).",
        1.0,
        20.0,
    )
    separate_opposed: bool = option(
        True,
        "Particles with opposed normals (n_i . n_j < 0, the two sides of a thin part) feel "
        "only the repulsive branch of the spacing potential and no orientation terms: "
        "opposite sheets never attract, align or merge.",
    )


@dataclass(frozen=True)
class GrowthConfig(Schema):
    PREFIX: ClassVar[str] = "growth."

    enabled: bool = option(True, "Run the growing and stretching rules.")
    max_rounds: int = option(40, "Cap on growth rounds.", 0, 10_000)
    grow_radius: float = option(
        1.5, "Neighbours within this distance count for the growing rule [r0].", 0.5, 5.0
    )
    gap_angle_deg: float = option(
        100.0, "An angular gap wider than this gets new particles.", 30.0, 359.0
    )
    gap_step_deg: float = option(
        60.0, "One new particle per this many degrees of gap.", 10.0, 180.0
    )
    min_neighbors: int = option(
        0, "Growing rule applies to particles with at least this many neighbours.", 0, 50
    )
    max_neighbors: int = option(5, "... and at most this many.", 1, 50)
    stretch_min: float = option(2.0, "Stretching rule: pair distance lower bound [r0].", 1.0, 10.0)
    stretch_max: float = option(2.5, "Stretching rule: pair distance upper bound [r0].", 1.0, 10.0)
    reject_radius: float = option(
        0.8, "Reject a candidate this close to a particle [r0].", 0.1, 2.0
    )
    max_gap: float | None = option(
        None,
        "Holes wider than this are not filled; candidates farther "
        "than max_gap/2 from the data are rejected [r0]. null = 10 x the "
        "median data spacing (4 r0 on dense data).",
        0.5,
        1000.0,
    )
    tangent_tolerance: float = option(
        0.5, "Reject a candidate farther than this from the local data plane [r0].", 0.01, 5.0
    )
    min_add_fraction: float = option(
        0.005, "Stop growing when a round adds fewer than this fraction of the particles.", 0.0, 1.0
    )
    active_radius: float = option(
        3.0,
        "Active set of a growth round's relaxation [r0]: only free particles within this "
        "distance of the last round's additions (or whose rest spacing changed) move, the "
        "relaxed rest of the sheet is held like the seeds (the release moves them all). "
        "0 = all free particles move.",
        0.0,
        None,
    )

    def check(self, prefix: str) -> None:
        if self.stretch_min > self.stretch_max:
            raise ConfigError(
                f"{prefix}stretch_min ({self.stretch_min}) must not exceed "
                f"{prefix}stretch_max ({self.stretch_max})"
            )
        if self.min_neighbors > self.max_neighbors:
            raise ConfigError(f"{prefix}min_neighbors must not exceed {prefix}max_neighbors")


@dataclass(frozen=True)
class TriangulationConfig(Schema):
    PREFIX: ClassVar[str] = "triangulation."

    method: str = option(
        "ball_pivoting",
        "ball_pivoting (manifold, default) or circumsphere "
        "(S&T92 empty-circumsphere test, for comparison).",
        choices=("ball_pivoting", "circumsphere"),
    )
    radii: list[float] = option([0.7, 1.0, 1.4, 2.0], "Ball-pivoting radii [r0].")
    fill_holes: bool = option(True, "Fill holes whose perimeter is below pi * max_hole.")
    max_hole: float | None = option(
        None, "Largest hole diameter to fill [r0]; null = growth.max_gap.", 0.0, None
    )
    max_density_scale: float = option(
        4.0,
        "Where the data is sparser than its median, ball radii, hole sizes and the "
        "data-coverage test scale with the local point spacing, up to this factor "
        "(1 = one uniform r0 everywhere).",
        1.0,
        None,
    )
    project_to_data: bool = option(
        True,
        "Move the final particles onto the local data surface "
        "(quadric fit) along its normal before meshing.",
    )
    smooth_rounds: int = option(
        2,
        "Rounds of mesh polishing after triangulation: angle-raising edge flips, then every "
        "vertex moved part of the way to its neighbours' centroid within its tangent plane and "
        "back onto the local data surface (with project_to_data; crease and boundary vertices "
        "stay). Raises the mean minimum angle by 0.3-2.5 degrees on the dev set. 0 = the "
        "particles as they are.",
        0,
        100,
    )
    smooth_flips: bool = option(
        True, "Edge flips in the polishing rounds (smooth_rounds); false = smoothing only."
    )
    trim_distance: float = option(
        1.0,
        "Drop particles farther than this from the local data plane, "
        "or farther than max_gap/2 from any data point [r0].",
        0.0,
        None,
        lo_open=True,
    )

    def check(self, prefix: str) -> None:
        if not self.radii:
            raise ConfigError(f"{prefix}radii: expected at least one radius")
        if any(r <= 0 for r in self.radii):
            raise ConfigError(f"{prefix}radii: every radius must be > 0, got {self.radii}")


@dataclass(frozen=True)
class CreasesConfig(Schema):
    PREFIX: ClassVar[str] = "creases."

    enabled: bool = option(
        True,
        "Detect sharp creases and corners in the data (Gauss-map clustering, recon.creases), "
        "report their length and count and keep them sharp in the mesh (creases.fit). Only "
        "long folds count: crease lines at least 5 neighbourhood radii long whose sides two "
        "planes fit down to the noise and one quadric does not. --no-creases turns it off.",
    )
    angle_deg: float = option(
        50.0,
        "Smallest angle between the two face normals that counts as a crease [deg] "
        "(0 = flat, 90 = box edge, 180 = knife edge).",
        5.0,
        175.0,
    )
    k: int = option(48, "Neighbourhood size of the normal clustering.", 16, 500)
    fit: bool = option(
        True,
        "Use the detected creases in the fit (when enabled): particles near a crease are "
        "anchored to the plane of their side, particles on a crease line or corner are snapped "
        "onto it and made unoriented (spacing only, no smoothing across the edge), and the "
        "mesh keeps the edge. False: detection feeds the report only.",
    )
    split_ply: bool = option(
        False,
        "PLY output: duplicate the vertices on creases, one copy per side with its side's "
        "normal (the surface is closed but its topology opens along the creases). False keeps "
        "them welded with one averaged normal (watertight). OBJ output always splits the "
        "normals per face corner (f v//vn) and keeps the vertices welded.",
    )


@dataclass(frozen=True)
class OutputConfig(Schema):
    PREFIX: ClassVar[str] = "output."

    write_report: bool = option(True, "Write <mesh>.report.json beside the mesh.")
    vertex_normals: bool = option(True, "Write per-vertex normals.")
    colors: bool = option(
        True,
        "When the input has colours, give each mesh vertex the distance-weighted mean colour "
        "of its nearest input points (PLY red green blue).",
    )
    obj_colors: bool = option(
        False, "Also write vertex colours into OBJ meshes, as 'v x y z r g b' (floats 0-1)."
    )
    transfer: list[str] = option(
        [],
        "Input attributes added as PLY vertex properties: intensity (weighted mean), "
        "classification (majority of the nearest points).",
        choices=None,
    )
    quality: bool = option(
        False, "Add a PLY vertex property 'quality': distance to the nearest input point [r0]."
    )
    attribute_neighbors: int = option(
        8, "Nearest input points per vertex for colours and transferred attributes.", 1, 64
    )

    def check(self, prefix: str) -> None:
        for name in self.transfer:
            if name not in ("intensity", "classification"):
                raise ConfigError(
                    f"{prefix}transfer: {name!r} is not one of: intensity, classification"
                    f"{did_you_mean(name, ['intensity', 'classification'])}"
                )


@dataclass(frozen=True)
class TilingConfig(Schema):
    PREFIX: ClassVar[str] = "tiling."

    size: float | None = option(
        None,
        "Fit in cubic tiles of this side [input length units], each on its own worker, and "
        "stitch one seamless mesh (oprecon fit --tile-size); null = one piece unless auto.",
        0.0,
        None,
        lo_open=True,
    )
    auto: bool = option(
        False,
        "Tile when one fit would exceed the memory budget (io.max_memory, else "
        "tiling.memory), with the largest tile size whose fit stays within it (--tiles auto).",
    )
    memory: str | int = option(
        "2G",
        "Memory budget of one tile's fit with tiling.auto when io.max_memory is unset "
        "(a size such as '2G' or a number of bytes).",
    )
    halo: float = option(
        4.0,
        "Each tile also fits (and triangulates over) the data this far around its core [r0].",
        2.0,
        50.0,
    )
    task_time_limit: float | None = option(
        None,
        "Seconds one tile's task may run before it is taken for stuck, stopped and run once "
        "more (a worker short of memory can hang); null = 120 s + 5 ms per point of the tile.",
        0.0,
        None,
        lo_open=True,
    )

    def check(self, prefix: str) -> None:
        parse_size(self.memory, f"{prefix}memory")


@dataclass(frozen=True)
class ReconConfig(Schema):
    version: int = option(CONFIG_VERSION, "Configuration format version.", 1, 1)
    seed: int = option(0, "Random seed: same input, config and seed give the same mesh.", 0, None)
    threads: int | None = option(
        None,
        "Threads for the numba kernels (capped by NUMBA_NUM_THREADS); null = all usable cores "
        "(oprecon batch: cores / jobs). The mesh does not depend on it.",
        1,
        None,
    )
    io: IOConfig = field(default_factory=IOConfig, metadata={"doc": "Reading and writing."})
    normals: NormalsConfig = field(
        default_factory=NormalsConfig, metadata={"doc": "Normal estimation and orientation."}
    )
    seeds: SeedsConfig = field(
        default_factory=SeedsConfig, metadata={"doc": "Rest spacing r0 and pinned seed particles."}
    )
    dynamics: DynamicsConfig = field(
        default_factory=DynamicsConfig,
        metadata={"doc": "Integrator, damping, caps, data fidelity."},
    )
    potentials: PotentialsConfig = field(
        default_factory=PotentialsConfig, metadata={"doc": "Pair potentials and weighting."}
    )
    growth: GrowthConfig = field(
        default_factory=GrowthConfig, metadata={"doc": "Growing and stretching rules, gap control."}
    )
    triangulation: TriangulationConfig = field(
        default_factory=TriangulationConfig, metadata={"doc": "Meshing the particles."}
    )
    output: OutputConfig = field(
        default_factory=OutputConfig, metadata={"doc": "What is written beside the mesh."}
    )
    creases: CreasesConfig = field(
        default_factory=CreasesConfig,
        metadata={"doc": "Sharp-feature detection (reported; the mesh is unchanged)."},
    )
    tiling: TilingConfig = field(
        default_factory=TilingConfig,
        metadata={"doc": "Tiled fits of large scans (seamless stitching)."},
    )


SECTIONS: tuple[str, ...] = tuple(
    f.name
    for f in fields(ReconConfig)
    if is_dataclass(f.default_factory)  # type: ignore[arg-type]
)


def config_from_dict(data: Mapping[str, Any] | None) -> ReconConfig:
    """Build and validate a :class:`ReconConfig` from a (YAML-like) mapping.

    Raises :class:`ConfigError` naming the dotted key for unknown keys (with the nearest valid
    key), wrong types and out-of-range values.
    """
    return from_dict(ReconConfig, data or {}, "")


def config_to_dict(cfg: Any) -> dict[str, Any]:
    """Plain nested dict of a config (lists copied), suitable for YAML/JSON."""
    return to_dict(cfg)


def load_yaml_file(path: str | Path) -> Any:
    """Read a YAML file safely; syntax errors name the file, line and column, and a key
    repeated within one mapping is refused with its line (YAML would keep the last)."""
    p = Path(path)
    if not p.exists():
        raise ConfigError(f"{p}: no such configuration file")
    if p.is_dir():
        raise ConfigError(f"{p}: is a directory, expected a YAML file")
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{p}: cannot read: {exc}") from None
    try:
        data = yaml.safe_load(text)
        repeated = duplicate_keys(yaml.compose(text, Loader=yaml.SafeLoader))
    except yaml.constructor.ConstructorError as exc:
        mark = exc.problem_mark
        where = f"line {mark.line + 1}, column {mark.column + 1}" if mark is not None else "?"
        tag = (exc.problem or "").rsplit(" ", 1)[-1].replace("tag:yaml.org,2002:", "!!")
        raise ConfigError(
            f"{p}: YAML tag {tag} at {where} is not allowed: configuration files hold plain "
            "values only (python object tags are never executed)"
        ) from None
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark
        where = f"line {mark.line + 1}, column {mark.column + 1}" if mark is not None else "?"
        raise ConfigError(f"{p}: invalid YAML at {where}: {exc.problem}") from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"{p}: invalid YAML: {exc}") from None
    if repeated:  # YAML keeps the last silently; a repeated key is a mistake in a settings file
        dotted, line = repeated[0]
        raise ConfigError(f"{p}, line {line}: {dotted}: duplicate key")
    return data


def duplicate_keys(root: yaml.Node | None) -> list[tuple[str, int]]:
    """Keys repeated within one mapping of a composed YAML document: ``(dotted key, line)``
    of each repetition (1-based lines; list items as ``key[i]``)."""
    out: list[tuple[str, int]] = []

    def walk(node: yaml.Node, prefix: str) -> None:
        if isinstance(node, yaml.MappingNode):
            seen: set[str] = set()
            for key_node, value_node in node.value:
                key = str(key_node.value) if isinstance(key_node, yaml.ScalarNode) else "?"
                if key in seen:
                    out.append((prefix + key, key_node.start_mark.line + 1))
                seen.add(key)
                walk(value_node, f"{prefix}{key}.")
        elif isinstance(node, yaml.SequenceNode):
            for i, item in enumerate(node.value):
                walk(item, f"{prefix.rstrip('.')}[{i}].")

    if root is not None:
        walk(root, "")
    return out


def parse_override(text: str) -> tuple[str, Any]:
    """Parse ``section.key=value`` (the value is read as YAML: ``0.1``, ``true``, ``[1, 2]``)."""
    if "=" not in text:
        raise ConfigError(f"--set {text!r}: expected section.key=value")
    key, raw = text.split("=", 1)
    key = key.strip()
    if not key:
        raise ConfigError(f"--set {text!r}: empty key")
    try:
        value = yaml.safe_load(raw) if raw.strip() else None
    except yaml.YAMLError:
        value = raw
    return key, value


def apply_overrides(cfg: ReconConfig, overrides: Mapping[str, Any]) -> ReconConfig:
    """Return a new config with dotted-key overrides applied and validated."""
    data = config_to_dict(cfg)
    for dotted, value in overrides.items():
        parts = dotted.split(".")
        node: Any = data
        for i, part in enumerate(parts[:-1]):
            if not isinstance(node, dict) or part not in node or not isinstance(node[part], dict):
                valid = (
                    [k for k, v in node.items() if isinstance(v, dict)]
                    if isinstance(node, dict)
                    else []
                )
                where = ".".join(parts[: i + 1])
                raise ConfigError(f"unknown section '{where}'{did_you_mean(part, valid)}")
            node = node[part]
        leaf = parts[-1]
        if leaf not in node:
            raise ConfigError(f"unknown key '{dotted}'{did_you_mean(leaf, node)}")
        if isinstance(node[leaf], dict):
            raise ConfigError(
                f"'{dotted}' is a section; set one of its keys, e.g. {dotted}."
                f"{next(iter(node[leaf]))}"
            )
        node[leaf] = value
    return config_from_dict(data)


def load_config(
    path: str | Path | None = None, overrides: Mapping[str, Any] | Iterable[str] | None = None
) -> ReconConfig:
    """Defaults, then the YAML file at ``path``, then dotted overrides.

    ``overrides`` is a mapping ``{"dynamics.dt": 0.1}`` or an iterable of ``"key=value"``
    strings as given to ``--set``.
    """
    cfg = ReconConfig()
    if path is not None:
        data = load_yaml_file(path)
        try:
            cfg = config_from_dict(data)
        except ConfigError as exc:
            raise ConfigError(f"{path}: {exc}") from None
    if overrides:
        if not isinstance(overrides, Mapping):
            overrides = dict(parse_override(t) for t in overrides)
        cfg = apply_overrides(cfg, overrides)
    return cfg


def with_values(cfg: ReconConfig, **sections: Mapping[str, Any]) -> ReconConfig:
    """Return ``cfg`` with some keys replaced, e.g. ``with_values(cfg, dynamics={"dt": 0.1})``.

    Values go through the same validation as a file. Keys whose value is ``None`` are skipped,
    so CLI options that were not given can be passed through unchanged.
    """
    flat = {f"{s}.{k}": v for s, kv in sections.items() for k, v in kv.items() if v is not None}
    return apply_overrides(cfg, flat) if flat else cfg


# --------------------------------------------------------------------------------------------
# YAML output


def _yaml_scalar(value: Any) -> str:
    text = yaml.safe_dump(value, default_flow_style=True, width=1000).strip()
    if text.endswith("\n..."):
        text = text[: -len("\n...")]
    return text.removesuffix("...").strip()


def dump_config(cfg: ReconConfig | None = None, comments: bool = True) -> str:
    """The configuration as YAML text; with ``comments`` every key carries its documentation."""
    cfg = cfg if cfg is not None else ReconConfig()
    lines: list[str] = []
    if comments:
        lines += [
            "# oprecon configuration. Lengths in seeds/dynamics/potentials/growth/triangulation",
            "# are in units of the rest spacing r0 unless a key says otherwise.",
            "# Precedence: command-line options > --set key=value > --config file > defaults.",
        ]

    def emit(obj: Any, indent: str) -> None:
        for f in fields(obj):
            value = getattr(obj, f.name)
            doc = f.metadata.get("doc", "")
            if is_dataclass(value):
                if comments:
                    lines.append("")
                    lines.append(f"{indent}# {doc}")
                lines.append(f"{indent}{f.name}:")
                emit(value, indent + "  ")
                continue
            entry = f"{indent}{f.name}: {_yaml_scalar(value)}"
            if comments and doc:
                extra = range_text(f.metadata)
                entry = f"{entry}  # {doc}{extra}"
            lines.append(entry)

    emit(cfg, "")
    return "\n".join(lines) + "\n"
