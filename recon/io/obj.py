"""Wavefront OBJ: reading points (``v``, ``vn``) and meshes (``f``), writing meshes.

Reading: ``v`` lines (with optional r g b), ``vn`` lines used as normals when there is one per
``v``; faces (``f``, 1-based or negative indices, ``v/vt/vn`` forms) are triangulated as fans.
Writing: vertices with 17 significant digits (read back exactly), optional ``vn``, faces
``f a b c`` (``f a//a ...`` with normals).

References
----------
[OBJ] Wavefront Technologies. "Object files (.obj)", Advanced Visualizer manual, appendix B1.
"""

from __future__ import annotations

import io as _io
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from .common import check_count, colors_from, input_error, read_text_file, triangulate_fans

__all__ = ["read_mesh", "read_points", "write"]


# --------------------------------------------------------------------------------------------
# reading


def _obj_lines(path: Path) -> list[str]:
    return read_text_file(path).splitlines()


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


def _obj_vertices(
    path: Path, lines: list[str]
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    v_rows: list[list[str]] = []
    v_lines: list[int] = []
    vn_rows: list[list[str]] = []
    vn_lines: list[int] = []
    rgb: list[list[str]] = []
    for i, line in enumerate(lines):
        if line.startswith("v "):
            t = line.split()
            v_rows.append(t[1:4])
            v_lines.append(i)
            rgb.append(t[4:7] if len(t) == 7 else [])
        elif line.startswith("vn "):
            vn_rows.append(line.split()[1:4])
            vn_lines.append(i)
    verts = _parse_rows(path, v_rows, "vertex", v_lines) if v_rows else np.zeros((0, 3))
    normals = None
    if vn_rows and len(vn_rows) == len(v_rows):
        normals = _parse_rows(path, vn_rows, "normal", vn_lines)
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
    n_v = sum(1 for ln in lines if ln.startswith("v "))
    check_count(path, n_v, max_points)
    if n_v == 0:
        raise input_error(path, "OBJ file has no 'v' vertex lines")
    verts, normals, colors = _obj_vertices(path, lines)
    n_f = sum(1 for ln in lines if ln.startswith("f "))
    info["elements"] = {"vertex": n_v, "face": n_f}
    info["has_faces"] = n_f > 0
    info["properties"] = ["x", "y", "z"] + (["nx", "ny", "nz"] if normals is not None else [])
    return "obj", verts, normals, colors


def read_mesh(path: Path) -> tuple[np.ndarray, np.ndarray]:
    lines = _obj_lines(path)
    verts, _, _ = _obj_vertices(path, lines)
    flat: list[int] = []
    sizes: list[int] = []
    n_before: list[int] = []  # vertices defined before each face (negative indices)
    n_seen = 0
    for i, line in enumerate(lines):
        if line.startswith("v "):
            n_seen += 1
        elif line.startswith("f "):
            tokens = line.split()[1:]
            if len(tokens) < 3:  # not a polygon (as in PLY, skipped)
                continue
            try:
                flat.extend(int(t.split("/", 1)[0]) for t in tokens)
            except ValueError:
                raise input_error(path, f"line {i + 1}: malformed face '{line.strip()}'") from None
            sizes.append(len(tokens))
            n_before.append(n_seen)
    if not sizes:
        return verts, np.zeros((0, 3), dtype=np.int64)
    idx = np.asarray(flat, dtype=np.int64)
    size_arr = np.asarray(sizes, dtype=np.int64)
    if np.any(idx == 0):
        raise input_error(path, "face index 0 (OBJ indices start at 1)")
    base = np.repeat(np.asarray(n_before, dtype=np.int64), size_arr)
    idx = np.where(idx > 0, idx - 1, base + idx)
    if np.all(size_arr == size_arr[0]):
        return verts, triangulate_fans(path, idx.reshape(-1, int(size_arr[0])))
    starts = np.concatenate([[0], np.cumsum(size_arr)[:-1]])
    polys = [idx[a : a + m] for a, m in zip(starts.tolist(), sizes, strict=True)]
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
