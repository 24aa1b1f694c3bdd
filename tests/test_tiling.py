"""Tiled fits (issue #14, part 2): the tile grid, the retry, the seam rules, and a 4-tile fit of
a small open terrain sheet compared with the untiled fit of the same file."""

from __future__ import annotations

import os
import time
from concurrent.futures import FIRST_COMPLETED, ThreadPoolExecutor, wait
from pathlib import Path

import numpy as np
import open3d as o3d
import pytest

from recon.config import ReconConfig, apply_overrides, with_values
from recon.errors import InputError, OpreconError
from recon.fitting import fit_file
from recon.io import read_mesh, write_points
from recon.mesh import boundary_loops, count_edge_faces
from recon.metrics import compare_meshes
from recon.tiling import TileError, TileGrid, choose_auto_tile_size, fit_tiled, run_tasks
from recon.tiling.stitch import agree_signs
from recon.tiling.tasks import seam_duplicates
from recon.topology import mesh_topology, triangle_quality

SIDE = 10.0


def height(xy: np.ndarray) -> np.ndarray:
    return 0.5 * np.sin(xy[:, 0] / 1.5) * np.cos(xy[:, 1] / 2.0)


def sheet(n: int, seed: int = 0) -> np.ndarray:
    """An open terrain patch SIDE x SIDE, area-uniform (its ground truth is ``height``)."""
    xy = np.random.default_rng(seed).uniform(0, SIDE, (n, 2))
    return np.column_stack([xy, height(xy)])


# -- the grid ---------------------------------------------------------------------------------


def test_every_point_has_one_owner_with_half_open_cores():
    grid = TileGrid.cover(np.zeros(3), np.array([10.0, 10.0, 1.0]), 5.0, 1.0)
    assert grid.shape == (2, 2, 1) and grid.count == 4
    pts = np.array([[5.0, 0.0, 0.0], [4.999, 0.0, 0.0], [10.0, 10.0, 1.0], [0.0, 5.0, 0.5]])
    owners = grid.cell_of(pts)
    # x = 5 lies on the face between tiles (0,0,0) and (1,0,0): the upper tile holds it
    assert grid.ijk(owners[0]) == (1, 0, 0)
    assert grid.ijk(owners[1]) == (0, 0, 0)
    assert grid.ijk(owners[2]) == (1, 1, 0)  # the bounding box's upper corner is in a core
    assert grid.ijk(owners[3]) == (0, 1, 0)
    rand = np.random.default_rng(1).uniform([-1, -1, -1], [11, 11, 2], (500, 3))
    inside = np.stack([grid.in_core(t, rand) for t in range(grid.count)])
    assert np.all(inside.sum(axis=0) == 1)
    assert sorted(grid.neighbours(0)) == [1, 2, 3]
    d = grid.seam_distance(np.array([[4.0, 1.0, 0.0], [1.0, 1.0, 0.0]]))
    assert d == pytest.approx([1.0, 4.0])


def test_a_tiles_crease_detection_reads_beyond_its_halo_and_its_fit_the_same_rows(tmp_path):
    """:func:`read_around` reads the rows within a margin of a tile's core, also from the
    tiles beyond its neighbours when the margin is wider than a tile; the rows within the
    halo among them are :func:`read_box`'s, in its order (the tile's fit is unchanged)."""
    from recon.tiling.source import TileStore, read_box
    from recon.tiling.tasks import read_around

    grid = TileGrid.cover(np.zeros(3), np.array([5.0, 5.0, 1.0]), 1.0, 0.4)
    pts = np.random.default_rng(2).uniform([0, 0, 0], [5, 5, 1], (3000, 3))
    owner = grid.cell_of(pts)
    store = TileStore(tmp_path, grid, {}, 3)
    for t in np.unique(owner):
        pts[owner == t].astype("<f8").tofile(store.path(int(t)))
    centre = int(grid.cell_of(np.array([[2.5, 2.5, 0.5]]))[0])
    for tile, margin in ((centre, 0.4), (centre, 1.0), (centre, 1.7), (0, 2.5)):
        rows = read_around(store, tile, margin)
        inside = pts[grid.in_halo_box(tile, pts, margin)]
        assert sorted(map(tuple, rows)) == sorted(map(tuple, inside)), (tile, margin)
        halo = rows[grid.in_halo_box(tile, rows)]
        assert np.array_equal(halo, read_box(store, tile, grid.halo))
        if margin <= grid.size:
            assert np.array_equal(rows, read_box(store, tile, margin))


@pytest.mark.parametrize(
    ("size", "halo", "match"),
    [
        (0.0, 0.0, "positive length"),
        (-2.0, 0.0, "positive length"),
        (float("nan"), 0.0, "positive length"),
        (0.5, 1.0, "smaller than the halo"),
        (1e-6, 0.0, "more than 100,000"),
        (1e-9, 0.0, "more than 100,000"),
    ],
)
def test_bad_tile_sizes_are_refused(size, halo, match):
    with pytest.raises(InputError, match=match):
        TileGrid.cover(np.zeros(3), np.ones(3) * 10, size, halo)


def test_auto_tile_size_fits_the_budget():
    lo, hi = np.zeros(3), np.array([100.0, 50.0, 5.0])

    def peak(n: int) -> int:
        return 1000 + 10 * n

    assert choose_auto_tile_size(lo, hi, 1000, peak, 20_000, 1.0) is None
    s = choose_auto_tile_size(lo, hi, 100_000, peak, 200_000, 1.0)
    assert s is not None and s < 100.0
    w = s + 2.0
    assert peak(int(100_000 * min(1, w / 100) * min(1, w / 50))) <= 200_000
    with pytest.raises(InputError, match="no tile size"):
        choose_auto_tile_size(lo, hi, 100_000, peak, 500, 1.0)


# -- the retry --------------------------------------------------------------------------------


class ThreadRunner:
    """A runner over threads (the retry logic does not depend on processes)."""

    jobs = 2

    def __init__(self) -> None:
        self.pool = ThreadPoolExecutor(2)

    def submit(self, fn, *args):
        return self.pool.submit(fn, *args)

    def wait(self, futures, timeout):
        wait(futures, timeout=timeout, return_when=FIRST_COMPLETED)

    def cancel(self, futures):
        for f in futures:
            f.cancel()


def test_a_failed_tile_is_retried_once():
    calls: dict[int, int] = {}

    def flaky(tile: int) -> int:
        calls[tile] = calls.get(tile, 0) + 1
        if tile == 1 and calls[tile] == 1:
            raise RuntimeError("worker lost")
        return 10 * tile

    events = []
    tasks = {t: (flaky, (t,)) for t in range(3)}
    out = run_tasks(ThreadRunner(), "fit", tasks, lambda t: f"tile {t}", events.append)
    assert out == {0: 0, 1: 10, 2: 20}
    assert calls == {0: 1, 1: 2, 2: 1}
    retry = [e for e in events if e.message]
    assert (
        len(retry) == 1
        and "tile 1 failed (RuntimeError: worker lost); retrying" in retry[0].message
    )
    assert events[-1].done == 3 and events[-1].in_flight == 0


@pytest.mark.parametrize(("error", "code"), [(RuntimeError, 1), (InputError, 2)])
def test_a_tile_failing_twice_is_reported_with_its_bounds(error, code):
    grid = TileGrid.cover(np.zeros(3), np.array([10.0, 10.0, 1.0]), 5.0, 1.0)

    def broken(tile: int) -> int:
        if tile == 3:
            raise error("no data")
        return tile

    tasks = {t: (broken, (t,)) for t in range(4)}
    with pytest.raises(TileError) as err:
        run_tasks(ThreadRunner(), "fit", tasks, grid.describe)
    assert err.value.exit_code == code
    assert "1 of 4 tile(s) failed twice" in str(err.value)
    assert "tile 3 (1, 1, 0) [5, 10) x [5, 10) x [0, 5)" in str(err.value)
    assert isinstance(err.value, OpreconError)


def test_a_stuck_task_is_stopped_and_the_tasks_lost_with_it_are_not_charged():
    """Regression: a worker short of memory spun without end inside OpenBLAS's allocator and
    the tiled fit never finished (nothing bounded a task). A task past its budget is now
    stopped and run once more; stopping it stops the pool's other workers, whose tasks run
    again without counting as failures."""
    from recon.tiling.executors import tile_runner

    events, got = [], {}
    tasks = {0: (time.sleep, (600,)), 1: (abs, (-1,)), 2: (abs, (-2,)), 3: (abs, (-3,))}
    t0 = time.monotonic()
    with tile_runner("local", 2) as runner, pytest.raises(TileError) as err:
        run_tasks(runner, "fit", tasks, str, events.append, got.__setitem__, budget=lambda t: 2.0)
    assert time.monotonic() - t0 < 60
    assert err.value.exit_code == 1
    assert "1 of 4 tile(s) failed twice" in str(err.value)
    assert "0: TileStuck: ran longer than 2 s and was taken for stuck" in str(err.value)
    assert got == {1: 1, 2: 2, 3: 3}
    retries = [e.message for e in events if e.message]
    assert len(retries) == 1 and retries[0].startswith("0 failed (TileStuck"), retries


def test_a_tiles_budget_grows_with_its_points_unless_set():
    from recon.tiling.run import TASK_BASE_S, TASK_S_PER_POINT, task_budget

    budget = task_budget(ReconConfig(), {0: 0, 1: 100_000})
    assert budget(0) == TASK_BASE_S
    assert budget(1) == pytest.approx(TASK_BASE_S + 100_000 * TASK_S_PER_POINT)
    assert budget(2) == TASK_BASE_S  # (a tile without points)
    fixed = task_budget(with_values(ReconConfig(), tiling={"task_time_limit": 7}), {1: 10**6})
    assert fixed(1) == 7.0


class WindowRunner(ThreadRunner):
    """A thread runner that counts the tasks submitted and not yet finished."""

    def __init__(self) -> None:
        super().__init__()
        self.open = self.most = 0

    def submit(self, fn, *args):
        self.open += 1
        self.most = max(self.most, self.open)
        future = self.pool.submit(fn, *args)
        future.add_done_callback(lambda f: setattr(self, "open", self.open - 1))
        return future


@pytest.mark.usefixtures("no_kernel_loading")
def test_the_scheduling_loop_holds_a_few_tasks_not_the_scans():
    """run_tasks submits a few tasks per job at a time (building each job when it is
    submitted) and hands each result on as it arrives: 4x the tiles, each job and result
    carrying 16 kB, the same peak allocation. Before, every tile's job was submitted at once
    and every result kept (on a Dask LocalCluster, whose scheduler runs in the coordinator,
    dummy tasks carrying a per-tile dict held 1.9 MB for 100 tiles, 16.6 MB for 400)."""
    import tracemalloc

    from recon.tiling.executors import IN_FLIGHT_PER_JOB, LazyTasks

    def work(job):
        return job[0], np.ones(2000)  # 16 kB back

    peaks, seen = {}, {}
    for n in (50, 200):
        runner = WindowRunner()
        seen[n] = 0

        def handle(tile, result, n=n):
            seen[n] += int(result[0] == tile)

        tracemalloc.start()
        tasks = LazyTasks(range(n), lambda t: (work, ((t, np.zeros(2000)),)))
        out = run_tasks(runner, "fit", tasks, str, on_result=handle)
        peaks[n] = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        runner.pool.shutdown()
        assert out == {} and seen[n] == n
        assert runner.most <= IN_FLIGHT_PER_JOB * runner.jobs
    assert peaks[200] < peaks[50] + 100_000, peaks


def test_a_tasks_arguments_do_not_grow_with_the_tile_count(tmp_path):
    """Every task gets the tile store without its per-tile point counts (a task reads its
    files): pickled per task, the counts made each task's arguments grow with the tiles, and
    all of them together with their square (the mesh jobs carry their neighbours' particle
    offsets and signs only)."""
    import pickle

    from recon.tiling.source import TileStore

    sizes = {}
    for n in (2, 20):
        grid = TileGrid.cover(np.zeros(3), np.array([n * 5.0, n * 5.0, 1.0]), 5.0, 1.0)
        store = TileStore(tmp_path, grid, {t: 1000 + t for t in range(grid.count)}, 3)
        assert store.for_tasks().tiles() == [] and store.tiles() == list(range(grid.count))
        sizes[n] = len(pickle.dumps(store.for_tasks()))
    assert abs(sizes[20] - sizes[2]) < 64, sizes


# -- the seam rules ---------------------------------------------------------------------------


def test_seam_duplicates_drop_the_higher_tiles_particle_only():
    pos = np.array([[0.0, 0, 0], [0.3, 0, 0], [3.0, 0, 0], [3.2, 0, 0], [6.0, 0, 0]])
    tiles = np.array([2, 1, 0, 0, 5])
    drop = seam_duplicates(pos, tiles, 0.5)
    # pair (0, 1) across tiles 2 / 1: tile 2's goes; pair (2, 3) is within one tile: kept
    assert drop.tolist() == [True, False, False, False, False]
    # the same rule whatever the order the particles come in
    perm = np.array([4, 3, 2, 1, 0])
    assert seam_duplicates(pos[perm], tiles[perm], 0.5).tolist() == drop[perm].tolist()


def test_normal_signs_agree_across_seams():
    grid = TileGrid.cover(np.zeros(3), np.array([10.0, 10.0, 1.0]), 5.0, 1.0)
    rng = np.random.default_rng(0)
    up = np.array([0.0, 0.0, 1.0])
    signs = {0: 1.0, 1: -1.0, 2: -1.0, 3: 1.0}  # tiles 1 and 2 oriented the other way
    border_in, border_out = {}, {}
    for t in range(4):
        lo, hi = grid.bounds(t)
        p = np.column_stack(
            [
                rng.uniform(lo[0] - 1, hi[0] + 1, 4000),
                rng.uniform(lo[1] - 1, hi[1] + 1, 4000),
                np.zeros(4000),
            ]
        )
        p = p[grid.in_halo_box(t, p, 1.0)]
        own = grid.in_core(t, p)
        n = np.tile(up * signs[t], (len(p), 1))
        border_in[t] = (p[own], n[own])
        border_out[t] = (p[~own], n[~own])
    flips, disagreeing = agree_signs(grid, border_in, border_out, r0=0.2)
    assert disagreeing == 4  # 0-1, 0-2, 1-3, 2-3 disagree; 1-2 and 0-3 agree
    oriented = {t: signs[t] * flips[t] for t in range(4)}
    assert len(set(oriented.values())) == 1


def _border_files(work, n_side: int, per_tile: int = 4000):
    """Border files (as fit_task writes them) of an n x n grid of 5 x 5 tiles over a plane."""
    from recon.tiling.tasks import BorderFiles, border_path

    side = 5.0 * n_side
    grid = TileGrid.cover(np.zeros(3), np.array([side, side, 1.0]), 5.0, 1.0)
    rng = np.random.default_rng(0)
    for t in range(grid.count):
        lo, hi = grid.bounds(t)
        p = np.column_stack(
            [
                rng.uniform(lo[0] - 1, hi[0] + 1, per_tile),
                rng.uniform(lo[1] - 1, hi[1] + 1, per_tile),
            ]
        )
        p = np.column_stack([p, np.zeros(len(p))])
        p = p[grid.in_halo_box(t, p, 1.0)]
        own = grid.in_core(t, p)
        n = np.tile([0.0, 0.0, 1.0], (len(p), 1))
        np.savez(
            border_path(work, t),
            in_positions=p[own],
            in_normals=n[own],
            out_positions=p[~own],
            out_normals=n[~own],
        )
    tiles = range(grid.count)
    return grid, BorderFiles(work, tiles, "in"), BorderFiles(work, tiles, "out")


@pytest.mark.usefixtures("no_kernel_loading")
def test_the_sign_agreement_holds_a_few_tiles_borders_not_the_scans(tmp_path):
    """The coordinator compares normal signs one tile at a time, reading the borders from the
    work folder: 4x the tiles, the same peak allocation (all trees at once grew with them)."""
    import tracemalloc

    peaks = {}
    for n in (3, 6):
        d = tmp_path / str(n)
        d.mkdir()
        grid, b_in, b_out = _border_files(d, n)
        tracemalloc.start()
        flips, disagreeing = agree_signs(grid, b_in, b_out, r0=0.2)
        peaks[n] = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        assert disagreeing == 0 and set(flips.values()) == {1.0}
        assert len(flips) == n * n
    assert peaks[6] < 1.3 * peaks[3]


@pytest.mark.usefixtures("no_kernel_loading")
def test_the_split_holds_a_chunk_not_the_scan(tmp_path, monkeypatch):
    """The coordinator splits a LAS file chunk by chunk: 4x the points, the same peak
    allocation (one chunk's working set; nothing per point is kept)."""
    import tracemalloc

    import recon.tiling.source as source

    laspy = pytest.importorskip("laspy")
    monkeypatch.setattr(source, "SPLIT_CHUNK_POINTS", 5000)
    cfg = ReconConfig()
    peaks = {}
    for n in (20_000, 80_000):
        rng = np.random.default_rng(n)
        side = np.sqrt(n / 100.0)  # the same density: a larger area
        pts = np.column_stack([rng.uniform(0, side, (n, 2)), rng.normal(0, 0.01, n)])
        header = laspy.LasHeader(point_format=3, version="1.2")
        header.scales = np.array([1e-4] * 3)
        header.offsets = np.floor(pts.min(axis=0))
        las = laspy.LasData(header)
        las.x, las.y, las.z = pts[:, 0], pts[:, 1], pts[:, 2]
        path = tmp_path / f"scan-{n}.las"
        las.write(str(path))
        scan = source.scan_header(path, cfg)
        grid = TileGrid.cover(scan.lo, scan.hi, 4.0, 0.0)
        tracemalloc.start()
        store = source.split_input(scan, grid, tmp_path / f"work-{n}", cfg)
        peaks[n] = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        assert sum(store.counts.values()) == n
    assert peaks[80_000] < 1.3 * peaks[20_000], peaks


# -- a tiled fit against the untiled one ------------------------------------------------------


@pytest.fixture(scope="module")
def fits(tmp_path_factory):
    """The same 3000-point sheet fitted whole and in 2 x 2 tiles (with tile 2's first fit
    failing, so that the retry is exercised end to end)."""
    d = tmp_path_factory.mktemp("tiles")
    src = d / "sheet.ply"
    write_points(src, sheet(3000))
    cfg = ReconConfig()
    whole = fit_file(src, d / "whole.ply", cfg)
    events = []
    old = os.environ.get("OPRECON_TILE_FAIL")
    os.environ["OPRECON_TILE_FAIL"] = "2"
    try:
        tiled = fit_tiled(
            src,
            d / "tiled.ply",
            with_values(cfg, tiling={"size": SIDE / 2}),
            jobs=2,
            on_event=events.append,
        )
    finally:
        if old is None:
            del os.environ["OPRECON_TILE_FAIL"]
        else:
            os.environ["OPRECON_TILE_FAIL"] = old
    return d, whole, tiled, events


def test_the_failed_tile_was_retried(fits):
    _, _, tiled, events = fits
    retries = [e.message for e in events if e.message]
    assert len(retries) == 1 and "tile 2 (1, 0, 0)" in retries[0] and "retrying" in retries[0]
    assert tiled.report["tiles"]["count"] == 4


def test_tiled_mesh_is_seamless(fits):
    d, whole, tiled, _ = fits
    v, f = read_mesh(d / "tiled.ply")
    topo = mesh_topology(v, f)
    whole_topo = whole.report.topology
    assert topo["boundary_loops"] == whole_topo.boundary_loops == 1
    assert topo["non_manifold_edges"] == 0 and topo["non_manifold_vertices"] == 0
    assert topo["duplicate_faces"] == 0
    assert topo["components"] == 1 and topo["consistently_oriented"]
    # no face twice, whatever its winding
    key = np.sort(f, axis=1)
    assert len(np.unique(key, axis=0)) == len(f)
    # tile borders leave no boundary edge: every boundary edge lies on the sheet's outer rim,
    # no deeper inside than the untiled mesh's (a crack along a seam would reach the centre)
    r0 = tiled.report["spacing"]
    depth = {}
    for name in ("whole", "tiled"):
        vv, ff = read_mesh(d / f"{name}.ply")
        edges, counts = count_edge_faces(ff)
        mid = vv[edges[counts == 1]].mean(axis=1)
        depth[name] = np.minimum(mid[:, :2], SIDE - mid[:, :2]).min(axis=1).max()
    assert depth["tiled"] <= depth["whole"] + r0
    assert depth["tiled"] < 5 * r0
    assert len(boundary_loops(f)) == 1
    seams = tiled.report["tiles"]["seams"]
    assert seams["non_manifold_edges"] == 0 and seams["seam_edges"] > 0


def test_tiled_fit_is_as_close_to_the_truth_as_the_untiled_one(fits):
    d, whole, tiled, _ = fits
    xy = np.random.default_rng(7).uniform(0, SIDE, (100_000, 2))
    truth = np.column_stack([xy, height(xy)])
    scores = {}
    for name in ("whole", "tiled"):
        v, f = read_mesh(d / f"{name}.ply")
        scores[name] = compare_meshes((v, f), (truth, None), n_samples=50_000)
    assert tiled.report["spacing"] == pytest.approx(whole.report.spacing, rel=1e-12)
    assert scores["tiled"]["chamfer_l1"] <= 1.05 * scores["whole"]["chamfer_l1"]
    assert scores["tiled"]["fscore"] >= scores["whole"]["fscore"] - 0.005
    n_whole = whole.report.topology.n_vertices
    assert abs(tiled.report["topology"]["n_vertices"] - n_whole) < 0.05 * n_whole


def test_tiled_report_has_tiles_section(fits):
    _, _, tiled, _ = fits
    tiles = tiled.report["tiles"]
    assert tiles["grid"] == [2, 2, 1]
    assert len(tiles["per_tile"]) == 4
    assert all(t["fit_s"] > 0 and t["mesh_s"] > 0 and t["particles"] > 0 for t in tiles["per_tile"])
    assert sum(t["points"] for t in tiles["per_tile"]) == 3000
    # each tile also fits the points of its halo, in its neighbours' cores
    assert all(t["points_with_halo"] > t["points"] for t in tiles["per_tile"])
    assert tiles["time_per_tile"]["max"] >= tiles["time_per_tile"]["mean"] > 0
    assert set(tiles["seams"]) >= {"seam_edges", "seam_boundary_edges", "non_manifold_edges"}


def test_a_tile_with_a_few_unusable_points_is_left_empty(tmp_path):
    from recon.config import config_to_dict
    from recon.tiling.source import TileStore
    from recon.tiling.tasks import FitJob, fit_task

    grid = TileGrid.cover(np.zeros(3), np.array([20.0, 10.0, 1.0]), 10.0, 0.5)
    line = np.column_stack([np.linspace(15, 19, 20), np.full(20, 5.0), np.zeros(20)])
    store = TileStore(tmp_path, grid, {1: len(line)}, 3)
    line.astype("<f8").tofile(store.path(1))
    cfg = config_to_dict(with_values(ReconConfig(), seeds={"spacing": 0.2}))
    out = fit_task(FitJob(1, store, cfg, 0.2, tmp_path))
    assert out["points"] == 20 and out["particles"] == 0
    assert "20 points not fitted" in out["warnings"][0]


def step(n: int, seed: int = 0, x0: float = 3.0, h: float = 1.5) -> np.ndarray:
    """Ground at z = 0 for x < x0, a wall at x = x0 up to h, ground at z = h beyond: a concave
    and a convex crease along y."""
    rng = np.random.default_rng(seed)
    m_w = int(n * h / (SIDE + h))
    xy = rng.uniform(0, SIDE, (n - m_w, 2))
    z = np.where(xy[:, 0] < x0, 0.0, h)
    wall = np.column_stack([np.full(m_w, x0), rng.uniform(0, SIDE, m_w), rng.uniform(0, h, m_w)])
    return np.vstack([np.column_stack([xy, z]), wall])


def test_tiles_triangulate_around_the_crease_particles_their_fits_found(tmp_path):
    """The tiles' triangulation gets the crease particles of the tiles' fits (issue 12: concave
    ones lifted for the pivoting, quads flipped along the line), as the untiled fit's does.
    Without them the 500k bench scene's tiles left slits along wall feet open (tile 0: an
    80-edge loop, and 55 crossings to untangle; with them none, and 0)."""
    src = tmp_path / "step.ply"
    write_points(src, step(4000))
    cfg = ReconConfig()
    whole = fit_file(src, tmp_path / "whole.ply", cfg)
    tiled = fit_tiled(src, tmp_path / "tiled.ply", with_values(cfg, tiling={"size": SIDE / 2}))
    per_tile = tiled.report["tiles"]["per_tile"]
    assert all(t["crease_particles"] > 0 for t in per_tile if t["index"][0] == 0)
    v, f = read_mesh(tmp_path / "tiled.ply")
    topo = mesh_topology(v, f)
    assert topo["boundary_loops"] == whole.report.topology.boundary_loops == 1
    assert topo["non_manifold_edges"] == 0


def test_tiled_report_topology_is_the_written_meshs(fits):
    """The coordinator measures the topology unit by unit (it never holds the whole mesh):
    the same counts as measuring the written mesh whole."""
    d, _, tiled, _ = fits
    v, f = read_mesh(d / "tiled.ply")
    whole = mesh_topology(v, f)
    report = tiled.report["topology"]
    for key in whole:
        assert report[key] == pytest.approx(whole[key]), key
    memory = tiled.report["tiles"]["coordinator"]
    assert 0 < memory["largest_unit_faces"] < len(f)
    phases = ["start", "split", "spacing", "fit", "mesh", "stitch", "write"]
    assert list(memory["peak_rss_mib"]) == phases


@pytest.mark.skipif(not Path("/proc/self/clear_refs").exists(), reason="Linux only")
def test_the_coordinators_peak_memory_is_measured_phase_by_phase():
    """The report's per-phase peaks: a phase that held 64 MiB more shows it, the next
    phase (after the reset) does not."""
    from recon.tiling.run import peak_rss_mib

    peak_rss_mib(reset=True)
    block = np.ones(2**23)  # 64 MiB, touched
    del block
    held = peak_rss_mib(reset=True)
    after = peak_rss_mib()
    assert held is not None and after is not None
    assert held - after > 48


def test_tiled_mesh_does_not_cross_itself(fits):
    """Every tile untangles its mesh (its own vertices move, the neighbours' stay put)."""
    from recon.intersections import self_intersections

    d, _, tiled, _ = fits
    v, f = read_mesh(d / "tiled.ply")
    assert len(self_intersections(v, f)) == 0
    found = tiled.report["tiles"]["self_intersections"]
    assert found["left"] <= found["found"]


def test_a_kept_work_folder_stitches_again_to_the_same_mesh(tmp_path, monkeypatch):
    """``OPRECON_KEEP_TILES`` keeps the work folder with the stitch's inputs (for seam
    experiments); :func:`recon.tiling.run.restitch` makes the same mesh from it."""
    from recon.tiling.run import STITCH_INPUTS, restitch

    src = tmp_path / "sheet.ply"
    write_points(src, sheet(1500, seed=3))
    keep = tmp_path / "work"
    monkeypatch.setenv("OPRECON_KEEP_TILES", str(keep))
    cfg = with_values(ReconConfig(), tiling={"size": SIDE / 2})
    fit_tiled(src, tmp_path / "tiled.ply", cfg, jobs=1)
    assert (keep / STITCH_INPUTS).exists()
    assert not list(tmp_path.glob(".oprecon-tiles-*"))  # moved, not left beside the output
    out = restitch(keep, tmp_path / "again.ply")
    v1, f1 = read_mesh(tmp_path / "tiled.ply")
    v2, f2 = read_mesh(tmp_path / "again.ply")
    assert np.array_equal(f1, f2) and np.allclose(v1, v2)
    assert out["topology"]["boundary_loops"] == mesh_topology(v2, f2)["boundary_loops"]


def test_only_the_particles_near_a_seam_go_to_the_sign_agreement(tmp_path, monkeypatch):
    """A tile's fit files for the normal-sign comparison its own particles within the sign
    band plus the pair distance of an inner tile face, not all of its particles (the
    coordinator held them all before: ~48 bytes per particle of the scan)."""
    import pickle

    from recon.tiling.run import STITCH_INPUTS
    from recon.tiling.stitch import SIGN_PAIR_DISTANCE
    from recon.tiling.tasks import SIGN_BAND, BorderFiles, particles_path

    src = tmp_path / "sheet.ply"
    write_points(src, sheet(3000, seed=4))
    keep = tmp_path / "work"
    monkeypatch.setenv("OPRECON_KEEP_TILES", str(keep))
    fit_tiled(src, tmp_path / "tiled.ply", with_values(ReconConfig(), tiling={"size": SIDE / 2}))
    grid, counts = pickle.loads((keep / STITCH_INPUTS).read_bytes())[:2]
    r0 = pickle.loads((keep / STITCH_INPUTS).read_bytes())[4]
    own = BorderFiles(keep, counts, "in")
    reach = (SIGN_BAND + SIGN_PAIR_DISTANCE) * r0
    for t in counts:
        p, n = own[t]
        with np.load(particles_path(keep, t)) as z:
            n_particles = len(z["positions"])
        assert len(p) == len(n) and 0 < len(p) < 0.8 * n_particles
        assert np.all(grid.seam_distance(p) <= reach + 1e-9)


def test_a_dask_coordinator_keeps_bounded_records_of_finished_tasks():
    """On a LocalCluster the scheduler runs in the coordinating process: its transition log,
    events, past computations and its connections' recent messages keep the last
    DASK_RECORDS of them, and no future or task state stays, so twice the tasks leave the
    same records. At Dask's defaults (1,000 of each, 100 computations) they held 15 MiB after
    2,000 tiny tasks (``bench_tiles.py tasks --default-records``)."""
    pytest.importorskip("dask.distributed")
    from recon.batch.executors import DASK_RECORDS
    from recon.tiling.executors import held_records, tile_runner

    cap = DASK_RECORDS["distributed.admin.low-level-log-length"]
    held = []

    def settled(runner) -> dict:
        # the last futures are released, and their tasks forgotten, asynchronously: wait
        # (at most 30 s) until none is left, as a long run's memory would see them
        deadline = time.monotonic() + 30.0
        while True:
            records = held_records(runner)
            if records["futures"] == records["tasks"] == 0 or time.monotonic() > deadline:
                return records
            time.sleep(0.05)

    with tile_runner("dask", 1) as runner:
        for _ in range(2):  # 3 x cap tasks fill every record; as many again add none
            jobs = {t: (abs, (-t,)) for t in range(3 * cap)}
            run_tasks(runner, "fit", jobs, str, on_result=lambda t, r: None)
            held.append(settled(runner))
    first, second = held
    for key in ("futures", "tasks"):
        assert first[key] == second[key] == 0, (key, held)
    for key in ("transition_log", "events", "computations", "client_messages"):
        assert second[key] == first[key], (key, held)
    assert first["transition_log"] == first["client_messages"] == cap, held
    assert first["computations"] <= DASK_RECORDS["distributed.diagnostics.computations.max-history"]


def test_tiles_cover_a_holes_inside_as_the_untiled_fit_does(tmp_path):
    """A tile's hole filling takes data as covering a hole's inside by the untiled fit's rule
    (a sample k times sparser than the scan's median covers k times farther, and within
    SAMPLING_REACH median spacings), not within r0 only. Before, a sparse body's thin ear
    (tests/test_sparse_holes.py) came out closed untiled and open in 3 tiles (1 loop, seed 2
    then), and a 12-edge hole on a roof of the 10M bench scene, inside tile 78, was the tile's
    alone. With the growth's active set that seed keeps a loop at the ear's tip whatever the
    reach, and the tiles run in worker processes where the reach cannot be patched, so the
    reach each tile reports is what shows the rule at work."""
    from test_sparse_holes import EARED, union_points

    from recon.fitting.pipeline import HOLE_COVER_DISTANCE

    src = tmp_path / "eared.ply"
    write_points(src, union_points(EARED, 1500, 0))
    whole = fit_file(src, tmp_path / "whole.ply", ReconConfig())
    tiled = fit_tiled(
        src, tmp_path / "tiled.ply", with_values(ReconConfig(), tiling={"size": 0.8}), jobs=1
    )
    tiles = tiled.report["tiles"]
    assert tiles["count"] == 3
    # the tiles cover with the sparse data's reach (2.5 r0 here), not within r0; a tile where
    # that reach leaves a crossing meshes again within r0, as the untiled fit (seed 0: tile 0)
    reach = [t["cover_reach_r0"] for t in tiles["per_tile"]]
    assert max(reach) > 2 * HOLE_COVER_DISTANCE, reach
    assert set(reach) <= {max(reach), HOLE_COVER_DISTANCE}, reach
    v, f = read_mesh(tmp_path / "tiled.ply")
    topo = mesh_topology(v, f)
    assert whole.report.topology.boundary_loops == 0
    assert topo["boundary_loops"] == 0 and topo["watertight"] and topo["genus"] == 0, topo


def test_a_tile_cuts_a_small_handle_inside_its_core_and_keeps_its_vertices(tmp_path):
    """The one-eared body at 1,500 points, seed 1, in tiles of 0.8: a tunnel at the ear's
    base, 1-8 r0 from a seam, inside one tile's core.

    Regression 1: the polish's cut of small handles (recon.small_handles) drops the vertices
    inside the cut, but a tile's polished vertices must stay those of its particles: the mesh
    phase failed with "operands could not be broadcast together" (with the growth's active
    set). A tile's cut leaves the vertices in place, unreferenced.
    Regression 2: tiles did not cut small handles at all, and the stitched mesh came out
    watertight with genus 1 where the untiled fit's is 0. A tile now cuts the handles whose
    ball holds only faces it writes, away from its seams (tasks.inner_handles_cut)."""
    from test_sparse_holes import EARED, union_points

    src = tmp_path / "eared.ply"
    write_points(src, union_points(EARED, 1500, 1))
    cfg = apply_overrides(ReconConfig(), {"growth.active_radius": 3.0})
    tiled = fit_tiled(src, tmp_path / "tiled.ply", with_values(cfg, tiling={"size": 0.8}), jobs=1)
    tiles = tiled.report["tiles"]
    assert tiles["count"] == 3
    assert tiles["small_handles_cut"] == 1 and tiles["repair"]["small_handles_cut"] == 0, tiles
    v, f = read_mesh(tmp_path / "tiled.ply")
    topo = mesh_topology(v, f)
    assert topo["components"] == 1 and topo["watertight"] and topo["genus"] == 0, topo
    assert topo["unreferenced_vertices"] == 0, topo


def test_the_seam_repair_cuts_a_small_handle_across_the_seam(tmp_path):
    """The one-eared body at 1,500 points, seed 7, in tiles of 0.8: the tunnel at the ear's
    base lies on a seam (0-0.6 r0 from it), where no tile may change its faces. Before, the
    stitched mesh came out watertight with genus 1; the coordinator's repair of the seam's
    zone now cuts a handle whose ball holds only the zone's faces (stitch.repair_cell)."""
    from test_sparse_holes import EARED, union_points

    src = tmp_path / "eared.ply"
    write_points(src, union_points(EARED, 1500, 7))
    tiled = fit_tiled(
        src, tmp_path / "tiled.ply", with_values(ReconConfig(), tiling={"size": 0.8}), jobs=1
    )
    tiles = tiled.report["tiles"]
    assert tiles["repair"]["small_handles_cut"] == 1 and tiles["small_handles_cut"] == 0, tiles
    v, f = read_mesh(tmp_path / "tiled.ply")
    topo = mesh_topology(v, f)
    assert topo["components"] == 1 and topo["watertight"] and topo["genus"] == 0, topo
    m = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(v), o3d.utility.Vector3iVector(f))
    # (Open3D's is_watertight also asks for no self-intersection: the seam keeps 2 crossing
    # pairs here, as before the cut)
    assert m.is_edge_manifold(allow_boundary_edges=False) and m.is_vertex_manifold()


def test_tiles_polish_their_triangles_as_the_untiled_fit_does(fits):
    d, whole, _, _ = fits
    angle = {}
    for name in ("whole", "tiled"):
        v, f = read_mesh(d / f"{name}.ply")
        angle[name] = triangle_quality(v, f)["min_angle_mean_deg"]
    # the tiles' polish has no flips and no data surface, but smooths all the same (measured:
    # whole 55.54, tiled 55.56; unpolished tiles gave 55.05)
    assert angle["tiled"] > angle["whole"] - 0.25, angle


def test_the_tiles_take_the_scans_per_point_normal_scale(tmp_path, monkeypatch):
    """``normals.per_point_scale`` reaches every tile's fit: the scan's widest neighbourhood
    (``MAX_SCALE`` x its configured k) goes with each FitJob, and :func:`fit_task` hands it
    to the fit; off, the jobs carry None (one k per point)."""
    from recon.fitting import pipeline
    from recon.normal_scales import MAX_SCALE
    from recon.tiling import executors
    from recon.tiling.tasks import FitJob, fit_task

    class Seen(Exception):
        pass

    given: list = []

    def spy_fit(cloud, cfg, normals_k_max=None, creases=None):
        given.append(normals_k_max)
        # the creases detected on the points within the crease reach, one per point fitted
        assert creases is not None and len(creases.labels) == len(cloud.points)
        raise Seen

    jobs: list = []
    submit = executors.TileRunner.submit

    def recording_submit(self, fn, *args):
        if fn is fit_task:
            job = args[0]
            assert isinstance(job, FitJob)
            jobs.append(job)
            if len(jobs) == 1:  # the task itself, in this process, up to the fit it calls
                with monkeypatch.context() as m:
                    m.setattr(pipeline, "fit_particles", spy_fit)
                    with pytest.raises(Seen):
                        fit_task(job)
        return submit(self, fn, *args)

    monkeypatch.setattr(executors.TileRunner, "submit", recording_submit)
    src = tmp_path / "step.ply"
    write_points(src, step(3000))
    for on, expected in ((True, MAX_SCALE * 20), (False, None)):
        jobs.clear()
        given.clear()
        cfg = with_values(
            ReconConfig(), normals={"per_point_scale": on, "k": 20}, tiling={"size": SIDE / 2}
        )
        fit_tiled(src, tmp_path / f"tiled-{on}.ply", cfg, jobs=1)
        assert len(jobs) > 1
        assert {job.normals_k_max for job in jobs} == {expected}
        assert given == [expected]
        assert all(job.crease_reach > job.store.grid.halo for job in jobs)
