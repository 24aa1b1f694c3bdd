"""Components: a remesh makes one piece of every component of the input, and no more.

Two disjoint tetrahedra came out as 4 components at --spacing 0.1 (the CLI test in
tests/test_cli_remesh.py); coarser, a single tetrahedron's triangulation fell apart into two
pieces that gap closing capped one by one (2 closed components); a fitted L block at
--crease-angle 10 grew a closed tetrahedron of four faces beside it, meshed from patches
smaller than a spacing at a fold of its concave corner.
"""

import numpy as np
import pytest

from recon.remesh import RemeshOptions, remesh
from recon.remesh.patches import stray_pieces
from recon.remesh.surface import MeshSurface
from tests.mesh_shapes import icosphere, tetrahedron


@pytest.mark.parametrize(
    ("order", "spacing"), [((0, 1, 2, 3), 0.2), ((0, 1, 3, 2), 0.2), ((0, 1, 2, 3), 0.3)]
)
def test_a_coarse_tetrahedron_stays_one_closed_piece(order, spacing):
    """Before: 2 closed components in the first case (the face order changes the seeding,
    hence which case falls apart), exit 1."""
    v, f = tetrahedron()
    f = f[list(order)]
    r = remesh(v, f, RemeshOptions(spacing=spacing))
    topo = r.report["output"]["topology"]
    assert r.report["topology_preserved"], r.report["warnings"]
    assert topo["components"] == 1 and topo["watertight"] and topo["genus"] == 0


def test_stray_pieces_are_small_extra_pieces_over_one_input_component():
    big, fb = icosphere(2)
    small, fs = icosphere(1, radius=0.2)
    # the input: a unit sphere and, apart, a small one (two components)
    v_in = np.vstack([big, small + [3.0, 0.0, 0.0]])
    f_in = np.vstack([fb, fs + len(big)])
    surface = MeshSurface(v_in, f_in)
    # the remesh: both spheres, and a tetrahedron of four faces on the unit sphere's surface
    tet, ft = tetrahedron()
    tet = 0.05 * tet + [1.0, 0.0, 0.0]
    v_out = np.vstack([v_in, tet])
    f_out = np.vstack([f_in, ft + len(v_in)])
    stray = stray_pieces(surface, v_out, f_out)
    np.testing.assert_array_equal(np.flatnonzero(stray), len(f_in) + np.arange(4))
    # the small sphere is a component of the input: never stray, however small
    assert not stray_pieces(surface, v_in, f_in).any()
