"""Input attributes carried onto the mesh: colours, intensity, classification, data support.

Every output vertex looks up its ``k`` nearest input points once (one :class:`scipy.spatial.cKDTree`
query for all vertices) and takes

- colour and intensity: the inverse-distance-weighted mean of those points' values,
  ``w_j = 1 / (d_j + eps)`` with ``eps = 1e-3 r0`` (a vertex on an input point takes its value);
- classification: the most frequent class among them (ties go to the class of the nearest
  point; classes are labels, an average would be meaningless), with the input's values:
  uint8 (PLY ``uchar``) when they are LAS classes 0-255, else int32 or float32
  (:func:`class_values`);
- quality: the distance to the nearest input point in units of r0 (0 = on the data; large =
  the mesh bridges a gap there), so that users can trim or colour by the data support.

The results are the arrays :func:`recon.io.write_mesh` writes: ``colors`` (V, 3) uint8 and
``vertex_properties`` (name -> (V,) array).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .cloud import PointCloud
from .config import OutputConfig, ReconConfig
from .errors import InputError

__all__ = [
    "TRANSFERABLE",
    "VertexAttributes",
    "check_attribute_output",
    "check_transfer",
    "class_type",
    "class_values",
    "majority",
    "transfer_attributes",
    "transfer_for_output",
]

#: Per-point attributes ``--transfer`` accepts.
TRANSFERABLE = ("intensity", "classification")

#: Inverse-distance weights use d + EPS_R0 * r0, so that a vertex on a point stays finite.
EPS_R0 = 1e-3

#: PLY types of a transferred classification, narrowest first (:func:`class_type`), and the
#: arrays that hold them (:func:`recon.io.write_mesh` writes each in its type).
CLASS_TYPES = {"u1": np.uint8, "i4": np.int32, "f4": np.float32}


@dataclass
class VertexAttributes:
    """What is written per vertex beside position and normal.

    Attributes
    ----------
    colors : (V, 3) uint8 or None
    properties : dict of str -> (V,) array
        ``intensity`` (float32), ``classification`` (uint8 for classes 0-255, else int32 or
        float32: :func:`class_values`), ``quality`` (float32 [r0]), in the order they are
        written.
    """

    colors: np.ndarray | None = None
    properties: dict[str, np.ndarray] = field(default_factory=dict)


def transfer_attributes(
    cloud: PointCloud,
    vertices: np.ndarray,
    r0: float,
    *,
    colors: bool = True,
    transfer: Sequence[str] = (),
    quality: bool = False,
    k: int = 8,
) -> VertexAttributes:
    """Attributes of the input points carried onto mesh vertices.

    Parameters
    ----------
    cloud : PointCloud
        The input (points relative to ``cloud.origin``; ``colors``, ``attributes``).
    vertices : (V, 3) float64 [length]
        Absolute (file) coordinates of the mesh vertices.
    r0 : float [length]
        The rest spacing (unit of ``quality`` and scale of the weights).
    colors : bool
        Transfer colours when the cloud has them.
    transfer : sequence of str
        Names from :data:`TRANSFERABLE`.
    quality : bool
        Add ``quality``, the distance to the nearest input point in r0.
    k : int
        Neighbours per vertex.

    Returns
    -------
    VertexAttributes
        Empty (``colors`` None, no properties) when there is nothing to transfer.

    Raises
    ------
    InputError
        An unknown name in ``transfer``, or a name the input does not have.
    """
    check_transfer(cloud, transfer)
    want_colors = colors and cloud.colors is not None
    out = VertexAttributes()
    if not (want_colors or transfer or quality):
        return out
    from scipy.spatial import cKDTree

    rel = np.asarray(vertices, dtype=np.float64) - np.asarray(cloud.origin, dtype=np.float64)
    kk = max(1, min(int(k), len(cloud)))
    dist, idx = cKDTree(cloud.points).query(rel, k=kk)
    dist = dist.reshape(len(rel), kk)
    idx = idx.reshape(len(rel), kk)
    w = 1.0 / (dist + EPS_R0 * r0)
    w /= w.sum(axis=1, keepdims=True)
    if want_colors:
        rgb = np.einsum("vk,vkc->vc", w, np.asarray(cloud.colors)[idx])
        out.colors = np.clip(np.rint(rgb * 255.0), 0, 255).astype(np.uint8)
    for name in transfer:
        values = np.asarray(cloud.attributes[name])[idx]
        if name == "classification":
            out.properties[name] = class_values(majority(values))
        else:
            out.properties[name] = np.sum(w * values, axis=1).astype(np.float32)
    if quality:
        out.properties["quality"] = (dist[:, 0] / r0).astype(np.float32)
    return out


def check_transfer(cloud: PointCloud, transfer: Sequence[str]) -> None:
    """Raise :class:`~recon.errors.InputError` unless the cloud has every attribute named.

    Called before a fit, so that a missing attribute costs no fitting time.
    """
    for name in transfer:
        if name not in TRANSFERABLE:
            raise InputError(
                f"--transfer: unknown attribute '{name}' (choose from {', '.join(TRANSFERABLE)})"
            )
        if name not in cloud.attributes:
            where = cloud.path if cloud.path is not None else "input array"
            have = ", ".join(sorted(cloud.attributes)) or "none"
            raise InputError(
                f"{where}: --transfer {name}: the input has no {name} per point (it has: "
                f"{have}; LAS/LAZ files have intensity and classification, E57 and PTS "
                "intensity, PLY the vertex properties of those names)"
            )


def check_attribute_output(path: Path, out: OutputConfig) -> None:
    """Raise :class:`~recon.errors.InputError` when vertex properties are asked for an OBJ."""
    if Path(path).suffix.lower() == ".obj" and (out.transfer or out.quality):
        asked = [*out.transfer, *(["quality"] if out.quality else [])]
        raise InputError(
            f"{path}: OBJ has no vertex properties for {', '.join(asked)} "
            "(--transfer, --quality); write a .ply mesh"
        )


def transfer_for_output(
    cloud: PointCloud, vertices: np.ndarray, r0: float, path: Path, cfg: ReconConfig
) -> VertexAttributes:
    """:func:`transfer_attributes` as the ``output`` section asks for the mesh file ``path``.

    Colours go into PLY meshes when ``output.colors`` is on, into OBJ meshes only with
    ``output.obj_colors`` too.
    """
    out = cfg.output
    is_obj = Path(path).suffix.lower() == ".obj"
    return transfer_attributes(
        cloud,
        vertices,
        r0,
        colors=out.colors and (out.obj_colors or not is_obj),
        transfer=out.transfer,
        quality=out.quality,
        k=out.attribute_neighbors,
    )


def class_type(classes: np.ndarray) -> str:
    """The narrowest type of :data:`CLASS_TYPES` that holds every class: ``'u1'`` (uchar)
    when they are integers 0-255 (LAS classes; also when there are none), ``'i4'`` (int)
    when they are integers of int32 (classes above 255, negative ones), else ``'f4'``
    (float: fractional or larger labels, NaN).

    The types of parts of a classification combine as the widest of them (the order of
    :data:`CLASS_TYPES`): the tiled writer takes it over the blocks of vertices it writes.

    Examples
    --------
    >>> [class_type(np.array(c)) for c in ([2, 6], [300, -7], [2.5])]
    ['u1', 'i4', 'f4']
    """
    a = np.asarray(classes)
    if a.dtype == np.uint8 or a.dtype.kind == "b" or a.size == 0:
        return "u1"
    if a.dtype.kind in "iu":
        lo, hi = int(a.min()), int(a.max())
    else:
        with np.errstate(invalid="ignore"):
            if not (np.all(np.isfinite(a)) and np.all(a == np.round(a))):
                return "f4"
        lo, hi = float(a.min()), float(a.max())
    if 0 <= lo and hi <= 255:
        return "u1"
    return "i4" if -(2**31) <= lo and hi < 2**31 else "f4"


def class_values(classes: np.ndarray) -> np.ndarray:
    """Transferred classes in the type that :func:`class_type` gives them: uint8 for the LAS
    classes 0-255 (as every reader gives those), int32 for other integers of int32, float32
    for the rest (a ``uint`` class past int32 or a ``double`` one is rounded to float32, the
    widest type a mesh property takes; the PLY reader warns of such classes).

    Examples
    --------
    >>> class_values(np.array([300.0, -7.0])).tolist(), class_values(np.array([2.0])).dtype
    ([300, -7], dtype('uint8'))
    """
    a = np.asarray(classes)
    return a.astype(CLASS_TYPES[class_type(a)], copy=False)


def majority(labels: np.ndarray) -> np.ndarray:
    """The most frequent label of each row; ties go to the earliest column (the nearest point).

    Parameters
    ----------
    labels : (V, k) integer array

    Returns
    -------
    (V,) array of ``labels.dtype``

    Examples
    --------
    >>> majority(np.array([[6, 2, 2], [6, 2, 5], [1, 1, 1]])).tolist()
    [2, 6, 1]
    """
    labels = np.asarray(labels)
    if labels.ndim != 2 or labels.shape[1] == 0:
        raise ValueError(f"labels: expected a (V, k) array with k >= 1, got {labels.shape}")
    votes = (labels[:, :, None] == labels[:, None, :]).sum(axis=2)  # (V, k) count per column
    best = np.argmax(votes, axis=1)  # first maximum = nearest among the tied classes
    return labels[np.arange(labels.shape[0]), best]
