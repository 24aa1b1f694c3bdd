"""recon.render: the PNG exists, has the requested size, is not blank, and is written atomically."""

from __future__ import annotations

import matplotlib
import matplotlib.image as mpimg
import numpy as np
import pytest
from mesh_shapes import icosphere, open_cylinder

from recon.errors import InputError
from recon.render import _simplify_for_drawing, render_mesh_png

HISTORY = {
    "step": [0, 15, 30, 45, 60, 160],
    "particles": [100, 400, 900, 1000, 1010, 1000],
    "kinetic": [0.0, 1e-1, 1e-2, 1e-3, 1e-4, 1e-6],  # the 0 is skipped on the log axis
    "coverage": [0.1, 0.5, 0.9, 0.97, 0.98, 0.99],
    "phase": ["grow", "grow", "grow", "grow", "release", "release"],
}


def read_png(path):
    image = mpimg.imread(path)
    return image[..., :3]


def test_png_with_history_has_size_and_content(tmp_path):
    backend = matplotlib.get_backend()
    v, f = icosphere(2)
    out = tmp_path / "sphere.png"
    render_mesh_png(out, v, f, history=HISTORY, title="sphere")
    image = read_png(out)
    assert image.shape == (500, 1500, 3)
    assert image.std() > 0.05
    assert matplotlib.get_backend() == backend  # no global state changed
    assert sorted(p.name for p in tmp_path.iterdir()) == ["sphere.png"]  # no temp file left


def test_open_mesh_shows_red_boundary(tmp_path):
    v, f = open_cylinder(24, 4)
    out = tmp_path / "tube.png"
    render_mesh_png(out, v, f, size=(600, 300))
    image = read_png(out)
    assert image.shape == (300, 600, 3)
    red = (image[..., 0] > 0.8) & (image[..., 1] < 0.3) & (image[..., 2] < 0.3)
    assert red.sum() > 50


def test_unreferenced_vertices_change_nothing_in_the_picture(tmp_path):
    # regression: the boundary edges index every vertex, but were drawn from the referenced
    # ones only (an IndexError, or lines between the wrong vertices)
    v, f = open_cylinder(24, 4)
    render_mesh_png(tmp_path / "plain.png", v, f, size=(600, 300))
    far = np.array([[50.0, -40.0, 30.0], [-9.0, 7.0, 12.0]])  # unused, outside the view
    render_mesh_png(tmp_path / "unused.png", np.vstack([far, v]), f + len(far), size=(600, 300))
    assert np.array_equal(read_png(tmp_path / "plain.png"), read_png(tmp_path / "unused.png"))


def test_non_manifold_edge_is_magenta(tmp_path):
    v = np.array([[0, 0, 0], [1, 0, 0], [0.5, 1, 0.2], [0.5, -1, 0.2], [0.5, 0.1, 1]], float)
    f = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]])
    out = tmp_path / "nm.png"
    render_mesh_png(out, v, f, size=(600, 300))
    image = read_png(out)
    magenta = (image[..., 0] > 0.8) & (image[..., 1] < 0.3) & (image[..., 2] > 0.8)
    assert magenta.sum() > 20


def test_bow_tie_vertex_is_circled_in_magenta(tmp_path):
    from recon.render import non_manifold_vertex_ids

    # two triangles meeting only at vertex 0: no non-manifold edge, one bow-tie vertex
    v = np.array([[0, 0, 0], [1, 1, 0.1], [1, -1, 0.1], [-1, 1, 0.1], [-1, -1, 0.1]], float)
    f = np.array([[0, 2, 1], [0, 3, 4]])
    assert non_manifold_vertex_ids(f).tolist() == [0]
    assert non_manifold_vertex_ids(f[:1]).tolist() == []
    out = tmp_path / "bowtie.png"
    render_mesh_png(out, v, f, size=(600, 300))
    image = read_png(out)
    magenta = (image[..., 0] > 0.8) & (image[..., 1] < 0.3) & (image[..., 2] > 0.8)
    assert magenta.sum() > 20


def test_empty_mesh_still_renders(tmp_path):
    out = tmp_path / "empty.png"
    render_mesh_png(out, np.zeros((0, 3)), np.zeros((0, 3), int), size=(300, 200))
    assert read_png(out).shape == (200, 300, 3)


def test_big_meshes_are_simplified_for_drawing():
    v, f = icosphere(4)  # 5120 faces
    dv, df = _simplify_for_drawing(v, f, 1000)
    assert 100 < len(df) <= 1000
    assert np.allclose(np.linalg.norm(dv, axis=1), 1.0, atol=0.05)  # still the sphere
    dv2, df2 = _simplify_for_drawing(v, f, 1000)
    np.testing.assert_array_equal(df, df2)
    assert _simplify_for_drawing(v, f, 10_000)[1] is f


def test_render_with_max_faces(tmp_path):
    v, f = icosphere(4)
    out = tmp_path / "s.png"
    render_mesh_png(out, v, f, max_faces=500, size=(450, 150))
    assert read_png(out).std() > 0.05


def test_bad_history_is_an_input_error_and_writes_nothing(tmp_path):
    v, f = icosphere(1)
    out = tmp_path / "bad.png"
    with pytest.raises(InputError, match="equal lengths"):
        render_mesh_png(out, v, f, history={"step": [0, 1], "particles": [1]})
    with pytest.raises(InputError, match="'step'"):
        render_mesh_png(out, v, f, history={"particles": [1]})
    with pytest.raises(InputError, match="at least 100"):
        render_mesh_png(out, v, f, size=(50, 50))
    assert list(tmp_path.iterdir()) == []


def test_history_with_gaps_and_bad_values(tmp_path):
    v, f = icosphere(1)
    gappy = dict(HISTORY, coverage=[None, 0.5, 0.9, 0.97, 0.98, 0.99])
    render_mesh_png(tmp_path / "ok.png", v, f, history=gappy, size=(600, 200))
    assert (tmp_path / "ok.png").is_file()
    with pytest.raises(InputError, match="'kinetic' must hold numbers"):
        render_mesh_png(tmp_path / "x.png", v, f, history=dict(HISTORY, kinetic=["a"] * 6))
