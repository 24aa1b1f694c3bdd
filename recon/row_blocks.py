"""Per-point numpy work in row blocks, spread over the fit's threads.

Much of the work before the dynamics is the same small computation for every data point: a
gather of its neighbours, a (block, k, 3) einsum, a batched 3x3 ``numpy.linalg.eigh``. Numpy
runs these loops without the GIL, so row blocks given to a few Python threads run on as many
cores; on bunny-clean the crease detection's PCA of 40k neighbourhoods ran in 0.18 s instead
of 0.22 s on the loaded 2-core machine (load 12), and near half the time on an idle one.

Each block's rows are computed from those rows alone, by the same numpy code whatever the
block, so the result does not depend on the number of threads or on the block size
(``tests/test_row_blocks.py`` checks it bit for bit).
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

from .kernels.options import query_workers

__all__ = ["MIN_ROWS", "for_row_blocks", "row_blocks"]

#: Fewer rows than this per thread are not worth a thread (a block of 2,000 3x3 eigen
#: decompositions takes ~1 ms).
MIN_ROWS = 2_000


def row_blocks(n: int, block: int, parts: int = 1) -> list[slice]:
    """Slices covering ``range(n)`` in order: at least ``parts`` of them (when ``n`` allows),
    none longer than ``block`` rows."""
    size = max(1, min(block, -(-n // max(1, parts))))
    return [slice(lo, min(lo + size, n)) for lo in range(0, n, size)]


def for_row_blocks(fn: Callable[[slice], None], n: int, block: int) -> None:
    """Call ``fn`` on row slices covering ``range(n)`` (each at most ``block`` rows), in up to
    :func:`~recon.kernels.options.query_workers` threads (the fit's thread count).

    ``fn`` must write only its own rows and must not start a numba parallel region (numba's
    workqueue threading layer does not allow two at once); numpy and scipy code is fine.
    Exceptions raised by ``fn`` propagate.
    """
    workers = max(1, min(query_workers(), n // MIN_ROWS))
    blocks = row_blocks(n, block, workers)
    if workers < 2 or len(blocks) < 2:
        for b in blocks:
            fn(b)
        return
    with ThreadPoolExecutor(max_workers=workers, thread_name_prefix="oprecon-rows") as pool:
        for _ in pool.map(fn, blocks):
            pass
