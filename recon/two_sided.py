"""Open sheets fitted to both faces of a part thinner than a spacing, closed into thin bodies.

Where a closed part is thinner than about one rest spacing (a blade or plate sampled sparsely,
so that r0 is as large as its thickness), the particles of its two faces merge into one layer
midway between them, and the mesh of the part is one open sheet whose rim runs round the
part's edge. The data tells the two cases apart: the points of an open scan lie *on* the
sheet (their signed distances along its normals spread round zero, as noise does), those of
a thin closed part lie on *both sides* of it, about half of them a half-thickness above and
half below, and few near the sheet itself.

:func:`two_sided_sheets` measures this per open component of a mesh; :func:`closed_two_sided`
replaces each such component by its two faces (:func:`recon.holes.thicken_sheet`: a copy at
the local data's median distance on either side, joined round the rims), when that closes it
without a crossing. The statistics, per component, of the signed distances ``d`` of the data
points within ``SIDE_REACH`` of it along its nearest vertex's normal:

* separation: the median of ``|d|`` at least ``MIN_SEPARATION`` [r0];
* balance: each side holds at least ``MIN_SIDE_SHARE`` of the points;
* two layers, not noise, by either of two measures:

  - ``mean |d| / rms d`` at least ``MIN_BIMODALITY``. It is 1 for two thin layers at
    ``+-h`` (about 0.95 measured on a sparse blade), sqrt(2/pi) = 0.80 for Gaussian noise
    round one layer and 0.87 for a uniform spread, whatever their width;
  - or, with ``MIN_LAYER_POINTS`` or more, the layers are smooth: a point's ``|d|`` is close
    to that of its neighbours on the same side (along the sheet), the median difference at
    most ``MAX_ROUGHNESS`` x the separation. Noise drawn for each point on its own makes the
    difference about the spread itself (0.55-0.67 of the separation on the dev set's open
    scans); a part whose thickness varies (a blade tapering to its edge, whose ``|d|`` spread
    makes the first measure 0.86-0.89) keeps it at 0.19-0.23. Noise that varies smoothly
    along the sheet is smooth too, so this measure also asks that the two sides interleave
    along the sheet: a median ``MIN_MIXING`` or more of a
    point's ``LAYER_NEIGHBOURS`` nearest feet lie on the other side (two faces' data, and
    noise: about 0.5). One layer that crosses the sheet (a sheet fitted off its data,
    tilted or bent against it) has smooth ``|d|`` too, but each point's neighbours on its
    own side, away from the line where it crosses. (The first measure does not ask it:
    scan lines that alternate between the faces, farther apart than their points, mix
    less in a point's nearest feet.)

A body's two faces lie at each vertex at the median ``|d|`` of the data nearest to it, so a
part whose thickness varies keeps its profile; a body that would then fold or cross is
tried once more at the separation everywhere.

Where such a part is thicker (a blade's middle, about two spacings), its particles may part
there, and one face's patch is meshed as an open sheet of its own beside the merged layer.
That patch (not two-sided itself, every vertex within ``SECOND_FACE_REACH`` of the two-sided
sheet, over it, all on one side of it and parallel to it) is the body's face there: the
bodies are made without it first (its data within ``SIDE_REACH`` then count for the sheet),
and that is kept when each sheet that lost such a patch became a body; else the mesh is
judged with the patches.

On the dev set's open scans (hemispheres, faces, the square with a hole, also with 0.25 %
noise) and the closed scans left open by missing data, the separation is at most 0.17 r0 and
the ratio at most 0.80; on a 0.8 %-thick blade of 5,000 points the sheet's data sit 0.47 r0
either side with a ratio of 0.95.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.spatial import cKDTree

from .holes import thicken_sheet
from .intersections import self_intersections
from .mesh import capped_volume, count_edge_faces, drop_unreferenced, face_components

__all__ = [
    "LAYER_NEIGHBOURS",
    "MAX_ROUGHNESS",
    "MIN_BIMODALITY",
    "MIN_SEPARATION",
    "MIN_SIDE_SHARE",
    "SECOND_FACE_REACH",
    "SIDE_REACH",
    "SheetSides",
    "closed_two_sided",
    "two_sided_sheets",
]

#: Data points within this distance [r0] of an open component's vertices are its data.
SIDE_REACH = 2.0
#: Median distance [r0] of the data from the sheet, at least.
MIN_SEPARATION = 0.25
#: Share of the data on each side of the sheet, at least.
MIN_SIDE_SHARE = 0.3
#: ``mean |d| / rms d`` of the data's signed distances, at least (two layers: near 1).
MIN_BIMODALITY = 0.9
#: Median difference between a point's ``|d|`` and that of its same-side neighbours along
#: the sheet, over the separation, at most (smooth layers: near 0; noise: about 0.6).
MAX_ROUGHNESS = 0.35
#: Fewest data points for the roughness (its medians over ``LAYER_NEIGHBOURS`` are noisy on
#: fewer: Gaussian noise of 20-40 points passed 16-38 times in 1,000 trials, of 80 once).
MIN_LAYER_POINTS = 200
#: Median share of a point's ``LAYER_NEIGHBOURS`` nearest feet that lie on the other side, at
#: least: two faces' data interleave along the sheet (about 0.5), while one layer crossing
#: the sheet (a sheet fitted off its data, tilted or bent against it) puts a point's
#: neighbours on its own side (near 0).
MIN_MIXING = 0.25
#: Neighbours along the sheet (nearest by their feet on it) that the roughness and the mixing
#: compare.
LAYER_NEIGHBOURS = 12
#: Data whose feet are a vertex's nearest give a body its half-thickness there (their median
#: ``|d|``): a knife that tapers gets a body that tapers; with 12 the constant blades' bodies
#: came out 1 % rougher in Chamfer-L1.
HALF_NEIGHBOURS = 36
#: A body's half-thickness at a vertex, as a multiple of the separation: at least, at most.
HALF_RANGE = (0.25, 2.0)
#: An open component that is not two-sided, with every vertex within this distance [r0] of a
#: two-sided sheet, over it (SECOND_FACE_OVER), all on one side of it, and parallel to it
#: (SECOND_FACE_PARALLEL), is the same part's other face meshed on its own where the part is
#: thicker (module docstring): a thin part's two faces are closer than about 2 spacings where
#: their particles merge; the knife's patch at 3,000 points, seed 0, lies 1.6-2.1 r0 from the
#: merged layer.
SECOND_FACE_REACH = 2.5
#: Parallel: the median |cosine| between the face's vertex normals and the sheet's, at least.
SECOND_FACE_PARALLEL = 0.9
#: Over the sheet: each of the face's vertices lies within this distance [r0] of the line
#: along its nearest sheet vertex's normal (the sheet's vertices are about a spacing apart;
#: a patch running past the sheet's rim is farther out there, and the body would not cover it).
SECOND_FACE_OVER = 1.0
#: Fewest data points that make the statistics.
MIN_POINTS = 20


@dataclass(frozen=True)
class SheetSides:
    """Where the data of one open component lie relative to it."""

    component: int  # label of the component (recon.mesh.face_components)
    faces: np.ndarray  # (F, 3) int64: the component's faces
    points: int  # data points within SIDE_REACH
    separation: float  # median |d| [r0]
    above: float  # share of the points with d > 0
    bimodality: float  # mean |d| / rms d
    roughness: float  # median | |d| - its same-side neighbours' | / separation (NaN: unmeasured)
    mixing: float  # median share of a point's neighbours on the other side (NaN: unmeasured)
    d: np.ndarray | None = field(default=None, repr=False, compare=False)  # the points' d
    feet: np.ndarray | None = field(default=None, repr=False, compare=False)  # their feet

    @property
    def apart(self) -> bool:
        """Enough data, far enough from the sheet and on both its sides."""
        return (
            self.points >= MIN_POINTS
            and self.separation >= MIN_SEPARATION
            and min(self.above, 1.0 - self.above) >= MIN_SIDE_SHARE
        )

    @property
    def two_sided(self) -> bool:
        """Do the data lie on both sides of the sheet, as two layers (module docstring)?"""
        if not self.apart:
            return False
        smooth = (
            self.points >= MIN_LAYER_POINTS
            and bool(self.roughness <= MAX_ROUGHNESS)
            and bool(self.mixing >= MIN_MIXING)
        )
        return self.bimodality >= MIN_BIMODALITY or smooth


def two_sided_sheets(
    vertices: np.ndarray, normals: np.ndarray, faces: np.ndarray, points: np.ndarray
) -> list[SheetSides]:
    """The sides statistics of every component of a mesh that has a boundary edge.

    ``vertices`` and ``points`` (the data) in r0 units; ``normals``: unit vertex normals.
    Each data point counts for the component whose vertex is nearest to it (within
    ``SIDE_REACH``), with its signed distance along that vertex's normal. A closed mesh
    costs one count of its edges.
    """
    return _sides(vertices, normals, faces, points)[1]


def _sides(
    vertices: np.ndarray, normals: np.ndarray, faces: np.ndarray, points: np.ndarray
) -> tuple[np.ndarray | None, list[SheetSides]]:
    """:func:`two_sided_sheets` and the component label of every face (None when there is
    no open component)."""
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    if len(faces) == 0 or len(points) == 0:
        return None, []
    edges, counts = count_edge_faces(faces)
    rim = np.unique(edges[counts == 1])
    if len(rim) == 0:  # closed: nothing to judge (one pass over the edges)
        return None, []
    n, label = face_components(faces, len(vertices))
    owner = np.full(len(vertices), -1, dtype=np.int64)
    owner[faces.reshape(-1)] = np.repeat(label, 3)
    is_open = np.zeros(n, dtype=bool)
    is_open[owner[rim]] = True
    used = np.unique(faces)  # a point nearest to a closed part's vertex is that part's
    dist, nearest = cKDTree(vertices[used]).query(points, distance_upper_bound=SIDE_REACH)
    hit = np.isfinite(dist)
    at = used[nearest[hit]]
    signed = np.einsum("ij,ij->i", points[hit] - vertices[at], normals[at])
    feet = points[hit] - signed[:, None] * normals[at]  # the points' feet on the sheet
    comp = owner[at]
    out = []
    for k in np.flatnonzero(is_open):
        mine = comp == k
        d = signed[mine]
        if len(d) == 0:
            continue
        rms = float(np.sqrt(np.mean(d * d)))
        sides = SheetSides(
            component=int(k),
            faces=faces[label == k],
            points=int(len(d)),
            separation=float(np.median(np.abs(d))),
            above=float(np.mean(d > 0)),
            bimodality=float(np.mean(np.abs(d)) / rms) if rms > 0 else 0.0,
            roughness=float("nan"),
            mixing=float("nan"),
            d=d,
            feet=feet[mine],
        )
        if sides.apart:  # the layers along the sheet
            rough, mixing = _layers(d, feet[mine])
            sides = replace(sides, roughness=rough / sides.separation, mixing=mixing)
        out.append(sides)
    return label, out


def _body(vertices: np.ndarray, sheet: SheetSides, local: bool) -> tuple | None:
    """``(sheet, copies' vertices, faces, normals, local)`` of the thin body of ``sheet``,
    its half-thickness the local data's (``local``) or the separation everywhere; None when
    it would not be closed (a rim through a vertex twice gets no strip) or encloses no
    positive volume (folded: thicker than it is curved)."""
    half = _local_half(vertices, sheet) if local else sheet.separation
    new_v, new_f = thicken_sheet(vertices, sheet.faces, half)
    if not np.all(count_edge_faces(new_f)[1] == 2) or capped_volume(new_v, new_f) <= 0:
        return None
    k = len(new_v) // 2  # the upper copy, then the lower one: normals from the offset
    up = new_v[:k] - new_v[k:]
    up /= np.maximum(np.linalg.norm(up, axis=1, keepdims=True), 1e-300)
    return sheet, new_v, new_f, np.concatenate([up, -up]), local


def _local_half(vertices: np.ndarray, sheet: SheetSides) -> np.ndarray:
    """Half the thickness for a body at each of ``vertices`` (those of ``sheet``'s faces; the
    others get the separation): the median ``|d|`` of the data whose feet are the vertex's
    ``HALF_NEIGHBOURS`` nearest, within ``HALF_RANGE`` x the separation."""
    used = np.unique(sheet.faces)
    k = min(HALF_NEIGHBOURS, len(sheet.d))
    _, near = cKDTree(sheet.feet).query(vertices[used], k=k)
    half = np.median(np.abs(sheet.d)[np.reshape(near, (len(used), k))], axis=1)
    out = np.full(len(vertices), sheet.separation)
    out[used] = np.clip(half, HALF_RANGE[0] * sheet.separation, HALF_RANGE[1] * sheet.separation)
    return out


def _layers(d: np.ndarray, feet: np.ndarray) -> tuple[float, float]:
    """``(roughness, mixing)`` of data at signed distances ``d`` with ``feet`` on a sheet,
    over each point's ``LAYER_NEIGHBOURS`` nearest other feet: the median over the points of
    ``| |d| - m |`` (``m`` the median ``|d|`` of those on the point's side; inf when no point
    has one) and the median share of those on the other side."""
    k = min(LAYER_NEIGHBOURS + 1, len(d))
    if k < 2:
        return float("inf"), 0.0
    _, near = cKDTree(feet).query(feet, k=k)
    near = near[:, 1:]  # not the point itself
    side = np.where(d > 0, 1, -1)  # as ``above`` counts them
    same = side[near] == side[:, None]
    mixing = float(np.median(np.mean(side[near] == -side[:, None], axis=1)))
    size = np.abs(d)
    has = same.any(axis=1)
    if not has.any():
        return float("inf"), mixing
    around = np.where(same[has], size[near[has]], np.nan)
    return float(np.median(np.abs(size[has] - np.nanmedian(around, axis=1)))), mixing


def closed_two_sided(
    vertices: np.ndarray,
    normals: np.ndarray,
    faces: np.ndarray,
    points: np.ndarray,
    crease: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None, int] | None:
    """The mesh with each open component whose data lie on both of its sides
    (:attr:`SheetSides.two_sided`) made the thin closed body the data outline: its two faces
    at the local data's median distance either side (:data:`HALF_NEIGHBOURS`), joined round
    its rims, wound outward (each copy's vertex normals point the way it was offset). A body
    at the local thickness that would not close, would fold or would cross is tried once at
    the separation everywhere. A component whose thick copy would not be closed (a rim that
    is not simple), would enclose no positive volume (folded: thicker than the sheet's radius
    of curvature) or would cross itself, another body or the rest of the mesh stays as it is
    (one crossing search for all bodies, repeated after each retry or drop). A two-sided
    sheet's other face meshed apart (:data:`SECOND_FACE_REACH`) is left out, its vertices
    dropped too, when every sheet that lost one becomes a body without it; otherwise the mesh
    is judged as given.

    Returns ``(vertices, normals, faces, crease, closed)`` (``crease``: the crease flags of
    the vertices, a copy's taken from its original, None when none were given; ``closed``:
    how many components were made bodies), or None when none was.
    """
    label, sides = _sides(vertices, normals, faces, points)
    pairs = _second_faces(vertices, normals, sides)
    if pairs:  # the sheet's body covers its other face: try without it first
        keep = ~np.isin(label, [face for _, face in pairs])
        # each such sheet must become a body, else its other face is lost: one face of each
        must = (np.cumsum(keep) - 1)[[int(np.argmax(label == sheet)) for sheet, _ in pairs]]
        out = _bodies(vertices, normals, faces[keep], points, crease, must=must)
        if out is not None:
            return out
    return _bodies(vertices, normals, faces, points, crease, label, sides)


def _second_faces(
    vertices: np.ndarray, normals: np.ndarray, sides: list[SheetSides]
) -> list[tuple[int, int]]:
    """``(sheet, face)`` components of ``sides``: ``face`` is two-sided ``sheet``'s other face
    meshed apart (:data:`SECOND_FACE_REACH`)."""
    out: list[tuple[int, int]] = []
    taken: set[int] = set()
    for sheet in (s for s in sides if s.two_sided):
        used = np.unique(sheet.faces)
        tree = cKDTree(vertices[used])
        for other in sides:
            if other.two_sided or other.component in taken:
                continue
            mine = np.unique(other.faces)
            dist, j = tree.query(vertices[mine], distance_upper_bound=SECOND_FACE_REACH)
            if not np.all(np.isfinite(dist)):
                continue
            at = used[j]
            offset = vertices[mine] - vertices[at]
            d = np.einsum("ij,ij->i", offset, normals[at])
            across = np.linalg.norm(offset - d[:, None] * normals[at], axis=1)
            cos = np.abs(np.einsum("ij,ij->i", normals[mine], normals[at]))
            if (
                (np.all(d > 0) or np.all(d < 0))
                and np.all(across <= SECOND_FACE_OVER)
                and np.median(cos) >= SECOND_FACE_PARALLEL
            ):
                out.append((sheet.component, other.component))
                taken.add(other.component)
    return out


def _bodies(
    vertices: np.ndarray,
    normals: np.ndarray,
    faces: np.ndarray,
    points: np.ndarray,
    crease: np.ndarray | None,
    label: np.ndarray | None = None,
    sides: list[SheetSides] | None = None,
    must: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None, int] | None:
    """:func:`closed_two_sided` on one mesh (``label`` and ``sides``: its :func:`_sides`,
    measured when not given); None also when a component of one of the faces ``must`` is
    not made a body."""
    if label is None or sides is None:
        label, sides = _sides(vertices, normals, faces, points)
    sheets = [s for s in sides if s.two_sided]
    if not sheets:
        return None
    made = []  # (sheet, copies' vertices, their faces, their normals, local) that close
    for sheet in sheets:
        body = _body(vertices, sheet, local=True) or _body(vertices, sheet, local=False)
        if body is not None:
            made.append(body)
    while made:  # one crossing search for all bodies; drop those that cross, until none
        gone = np.zeros(int(label.max()) + 1, dtype=bool)
        gone[[m[0].component for m in made]] = True
        rest = faces[~gone[label]]
        offsets = len(vertices) + np.cumsum([0] + [len(m[1]) for m in made[:-1]])
        bodies = [m[2] + o for m, o in zip(made, offsets, strict=True)]
        all_v = np.concatenate([vertices, *(m[1] for m in made)])
        kept = np.concatenate([rest, *bodies])
        owner = np.repeat(np.arange(-1, len(made)), [len(rest), *(len(b) for b in bodies)])
        pairs = self_intersections(all_v, kept, np.arange(len(rest), len(kept)))
        crossing = np.unique(owner[pairs.reshape(-1)]) if len(pairs) else np.zeros(0, int)
        crossing = crossing[crossing >= 0]
        if len(crossing) == 0:
            break
        # a body that follows the local thickness and crosses gets one more try at the
        # sheet's separation everywhere (thinner where a curved part is thick); else it goes
        again = {
            i: _body(vertices, made[i][0], local=False) if made[i][4] else None
            for i in crossing.tolist()
        }
        made = [again[i] if i in again else m for i, m in enumerate(made)]
        made = [m for m in made if m is not None]
    if not made or (
        must is not None and not set(label[must].tolist()) <= {m[0].component for m in made}
    ):
        return None
    all_n = np.concatenate([normals, *(m[3] for m in made)])
    flag_all = None
    if crease is not None:
        flags = np.asarray(crease, dtype=bool)
        flag_all = np.concatenate(
            [flags, *(np.tile(flags[np.unique(m[0].faces)], 2) for m in made)]
        )
    return (*drop_unreferenced(all_v, all_n, kept, flag_all), len(made))
