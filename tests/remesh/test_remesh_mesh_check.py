"""check_mesh drops duplicate faces (any vertex order), keeping the first of each, in order."""

import numpy as np

from recon.remesh.mesh_check import check_mesh
from tests.mesh_shapes import grid


def test_duplicate_faces_are_dropped_keeping_the_first():
    v, f = grid(5, 5)
    dup = np.vstack([f, f[[3, 0, 7]][:, [1, 2, 0]], f[[5]][:, ::-1]])
    checked = check_mesh(v, dup, "d.ply", intersections=False)
    assert any("dropped 4 duplicate faces" in r for r in checked.repairs)
    np.testing.assert_array_equal(np.sort(checked.faces, axis=1), np.sort(f, axis=1))
    assert len(checked.faces) == len(f)
