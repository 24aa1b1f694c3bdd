"""Start-up: open3d's plotly viewer (dash, plotly) is not imported by a fit, but still works."""

from __future__ import annotations

import subprocess
import sys

import pytest

pytest.importorskip("open3d")


def _run(code: str) -> str:
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=300, check=True
    )
    return done.stdout.strip()


def test_a_fit_does_not_import_the_plotly_viewer():
    out = _run(
        "import sys, recon.fitting.pipeline, recon.triangulate, open3d\n"
        "print('dash' in sys.modules, 'plotly' in sys.modules)"
    )
    assert out == "False False"


def test_the_viewer_loads_on_first_use():
    out = _run(
        "import sys, recon, open3d, numpy as np\n"
        "pc = open3d.geometry.PointCloud(open3d.utility.Vector3dVector(np.eye(3)))\n"
        "fig = open3d.visualization.get_plotly_fig([pc])\n"
        "print(type(fig).__name__, 'dash' in sys.modules,"
        " open3d.visualization.draw_plotly.__module__)"
    )
    assert out == "Figure True open3d.visualization.draw_plotly"


def test_no_stand_in_once_open3d_was_imported_first():
    out = _run(
        "import sys, open3d, recon\n"
        "print(getattr(sys.modules['open3d.visualization.draw_plotly'], '_oprecon_stand_in',"
        " False))"
    )
    assert out == "False"


def test_any_other_name_of_the_module_loads_the_real_one():
    out = _run(
        "import sys, recon\n"
        "from open3d.visualization.draw_plotly import get_point_object\n"
        "print(callable(get_point_object), 'plotly' in sys.modules)"
    )
    assert out == "True True"
