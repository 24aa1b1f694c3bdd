"""Wavefront OBJ: reading points (``v``, ``vn``) and meshes (``f``), writing meshes.

Reading: ``v`` lines (with optional r g b); faces (``f``, 1-based or negative indices,
``v/vt/vn`` forms) are triangulated as fans. ``vn`` lines become a vertex's normal only where
the faces pair them (``f v//vn``), or in order in a file without faces and with one ``vn`` per
``v``: the two lists need not be in the same order. Words may be separated by tabs and lines
indented.
Writing: vertices with 17 significant digits (read back exactly), optional ``vn``, faces
``f a b c`` (``f a//a ...`` with normals).

References
----------
[OBJ] Wavefront Technologies. "Object files (.obj)", Advanced Visualizer manual, appendix B1.
"""

from __future__ import annotations

import io as _io
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from .common import check_count, colors_from, input_error, read_text_file, triangulate_fans

__all__ = ["read_mesh", "read_points", "write"]

logger = logging.getLogger("recon.io")


# --------------------------------------------------------------------------------------------
# reading


def _obj_lines(path: Path) -> list[str]:
    return read_text_file(path).splitlines()


def _keyword(line: str) -> str:
    """The first word of an OBJ line (``v``, ``vn``, ``f`` ...); words may be separated by any
    whitespace, tabs included, and a line may start with some."""
    words = line.split(None, 1)
    return words[0] if words else ""


def _parse_rows(path: Path, rows: list[list[str]], what: str, lines: list[int]) -> np.ndarray:
    try:
        return np.array(rows, dtype=np.float64).reshape(len(rows), 3)
    except ValueError:
        for r, ln in zip(rows, lines, strict=True):
            try:
                [float(t) for t in r]
            except ValueError:
                raise input_error(
                    path, f"line {ln + 1}: non-numeric {what} '{' '.join(r)}'"
                ) from None
            if len(r) != 3:
                raise input_error(path, f"line {ln + 1}: {what} needs 3 numbers") from None
        raise input_error(path, f"malformed {what} lines") from None


@dataclass
class _ObjFaces:
    """The corners of the ``f`` lines, as written (1-based, or negative: relative)."""

    v: np.ndarray  # (m,) int64 vertex index of each corner
    vn: np.ndarray  # (m,) int64 normal index of each corner, 0 where the corner has none
    sizes: np.ndarray  # (F,) int64 corners of each face
    v_before: np.ndarray  # (m,) int64 'v' lines before the corner's face (negative indices)
    vn_before: np.ndarray  # (m,) int64 'vn' lines before the corner's face


def _obj_faces(path: Path, lines: list[str]) -> _ObjFaces:
    """Parse the faces (``f v``, ``f v/vt``, ``f v//vn``, ``f v/vt/vn``) of at least 3 corners."""
    v: list[int] = []
    vn: list[int] = []
    sizes: list[int] = []
    v_before: list[int] = []
    vn_before: list[int] = []
    n_v = n_vn = 0
    for i, line in enumerate(lines):
        key = _keyword(line)
        if key == "v":
            n_v += 1
        elif key == "vn":
            n_vn += 1
        elif key == "f":
            tokens = line.split()[1:]
            if len(tokens) < 3:  # not a polygon (as in PLY, skipped)
                continue
            try:
                for t in tokens:
                    parts = t.split("/")
                    v.append(int(parts[0]))
                    vn.append(int(parts[2]) if len(parts) > 2 and parts[2] else 0)
            except ValueError:
                raise input_error(path, f"line {i + 1}: malformed face '{line.strip()}'") from None
            sizes.append(len(tokens))
            v_before.extend([n_v] * len(tokens))
            vn_before.extend([n_vn] * len(tokens))
    return _ObjFaces(*(np.asarray(a, dtype=np.int64) for a in (v, vn, sizes, v_before, vn_before)))


def _resolve(idx: np.ndarray, before: np.ndarray) -> np.ndarray:
    """0-based indices from OBJ's 1-based (positive) or relative (negative) ones."""
    return np.where(idx > 0, idx - 1, before + idx)


def _paired_normals(path: Path, lines: list[str], vn: np.ndarray, n_v: int) -> np.ndarray | None:
    """The normal of each vertex, as the faces pair ``vn`` with ``v`` (NaN where they do not).

    A ``vn`` line belongs to a vertex only through the faces (``f v//vn``): the two lists may be
    in different orders or of different lengths. A file with one ``vn`` per ``v`` is paired in
    order when it has no faces (points with normals) or when every pairing of its faces is
    ``f a//a``. Otherwise the vertices that the faces give different normals (split normals
    at a crease) or none get NaN, re-estimated later; when no vertex gets one, or the faces
    name missing lines, the normals are not used. Each of these cases is logged.
    """
    faces = _obj_faces(path, lines)
    if faces.sizes.size == 0:
        if vn.shape[0] == n_v:
            return vn
        logger.warning(
            "%s: %d 'vn' lines for %d 'v' lines and no faces to pair them; the file's normals "
            "are not used",
            path,
            vn.shape[0],
            n_v,
        )
        return None
    has = faces.vn != 0
    if not np.any(has):
        logger.warning(
            "%s: no face names a 'vn' for its corners (f v//vn), so nothing pairs the normals "
            "with the vertices; the file's normals are not used",
            path,
        )
        return None
    vi = _resolve(faces.v[has], faces.v_before[has])
    ni = _resolve(faces.vn[has], faces.vn_before[has])
    if vi.min() < 0 or vi.max() >= n_v or ni.min() < 0 or ni.max() >= vn.shape[0]:
        logger.warning(
            "%s: faces name 'v' or 'vn' lines that do not exist (%d 'v', %d 'vn' lines); the "
            "file's normals are not used",
            path,
            n_v,
            vn.shape[0],
        )
        return None
    if vn.shape[0] == n_v and np.array_equal(vi, ni):
        # Every pairing the faces make is vn i with v i (f a//a, as oprecon writes): the lists
        # are in the same order, which pairs the vertices in no face too.
        return vn
    # Group the corners by vertex: a vertex keeps its normal only if all its corners agree.
    order = np.argsort(vi, kind="stable")
    vs, ns = vi[order], vn[ni[order]]
    first = np.ones(vs.size, dtype=bool)
    first[1:] = vs[1:] != vs[:-1]
    group_first = np.maximum.accumulate(np.where(first, np.arange(vs.size), 0))
    differs = np.any(ns != ns[group_first], axis=1)
    normals = np.full((n_v, 3), np.nan)
    normals[vs[first]] = ns[first]
    split = np.unique(vs[differs])
    normals[split] = np.nan
    n_none = n_v - int(np.count_nonzero(first))
    n_paired = n_v - n_none - split.size
    if split.size or n_none:
        said = [f"{split.size} get different normals from different faces"] if split.size else []
        said += [f"{n_none} get no normal from any face"] if n_none else []
        logger.warning(
            "%s: of the %d vertices, %s; the file's normals are not used for those",
            path,
            n_v,
            " and ".join(said),
        )
    return normals if n_paired else None


def _obj_vertices(
    path: Path, lines: list[str]
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    v_rows: list[list[str]] = []
    v_lines: list[int] = []
    vn_rows: list[list[str]] = []
    vn_lines: list[int] = []
    rgb: list[list[str]] = []
    for i, line in enumerate(lines):
        key = _keyword(line)
        if key == "v":
            t = line.split()
            v_rows.append(t[1:4])
            v_lines.append(i)
            rgb.append(t[4:7] if len(t) == 7 else [])
        elif key == "vn":
            vn_rows.append(line.split()[1:4])
            vn_lines.append(i)
    verts = _parse_rows(path, v_rows, "vertex", v_lines) if v_rows else np.zeros((0, 3))
    normals = None
    if vn_rows and v_rows:
        vn = _parse_rows(path, vn_rows, "normal", vn_lines)
        normals = _paired_normals(path, lines, vn, len(v_rows))
    colors = None
    if rgb and all(len(c) == 3 for c in rgb):
        try:
            colors = colors_from(np.array(rgb, dtype=np.float64))
        except ValueError:
            colors = None
    return verts, normals, colors


def read_points(
    path: Path, max_points: int, info: dict[str, Any]
) -> tuple[str, np.ndarray, np.ndarray | None, np.ndarray | None]:
    lines = _obj_lines(path)
    keys = [_keyword(ln) for ln in lines]
    n_v = keys.count("v")
    check_count(path, n_v, max_points)
    if n_v == 0:
        raise input_error(path, "OBJ file has no 'v' vertex lines")
    verts, normals, colors = _obj_vertices(path, lines)
    n_f = keys.count("f")
    info["elements"] = {"vertex": n_v, "face": n_f}
    info["has_faces"] = n_f > 0
    info["properties"] = ["x", "y", "z"] + (["nx", "ny", "nz"] if normals is not None else [])
    return "obj", verts, normals, colors


def read_mesh(path: Path) -> tuple[np.ndarray, np.ndarray]:
    lines = _obj_lines(path)
    verts, _, _ = _obj_vertices(path, lines)
    faces = _obj_faces(path, lines)
    if faces.sizes.size == 0:
        return verts, np.zeros((0, 3), dtype=np.int64)
    if np.any(faces.v == 0):
        raise input_error(path, "face index 0 (OBJ indices start at 1)")
    idx = _resolve(faces.v, faces.v_before)
    sizes = faces.sizes
    if np.all(sizes == sizes[0]):
        return verts, triangulate_fans(path, idx.reshape(-1, int(sizes[0])))
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    polys = [idx[a : a + m] for a, m in zip(starts.tolist(), sizes.tolist(), strict=True)]
    return verts, triangulate_fans(path, polys)


# --------------------------------------------------------------------------------------------
# writing


def write(
    fh: BinaryIO,
    xyz: np.ndarray,
    normals: np.ndarray | None,
    faces: np.ndarray,
    colors: np.ndarray | None = None,
    corner_normals: np.ndarray | None = None,
) -> None:
    """Write a triangle mesh as OBJ text to an open binary file.

    Parameters
    ----------
    fh : binary file
    xyz : (V, 3) float64 [length]
        Absolute coordinates.
    normals : (V, 3) float64 or None
    faces : (F, 3) int64
        0-based vertex indices.
    colors : (V, 3) uint8 or None
        Vertex colours, written as the common OBJ extension ``v x y z r g b`` with r, g, b
        floats in [0, 1] (read by MeshLab, Blender, Open3D, trimesh).
    corner_normals : (F, 3, 3) float64 or None
        A normal per face corner (split across creases): written as the distinct ``vn`` lines
        and ``f v//vn`` per corner, instead of ``normals``. The faces keep their shared
        vertices (the mesh stays welded).
    """
    # OBJ has no number type: a reader parses float64, so 17 digits are needed for the values
    # to come back exactly (9 would round-trip only through float32)
    vfmt = "v %.17g %.17g %.17g"
    text = _io.TextIOWrapper(fh, encoding="ascii", newline="\n")
    try:
        text.write("# written by oprecon\n")
        if colors is None:
            np.savetxt(text, xyz, fmt=vfmt)
        else:
            rgb = np.asarray(colors, dtype=np.float64) / 255.0
            np.savetxt(text, np.hstack([xyz, rgb]), fmt=vfmt + " %.6g %.6g %.6g")
        if corner_normals is not None and faces.shape[0]:
            flat = np.asarray(corner_normals, dtype=np.float64).reshape(-1, 3)
            uniq, inverse = np.unique(np.round(flat, 9), axis=0, return_inverse=True)
            np.savetxt(text, uniq, fmt="vn %.9g %.9g %.9g")
            pairs = np.stack([faces + 1, inverse.reshape(-1, 3) + 1], axis=2).reshape(-1, 6)
            np.savetxt(text, pairs, fmt="f %d//%d %d//%d %d//%d")
            text.flush()
            return
        if normals is not None:
            np.savetxt(text, normals, fmt="vn %.9g %.9g %.9g")
        if faces.shape[0]:
            f1 = faces + 1
            if normals is not None:
                np.savetxt(text, np.repeat(f1, 2, axis=1), fmt="f %d//%d %d//%d %d//%d")
            else:
                np.savetxt(text, f1, fmt="f %d %d %d")
        text.flush()
    finally:
        text.detach()
