"""A tiled fit from a file to the output files: :func:`fit_tiled`.

1. The scan's header (LAS/LAZ: point count and bounds without reading the points) and the
   tile size (``tiling.size``, or with ``tiling.auto`` the largest whose fit stays within the
   memory budget, :func:`recon.tiling.grid.choose_auto_tile_size`).
2. The points are split into one file per tile in a work folder beside the output
   (:mod:`recon.tiling.source`; shared storage on a cluster).
3. r0, ``growth.max_gap`` and ``normals.k`` are decided once for the whole scan: from all the
   points for formats read whole (exactly as an untiled fit decides them), from per-tile
   samples for LAS/LAZ (:func:`recon.tiling.tasks.spacing_task`).
4. Every tile fits its core plus a halo of ``tiling.halo`` r0 and keeps the particles in its
   half-open core (:func:`recon.tiling.tasks.fit_task`); its crease detection reads the
   points farther around (:func:`crease_reach`), so that it labels the core and halo as the
   untiled detection does.
5. Normal signs are agreed across seams (:func:`recon.tiling.stitch.agree_signs`).
6. Every tile triangulates its particles plus its neighbours' within the halo and keeps the
   faces whose centroid lies in its core (:func:`recon.tiling.tasks.mesh_task`): near a seam
   both tiles see the same particles, so they agree on the faces there.
7. The seam zone is repaired one dual cell at a time, the topology measured unit by unit and
   the mesh streamed into its file tile by tile (:mod:`recon.tiling.assemble`): the
   coordinator holds a tile's worth of faces, never the whole mesh. The mesh, particles and
   report are written all or nothing. The work folder is removed whatever happens.
"""

from __future__ import annotations

import contextlib
import math
import os
import pickle
import shutil
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from ..cloud import spatial_order
from ..config import ReconConfig, config_to_dict, parse_size, with_values
from ..errors import InputError
from ..fitting.memory import check_memory, estimate_peak_memory
from ..fitting.mesh_warnings import mesh_warnings
from ..fitting.report import report_path_for
from ..fitting.scale import (
    choose_spacing,
    sampled_spacing,
    sampling_note,
    spacing_from_median,
    surround_median,
    with_max_gap,
)
from ..geometry import SPACING_SAMPLE_SEED, median_nearest_neighbor_distance
from ..serialize import dumps
from ..thinning import LINES_THINNED
from ..version import __version__
from .assemble import stitch_streamed
from .executors import LazyTasks, TileEvent, run_tasks, tile_runner
from .grid import TileGrid, choose_auto_tile_size
from .records import TileRecords
from .source import ScanHeader, scan_header, split_input
from .stitch import SIGN_PAIR_DISTANCE, agree_signs, unmatched_crease_particles
from .tasks import (
    SIGN_BAND,
    BorderFiles,
    FitJob,
    MeshJob,
    fit_task,
    mesh_task,
    particles_path,
    property_names,
    spacing_task,
)
from .writer import write_particles_streamed, write_streamed

__all__ = ["TiledResult", "fit_tiled", "plan_tile_size", "restitch"]

#: Points whose spacing the whole scan samples (as ``median_nearest_neighbor_distance``).
SPACING_SAMPLE = 20_000
#: The stitch's inputs in a kept work folder (see ``_KEEP_ENV`` and :func:`restitch`).
STITCH_INPUTS = "stitch-inputs.pkl"
#: For stitch experiments (``benchmarks/bench_tiles.py --keep-work``): a folder that receives
#: the work folder, with the stitch's inputs (``stitch-inputs.pkl``), instead of removing it.
_KEEP_ENV = "OPRECON_KEEP_TILES"


@dataclass
class TiledResult:
    """The report (a JSON-ready dict) of a tiled fit; the mesh is in the output file (it is
    streamed there, never held whole)."""

    report: dict = field(default_factory=dict)


#: Tiles narrower than this many r0 warn: their seams kept holes and winding conflicts (the
#: held-out terrain at 6.5 r0: 18 loops against 1 untiled, 2 at 10 r0; the bunny at 5.5 r0:
#: 76 loops, faces wound inside out; both clean from 11 r0 on; eighteenth round's hunt).
SMALL_TILE_R0 = 12.0
#: A tile's task running longer than TASK_BASE_S + TASK_S_PER_POINT x the points of its core
#: is taken for stuck (tiling.task_time_limit overrides it): a worker short of memory can spin
#: without end in OpenBLAS's allocator. The base covers a worker's first task, which also
#: loads the kernels. Measured on 2 cores, 2 jobs: tiles of a 200k-point terrain (side 40,
#: 16k-32k points) fitted in 0.2-0.25 ms a point, max 7.9 s (budget 200-280 s); a loaded
#: machine ran the untiled million-point fit at 0.85 ms a point.
TASK_BASE_S = 120.0
TASK_S_PER_POINT = 5e-3


def peak_rss_mib(reset: bool = False) -> float | None:
    """This process's peak resident memory [MiB] since it started or since the last
    ``reset`` (None where the OS does not say).

    Linux: ``VmHWM`` of ``/proc/self/status``, reset through ``/proc/self/clear_refs``
    (``ru_maxrss`` would keep the high-water mark of the parent that started the process).
    Elsewhere ``ru_maxrss``, never reset."""
    status = Path("/proc/self/status")
    if status.exists():
        hwm = next((ln for ln in status.read_text().splitlines() if ln.startswith("VmHWM")), "")
        if reset:
            with contextlib.suppress(OSError):
                Path("/proc/self/clear_refs").write_text("5")
        return int(hwm.split()[1]) / 2**10 if hwm else None
    try:
        import resource
    except ImportError:  # Windows
        return None
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / 2**20 if sys.platform == "darwin" else peak / 2**10  # bytes / KiB


def _budget(cfg: ReconConfig) -> int:
    if cfg.io.max_memory is not None:
        return parse_size(cfg.io.max_memory, "io.max_memory")
    return parse_size(cfg.tiling.memory, "tiling.memory")


def plan_tile_size(header: ScanHeader, cfg: ReconConfig) -> float | None:
    """The tile side [length]: ``tiling.size``, or with ``tiling.auto`` the largest that fits
    the memory budget (None: the whole scan fits in one fit)."""
    if cfg.tiling.size is not None:
        return float(cfg.tiling.size)
    if not cfg.tiling.auto:
        return None
    if header.kind == "whole":
        r0, d_nn = choose_spacing(header.cloud.points, cfg)
    else:
        from .source import spacing_sample

        d_nn = spacing_sample(header, cfg, SPACING_SAMPLE_SEED)
        diag = float(np.linalg.norm(header.hi - header.lo))
        r0 = spacing_from_median(d_nn, header.n_points, diag, cfg)

    def peak(n: int) -> int:
        return estimate_peak_memory(n, r0, d_nn, cfg.dynamics.max_particles).peak_bytes

    return choose_auto_tile_size(
        header.lo, header.hi, header.n_points, peak, _budget(cfg), cfg.tiling.halo * r0
    )


def task_budget(cfg: ReconConfig, counts: dict[int, int]) -> Callable[[int], float]:
    """Seconds a tile's task may run before it is taken for stuck: ``tiling.task_time_limit``,
    else :data:`TASK_BASE_S` plus :data:`TASK_S_PER_POINT` per point of the tile's core."""
    limit = cfg.tiling.task_time_limit
    if limit is not None:
        return lambda t: float(limit)
    return lambda t: TASK_BASE_S + TASK_S_PER_POINT * counts.get(t, 0)


def _default_threads(
    cfg: ReconConfig, jobs: int, executor: str, scheduler: str | None
) -> int | None:
    """Threads per tile: cores / jobs (as ``oprecon batch``) unless set; a remote cluster's
    workers use their own cores."""
    if cfg.threads is not None or (executor == "dask" and scheduler):
        return cfg.threads
    from ..batch.executors import default_jobs

    return max(1, default_jobs() // max(1, jobs))


def _scan_scales(header: ScanHeader, store: Any, cfg: ReconConfig, runner: Any, emit: Any):
    """(n_points, median nearest-neighbour distance, point spacing
    (:func:`recon.fitting.scale.sampled_spacing`), median 6th-neighbour distance, k) of the
    whole scan."""
    from scipy.spatial import cKDTree

    from ..fitting.pipeline import DENSITY_NEIGHBOURS
    from ..fitting.scale import with_neighborhood_size

    n_total = sum(store.counts.values())
    if header.cloud is not None:  # read whole: exactly as an untiled fit
        pts = header.cloud.points
        pts = pts[spatial_order(pts)]  # the untiled fit's order: its spacing samples
        tree = cKDTree(pts)
        _, spacing = choose_spacing(pts, cfg, tree)
        near = tree.query(pts, DENSITY_NEIGHBOURS + 1)[0]
        d6 = float(np.median(near[:, -1]))
        d_nn = median_nearest_neighbor_distance(
            pts, rng=np.random.default_rng(SPACING_SAMPLE_SEED), nearest=near[:, 1]
        )
        k = with_neighborhood_size(pts, cfg).normals.k
        return n_total, d_nn, spacing, d6, k
    task_store = store.for_tasks()
    d1s: list[np.ndarray] = []
    d6s: list[np.ndarray] = []
    arounds: list[np.ndarray] = []
    ks: list[int] = []

    def sample(t: int) -> tuple:
        n = max(1, math.ceil(SPACING_SAMPLE * store.counts[t] / n_total))
        return spacing_task, (task_store, t, n, cfg.normals.k, cfg.normals.auto_scale)

    def keep(t: int, r: dict) -> None:
        d1s.append(r["d1"])
        d6s.append(r["d6"])
        arounds.append(r["surround"])
        if "k" in r:
            ks.append(r["k"])

    tiles = store.tiles()
    run_tasks(
        runner,
        "spacing",
        LazyTasks(tiles, sample),
        store.grid.describe,
        emit,
        keep,
        budget=task_budget(cfg, store.counts),
    )
    d1, d6 = np.concatenate(d1s), np.concatenate(d6s)
    if len(d1) == 0:
        raise InputError(f"{header.path}: too few points per tile to measure the point spacing")
    k = int(np.median(ks)) if ks else cfg.normals.k
    d_nn = float(np.median(d1))
    spacing = sampled_spacing(d_nn, surround_median(np.concatenate(arounds)))
    return n_total, d_nn, spacing, float(np.median(d6)), k


def fit_tiled(
    input_path: str | Path,
    output_path: str | Path,
    config: ReconConfig | None = None,
    *,
    jobs: int | None = None,
    executor: str = "local",
    scheduler: str | None = None,
    particles_path_out: str | Path | None = None,
    preview_path: str | Path | None = None,
    write_report: bool | None = None,
    mkdir: bool = False,
    on_event: Callable[[TileEvent], None] | None = None,
) -> TiledResult | None:
    """Fit ``input_path`` tile by tile and write one stitched mesh (see the module docstring).

    Returns None, having written nothing, when ``tiling.auto`` finds that the whole scan fits
    in one fit (the caller then runs the ordinary fit).

    Raises
    ------
    InputError
        Bad input, a bad tile size, a tile that would exceed ``io.max_memory``.
    TileError
        Tiles failed twice (each named with its bounds).
    """
    from ..io import atomic_output, atomic_outputs, check_output_path

    cfg = config if config is not None else ReconConfig()
    t_start = time.perf_counter()
    limit = cfg.dynamics.time_limit  # the whole tiled fit's, checked between its tasks
    deadline = None if limit is None else (t_start, float(limit))
    input_path = Path(input_path)
    output_path = check_output_path(Path(output_path), inputs=[input_path], mkdir=mkdir)
    want_report = cfg.output.write_report if write_report is None else write_report
    report_path = report_path_for(output_path) if want_report else None
    for p in (particles_path_out, preview_path, report_path):
        if p is not None:
            check_output_path(
                Path(p), inputs=[input_path], mkdir=mkdir, taken=[(output_path, "the mesh output")]
            )
    from ..attributes import check_attribute_output, check_transfer

    check_attribute_output(output_path, cfg.output)  # OBJ: no --transfer, --quality
    if cfg.tiling.size is not None:
        _check_no_outlier_removal(input_path, cfg)  # before reading the scan
    header = scan_header(input_path, cfg)
    if header.cloud is not None:  # LAS/LAZ points always have intensity and classification
        check_transfer(header.cloud, cfg.output.transfer)
    size = plan_tile_size(header, cfg)
    if size is None:
        return None
    _check_no_outlier_removal(input_path, cfg)  # (tiling.auto chose to tile)
    _check_crease_outputs(output_path, cfg)
    grid = TileGrid.cover(header.lo, header.hi, size, 0.0)
    timings: dict[str, float] = {}
    peaks: dict[str, float | None] = {}  # the coordinator's peak RSS in each phase [MiB]
    warnings: list[str] = []
    work = Path(tempfile.mkdtemp(prefix=".oprecon-tiles-", dir=output_path.parent))
    try:
        peaks["start"] = peak_rss_mib(reset=True)  # imports, the header (formats read whole)
        t0 = time.perf_counter()
        cloud = header.cloud
        store = split_input(header, grid, work, cfg)
        header.cloud = cloud  # the scales below need it once more (formats read whole)
        timings["split"] = time.perf_counter() - t0
        peaks["split"] = peak_rss_mib(reset=True)
        executor_jobs = jobs
        with tile_runner(executor, executor_jobs, scheduler) as runner:
            t0 = time.perf_counter()
            n_points, nearest, d_nn, d6, k = _scan_scales(header, store, cfg, runner, on_event)
            header.cloud = cloud = None
            # the points kept: --classes drops some of the header's box (as the untiled fit)
            diag = float(np.linalg.norm(store.hi - store.lo))
            r0 = spacing_from_median(d_nn, n_points, diag, cfg)
            note = sampling_note(nearest, d_nn, r0, cfg)  # r0 across scan lines
            warnings.extend([] if note is None else [note])
            cfg = with_max_gap(cfg, r0, d_nn)
            # the scan's r0 for every tile, in place of either form it came from (with
            # spacing_relative still set, the two were refused as exclusive)
            tile_cfg = with_values(
                replace(cfg, seeds=replace(cfg.seeds, spacing_relative=None)),
                seeds={"spacing": r0},
                normals={"k": k, "auto_scale": False},
                io={"max_memory": None},
            )
            tile_cfg = replace(
                tile_cfg, threads=_default_threads(cfg, runner.jobs, executor, scheduler)
            )
            grid = TileGrid.cover(header.lo, header.hi, size, cfg.tiling.halo * r0)
            store = replace(store, grid=grid)
            _check_tile_memory(store, cfg, r0, d_nn)
            if grid.count > 1 and size < SMALL_TILE_R0 * r0:
                warnings.append(
                    f"tiles of {size:.4g} are only {size / r0:.1f} r0 across: seams of tiles "
                    f"under about {SMALL_TILE_R0:g} r0 keep holes and winding conflicts; give "
                    f"--tile-size {SMALL_TILE_R0 * r0:.4g} or more"
                )
            timings["spacing"] = time.perf_counter() - t0
            peaks["spacing"] = peak_rss_mib(reset=True)

            t0 = time.perf_counter()
            cfg_dict = config_to_dict(tile_cfg)
            from ..normal_scales import per_point_k_max

            k_max = per_point_k_max(cfg.normals.k, cfg.normals.per_point_scale)
            reach = crease_reach(cfg, d6, r0)
            records = TileRecords(grid)
            task_store = store.for_tasks()  # without the per-tile counts: one per task
            run_tasks(
                runner,
                "fit",
                LazyTasks(
                    store.tiles(),
                    lambda t: (
                        fit_task,
                        (FitJob(t, task_store, cfg_dict, r0, work, k_max, reach),),
                    ),
                ),
                grid.describe,
                on_event,
                records.add_fit,
                deadline,
                task_budget(cfg, store.counts),
            )
            timings["fit"] = time.perf_counter() - t0
            peaks["fit"] = peak_rss_mib(reset=True)
            fitted = records.fitted()
            border_in, border_out = (
                BorderFiles(work, fitted, "in"),
                BorderFiles(work, fitted, "out"),
            )
            flips, disagreeing = agree_signs(grid, border_in, border_out, r0)
            unmatched = None
            if cfg.creases.enabled and cfg.creases.fit:
                unmatched = unmatched_crease_particles(
                    grid,
                    border_in.creases(),
                    border_out.creases(),
                    r0,
                    SIGN_BAND + SIGN_PAIR_DISTANCE,
                )
            offsets = records.offsets()
            meshed = records.with_particles().tolist()
            total = records.total("particles")
            if total == 0:
                raise InputError(f"{input_path}: no tile produced particles")

            def mesh_job(t: int) -> tuple:
                near = [n for n in (t, *grid.neighbours(t)) if n in has_particles]
                job = MeshJob(
                    t,
                    task_store,
                    work,
                    r0,
                    cfg_dict,
                    {n: int(offsets[n]) for n in near},  # the tile's and its neighbours' only
                    {n: flips.get(n, 1.0) for n in near},
                    d6,
                    d_nn,
                )
                return mesh_task, (job,)

            has_particles = set(meshed)
            t0 = time.perf_counter()
            run_tasks(
                runner,
                "mesh",
                LazyTasks(meshed, mesh_job),
                grid.describe,
                on_event,
                records.add_mesh,
                deadline,
                task_budget(cfg, store.counts),
            )
            timings["mesh"] = time.perf_counter() - t0
            peaks["mesh"] = peak_rss_mib(reset=True)
            n_jobs = runner.jobs
        t0 = time.perf_counter()
        max_hole = (
            cfg.triangulation.max_hole
            if cfg.triangulation.max_hole is not None
            else cfg.growth.max_gap
        )
        stitch_args = (
            grid,
            records.particle_counts(),
            flips,
            records.new_vertices(),
            r0,
            max_hole,
            particles_path,
            len(property_names(cfg.output)),
        )
        if os.environ.get(_KEEP_ENV):
            (work / STITCH_INPUTS).write_bytes(pickle.dumps(stitch_args))
        stitched = stitch_streamed(work, *stitch_args)
        if stitched["n_faces"] == 0:
            raise InputError(
                f"{input_path}: the reconstruction produced no triangles: the data may be too "
                "sparse for the spacing (try a smaller --spacing or a larger --max-gap)"
            )
        seams, repair = stitched["seams"], stitched["repair"]
        timings["stitch"] = time.perf_counter() - t0
        peaks["stitch"] = peak_rss_mib(reset=True)
        topology, quality = stitched["topology"], stitched["quality"]
        timings["total"] = time.perf_counter() - t_start
        # (the tiles' notes of their thinned lines: the scan's note above says it once)
        warnings += [w for w in records.warnings() if LINES_THINNED not in w]
        is_obj = output_path.suffix.lower() == ".obj"
        creases, crease_warnings = _crease_section(cfg, records, unmatched, d6, r0, is_obj)
        warnings += crease_warnings
        # (no crossings warning: the tiles' counts include their halos, not the stitched mesh's)
        warnings += mesh_warnings(
            topology, {}, particles=int(total), r0=r0, largest=stitched["largest_component_faces"]
        )
        tile_times = records.tile_times()
        report: dict[str, Any] = {
            "oprecon_version": __version__,
            "input": {
                "path": str(input_path),
                "points": int(n_points),
                "bbox_diagonal": diag,
                "median_spacing": d_nn,
            },
            "spacing": r0,
            "particles": int(total),
            "topology": topology,
            "triangle_quality": quality,
            "timings": timings,
            "tiles": {
                "count": len(fitted),
                "grid": list(grid.shape),
                "size": float(size),
                "halo": float(grid.halo),
                "executor": executor,
                "jobs": n_jobs,
                "time_per_tile": {
                    "mean": float(np.mean(tile_times)) if len(tile_times) else 0.0,
                    "max": float(np.max(tile_times)) if len(tile_times) else 0.0,
                },
                "sign_disagreements": disagreeing,
                "seams": seams,
                "repair": repair,
                "coordinator": {**stitched["memory"], "peak_rss_mib": peaks},
                # each tile untangles its own mesh (halo included, the neighbours' particles
                # fixed); crossings the seam repair makes are not searched
                "self_intersections": {
                    "found": records.total("self_intersections_found"),
                    "left": records.total("self_intersections_left"),
                },
                # small handles cut inside the tiles' cores (across the seams: "repair")
                "small_handles_cut": records.total("small_handles_cut"),
                "per_tile": records.per_tile(flips),
            },
            "warnings": warnings,
            **({} if creases is None else {"creases": creases}),
            "config": config_to_dict(cfg),
            "output": {
                "mesh": str(output_path),
                "particles": None if particles_path_out is None else str(particles_path_out),
                "preview": None if preview_path is None else str(preview_path),
                "report": None if report_path is None else str(report_path),
            },
        }
        with atomic_outputs() as outputs:
            with atomic_output(output_path, outputs) as tmp:
                write_streamed(
                    tmp,
                    stitched,
                    stitched["coordinate_type"],
                    cfg.output.vertex_normals,
                    cfg.io.ascii,
                    colors=store.has_colors and (cfg.output.obj_colors or not is_obj),
                    properties=property_names(cfg.output),
                )
            peaks["write"] = peak_rss_mib(reset=True)
            if particles_path_out is not None:
                with atomic_output(Path(particles_path_out), outputs) as tmp:
                    write_particles_streamed(tmp, stitched["store"], len(meshed), cfg.io.ascii)
            if preview_path is not None:
                from .preview import write_preview

                write_preview(Path(preview_path), stitched, input_path.name, outputs)
            if report_path is not None:
                with atomic_output(report_path, outputs) as tmp:
                    tmp.write_text(dumps(report) + "\n")
        return TiledResult(report)
    finally:
        keep = os.environ.get(_KEEP_ENV)
        if keep and (work / STITCH_INPUTS).exists():
            shutil.rmtree(keep, ignore_errors=True)
            shutil.move(work, keep)
        shutil.rmtree(work, ignore_errors=True)


def _check_no_outlier_removal(input_path: Path, cfg: ReconConfig) -> None:
    """Refuse ``io.outliers`` in a tiled fit (an :class:`InputError`, exit 2).

    The statistical removal's threshold is a median over the whole scan, which no tile sees,
    and the tiles measure the scan's spacing before any of them is fitted: removing per tile
    would judge each tile by its own points, after the spacing was taken with the outliers.
    """
    if cfg.io.outliers != "none":
        raise InputError(
            f"{input_path}: --remove-outliers (io.outliers: statistical) is not available in "
            "tiled fits (--tile-size, --tiles auto): its threshold is taken over the whole "
            "scan, which no tile sees; remove them first with `oprecon normals "
            f"{input_path} -o cleaned.ply --remove-outliers`, then fit cleaned.ply tiled"
        )


def _check_crease_outputs(output_path: Path, cfg: ReconConfig) -> None:
    """Refuse (exit 2), before any work, the crease output a tiled fit cannot write:
    ``creases.split_ply`` (the tiled mesh is streamed into its file with one vertex and one
    normal per particle; an untiled fit duplicates each crease vertex per side)."""
    c = cfg.creases
    split = c.enabled and c.fit and c.split_ply and cfg.output.vertex_normals
    if split and output_path.suffix.lower() != ".obj":
        raise InputError(
            "creases.split_ply is not available in tiled fits (--tile-size, --tiles auto): "
            "they write each crease vertex once, with one normal; fit without tiles, or drop "
            "creases.split_ply"
        )


#: The crease section's statistics that a tiled fit does not measure (null in its report).
UNMEASURED_CREASE_KEYS = ("length", "length_relative", "corners", "crease_points", "corner_points")
#: The halo suggested when tiles disagree on a crease: this many times the crease detection's
#: neighbourhood radius (the L-block sample, 4,000 points, 0.5 tiles, before the detection
#: read beyond the halo: two lines missed at 0.67 and 2 radii, none at 3).
CREASE_HALO_RADII = 3.0
#: A tile's crease detection reads the points within its halo plus this many of the
#: detection's neighbourhood radii (:func:`crease_radius`) of its core: the neighbourhoods of
#: the halo's points are complete, and so are their neighbours', whose labels the detection's
#: line filters compare. Labels of the core and halo points against the untiled detection's
#: (summed over the tiles), at 0 / 1 / 2 / 2.5 / 3 radii: sample_data/lblock-sparse.ply in
#: 0.5 tiles (radius 6.1 r0) 179 / 76 / 37 / 1 / 1 differ of 942 (the last one at the halo's
#: outer edge, none from 5 radii on); lblock-clean (20,000 points, radius 3.2 r0) in 0.3
#: tiles 271 / 8 / 0 / 0 / 0 of 2,887, in 0.2 tiles 913 / - / 0 / 0 / 0 of 4,928.
CREASE_REACH_RADII = 3.0


def crease_radius(d6: float, k: int) -> float:
    """The crease detection's neighbourhood radius [length]: the distance to the ``k``-th
    nearest point on a surface whose median 6th-neighbour distance is ``d6``."""
    return d6 * math.sqrt(k / 6.0)


def crease_reach(cfg: ReconConfig, d6: float, r0: float) -> float:
    """How far [length] around its core a tile's crease detection reads the points: the halo
    plus ``CREASE_REACH_RADII`` neighbourhood radii (0 without crease detection: the fit's
    halo only). The particle fit keeps to the halo."""
    if not cfg.creases.enabled:
        return 0.0
    return cfg.tiling.halo * r0 + CREASE_REACH_RADII * crease_radius(d6, cfg.creases.k)


def _crease_section(
    cfg: ReconConfig,
    records: TileRecords,
    unmatched: int | None,
    d6: float,
    r0: float,
    is_obj: bool,
) -> tuple[dict[str, Any] | None, list[str]]:
    """The report's ``creases`` section of a tiled fit (None without crease detection, as an
    untiled fit's report) and its warnings.

    Each tile detects and fits the creases of its core and halo, so the scan's statistics
    (:class:`recon.fitting.report.CreaseStats`) are not measured: they are null, not summed
    over overlapping tiles. Counted: the crease particles of the mesh, and those that one tile
    placed near a seam and its neighbour has no match for (``unmatched_at_seams``)."""
    c = cfg.creases
    if not c.enabled:
        return None, []
    particles = records.total("own_crease_particles")
    section: dict[str, Any] = {
        "angle_deg": float(c.angle_deg),
        **dict.fromkeys(UNMEASURED_CREASE_KEYS),
        "crease_particles": particles,
        "unmatched_at_seams": unmatched,
        "note": "length, corners and crease points not measured in tiled fits (each tile "
        "detects the creases of its core and halo, reading the points within reach [length] "
        "of its core); crease_particles: the particles the tiles fitted on creases, each "
        "counted by the tile whose core holds it",
        "reach": crease_reach(cfg, d6, r0),
    }
    warnings = []
    if unmatched:
        radius = crease_radius(d6, c.k)
        halo = min(50, max(math.ceil(CREASE_HALO_RADII * radius / r0), int(cfg.tiling.halo) + 1))
        warnings.append(
            f"{unmatched} crease particles near tile seams have no match in the neighbouring "
            "tile's fit: a crease one tile fitted was missed by its neighbour, which rounds "
            f"it; the crease detection looks {radius:.3g} around a point and reads "
            f"{crease_reach(cfg, d6, r0):.3g} around a tile, the halo {cfg.tiling.halo:g} r0 "
            f"= {cfg.tiling.halo * r0:.3g}: --set tiling.halo={halo} or an untiled fit keeps "
            "them"
        )
    if is_obj and c.fit and particles and cfg.output.vertex_normals:
        warnings.append(
            f"the OBJ's normals are not split at the creases: a tiled fit writes one normal "
            f"per vertex, averaged across the crease at its {particles} crease particles (an "
            "untiled fit writes one per face corner); shading rounds the sharp edges"
        )
    return section, warnings


def _check_tile_memory(store: Any, cfg: ReconConfig, r0: float, d_nn: float) -> None:
    """Refuse (exit 2) when the largest tile's fit would exceed ``io.max_memory``."""
    if cfg.io.max_memory is None or not store.counts:
        return
    grid = store.grid
    grow = (1.0 + 2.0 * grid.halo / grid.size) ** 2
    n = int(max(store.counts.values()) * grow)
    estimate = estimate_peak_memory(n, r0, d_nn, cfg.dynamics.max_particles)
    try:
        check_memory(estimate, cfg.io.max_memory, r0)
    except InputError as exc:
        raise InputError(f"the largest tile: {exc}; or use a smaller --tile-size") from None


def restitch(work: str | Path, output_path: str | Path) -> dict[str, Any]:
    """Stitch the tiles of a work folder kept by ``OPRECON_KEEP_TILES`` again (for seam
    experiments: minutes instead of a refit) and write the mesh (PLY or OBJ, positions only).

    Returns the stitch's ``topology``, ``seams`` and ``repair``."""
    work = Path(work)
    args = pickle.loads((work / STITCH_INPUTS).read_bytes())
    stitched = stitch_streamed(work, *args)
    write_streamed(Path(output_path), stitched, stitched["coordinate_type"], False, False)
    return {k: stitched[k] for k in ("topology", "seams", "repair")}
