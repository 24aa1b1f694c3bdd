"""Neighbour lists: cell grid, full CSR rows, rebuilt only past half the skin.

A :class:`NeighborList` stores, for every particle, all others closer than the list radius
r_l = cutoff + skin (S&T92 §4.2 caches neighbour lists; the skin is a Verlet buffer). As long as
no particle has moved more than skin/2 since the build, every pair within the cutoff is still in
the list, so the list is rebuilt only when the largest displacement exceeds skin/2. Lists are
*full*: each pair appears in both rows, so a parallel loop over rows writes only its own row.

Build: particles are binned into cells of side r_l (only occupied cells are stored, so memory is
O(n) for a surface inside a large box), then each row is collected from the 27 surrounding cells
and sorted; see :mod:`recon.kernels.cell_list`. For a surface-like arrangement every row has a
bounded length, so a build is O(n log n) (one sort) and a step O(n).

References
----------
.. [ST92] R. Szeliski, D. Tonnesen. "Surface Modeling with Oriented Particle Systems".
   SIGGRAPH '92, §4.2.
.. [AT87] M. P. Allen, D. J. Tildesley. "Computer Simulation of Liquids", §5.3.
"""

from __future__ import annotations

import numpy as np

from .errors import DivergenceError
from .geometry import as_points
from .kernels.cell_list import (
    bin_particles,
    build_neighbor_list_kernel,
    list_covers,
    max_displacement2,
    sublist_within,
)
from .kernels.grid_query import coordinate_extent, covered_kernel, grid_build, knn_grid_kernel
from .kernels.options import ThreadChooser, query_workers, thread_limit, timed_threads

PARALLEL_MIN_PARTICLES = 30_000
"""From this many particles the kernels run threaded, below it in the calling thread, except
those that time both ways and take the faster (:class:`~recon.kernels.options.ThreadChooser`,
from ``TIMED_MIN_ITEMS`` items): the step and the list builds (unless ``ALWAYS_THREADED`` or a
simulation's ``parallel`` decides), the anchors, and :class:`PointGrid`'s queries below this
size.

Measured (median step time, sphere, 2 cores): with the other core mostly idle two threads win
from ~2,000 particles (5k: 1.0 vs 2.0 ms), but with both cores busy with other work a parallel
region waits for a descheduled thread (5k: 8.0 vs 2.1 ms; 20k: 14.6 vs 9.0 ms) and threads only
pay off from ~50k (50k: 52 vs 70 ms). DESIGN §3 saw the same (~8 ms per region)."""

_MAX_CELLS = 2**62
_ROW_CAPACITY = 32  # scratch row length; a surface at skin 0.4 r0 has ~20 neighbours


def _check_positions(position: np.ndarray) -> np.ndarray:
    pos = as_points(position, "position")
    finite = np.isfinite(pos).all(axis=1)
    if not finite.all():
        first = int(np.flatnonzero(~finite)[0])
        raise DivergenceError(
            f"particle {first} has a non-finite position {pos[first]}; "
            "cannot build a neighbour list"
        )
    return pos


def build_neighbor_list(
    position: np.ndarray, radius: float, *, parallel: bool | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Full CSR neighbour list of all pairs closer than ``radius``.

    Parameters
    ----------
    position : (n, 3) float64
        Positions [length]; must be finite.
    radius : float
        List radius [length], > 0.
    parallel : bool, optional
        Use the threaded kernel; default: when n ≥ ``PARALLEL_MIN_PARTICLES``.

    Returns
    -------
    offsets : (n + 1,) int64
        Row i is ``indices[offsets[i]:offsets[i + 1]]``.
    indices : (nnz,) int32
        Neighbours of each particle in ascending order; each pair appears in both rows.

    Raises
    ------
    DivergenceError
        If a position is not finite.
    ValueError
        On a bad shape or radius, or an extent too large for the cell grid.

    Examples
    --------
    >>> offsets, indices = build_neighbor_list(np.array([[0.0, 0, 0], [1, 0, 0], [5, 0, 0]]), 2.0)
    >>> offsets.tolist(), indices.tolist()
    ([0, 1, 2, 2], [1, 0])
    """
    pos = _check_positions(position)
    if not (np.isfinite(radius) and radius > 0.0):
        raise ValueError(f"radius: expected a finite number > 0, got {radius}")
    if pos.shape[0] > 0:
        extent = coordinate_extent(pos)
        cells = np.prod(np.floor(extent / radius) + 1.0)
        if cells > _MAX_CELLS:
            raise ValueError(
                f"the particles span {extent.tolist()}, too large for a cell grid of side {radius}"
            )
    if parallel is None:
        parallel = pos.shape[0] >= PARALLEL_MIN_PARTICLES
    capacity = _ROW_CAPACITY
    with thread_limit(parallel):
        offsets, indices, longest = build_neighbor_list_kernel(pos, float(radius), capacity)
        if longest > capacity:
            offsets, indices, longest = build_neighbor_list_kernel(pos, float(radius), longest)
    return offsets, indices


def sort_order_by_cell(position: np.ndarray, cell_size: float) -> np.ndarray:
    """A permutation that sorts particles by grid cell (for memory locality).

    Parameters
    ----------
    position : (n, 3) float64
        Finite positions [length].
    cell_size : float
        Cell side [length], e.g. the list radius.

    Returns
    -------
    (n,) int64
        ``order`` such that ``position[order]`` visits the cells in key order (stable).
    """
    pos = _check_positions(position)
    if not (np.isfinite(cell_size) and cell_size > 0.0):
        raise ValueError(f"cell_size: expected a finite number > 0, got {cell_size}")
    return bin_particles(pos, float(cell_size))[0]


class NeighborList:
    """A cached full neighbour list with a Verlet skin.

    Parameters
    ----------
    cutoff : float
        Interaction cutoff r_c [length].
    skin : float
        Skin [length]; the list radius is ``cutoff + skin`` and the list is rebuilt once some
        particle has moved more than ``skin / 2`` since the last build.

    Attributes
    ----------
    offsets : (n + 1,) int64
    indices : (nnz,) int32
    reference_position : (n, 3) float64
        Positions at the last build.
    n_builds : int
        Number of builds so far.
    """

    def __init__(self, cutoff: float, skin: float) -> None:
        if not (cutoff > 0.0 and skin > 0.0):
            raise ValueError(f"cutoff and skin must be > 0, got cutoff={cutoff}, skin={skin}")
        self.cutoff = float(cutoff)
        self.skin = float(skin)
        self.offsets = np.zeros(1, dtype=np.int64)
        self.indices = np.zeros(0, dtype=np.int32)
        self.reference_position = np.zeros((0, 3))
        self.n_builds = 0
        self._binning: tuple | None = None

    @property
    def radius(self) -> float:
        """List radius cutoff + skin [length]."""
        return self.cutoff + self.skin

    @property
    def n(self) -> int:
        """Number of rows (particles at the last build)."""
        return self.offsets.shape[0] - 1

    def build(self, position: np.ndarray, *, parallel: bool | None = None) -> None:
        """Rebuild from ``position`` (n, 3) and remember it as the reference."""
        pos = _check_positions(position)
        self.offsets, self.indices = build_neighbor_list(pos, self.radius, parallel=parallel)
        self.reference_position = pos.copy()
        self.n_builds += 1
        self._binning = None

    def within(self, position: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
        """CSR lists of the pairs closer than ``radius`` at ``position``, taken from this list:
        the same lists as ``build_neighbor_list(position, radius)`` provided that the list
        holds every such pair, i.e. ``radius`` ≤ :attr:`cutoff` and :meth:`covers` is true
        for ``position`` (the caller's duty; checked only for the radius)."""
        if not radius <= self.cutoff:
            raise ValueError(f"radius {radius} exceeds the list's cutoff {self.cutoff}")
        pos = np.ascontiguousarray(position, dtype=np.float64)
        return sublist_within(pos, self.offsets, self.indices, float(radius))

    def covers(self, position: np.ndarray) -> bool:
        """Whether every pair closer than ``cutoff`` at ``position`` is in the list (exact).

        True whenever no particle moved more than skin/2 since the build (the usual rule);
        otherwise the few particles that did are checked against the build-time cell grid
        (:func:`recon.kernels.cell_list.list_covers`), so that a handful of fast particles do
        not force a rebuild of the whole list. False when the particle count changed, some
        particle moved more than the skin, or more than ``FAST_FRACTION`` of them moved
        more than skin/2.
        """
        pos = np.ascontiguousarray(position, dtype=np.float64)
        if pos.shape != self.reference_position.shape or self.n_builds == 0:
            return False
        n = pos.shape[0]
        if n == 0:
            return True
        if self._binning is None:
            self._binning = bin_particles(self.reference_position, self.radius)
        max_fast = max(int(FAST_FRACTION * n), 1)
        return bool(
            list_covers(
                pos,
                self.reference_position,
                self.offsets,
                self.indices,
                self.cutoff,
                self.skin,
                self._binning,
                max_fast,
            )
        )

    def needs_rebuild(self, position: np.ndarray) -> bool:
        """True if the particle count changed or some particle moved more than skin/2."""
        pos = np.ascontiguousarray(position, dtype=np.float64)
        if pos.shape != self.reference_position.shape or self.n_builds == 0:
            return True
        limit = 0.5 * self.skin
        d2 = max_displacement2(pos, self.reference_position)
        return not (d2 <= limit * limit)

    def update(self, position: np.ndarray, *, parallel: bool | None = None) -> bool:
        """Rebuild if :meth:`needs_rebuild`; return whether it did."""
        if self.needs_rebuild(position):
            self.build(position, parallel=parallel)
            return True
        return False

    def neighbors_of(self, i: int) -> np.ndarray:
        """Indices of the neighbours of particle ``i`` (a view)."""
        return self.indices[self.offsets[i] : self.offsets[i + 1]]


#: :meth:`NeighborList.covers` answers False (rebuild) when more than this fraction of the
#: particles moved more than half the skin: checking them one by one would then cost about as
#: much as the rebuild.
FAST_FRACTION = 0.05

#: Shells searched around a query's cell before :class:`PointGrid` hands the query to a k-d tree.
GRID_MAX_RING = 3

#: :class:`PointGrid`'s k-nearest queries (one chooser per k: the cost per query grows with k)
#: and coverage tests run threaded or serial, whichever was faster lately. The answers do not
#: depend on it. Below ``PARALLEL_MIN_PARTICLES`` queries they ran serial before: a fit's
#: growth rounds and coverage tests query 2,000-30,000 points at a time (bunny-clean: the
#: grid kernels 0.27 -> 0.21 s per fit, the same mesh; docs/performance-history.md).
_QUERY_THREADS: dict[int, ThreadChooser] = {}
_COVER_THREADS = ThreadChooser()


class PointGrid:
    """Static points binned once into a hashed cell grid: exact nearest-point queries.

    Replaces a k-d tree where the same points are queried many times (the data during a fit)
    or where a tree would be rebuilt every round (the particles). Queries farther than
    ``GRID_MAX_RING`` cells from their k-th neighbour go to a k-d tree built on first need, so
    every answer is exact; see :mod:`recon.kernels.grid_query`.

    Parameters
    ----------
    points : (n, 3) float64
        Finite points [length].
    cell_size : float
        Cell side [length], > 0; about the distance of the k-th neighbour of a typical query.
    """

    def __init__(self, points: np.ndarray, cell_size: float) -> None:
        self.points = np.ascontiguousarray(points, dtype=np.float64)
        if not (np.isfinite(cell_size) and cell_size > 0.0):
            raise ValueError(f"cell_size: expected a finite number > 0, got {cell_size}")
        self.cell_size = float(cell_size)
        self.grid: tuple | None = None
        if len(self.points):
            extent = coordinate_extent(self.points)
            if np.prod(np.floor(extent / self.cell_size) + 1.0) <= _MAX_CELLS:
                self.grid = grid_build(self.points, self.cell_size)
        self._tree = None

    @property
    def tree(self):  # noqa: ANN201 - scipy type
        """A k-d tree of the points (built on first use, for the queries the grid hands on)."""
        if self._tree is None:
            from scipy.spatial import cKDTree

            self._tree = cKDTree(self.points)
        return self._tree

    @property
    def n(self) -> int:
        return len(self.points)

    def query(
        self, query: np.ndarray, k: int = 1, workers: int | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Distances and indices of the ``k`` nearest points (shape (m,) for k = 1, else
        (m, k); inf and n past the number of points): ``cKDTree.query``'s answer, so a grid
        can stand in for a tree (``workers``: for the queries the tree answers)."""
        q = np.ascontiguousarray(query, dtype=np.float64).reshape(-1, 3)
        m = len(q)
        k = int(k)
        dist = np.full((m, k), np.inf)
        idx = np.full((m, k), self.n, dtype=np.int64)
        if m and self.n:
            ok = np.zeros(m, dtype=np.bool_)
            if self.grid is not None:
                chooser = _QUERY_THREADS.setdefault(k, ThreadChooser())
                with timed_threads(chooser, m, PARALLEL_MIN_PARTICLES):
                    knn_grid_kernel(q, self.grid, self.cell_size, k, GRID_MAX_RING, dist, idx, ok)
                idx[idx < 0] = self.n
            rest = np.flatnonzero(~ok)
            if len(rest):
                w = query_workers() if workers is None else workers
                d, i = self.tree.query(q[rest], k=k, workers=w)
                dist[rest] = np.reshape(d, (len(rest), k))
                idx[rest] = np.reshape(i, (len(rest), k))
        if k == 1:
            return dist[:, 0], idx[:, 0]
        return dist, idx

    def covered(self, query: np.ndarray, radius: float) -> np.ndarray:
        """Whether some point lies within ``radius`` of each query (bool (m,))."""
        q = np.ascontiguousarray(query, dtype=np.float64).reshape(-1, 3)
        if self.grid is None or radius > self.cell_size:
            d, _ = self.query(q, k=1)
            return d <= radius
        out = np.zeros(len(q), dtype=np.bool_)
        with timed_threads(_COVER_THREADS, len(q), PARALLEL_MIN_PARTICLES):
            covered_kernel(q, self.grid, self.cell_size, float(radius), out)
        return out
