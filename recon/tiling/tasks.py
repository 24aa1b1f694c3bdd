"""The work of one tile, run on a worker (a local process or a Dask worker).

Three tasks, each a plain function of picklable arguments that reads its inputs from the work
folder (shared storage on a cluster) and returns small results:

* :func:`spacing_task`: the point-spacing sample of one tile (r0 is then chosen once for the
  whole scan);
* :func:`fit_task`: the particle sheet over the tile's core and halo with the scan's r0 and
  configuration, with the creases detected on the points within the crease reach (wider than
  the halo: the detection's neighbourhoods near the seams are the untiled fit's); the
  particles in the tile's half-open core are written to the work folder, and so are the
  particles near the core's faces, to compare normal signs across seams;
* :func:`mesh_task`: the triangulation over the tile's particles and its neighbours' (the halo),
  keeping the faces whose centroid lies in the core, in global particle ids.
"""

from __future__ import annotations

import itertools
import math
import time
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .assemble import write_tile_mesh
from .grid import TileGrid
from .source import TileStore, read_box, read_tile
from .stitch import SEAM_BAND, SIGN_PAIR_DISTANCE

__all__ = [
    "SIGN_BAND",
    "BorderFiles",
    "CreaseBorders",
    "border_path",
    "fit_task",
    "mesh_task",
    "particles_path",
    "read_around",
    "spacing_task",
]

#: Particles within this many r0 of a core face are sent back to compare normal signs.
SIGN_BAND = 1.5
#: Particles of different tiles closer than this [r0] are one too many (see
#: :func:`seam_duplicates`).
SEAM_MERGE = 0.6
#: A tile whose core holds fewer points is not fitted (its neighbours' halos cover it).
MIN_TILE_POINTS = 8
#: ... and a tile with fewer points whose fit finds no usable data (too few, collinear) is
#: left empty with a warning instead of failing the scan.
SMALL_TILE_POINTS = 200
#: For the tests of the retry: the tile whose fit fails (see ``_injected_failure``).
_FAIL_ENV = "OPRECON_TILE_FAIL"


def _quiet_worker() -> None:
    """Keep numba's notice about an old TBB off a worker's stderr (as ``oprecon`` does)."""
    import warnings

    warnings.filterwarnings("ignore", message="The TBB threading layer requires")


def particles_path(directory: Path, tile: int) -> Path:
    return Path(directory) / f"particles-{tile}.npz"


def border_path(directory: Path, tile: int) -> Path:
    """The particles of a tile's fit near its core's faces (see :class:`BorderFiles`)."""
    return Path(directory) / f"border-{tile}.npz"


class BorderFiles(Mapping):
    """tile -> (positions, normals) of the particles a tile's fit placed near its core's
    faces, on one ``side``: ``"in"`` its own, ``"out"`` those in its neighbours' cores.
    Each entry is read from the work folder when asked for (:func:`fit_task` writes them),
    so the coordinator holds a few tiles' borders at a time, not the scan's
    (:func:`recon.tiling.stitch.agree_signs`)."""

    def __init__(self, work: Path, tiles: Iterable[int], side: str) -> None:
        self.work, self.tiles, self.side = Path(work), sorted(tiles), side
        self._known = set(self.tiles)

    def __getitem__(self, tile: int) -> tuple[np.ndarray, np.ndarray]:
        if tile not in self._known:
            raise KeyError(tile)
        with np.load(border_path(self.work, tile)) as z:
            return z[f"{self.side}_positions"], z[f"{self.side}_normals"]

    def __contains__(self, tile: object) -> bool:
        return tile in self._known

    def __iter__(self) -> Iterator[int]:
        return iter(self.tiles)

    def __len__(self) -> int:
        return len(self.tiles)

    def creases(self) -> CreaseBorders:
        """The same particles' positions with their crease flags instead of their normals."""
        return CreaseBorders(self.work, self.tiles, self.side)


class CreaseBorders(BorderFiles):
    """tile -> (positions, crease flags) of the particles of :class:`BorderFiles`."""

    def __getitem__(self, tile: int) -> tuple[np.ndarray, np.ndarray]:
        if tile not in self._known:
            raise KeyError(tile)
        with np.load(border_path(self.work, tile)) as z:
            return z[f"{self.side}_positions"], z[f"{self.side}_crease"]


def spacing_task(store: TileStore, tile: int, sample: int, k: int, auto_scale: bool) -> dict:
    """Nearest-neighbour, 6th-neighbour and surround distances
    (:func:`recon.geometry.surround_distances`) of ``sample`` random points of the tile
    (against the points within a small margin around it), and the k that
    ``normals.auto_scale`` would choose there."""
    _quiet_worker()
    from scipy.spatial import cKDTree

    from ..fitting.pipeline import DENSITY_NEIGHBOURS
    from ..geometry import SPACING_SAMPLE_SEED, surround_distances
    from ..normals import choose_neighborhood_size

    rows = read_tile(store, tile)[:, :3]
    empty = np.zeros(0)
    out: dict[str, Any] = {"tile": tile, "n": len(rows), "d1": empty, "d6": empty}
    out["surround"] = empty
    if len(rows) < DENSITY_NEIGHBOURS + 2:
        return out
    rng = np.random.default_rng([SPACING_SAMPLE_SEED, tile])
    tree = cKDTree(rows)
    picked = np.arange(len(rows))
    if sample < len(rows):
        picked = rng.choice(len(rows), sample, replace=False)
    d, _ = tree.query(rows[picked], DENSITY_NEIGHBOURS + 1)
    out["d1"] = d[:, 1]
    out["d6"] = d[:, -1]
    out["surround"] = surround_distances(rows, picked, tree)
    if auto_scale:
        out["k"] = choose_neighborhood_size(rows, k)
    return out


@dataclass(frozen=True)
class FitJob:
    """What :func:`fit_task` needs."""

    tile: int
    store: TileStore
    config: dict  # config_to_dict of the scan's resolved configuration
    r0: float
    work: Path
    #: the widest neighbourhood a point's normal may take (``normals.per_point_scale`` of the
    #: scan: ``MAX_SCALE`` x its configured ``normals.k``; the tiles' own ``k`` is resolved
    #: already)
    normals_k_max: int | None = None
    #: the crease detection reads the points within this distance [length] of the core when
    #: it is wider than the halo (:func:`recon.tiling.run.crease_reach`), the particle fit
    #: those within the halo (0: both the halo's)
    crease_reach: float = 0.0


def fit_task(job: FitJob) -> dict:
    """Fit the particles of one tile (core + halo); write the core's particles."""
    _quiet_worker()
    import os

    from ..config import config_from_dict
    from ..errors import InputError
    from ..fitting.pipeline import fit_particles
    from ..fitting.wide_creases import creases_around

    t0 = time.perf_counter()
    _injected_failure(job, os.environ.get(_FAIL_ENV, ""))
    grid = job.store.grid
    cfg = config_from_dict(job.config)
    if cfg.creases.enabled and job.crease_reach > grid.halo:
        # the crease detection's points: core + crease reach; the fit's: core + halo (the
        # same rows in the same order as read_box's: the tiles beyond the neighbours hold
        # none within the halo, which is at most a tile's side)
        wide = read_around(job.store, job.tile, job.crease_reach)
        rows = wide[grid.in_halo_box(job.tile, wide[:, :3])] if len(wide) else wide
    else:
        rows = wide = read_box(job.store, job.tile, grid.halo)
    n_core = int(grid.in_core(job.tile, rows[:, :3]).sum()) if len(rows) else 0
    result: dict[str, Any] = {
        "tile": job.tile,
        "points": n_core,
        "points_with_halo": len(rows),
        "particles": 0,
    }
    pos = np.zeros((0, 3))
    nrm = np.zeros((0, 3))
    rest = None
    crease = None
    if n_core >= MIN_TILE_POINTS:
        try:
            cloud = job.store.cloud(rows)
            creases = None  # no point beyond the halo: the fit's own detection is the same
            if len(wide) > len(rows):
                lo, hi = grid.core(job.tile)
                creases = creases_around(
                    cloud,
                    job.store.cloud(wide),
                    cfg,
                    (lo - grid.halo, hi + grid.halo),
                    job.normals_k_max,
                )
            pf = fit_particles(cloud, cfg, normals_k_max=job.normals_k_max, creases=creases)
        except InputError as exc:
            if n_core >= SMALL_TILE_POINTS:
                raise
            # a few points at a tile's corner (a roof edge, a stray return): no sheet there
            result["warnings"] = [f"{n_core} points not fitted: {exc}"]
        else:
            pos, nrm, rest, crease = pf.positions, pf.normals, pf.rest, pf.crease
            result["steps"] = pf.steps
            result["warnings"] = pf.warnings
            result["trimmed"] = pf.n_trimmed
    owned = grid.in_core(job.tile, pos) if len(pos) else np.zeros(0, dtype=bool)
    rgb, props = vertex_attributes(job.store, rows, pos[owned], job.r0, cfg.output)
    np.savez(
        particles_path(job.work, job.tile),
        positions=pos[owned],
        normals=nrm[owned],
        rest=rest[owned] if rest is not None else np.zeros(0),
        # crease particles (creases fitted): the mesh task pivots around them as the untiled
        # triangulation does; absent (empty) when creases were not fitted
        crease=crease[owned] if crease is not None else np.zeros(0, dtype=bool),
        has_crease=crease is not None,
        colors=rgb,
        properties=props,
    )
    # the particles close to the core's faces, inside and outside: the seam sign comparison
    # (to the work folder: the coordinator reads a few tiles' at a time)
    band = SIGN_BAND * job.r0
    near = grid.in_halo_box(job.tile, pos, band) if len(pos) else owned
    # own particles deeper than the band plus the pair distance are never the nearest of a
    # neighbour's halo particle within that distance: the comparison is the same without them
    deep = (
        grid.in_halo_box(job.tile, pos, -(band + SIGN_PAIR_DISTANCE * job.r0))
        if len(pos)
        else owned
    )
    result["particles"] = int(owned.sum())
    flags = crease if crease is not None else np.zeros(len(pos), dtype=bool)
    # the crease particles of the mesh, each counted by the tile whose core holds it
    result["own_crease_particles"] = int(np.count_nonzero(flags[owned]))
    np.savez(
        border_path(job.work, job.tile),
        in_positions=pos[owned & ~deep],
        in_normals=nrm[owned & ~deep],
        out_positions=pos[near & ~owned],
        out_normals=nrm[near & ~owned],
        # which of them are crease particles: a crease one tile found and its neighbour
        # missed (:func:`recon.tiling.stitch.unmatched_crease_particles`)
        in_crease=flags[owned & ~deep],
        out_crease=flags[near & ~owned],
    )
    result["seconds"] = time.perf_counter() - t0
    return result


def read_around(store: TileStore, tile: int, margin: float) -> np.ndarray:
    """The rows within ``margin`` [length] of a tile's core, as :func:`read_box` reads them
    (the tile's file, then its neighbours', in that order) and then those of the tiles
    farther out that the margin reaches when it is wider than a tile."""
    grid = store.grid
    rings = max(1, math.ceil(margin / grid.size))
    if rings == 1:
        return read_box(store, tile, margin)
    near = [tile, *grid.neighbours(tile)]
    centre = np.asarray(grid.ijk(tile))
    lo = np.maximum(centre - rings, 0)
    hi = np.minimum(centre + rings, np.asarray(grid.shape) - 1)
    seen = set(near)
    far = [
        t
        for t in (
            int(np.ravel_multi_index(ijk, grid.shape))
            for ijk in itertools.product(*(range(a, b + 1) for a, b in zip(lo, hi, strict=True)))
        )
        if t not in seen
    ]
    parts = []
    for t in near + far:
        rows = read_tile(store, t)
        if len(rows):
            parts.append(rows[grid.in_halo_box(tile, rows[:, :3], margin)])
    return np.concatenate(parts) if parts else np.zeros((0, store.columns))


def property_names(output: Any) -> list[str]:
    """The per-vertex properties the ``output`` section asks for, in the order they are
    written (as :func:`recon.attributes.transfer_attributes`: the transferred names, then
    ``quality``)."""
    return [*output.transfer, *(["quality"] if output.quality else [])]


def vertex_attributes(
    store: TileStore, rows: np.ndarray, vertices: np.ndarray, r0: float, output: Any
) -> tuple[np.ndarray, np.ndarray]:
    """Colours and properties of ``vertices`` from the input points ``rows`` of the tile and
    its halo (:func:`recon.attributes.transfer_attributes`: the distance-weighted mean of the
    k nearest for colours and intensity, their majority for the classification, the distance
    to the nearest in r0 for ``quality``).

    Returns (colours (n, 3) uint8, or (0, 3) when the scan has none; properties (n, m)
    float64, one column per name of :func:`property_names`). ``quality`` is exact wherever
    the data lies within the rows' margin (the halo); farther from any point it is at least
    that margin.
    """
    names = property_names(output)
    rgb = store.colors(rows)
    n = len(vertices)
    no_rgb = np.zeros((0, 3), dtype=np.uint8)
    props = np.zeros((n, len(names)))
    if n == 0 or (rgb is None and not names):
        return no_rgb, props
    if len(rows) == 0:  # no data around (a tile's vertices always have some)
        if "quality" in names:
            props[:, names.index("quality")] = np.inf
        return (no_rgb if rgb is None else np.zeros((n, 3), np.uint8)), props
    from ..attributes import transfer_attributes
    from ..io import cloud_from_arrays

    cloud = cloud_from_arrays(
        rows[:, :3],
        colors=rgb,
        attributes={k: np.asarray(v) for k, v in store.point_attributes(rows).items()},
        merge_duplicates=False,
    )
    out = transfer_attributes(
        cloud,
        vertices,
        r0,
        colors=rgb is not None,
        transfer=list(output.transfer),
        quality=bool(output.quality),
        k=output.attribute_neighbors,
    )
    for j, name in enumerate(names):
        props[:, j] = out.properties[name]
    return (no_rgb if out.colors is None else out.colors), props


def _injected_failure(job: FitJob, spec: str) -> None:
    """Tests of the retry: ``OPRECON_TILE_FAIL=3`` makes the first fit of tile 3 fail,
    ``3!`` every fit of it; ``3~`` makes its first fit hang instead (sleep until stopped,
    having written ``hung-3`` into the work folder), ``3!~`` every fit of it."""
    if spec.rstrip("!~") != str(job.tile):
        return
    flag = Path(job.work) / f"failed-once-{job.tile}"
    if "!" in spec or not flag.exists():
        flag.write_text("")
        if "~" in spec:
            (Path(job.work) / f"hung-{job.tile}").write_text("")
            while True:
                time.sleep(1.0)
        raise RuntimeError(f"injected failure of tile {job.tile}")


@dataclass(frozen=True)
class MeshJob:
    """What :func:`mesh_task` needs."""

    tile: int
    store: TileStore
    work: Path
    r0: float
    config: dict
    offsets: dict[int, int]  # tile -> global id of its first particle
    flips: dict[int, float]  # tile -> +1 / -1 normal sign
    median_d6: float  # median 6th-neighbour distance of the scan [length]
    median_spacing: float  # median nearest-neighbour distance of the scan [length]


def _load_particles(
    job: MeshJob, grid: TileGrid
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """The particles of the tile and its neighbours within the halo: positions, normals,
    rest spacings, global ids, and the crease flags (None when no tile fitted creases)."""
    pos, nrm, rest, gid, owners, crease = [], [], [], [], [], []
    any_crease = False
    for t in [job.tile, *grid.neighbours(job.tile)]:
        if t not in job.offsets:
            continue
        owners.append(t)
        with np.load(particles_path(job.work, t)) as z:
            p, n, r = z["positions"], z["normals"], z["rest"]
            c = z["crease"] if "crease" in z.files else np.zeros(0, dtype=bool)
            any_crease |= bool(z["has_crease"]) if "has_crease" in z.files else False
        keep = grid.in_halo_box(job.tile, p) if len(p) else np.zeros(0, dtype=bool)
        idx = np.flatnonzero(keep)
        pos.append(p[idx])
        nrm.append(n[idx] * job.flips.get(t, 1.0))
        rest.append(r[idx] if len(r) else np.ones(len(idx)))
        crease.append(c[idx] if len(c) == len(p) else np.zeros(len(idx), dtype=bool))
        gid.append(job.offsets[t] + idx)
    if not pos:
        z3 = np.zeros((0, 3))
        return z3, z3, np.zeros(0), np.zeros(0, dtype=np.int64), None
    tiles = np.concatenate([np.full(len(p), t) for p, t in zip(pos, owners, strict=True)])
    pos_a, gid_a = np.concatenate(pos), np.concatenate(gid)
    keep = ~seam_duplicates(pos_a, tiles, SEAM_MERGE * job.r0)
    flags = np.concatenate(crease)[keep] if any_crease else None
    return pos_a[keep], np.concatenate(nrm)[keep], np.concatenate(rest)[keep], gid_a[keep], flags


def seam_duplicates(positions: np.ndarray, tiles: np.ndarray, distance: float) -> np.ndarray:
    """Particles of two tiles closer than ``distance``: the one of the higher tile is marked.

    Each tile fitted its side of a seam without the other's particles, so a few pairs across
    the seam sit much closer than r0 and would make slivers. The rule depends only on the
    pair, so every tile that sees it drops the same particle.
    """
    from scipy.spatial import cKDTree

    drop = np.zeros(len(positions), dtype=bool)
    if len(positions) < 2:
        return drop
    pairs = cKDTree(positions).query_pairs(distance, output_type="ndarray")
    if len(pairs) == 0:
        return drop
    a, b = pairs[:, 0], pairs[:, 1]
    cross = tiles[a] != tiles[b]
    a, b = a[cross], b[cross]
    drop[np.where(tiles[a] > tiles[b], a, b)] = True
    return drop


def mesh_task(job: MeshJob) -> dict:
    """Triangulate a tile over its particles and its neighbours' within the halo; keep the
    faces whose centroid lies in the tile's half-open core.

    The faces, in global particle ids (``-1 - j``: the ``j``-th vertex the tile's repair
    added), go to the work folder split into seam zone, rim and interior
    (:func:`recon.tiling.assemble.write_tile_mesh`); the result holds their counts.
    """
    _quiet_worker()
    from scipy.spatial import cKDTree

    from ..config import config_from_dict
    from ..fitting.pipeline import (
        HOLE_COVER_DISTANCE,
        cover_reach,
        covered,
        local_density_scale,
        sampling_spacing,
        sparse_cover,
    )
    from ..kernels.options import thread_count
    from ..polish import polish_and_untangle
    from ..triangulate import triangulate_particles

    t0 = time.perf_counter()
    grid = job.store.grid
    cfg = config_from_dict(job.config)
    pos, nrm, rest, gid, crease = _load_particles(job, grid)
    empty = {
        "tile": job.tile,
        "faces": 0,
        "zone_faces": 0,
        "new_vertices": 0,
        "cover_reach": HOLE_COVER_DISTANCE,
        "seconds": 0.0,
    }
    if len(pos) < 3:
        write_tile_mesh(job.work, job.tile, grid, job.r0, *_no_mesh())
        return empty
    lo, hi = grid.bounds(job.tile)
    centre = 0.5 * (lo + hi)
    r0 = job.r0
    x = (pos - centre) / r0
    rows = read_box(job.store, job.tile, grid.halo + r0)
    data = (rows[:, :3] - centre) / r0
    tree = cKDTree(data) if len(data) else None
    tri_cfg = cfg.triangulation
    max_hole = tri_cfg.max_hole if tri_cfg.max_hole is not None else cfg.growth.max_gap
    # the untiled fit's rules against the scan's medians (a tile's own would differ by tile)
    median_d6 = job.median_d6 / r0
    spacing = None
    with thread_count(cfg.threads):
        sampling = sampling_spacing(tree, data)  # each data point's (0: too few to tell)
        if tri_cfg.max_density_scale > 1.0 and tree is not None:
            spacing = local_density_scale(
                tree, data, x, tri_cfg.max_density_scale, median_d6, local=sampling
            )
    if cfg.seeds.adaptive:
        spacing = rest if spacing is None else np.maximum(spacing, rest)
    sparser = sparse_cover(sampling, median_d6, tri_cfg.max_density_scale)

    def mesh(reach: float) -> tuple[Any, np.ndarray, np.ndarray, np.ndarray, int, int, int]:
        """Triangulate with the coverage ``reach``, untangle over the tile's core and halo
        moving only its own particles and new vertices (the neighbours' belong to their
        tiles), cut the small handles inside the core (:func:`inner_handles_cut`): the
        result, the vertices' global ids (``-1 - j`` for the ``j``-th new one), the untangled
        vertices, the faces, handles cut, crossings found and left."""

        def is_covered(c: np.ndarray, s: Any = 1.0, across: bool = False) -> np.ndarray:
            if tree is None:
                return np.zeros(len(c), dtype=bool)
            dist, idx = tree.query(c)
            return covered(dist, sparser[idx], s, reach, across)

        tri = triangulate_particles(
            x,
            nrm,
            tri_cfg,
            max_hole,
            is_covered=is_covered,
            local_spacing=spacing,
            crease=crease,
            join_sheets=False,  # a thin part's faces cut by the tile are not its edge
        )
        if len(tri.faces) == 0:
            return tri, np.zeros(0, dtype=np.int64), tri.vertices, tri.faces, 0, 0, 0
        # result vertices -> input particles (order kept; repair adds shifted copies at the end)
        d, src = cKDTree(x).query(tri.vertices)
        original = d <= 1e-9
        code = np.empty(len(tri.vertices), dtype=np.int64)
        code[original] = gid[src[original]]
        code[~original] = -1 - np.arange(np.count_nonzero(~original))
        own = ~original | (grid.cell_of(tri.vertices * r0 + centre) == job.tile)
        fixed = ~own if tri.crease is None else ~own | np.asarray(tri.crease, dtype=bool)
        # the untiled fit's polish without flips (the faces near the core's edge must stay
        # those the neighbour tiles see) and in the tangent planes (no data surface here)
        polished, found, left = polish_and_untangle(
            tri, None, tri_cfg.smooth_rounds, flips=False, fixed=fixed, cut_handles=False
        )
        faces, cuts = inner_handles_cut(
            grid, job.tile, tri.vertices * r0 + centre, polished.vertices, tri.faces, r0,
            np.pi * max_hole,
        )  # fmt: skip
        return tri, code, polished.vertices, faces, cuts, found, left

    with thread_count(cfg.threads):
        reach = cover_reach(job.median_spacing / r0)
        tri, code, moved_x, faces, cuts, found, left = mesh(reach)
        if left and reach > HOLE_COVER_DISTANCE:  # as the untiled fit: see its _triangulate
            reach = 0.0
            tri, code, moved_x, faces, cuts, found, left = mesh(reach)
    if len(faces) == 0:
        write_tile_mesh(job.work, job.tile, grid, r0, *_no_mesh())
        return empty
    new_ids = np.flatnonzero(code < 0)
    moved = np.flatnonzero(np.any(moved_x != tri.vertices, axis=1) & (code >= 0))
    absolute = moved_x * r0 + centre
    # each face goes to the tile whose core holds its centroid at the particles' positions,
    # which every tile sees alike (the moved positions are known only to the owner's tile)
    faces = faces[grid.in_core(job.tile, (tri.vertices * r0 + centre)[faces].mean(axis=1))]
    counts = write_tile_mesh(
        job.work,
        job.tile,
        grid,
        r0,
        absolute,
        faces,
        code,
        absolute[new_ids],
        tri.normals[new_ids],
        *vertex_attributes(job.store, rows, absolute[new_ids], r0, cfg.output),
        moved_ids=code[moved],
        moved_positions=absolute[moved],
        moved_attributes=vertex_attributes(job.store, rows, absolute[moved], r0, cfg.output),
    )
    return {
        "tile": job.tile,
        **counts,
        # crease particles (tile and halo) the triangulation pivoted and flipped around
        "crease_particles": 0 if crease is None else int(np.count_nonzero(crease)),
        "self_intersections_found": int(found),
        "self_intersections_left": int(left),
        "small_handles_cut": int(cuts),
        # data covered a hole's inside within this distance [r0] (at least r0)
        "cover_reach": max(reach, HOLE_COVER_DISTANCE),
        "seconds": time.perf_counter() - t0,
        "stats": tri.stats,
    }


def inner_handles_cut(
    grid: TileGrid,
    tile: int,
    where: np.ndarray,
    vertices: np.ndarray,
    faces: np.ndarray,
    r0: float,
    tunnel_perimeter: float,
) -> tuple[np.ndarray, int]:
    """A tile's ``faces`` with the small handles cut (:func:`recon.small_handles.cut_small_handles`
    at ``vertices`` [r0], with the untiled fit's stalk cut up to ``tunnel_perimeter`` [r0])
    where the cut removes only faces this tile writes (centroid in its core, at the particles'
    positions ``where`` [length]) that share no vertex with a face it does not write and have
    every vertex ``SEAM_BAND`` r0 or more from an inner tile face: the faces along a seam
    stay those the neighbour tiles see. A handle across the seam is the coordinator's
    (:func:`recon.tiling.stitch.repair_cell` cuts those in the seam's zone).
    Returns the faces (a cut's patch last) and the number of cuts."""
    from ..small_handles import SMALL_HANDLE_REACH, cut_small_handles

    if len(faces) == 0:
        return faces, 0
    in_core = grid.in_core(tile, where[faces].mean(axis=1))
    held = grid.seam_distance(where) < SEAM_BAND * r0
    held[faces[~in_core].ravel()] = True
    editable = in_core & ~held[faces].any(axis=1)
    return cut_small_handles(vertices, faces, SMALL_HANDLE_REACH, tunnel_perimeter, editable)


def _no_mesh() -> tuple[np.ndarray, ...]:
    z3 = np.zeros((0, 3))
    return z3, np.zeros((0, 3), dtype=np.int64), np.zeros(0, dtype=np.int64), z3, z3
