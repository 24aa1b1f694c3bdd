"""Binning kernels of the cell grids (recon.kernels.cell_list)."""

import numpy as np
import pytest

from recon.kernels.cell_list import sort_into_cells, stable_key_order


@pytest.mark.parametrize("top", [1, 2, 5, 2**11, 2**11 + 3, 2**22, 2**40, 2**62])
def test_stable_key_order_is_the_stable_argsort(top):
    """The radix passes give np.argsort(kind="mergesort")'s order (ties by index), for keys
    of one to six digits, sorted input and a negative key (the merge-sort path)."""
    rng = np.random.default_rng(top % 1000)
    for trial in range(20):
        keys = rng.integers(0, top, int(rng.integers(0, 400))).astype(np.int64)
        if trial % 4 == 0:
            keys.sort()
        if trial % 5 == 1 and len(keys):
            keys[len(keys) // 2] = -3
        want = np.argsort(keys, kind="mergesort")
        np.testing.assert_array_equal(stable_key_order(keys), want)


def test_sort_into_cells_groups_items_by_key_in_index_order():
    coords = np.array([[1, 0, 0], [0, 0, 1], [1, 0, 0], [0, 0, 0], [0, 0, 1]], dtype=np.int64)
    order, cell_keys, cell_start, item_cell = sort_into_cells(coords, np.array([2, 1, 2]))
    assert order.tolist() == [3, 1, 4, 0, 2]
    assert cell_keys.tolist() == [0, 1, 2] and cell_start.tolist() == [0, 1, 3, 5]
    assert item_cell.tolist() == [2, 1, 2, 0, 1]
