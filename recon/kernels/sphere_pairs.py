r"""Pairs of overlapping bounding spheres on a cell grid (the broad phase of the crossing test).

Two faces can cross only if their bounding spheres (centroid c, radius r: the farthest corner)
overlap:

.. math::

    |c_i - c_j| \le r_i + r_j .

:func:`sphere_pairs` returns every such pair ``i < j`` with at least one face marked and at
least one face ordinary, as sorted keys ``i n + j``. Ordinary faces are binned into cubic cells of
side h = 2 r_s (r_s: the largest ordinary radius; ``CELL_FACTOR``); an ordinary partner of face i
lies within r_i + r_s of it, so in the cells up to ceil((r_i + r_s) / h) away (27 for an
ordinary face; the cells of one column are consecutive keys: one binary search per column). The
few "large" faces (flagged by the caller) search the same way with their own radius, or compare
with every face when that ring holds more columns than there are faces; pairs of two large faces
are left to the caller (:func:`recon.intersections.candidate_pairs` pairs them on a grid of their
own), so that no large face is ever compared with every face of a big mesh. Each pair is emitted
once (by its marked face of lower index, or by its large face), counted in a first pass and
written in a second, each face into its own slice, so the result is the same for any thread
count. A face looks in the cells only at the faces it can emit a pair with: the ordinary ones,
and for a large face that is not marked the marked ordinary ones (the cells of the grid of
every face with the others left out, :func:`_members`: the same cells are searched). With the
crossing test fused in, the first pass notes each face's first few crossing partners, so that
the second writes them without testing again.

References
----------
.. [AT87] M. P. Allen, D. J. Tildesley. "Computer Simulation of Liquids", §5.3 (cell lists).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from .cell_list import bin_particles
from .options import EXACT_JIT_OPTIONS
from .tri_intersect import faces_cross

_PARALLEL = dict(EXACT_JIT_OPTIONS, parallel=True)

#: Cell side of the grid in units of r_s (see the module docstring).
CELL_FACTOR = 2.0
#: Crossing partners per face noted by the counting pass (:func:`_scan`).
FIRST_FOUND = 4


@njit(inline="always", **EXACT_JIT_OPTIONS)
def _overlap(centroid, radius, i, j):
    dx = centroid[i, 0] - centroid[j, 0]
    dy = centroid[i, 1] - centroid[j, 1]
    dz = centroid[i, 2] - centroid[j, 2]
    return math.sqrt(dx * dx + dy * dy + dz * dz) <= radius[i] + radius[j]


@njit(inline="always", **EXACT_JIT_OPTIONS)
def _emits(i, j, mark, large):
    """Whether face i emits the pair (i, j) (so that every pair is emitted exactly once; pairs
    of two large faces are not emitted here)."""
    if large[i]:
        return not large[j] and (mark[i] or mark[j])
    if large[j]:
        return False  # the large face emits it
    if not mark[i]:
        return False
    return j > i or not mark[j]


@njit(inline="always", **EXACT_JIT_OPTIONS)
def _keeps(vertices, faces, i, j, work):
    """With ``faces`` (the crossing test fused in): do faces i and j cross (sharing no
    vertex)? Without (empty ``faces``): every overlapping pair is kept. ``work``: (3, 3)
    scratch of the test (:func:`recon.kernels.tri_intersect.faces_cross`)."""
    if faces.shape[0] == 0:
        return True
    for a in range(3):
        for b in range(3):
            if faces[i, a] == faces[j, b]:
                return False
    return faces_cross(vertices, faces[i], faces[j], work)


@njit(inline="always", **EXACT_JIT_OPTIONS)
def _emit(i, j, n, out_keys, base, count, write, found):
    """Write the key of pair (i, j) at slot ``base + count`` (second pass), or note j among
    i's first partners (first pass, ``found``); the new count."""
    if write:
        out_keys[base + count] = min(i, j) * n + max(i, j)
    elif count < found.shape[1] and found.shape[0] > 0:
        found[i, count] = j
    return count + 1


@njit(**EXACT_JIT_OPTIONS)
def _members(order, cell_keys, cell_start, keep):
    """The occupied cells of a grid with only the items ``keep`` (bool per item) left in
    them, each in its cell and in its order there: ``(order, cell_keys, cell_start)`` as
    :func:`recon.kernels.cell_list.bin_particles` gives them, of those items."""
    total = 0
    for p in range(order.shape[0]):
        if keep[order[p]]:
            total += 1
    kept_order = np.empty(total, dtype=np.int64)
    kept_keys = np.empty(cell_keys.shape[0], dtype=np.int64)
    kept_start = np.empty(cell_keys.shape[0] + 1, dtype=np.int64)
    k = 0
    cells = 0
    for c in range(cell_keys.shape[0]):
        first = k
        for p in range(cell_start[c], cell_start[c + 1]):
            if keep[order[p]]:
                kept_order[k] = order[p]
                k += 1
        if k > first:
            kept_keys[cells] = cell_keys[c]
            kept_start[cells] = first
            cells += 1
    kept_start[cells] = k
    return kept_order, kept_keys[:cells], kept_start[: cells + 1]


@njit(**_PARALLEL)
def _scan(
    centroid,
    radius,
    mark,
    large,
    grids,
    dims,
    lo,
    cell,
    r_small,
    vertices,
    faces,
    out_keys,
    offsets,
    write,
    found,
):
    """Count (``write`` False) or write the pair keys each face emits. ``grids``: the cells
    of the ordinary faces, and of the marked ordinary ones (:func:`_members`): the partners
    a face can emit a pair with (an unmarked large face: marked ordinary ones only).
    ``found`` (n, k): the first k partners of each face, noted by the first pass (or (0, k)):
    a face with at most k is written from them, without testing its pairs again."""
    ordinary, marked = grids
    n = centroid.shape[0]
    inv = 1.0 / cell
    for i in prange(n):
        if not (mark[i] or large[i]):
            continue
        if write and offsets[i + 1] == offsets[i]:
            continue  # nothing to write (most faces, when only crossing pairs are kept)
        if write and found.shape[0] > 0 and offsets[i + 1] - offsets[i] <= found.shape[1]:
            for c in range(offsets[i + 1] - offsets[i]):
                j = found[i, c]
                out_keys[offsets[i] + c] = min(i, j) * n + max(i, j)
            continue
        count = 0
        base = offsets[i] if write else 0
        work = np.empty((3 if faces.shape[0] else 0, 3))  # the crossing test's scratch
        order, cell_keys, cell_start = marked if large[i] and not mark[i] else ordinary
        # an ordinary partner j lies within r_i + r_j <= r_i + r_small
        ring = np.int64(math.ceil((radius[i] + r_small) * inv))
        columns = min(2 * ring + 1, dims[0]) * min(2 * ring + 1, dims[1])
        if large[i] and columns > n:
            for j in order:
                if j != i and _emits(i, j, mark, large) and _overlap(centroid, radius, i, j):
                    if _keeps(vertices, faces, i, j, work):
                        count = _emit(i, j, n, out_keys, base, count, write, found)
        else:
            cx = np.int64(math.floor((centroid[i, 0] - lo[0]) * inv))
            cy = np.int64(math.floor((centroid[i, 1] - lo[1]) * inv))
            cz = np.int64(math.floor((centroid[i, 2] - lo[2]) * inv))
            for ddx in range(-ring, ring + 1):
                x = cx + ddx
                if x < 0 or x >= dims[0]:
                    continue
                for ddy in range(-ring, ring + 1):
                    y = cy + ddy
                    if y < 0 or y >= dims[1]:
                        continue
                    # cells (x, y, z - ring .. z + ring) have consecutive keys
                    z_lo = max(cz - ring, 0)
                    z_hi = min(cz + ring, dims[2] - 1)
                    if z_lo > z_hi:
                        continue
                    key_lo = (x * dims[1] + y) * dims[2] + z_lo
                    key_hi = key_lo + (z_hi - z_lo)
                    c = np.searchsorted(cell_keys, key_lo)
                    while c < cell_keys.shape[0] and cell_keys[c] <= key_hi:
                        for p in range(cell_start[c], cell_start[c + 1]):
                            j = order[p]
                            if j == i or not _emits(i, j, mark, large):
                                continue
                            if _overlap(centroid, radius, i, j):
                                if _keeps(vertices, faces, i, j, work):
                                    count = _emit(i, j, n, out_keys, base, count, write, found)
                        c += 1
        if not write:
            offsets[i + 1] = count
    return 0


@njit(**EXACT_JIT_OPTIONS)
def sphere_pairs(centroid, radius, mark, large, r_small, vertices, faces):
    r"""Sorted keys ``i n + j`` (i < j) of the face pairs whose bounding spheres overlap,
    :math:`|c_i - c_j| \le r_i + r_j`, with at least one face marked and at least one ordinary
    (not ``large``).

    Parameters
    ----------
    centroid : (n, 3) float64
    radius : (n,) float64
        Bounding radii.
    mark : (n,) bool
        Faces whose pairs are wanted (all True for every pair).
    large : (n,) bool
        Faces larger than ``r_small``: they search the cells within their own radius (every
        face when that is cheaper); pairs of two large faces are not returned.
    r_small : float
        The largest radius of the faces that are not large, > 0.
    vertices : (V, 3) float64
    faces : (n, 3) int64, or (0, 3)
        With faces, only the pairs that cross are returned (sharing no vertex;
        :func:`recon.kernels.tri_intersect.faces_cross`), tested as they are found:
        the candidate pairs (tens per face) are never held. Empty: every overlapping pair.

    Returns
    -------
    (m,) int64, ascending.
    """
    n = centroid.shape[0]
    cell = CELL_FACTOR * r_small
    order, cell_keys, cell_start, _, dims, lo = bin_particles(centroid, cell)
    # a large face is never the partner found in a cell, and an unmarked one pairs with
    # marked faces only: each face searches the cells of its possible partners alone (in the
    # cells of the grid of every face, so the same cells are searched, with fewer faces)
    ordinary = _members(order, cell_keys, cell_start, ~large)
    marked = ordinary if mark.all() else _members(order, cell_keys, cell_start, mark & ~large)
    offsets = np.zeros(n + 1, dtype=np.int64)
    empty = np.zeros(0, dtype=np.int64)
    grids = (ordinary, marked)
    args = (centroid, radius, mark, large, grids, dims, lo, cell, r_small, vertices, faces)
    # crossing pairs are few per face: the first pass notes them, so that the second writes
    # them without testing the face's candidates again (every overlapping pair: too many)
    found = np.empty((n if faces.shape[0] else 0, FIRST_FOUND), dtype=np.int64)
    _scan(*args, empty, offsets, False, found)
    for i in range(n):
        offsets[i + 1] += offsets[i]
    keys = np.zeros(offsets[n], dtype=np.int64)
    _scan(*args, keys, offsets, True, found)
    keys.sort()
    return keys
