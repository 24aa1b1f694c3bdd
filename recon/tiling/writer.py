"""The stitched mesh of a tiled fit streamed into its file, vertices block by block, then
faces unit by unit (:func:`write_streamed`), as :func:`recon.io.write_mesh` writes PLY and
OBJ; the particles likewise (:func:`write_particles_streamed`).

The vertex properties come as float64 columns; each is written in the PLY type the untiled fit
gives it (:data:`PROPERTY_TYPES`). The classification's type depends on its values (uchar for
the LAS classes 0-255, else int or float: :func:`recon.attributes.class_type`), so the
writer looks over the blocks' written classes once before the header."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from ..attributes import CLASS_TYPES, class_type
from .measure import CoordinateRange
from .vertices import UsedVertices, VertexStore

__all__ = ["write_particles_streamed", "write_streamed"]

_PLY_NAMES = {"f4": "float", "f8": "double", "u1": "uchar", "i4": "int"}
#: PLY types of the vertex properties (as recon.attributes makes them: intensity and quality
#: float32, classification uint8 for the LAS classes 0-255, else int32 or float32: the
#: written type is the :func:`recon.attributes.class_type` of the written classes).
PROPERTY_TYPES = {"classification": "u1", "intensity": "f4", "quality": "f4"}


def _ply_vertex_props(
    coord_type: str,
    normals: bool,
    colors: bool,
    properties: Sequence[str] = (),
    types: Sequence[str] | None = None,
) -> list[tuple[str, str]]:
    props = [("x", coord_type), ("y", coord_type), ("z", coord_type)]
    if normals:
        props += [("nx", "f4"), ("ny", "f4"), ("nz", "f4")]
    if colors:
        props += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    props += list(zip(properties, _types(properties, types), strict=True))
    return props


def _types(properties: Sequence[str], types: Sequence[str] | None) -> list[str]:
    """The PLY types of ``properties``: ``types``, or else :data:`PROPERTY_TYPES`."""
    return list(types) if types is not None else [PROPERTY_TYPES[n] for n in properties]


def write_vertex_rows(
    fh: BinaryIO,
    fmt: str,
    pos: np.ndarray,
    nrm: np.ndarray | None,
    coord_type: str,
    ascii: bool,
    rgb: np.ndarray | None = None,
    properties: Sequence[str] = (),
    values: np.ndarray | None = None,
    types: Sequence[str] | None = None,
) -> None:
    """Append vertex rows as :func:`recon.io.write_mesh` writes them (OBJ: ``v`` lines, the
    ``vn`` lines are written apart); PLY: then the ``properties`` (columns of ``values``), in
    the PLY ``types`` (by default :data:`PROPERTY_TYPES`)."""
    types = _types(properties, types)
    if fmt == "obj":
        if rgb is None:
            np.savetxt(fh, pos, fmt="v %.17g %.17g %.17g")
        else:
            data = np.hstack([pos, rgb.astype(np.float64) / 255.0])
            np.savetxt(fh, data, fmt="v %.17g %.17g %.17g %.6g %.6g %.6g")
        return
    if ascii:
        cols = [pos] + ([nrm] if nrm is not None else []) + ([rgb] if rgb is not None else [])
        if properties:
            cols.append(_cast_properties(types, values))
        data = np.hstack([np.asarray(c, dtype=np.float64) for c in cols])
        f = ["%.17g" if coord_type == "f8" else "%.9g"] * 3 + ["%.9g"] * (0 if nrm is None else 3)
        f += ["%d"] * (0 if rgb is None else 3)
        f += ["%.9g" if t[0] == "f" else "%d" for t in types]
        np.savetxt(fh, data, fmt=f, delimiter=" ")
        return
    props = _ply_vertex_props(coord_type, nrm is not None, rgb is not None, properties, types)
    rows = np.zeros(len(pos), dtype=[(n, "<" + t) for n, t in props])
    for j, c in enumerate("xyz"):
        rows[c] = pos[:, j]
    if nrm is not None:
        for j, c in enumerate(("nx", "ny", "nz")):
            rows[c] = nrm[:, j]
    if rgb is not None:
        for j, c in enumerate(("red", "green", "blue")):
            rows[c] = rgb[:, j]
    if properties:
        cast = _cast_properties(types, values)
        for j, name in enumerate(properties):
            rows[name] = cast[:, j]
    fh.write(rows.tobytes())


def _cast_properties(types: Sequence[str], values: np.ndarray | None) -> np.ndarray:
    """The property columns rounded to their written types (as float64 columns)."""
    assert values is not None and values.shape[1] == len(types)
    out = np.empty(values.shape)
    for j, t in enumerate(types):
        out[:, j] = values[:, j].astype("<" + t)
    return out


def property_types(properties: Sequence[str], store: VertexStore, used: UsedVertices) -> list[str]:
    """The PLY type of each of ``properties`` as the store's used vertices hold them:
    :data:`PROPERTY_TYPES`, the classification's the widest :func:`class_type` of its blocks
    (a look over every block: the header comes before the rows)."""
    types = [PROPERTY_TYPES[n] for n in properties]
    if "classification" not in properties:
        return types
    j = list(properties).index("classification")
    order = list(CLASS_TYPES)
    widest = 0
    for k in range(len(store.starts)):
        sel, block = used.local(k), store.block(k)
        vals = block[3]
        if len(sel) and vals.shape == (len(block[0]), len(properties)):  # else written as 0
            widest = max(widest, order.index(class_type(vals[sel, j])))
    types[j] = order[widest]
    return types


def write_face_rows(fh: BinaryIO, fmt: str, faces: np.ndarray, ascii: bool, normals: bool) -> None:
    if len(faces) == 0:
        return
    if fmt == "obj":
        f1 = faces + 1
        if normals:
            np.savetxt(fh, np.repeat(f1, 2, axis=1), fmt="f %d//%d %d//%d %d//%d")
        else:
            np.savetxt(fh, f1, fmt="f %d %d %d")
        return
    if ascii:
        np.savetxt(fh, np.hstack([np.full((len(faces), 1), 3), faces]), fmt="%d")
        return
    rows = np.zeros(len(faces), dtype=[("n", "u1"), ("v", "<i4", (3,))])
    rows["n"] = 3
    rows["v"] = faces
    fh.write(rows.tobytes())


def ply_header(
    n_vertices: int,
    n_faces: int | None,
    coord_type: str,
    normals: bool,
    ascii: bool,
    colors: bool = False,
    properties: Sequence[str] = (),
    types: Sequence[str] | None = None,
) -> bytes:
    fmt = "ascii" if ascii else "binary_little_endian"
    lines = ["ply", f"format {fmt} 1.0", "comment written by oprecon"]
    lines.append(f"element vertex {n_vertices}")
    props = _ply_vertex_props(coord_type, normals, colors, properties, types)
    lines += [f"property {_PLY_NAMES[t]} {n}" for n, t in props]
    if n_faces is not None:
        lines.append(f"element face {n_faces}")
        lines.append("property list uchar int vertex_indices")
    lines.append("end_header")
    return ("\n".join(lines) + "\n").encode("ascii")


def write_streamed(
    path: Path,
    stitched: dict[str, Any],
    coord_type: str,
    normals: bool,
    ascii: bool,
    colors: bool = False,
    properties: Sequence[str] = (),
) -> None:
    """Write the stitched mesh to ``path`` (an open temporary, see :mod:`recon.io.files`):
    vertices block by block, then faces unit by unit, renumbered to the used vertices.

    ``colors``: write the vertex colours (PLY ``red green blue``, OBJ ``v x y z r g b``);
    ``properties``: PLY vertex properties (the store's property columns, in this order), in
    the types of :func:`property_types`."""
    if properties and path.suffix.lower() == ".obj":
        raise ValueError("OBJ has no vertex properties")
    store: VertexStore = stitched["store"]
    used: UsedVertices = stitched["used"]
    starts = np.asarray(store.starts)
    prefix = np.concatenate([[0], np.cumsum(used.counts)])
    fmt = "obj" if path.suffix.lower() == ".obj" else "ply"

    def new_ids(ids: np.ndarray) -> np.ndarray:
        """Global ids -> rows of the written vertices (the used ones, block by block)."""
        b = np.searchsorted(starts, ids, side="right") - 1
        out = np.empty(len(ids), dtype=np.int64)
        for k in np.unique(b):
            k = int(k)
            sel = b == k
            out[sel] = prefix[k] + np.searchsorted(used.local(k), ids[sel] - store.starts[k])
        return out

    types = property_types(properties, store, used) if properties else []
    with open(path, "wb") as fh:
        if fmt == "ply":
            n_used = used.total
            fh.write(
                ply_header(
                    n_used,
                    stitched["n_faces"],
                    coord_type,
                    normals,
                    ascii,
                    colors,
                    properties,
                    types,
                )
            )
        else:
            fh.write(b"# written by oprecon\n")
        for k in range(len(store.starts)):
            sel = used.local(k)
            if not len(sel):
                continue
            p, nr, rgb, vals = store.block(k)
            if colors and len(rgb) != len(p):
                rgb = np.zeros((len(p), 3), dtype=np.uint8)
            if properties and vals.shape != (len(p), len(properties)):
                vals = np.zeros((len(p), len(properties)))
            write_vertex_rows(
                fh,
                fmt,
                p[sel],
                nr[sel] if normals else None,
                coord_type,
                ascii,
                rgb[sel] if colors else None,
                properties,
                vals[sel] if properties else None,
                types,
            )
        if fmt == "obj" and normals:
            for k in range(len(store.starts)):
                sel = used.local(k)
                if len(sel):
                    np.savetxt(fh, store.block(k)[1][sel], fmt="vn %.9g %.9g %.9g")
        for f in stitched["units"]:
            f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])]
            if len(f):
                write_face_rows(fh, fmt, new_ids(f.ravel()).reshape(-1, 3), ascii, normals)


def write_particles_streamed(path: Path, store: VertexStore, n_blocks: int, ascii: bool) -> None:
    """The particles (the store's first ``n_blocks`` blocks) as a PLY point cloud, with the
    coordinate type of their positions (:class:`CoordinateRange`)."""
    n = int(sum(store.counts[:n_blocks]))
    coords = CoordinateRange()
    for k in range(n_blocks):
        coords.add(store.block(k)[0])
    coord_type = coords.type()
    with open(path, "wb") as fh:
        fh.write(ply_header(n, None, coord_type, True, ascii))
        for k in range(n_blocks):
            p, nr = store.block(k)[:2]
            write_vertex_rows(fh, "ply", p, nr, coord_type, ascii)
