"""Pure ``@njit`` kernels of the oriented-particle engine (import only numpy and numba).

One module per term: :mod:`.lennard_jones` (spacing, S&T92 §4), :mod:`.planarity` (eq. 3),
:mod:`.normality` (eq. 4), :mod:`.circularity` (eq. 5), :mod:`.weights` (ψ, eq. 7),
:mod:`.anchor` (data fidelity), :mod:`.quaternion` (frames), :mod:`.cell_list` (neighbour lists)
and :mod:`.pair_loop` (the one per-particle loop: forces, torques, damping, integration).

Geometry kernels of the stages: :mod:`.poisson_disk` (seed and candidate thinning),
:mod:`.local_surface` (tangent frames, local quadrics, angular gaps), :mod:`.growth_rules` (the
growing rule, S&T92 §6), :mod:`.grid_query` (k-nearest and radius queries on a cell grid built
once, and the anchor refresh: nearest agreeing data point and its quadric foot point),
:mod:`.thin_sides` (the two-means split across a thin part, for the normal orientation),
:mod:`.circumsphere` (S&T92 §8) and :mod:`.mesh_tables` (edge, fan and component tables of a
mesh by counting sorts, for its repair and its report). They are compiled with
:data:`.options.EXACT_JIT_OPTIONS` (no fast-math); the particle kernels with
:data:`.options.JIT_OPTIONS`. The packed coefficients the pair loop reads are laid out by
:class:`recon.params.Coefficients`.

Kernels never take jitted functions as arguments (that defeats ``cache=True``); the weighting
function is chosen by an integer mode. See :func:`recon.dynamics.warmup` to compile them all.

References
----------
.. [ST92] R. Szeliski, D. Tonnesen. "Surface Modeling with Oriented Particle Systems".
   SIGGRAPH '92.
.. [T00] D. Tonnesen. PhD thesis, chapter 4.
"""

from __future__ import annotations

from .anchor import anchor_interaction
from .circularity import circularity_pair
from .lennard_jones import calibrate_lj_minimum, lj_cutoff_values, lj_pair
from .normality import normality_pair
from .options import EXACT_JIT_OPTIONS, FASTMATH, JIT_OPTIONS
from .pair_loop import pair_interaction
from .planarity import planarity_pair
from .quaternion import (
    normals_from_quaternions,
    quaternion_normal,
    quaternions_from_normals,
    rotate_quaternion,
)
from .weights import (
    WEIGHT_ANISOTROPIC,
    WEIGHT_GAUSSIAN,
    WEIGHT_MODES,
    WEIGHT_POLY,
    pair_weights,
    weight_value,
)

__all__ = [
    "EXACT_JIT_OPTIONS",
    "FASTMATH",
    "JIT_OPTIONS",
    "WEIGHT_ANISOTROPIC",
    "WEIGHT_GAUSSIAN",
    "WEIGHT_MODES",
    "WEIGHT_POLY",
    "anchor_interaction",
    "calibrate_lj_minimum",
    "circularity_pair",
    "lj_cutoff_values",
    "lj_pair",
    "normality_pair",
    "normals_from_quaternions",
    "pair_interaction",
    "pair_weights",
    "planarity_pair",
    "quaternion_normal",
    "quaternions_from_normals",
    "rotate_quaternion",
    "weight_value",
]
