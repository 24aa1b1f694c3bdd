r"""Cell-grid construction of full CSR neighbour lists.

Particles are binned into cubic cells of side ≥ the list radius r_l, so every neighbour of a
particle lies in its own cell or one of the 26 around it. Only occupied cells are stored: their
linear keys are sorted (a stable sort of the particles by cell), and a cell's neighbours are found
through an open-addressing hash table of the occupied keys. Memory is O(n) however sparse the
cloud (a surface occupies a vanishing fraction of its bounding box's cells). Build cost: one
O(n log n) sort and O(n k) distance tests in one pass that writes each particle's candidates to
its own scratch row; the rows are then compacted into CSR form and sorted, so the list is the
same for any thread count.

.. math::

    \mathcal N(i) = \{\, j \ne i : |x_j - x_i| < r_l \,\}

References
----------
.. [AT87] M. P. Allen, D. J. Tildesley. "Computer Simulation of Liquids", §5.3 (cell lists,
   Verlet lists with a skin).
.. [ST92] R. Szeliski, D. Tonnesen. "Surface Modeling with Oriented Particle Systems".
   SIGGRAPH '92, §4.2 (spatial data structures; cached neighbour lists).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from .options import EXACT_JIT_OPTIONS, JIT_OPTIONS

_PARALLEL = dict(JIT_OPTIONS, parallel=True)


@njit(**JIT_OPTIONS)
def bin_particles(position, cell_size):
    """Sort particles into occupied cells.

    Parameters
    ----------
    position : (n, 3) float64
        Finite positions [length].
    cell_size : float64
        Cell side ≥ the list radius [length].

    Returns
    -------
    order : (n,) int64
        Particle indices sorted by cell key (stable: ascending index within a cell).
    cell_keys : (m,) int64
        Sorted keys (cx·n_y + cy)·n_z + cz of the m occupied cells.
    cell_start : (m + 1,) int64
        ``order[cell_start[c]:cell_start[c + 1]]`` are the particles of cell c.
    particle_cell : (n,) int64
        Cell index (into ``cell_keys``) of every particle.
    dims : (3,) int64
        Grid dimensions n_x, n_y, n_z.
    origin : (3,) float64
        Lower corner of the grid [length].
    """
    n = position.shape[0]
    lo = np.zeros(3)
    for c in range(3):
        lo[c] = np.inf
    for i in range(n):
        for c in range(3):
            if position[i, c] < lo[c]:
                lo[c] = position[i, c]
    inv = 1.0 / cell_size
    coords = np.zeros((n, 3), dtype=np.int64)
    dims = np.ones(3, dtype=np.int64)
    for i in range(n):
        for c in range(3):
            k = np.int64(math.floor((position[i, c] - lo[c]) * inv))
            coords[i, c] = k
            if k + 1 > dims[c]:
                dims[c] = k + 1
    order, cell_keys, cell_start, particle_cell = sort_into_cells(coords, dims)
    return order, cell_keys, cell_start, particle_cell, dims, lo


@njit(**JIT_OPTIONS)
def sort_into_cells(coords, dims):
    """Group items by their integer cell coordinates (the binning shared by every grid).

    The key of cell (x, y, z) is (x n_y + y) n_z + z; items are sorted by key, stably.

    Returns
    -------
    order : (n,) int64
        Item indices sorted by cell key (ascending index within a cell).
    cell_keys : (m,) int64
        Sorted keys of the m occupied cells.
    cell_start : (m + 1,) int64
        ``order[cell_start[c]:cell_start[c + 1]]`` are the items of occupied cell c.
    item_cell : (n,) int64
        Occupied-cell index of every item.
    """
    n = coords.shape[0]
    keys = np.zeros(n, dtype=np.int64)
    for i in range(n):
        keys[i] = (coords[i, 0] * dims[1] + coords[i, 1]) * dims[2] + coords[i, 2]
    order = stable_key_order(keys)
    m = 0
    for p in range(n):
        if p == 0 or keys[order[p]] != keys[order[p - 1]]:
            m += 1
    cell_keys = np.zeros(m, dtype=np.int64)
    cell_start = np.zeros(m + 1, dtype=np.int64)
    item_cell = np.zeros(n, dtype=np.int64)
    c = -1
    for p in range(n):
        key = keys[order[p]]
        if p == 0 or key != keys[order[p - 1]]:
            c += 1
            cell_keys[c] = key
            cell_start[c] = p
        item_cell[order[p]] = c
    cell_start[m] = n
    return order, cell_keys, cell_start, item_cell


#: Bits per pass of :func:`stable_key_order` (2,048 buckets).
_RADIX_BITS = 11


@njit(**JIT_OPTIONS)
def stable_key_order(keys):
    """``np.argsort(keys, kind="mergesort")`` of int64 ``keys``: the unique stable order; for
    non-negative keys by a least-significant-digit radix sort (``_RADIX_BITS`` per pass, as many
    passes as the largest key has digits). O(n) per pass against the merge sort's O(n log n):
    a cell grid's keys have 20-35 bits, so 2-4 passes. Keys already in order (the particles
    after a reorder by cell) are returned after one check."""
    n = keys.shape[0]
    order = np.arange(n, dtype=np.int64)
    top = 0
    ordered = True
    negative = False
    for i in range(n):
        if keys[i] > top:
            top = keys[i]
        negative |= keys[i] < 0
        if i > 0 and keys[i] < keys[i - 1]:
            ordered = False
    if ordered:
        return order
    if negative:  # (a non-finite coordinate's cell): the merge sort orders those too
        return np.argsort(keys, kind="mergesort").astype(np.int64)
    size = 1 << _RADIX_BITS
    mask = size - 1
    other = np.empty(n, dtype=np.int64)
    count = np.empty(size + 1, dtype=np.int64)
    shift = 0
    while shift < 63 and (top >> shift) > 0:
        count[:] = 0
        for i in range(n):
            count[((keys[order[i]] >> shift) & mask) + 1] += 1
        for b in range(size):
            count[b + 1] += count[b]
        for i in range(n):  # stable: equal digits keep the previous pass's order
            d = (keys[order[i]] >> shift) & mask
            other[count[d]] = order[i]
            count[d] += 1
        order, other = other, order
        shift += _RADIX_BITS
    return order


@njit(inline="always", **JIT_OPTIONS)
def cell_hash(key):
    """Mix the bits of a non-negative cell key (for the open-addressing table)."""
    # (31 bits) x (32 bits) < 2**63: no overflow, also without the JIT
    h = (key & 0x7FFFFFFF) * 0x9E3779B1
    h = h ^ (key >> 31) ^ (h >> 29)
    return h & 0x7FFFFFFFFFFFFFFF


@njit(**JIT_OPTIONS)
def cell_table(cell_keys):
    """Open-addressing hash table of the occupied cells: ``slot_key``, ``slot_cell`` (a power
    of two, at least four slots per cell; empty slots hold key -1), so that
    :func:`cell_lookup` finds a cell key's index into ``cell_keys`` in O(1). Serial, O(m)."""
    m = cell_keys.shape[0]
    size = 1
    while size < 4 * m:
        size *= 2
    mask = size - 1
    slot_key = np.full(size, -1, dtype=np.int64)
    slot_cell = np.zeros(size, dtype=np.int64)
    for c in range(m):
        h = cell_hash(cell_keys[c]) & mask
        while slot_key[h] != -1:
            h = (h + 1) & mask
        slot_key[h] = cell_keys[c]
        slot_cell[h] = c
    return slot_key, slot_cell


@njit(inline="always", **JIT_OPTIONS)
def cell_lookup(x, y, z, dims, slot_key, slot_cell):
    """Occupied-cell index of grid cell (x, y, z) in a :func:`cell_table`, or -1."""
    if x < 0 or y < 0 or z < 0 or x >= dims[0] or y >= dims[1] or z >= dims[2]:
        return -1
    key = (x * dims[1] + y) * dims[2] + z
    mask = slot_key.shape[0] - 1
    h = cell_hash(key) & mask
    while slot_key[h] != -1:
        if slot_key[h] == key:
            return slot_cell[h]
        h = (h + 1) & mask
    return -1


@njit(inline="always", **EXACT_JIT_OPTIONS)
def home_cell(q0, q1, q2, dims, lo, cell_size):
    """The grid cell of a query point, clamped into the grid (shell bounds stay valid)."""
    x = np.int64(math.floor((q0 - lo[0]) / cell_size))
    y = np.int64(math.floor((q1 - lo[1]) / cell_size))
    z = np.int64(math.floor((q2 - lo[2]) / cell_size))
    x = min(max(x, 0), dims[0] - 1)
    y = min(max(y, 0), dims[1] - 1)
    z = min(max(z, 0), dims[2] - 1)
    return x, y, z


@njit(inline="always", **EXACT_JIT_OPTIONS)
def block_bound(q0, q1, q2, hx, hy, hz, r, dims, lo, cell_size):
    """Distance from a query to the nearest face of the block of cells within ``r`` shells of
    its home cell (hx, hy, hz) that has cells beyond it: every item not yet visited lies at
    least this far away. ``inf`` when the block covers the whole grid."""
    bound = np.inf
    for ax in range(3):
        home = hx if ax == 0 else (hy if ax == 1 else hz)
        qa = q0 if ax == 0 else (q1 if ax == 1 else q2)
        if home - r > 0:
            bound = min(bound, qa - (lo[ax] + (home - r) * cell_size))
        if home + r < dims[ax] - 1:
            bound = min(bound, lo[ax] + (home + r + 1) * cell_size - qa)
    return bound


@njit(**_PARALLEL)
def build_neighbor_list_kernel(position, radius, row_capacity):
    """Full CSR neighbour list of all pairs closer than ``radius``.

    Threaded over cells and particles; run it single-threaded with
    :func:`recon.kernels.options.thread_limit` (the result is identical). The loop bodies are
    written out in full: helpers taking arrays would cost contended reference-count updates.

    Parameters
    ----------
    position : (n, 3) float64
        Finite positions [length].
    radius : float64
        List radius r_l (cutoff + skin) [length], > 0.
    row_capacity : int
        Scratch entries per particle. If some particle has more neighbours, ``indices`` is
        returned empty and the call must be repeated with ``row_capacity = longest``.

    Returns
    -------
    offsets : (n + 1,) int64
        Row i is ``indices[offsets[i]:offsets[i + 1]]``.
    indices : (nnz,) int32
        Neighbour indices, ascending within each row; every pair appears in both rows.
    longest : int
        Length of the longest row.
    """
    n = position.shape[0]
    radius2 = radius * radius
    order, cell_keys, cell_start, particle_cell, dims, _ = bin_particles(position, radius)
    m = cell_keys.shape[0]
    nx = dims[0]
    ny = dims[1]
    nz = dims[2]
    # open-addressing hash table: cell key -> index into cell_keys (serial, O(m))
    slot_key, slot_cell = cell_table(cell_keys)
    mask = slot_key.shape[0] - 1
    # the (up to) 27 occupied cells around every occupied cell, -1 where empty
    cell_neighbors = np.full((m, 27), -1, dtype=np.int64)
    for c in prange(m):
        key = cell_keys[c]
        cz = key % nz
        cy = (key // nz) % ny
        cx = key // (nz * ny)
        k = 0
        for dx in range(-1, 2):
            for dy in range(-1, 2):
                for dz in range(-1, 2):
                    x = cx + dx
                    y = cy + dy
                    z = cz + dz
                    if 0 <= x < nx and 0 <= y < ny and 0 <= z < nz:
                        key2 = (x * ny + y) * nz + z
                        h = cell_hash(key2) & mask
                        while slot_key[h] != -1:
                            if slot_key[h] == key2:
                                cell_neighbors[c, k] = slot_cell[h]
                                break
                            h = (h + 1) & mask
                    k += 1
    # one pass: collect up to row_capacity neighbours per particle (and count all of them)
    counts = np.zeros(n, dtype=np.int64)
    # one spare column: rejected candidates past a full row land there, not on a neighbour
    rows = np.zeros((n, row_capacity + 1), dtype=np.int32)
    for i in prange(n):
        c = particle_cell[i]
        xi = position[i, 0]
        yi = position[i, 1]
        zi = position[i, 2]
        count = 0
        for k in range(27):
            nc = cell_neighbors[c, k]
            if nc < 0:
                continue
            for p in range(cell_start[nc], cell_start[nc + 1]):
                j = order[p]
                dx = position[j, 0] - xi
                dy = position[j, 1] - yi
                dz = position[j, 2] - zi
                # branch-free: always store the candidate, advance only if it is a neighbour
                # (about one candidate in eight is; the branch would mispredict)
                rows[i, min(count, row_capacity)] = j
                count += (dx * dx + dy * dy + dz * dz < radius2) & (j != i)
        counts[i] = count
    longest = 0
    offsets = np.zeros(n + 1, dtype=np.int64)
    for i in range(n):
        offsets[i + 1] = offsets[i] + counts[i]
        if counts[i] > longest:
            longest = counts[i]
    if longest > row_capacity:
        # the caller retries with row_capacity = longest
        return offsets, np.zeros(0, dtype=np.int32), longest
    indices = np.zeros(offsets[n], dtype=np.int32)
    # compact into CSR and sort each row (each iteration writes only its own row)
    for i in prange(n):
        lo = offsets[i]
        w = offsets[i + 1]
        for a in range(w - lo):
            indices[lo + a] = rows[i, a]
        for a in range(lo + 1, w):
            v = indices[a]
            b = a - 1
            while b >= lo and indices[b] > v:
                indices[b + 1] = indices[b]
                b -= 1
            indices[b + 1] = v
    return offsets, indices, longest


@njit(**JIT_OPTIONS)
def max_displacement2(position, reference_position):
    """Largest squared displacement between two position arrays [length²] (serial)."""
    best = 0.0
    for i in range(position.shape[0]):
        dx = position[i, 0] - reference_position[i, 0]
        dy = position[i, 1] - reference_position[i, 1]
        dz = position[i, 2] - reference_position[i, 2]
        d2 = dx * dx + dy * dy + dz * dz
        if d2 > best:
            best = d2
    return best


@njit(**JIT_OPTIONS)
def list_covers(position, reference_position, offsets, indices, cutoff, skin, binning, max_fast):
    r"""Whether a Verlet list built at ``reference_position`` still holds every pair closer
    than ``cutoff`` at ``position`` (exact; Allen & Tildesley §5.3 with a per-particle test).

    Let Δ_i = |x_i − x_i⁰|. A pair missing from the list was at least r_l = r_c + s apart at the
    build, so it can be closer than r_c now only if Δ_i + Δ_j > s. Pairs of two particles with
    Δ ≤ s/2 are therefore covered (the usual rebuild rule); the "fast" particles with
    Δ > s/2 are checked one by one: every particle j with Δ_j ≤ s within r_c of such a
    particle a now (its build position then lies within r_c + Δ_j ≤ r_l of x_a, so in the 27
    cells of the build-time grid of side r_l around x_a) must be in a's row. A pair of two
    particles that both moved more than the skin may lie farther apart in the build grid: such
    pairs (few: at most ``max_fast`` particles) are compared directly.

    Parameters
    ----------
    position, reference_position : (n, 3) float64
        Current positions and the positions at the build [length].
    offsets, indices : CSR list (rows ascending, full)
        Built with radius r_l = ``cutoff + skin`` at ``reference_position``.
    cutoff, skin : float
        r_c and s [length].
    binning : tuple
        :func:`bin_particles` of ``reference_position`` with cell side r_l.
    max_fast : int
        More fast particles than this: answer False (a rebuild is cheaper than the test).

    Returns
    -------
    bool
    """
    n = position.shape[0]
    half2 = 0.25 * skin * skin
    skin2 = skin * skin
    fast = np.zeros(max_fast + 1, dtype=np.int64)
    n_fast = 0
    beyond = np.zeros(max_fast + 1, dtype=np.int64)  # the fast ones past the whole skin
    n_beyond = 0
    for i in range(n):
        dx = position[i, 0] - reference_position[i, 0]
        dy = position[i, 1] - reference_position[i, 1]
        dz = position[i, 2] - reference_position[i, 2]
        d2 = dx * dx + dy * dy + dz * dz
        if d2 > half2:
            if n_fast == max_fast:
                return False
            fast[n_fast] = i
            n_fast += 1
            if d2 > skin2:
                beyond[n_beyond] = i
                n_beyond += 1
    order, cell_keys, cell_start, _, dims, lo = binning
    inv = 1.0 / (cutoff + skin)
    cutoff2 = cutoff * cutoff
    for f in range(n_fast):
        a = fast[f]
        xa = position[a, 0]
        ya = position[a, 1]
        za = position[a, 2]
        cx = np.int64(math.floor((xa - lo[0]) * inv))
        cy = np.int64(math.floor((ya - lo[1]) * inv))
        cz = np.int64(math.floor((za - lo[2]) * inv))
        row_lo = offsets[a]
        row_hi = offsets[a + 1]
        for ddx in range(-1, 2):
            x = cx + ddx
            if x < 0 or x >= dims[0]:
                continue
            for ddy in range(-1, 2):
                y = cy + ddy
                if y < 0 or y >= dims[1]:
                    continue
                for ddz in range(-1, 2):
                    z = cz + ddz
                    if z < 0 or z >= dims[2]:
                        continue
                    key = (x * dims[1] + y) * dims[2] + z
                    c = np.searchsorted(cell_keys, key)
                    if c >= cell_keys.shape[0] or cell_keys[c] != key:
                        continue
                    for p in range(cell_start[c], cell_start[c + 1]):
                        j = order[p]
                        if j == a:
                            continue
                        rx = position[j, 0] - xa
                        ry = position[j, 1] - ya
                        rz = position[j, 2] - za
                        if rx * rx + ry * ry + rz * rz >= cutoff2:
                            continue
                        # j interacts with a now: it must be in a's (ascending) row
                        k = row_lo + np.searchsorted(indices[row_lo:row_hi], j)
                        if k >= row_hi or indices[k] != j:
                            return False
    for u in range(n_beyond):
        a = beyond[u]
        row_lo = offsets[a]
        row_hi = offsets[a + 1]
        for v in range(u + 1, n_beyond):
            j = beyond[v]
            rx = position[j, 0] - position[a, 0]
            ry = position[j, 1] - position[a, 1]
            rz = position[j, 2] - position[a, 2]
            if rx * rx + ry * ry + rz * rz < cutoff2:
                k = row_lo + np.searchsorted(indices[row_lo:row_hi], j)
                if k >= row_hi or indices[k] != j:
                    return False
    return True


@njit(**JIT_OPTIONS)
def sublist_within(position, offsets, indices, radius):
    r"""The pairs of a full CSR list that are closer than ``radius`` now (a shorter list).

    .. math::

        \mathcal N_r(i) = \{\, j \in \mathcal N(i) : |x_j - x_i| < r \,\}

    Equal to :func:`build_neighbor_list_kernel` with ``radius`` when the list holds every
    pair closer than ``radius`` at ``position`` (a Verlet list whose cutoff is at least
    ``radius`` and that :func:`list_covers` the positions): the same distance test in the
    same arithmetic, rows kept ascending. Serial, two passes over the list (count, then fill).

    Parameters
    ----------
    position : (n, 3) float64
        Current positions [length].
    offsets, indices : CSR list (rows ascending, full)
    radius : float64
        The shorter radius [length].

    Returns
    -------
    offsets : (n + 1,) int64
    indices : (nnz,) int32
    """
    n = position.shape[0]
    radius2 = radius * radius
    keep = np.zeros(indices.shape[0], dtype=np.bool_)
    new_offsets = np.zeros(n + 1, dtype=np.int64)
    for i in range(n):
        xi = position[i, 0]
        yi = position[i, 1]
        zi = position[i, 2]
        count = 0
        for k in range(offsets[i], offsets[i + 1]):
            j = indices[k]
            dx = position[j, 0] - xi
            dy = position[j, 1] - yi
            dz = position[j, 2] - zi
            if dx * dx + dy * dy + dz * dz < radius2:
                keep[k] = True
                count += 1
        new_offsets[i + 1] = new_offsets[i] + count
    new_indices = np.zeros(new_offsets[n], dtype=np.int32)
    w = 0
    for k in range(indices.shape[0]):
        if keep[k]:
            new_indices[w] = indices[k]
            w += 1
    return new_offsets, new_indices
