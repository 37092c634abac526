"""Where a cell's fixed marks go: a few per measuring pose, on the fixture around the view's hole, in its image.

For each view the candidates lie on a circle of ``distance_mm`` about its hole, in the part's plane lowered by
``below_mm`` (on the fixture beside the part), every ``step_deg``. A candidate is kept when it is in front of the
camera, imaged ``margin_px`` inside the image, within ``depth_mm`` when given, and on the side of the hole away
from the other holes (outside the part, where the part cannot cover it; dropped when too few candidates remain).
Of those, the ``count`` whose image is spread widest are chosen (the largest triangle; for 2 the farthest pair),
so the view's camera pose is measured best. Whether a part inside its envelope can hide a mark is the planner's
check, not this one.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from monoguide.solver import frames
from monoguide.solver.camera import CameraModel
from monoguide.solver.marks_problem import MARK_SIGMA_MM, ReferenceMark
from monoguide.solver.planning.errors import LayoutOutOfView


@dataclass(frozen=True)
class MarkLayout:
    """Marks placed for a cell: ``marks`` and, per view, the indices of the marks it sees."""

    marks: tuple[ReferenceMark, ...]
    marks_per_view: tuple[tuple[int, ...], ...]

    def sightings(self) -> tuple[np.ndarray, np.ndarray]:
        """(view, mark) index arrays of every sighting, in view order."""
        pairs = [(v, m) for v, marks in enumerate(self.marks_per_view) for m in marks]
        return np.array([v for v, _ in pairs], dtype=int), np.array([m for _, m in pairs], dtype=int)


def place_marks(
    camera: CameraModel,
    T_cf_si: Sequence[np.ndarray],
    holes_cf: np.ndarray,
    *,
    count: int = 3,
    distance_mm: float = 200.0,
    below_mm: float = 10.0,
    margin_px: float = 200.0,
    normal_cf: np.ndarray | None = None,
    depth_mm: tuple[float, float] | None = None,
    view_names: Sequence[str] = (),
    step_deg: float = 5.0,
    sigma_mm: float = MARK_SIGMA_MM,
) -> MarkLayout:
    """``count`` marks for each view i (camera at ``T_cf_si[i]``) about its hole ``holes_cf[i]`` (k, 3), all in
    the cell frame. ``normal_cf``: the part's plane normal (default: the holes' best-fit plane), turned towards
    the cameras. Marks are named ``<view>-M<j>``. Raises :class:`LayoutOutOfView` naming a view that cannot hold
    ``count`` marks."""
    holes_cf = np.asarray(holes_cf, dtype=float).reshape(-1, 3)
    if count < 2:
        raise ValueError(f"count must be at least 2, got {count!r}")
    if len(holes_cf) != len(T_cf_si):
        raise ValueError(f"{len(holes_cf)} holes for {len(T_cf_si)} views: give the hole each view sees")
    names = list(view_names) or [f"S{i + 1}" for i in range(len(T_cf_si))]
    normal = _plane_normal(holes_cf, T_cf_si, normal_cf)
    a = np.cross(normal, [1.0, 0.0, 0.0] if abs(normal[0]) < 0.9 else [0.0, 1.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(normal, a)
    theta = np.radians(np.arange(0.0, 360.0, step_deg))
    ring = np.cos(theta)[:, None] * a + np.sin(theta)[:, None] * b
    centroid = holes_cf.mean(axis=0)
    marks: list[ReferenceMark] = []
    per_view = []
    for view, (T, hole) in enumerate(zip(T_cf_si, holes_cf, strict=True)):
        candidates = hole - below_mm * normal + distance_mm * ring
        points_c = frames.transform_points(frames.invert(np.asarray(T, dtype=float)), candidates)
        ok = points_c[:, 2] > 1e-6
        if depth_mm is not None:
            ok &= (points_c[:, 2] >= depth_mm[0]) & (points_c[:, 2] <= depth_mm[1])
        pixels = np.full((len(candidates), 2), np.nan)
        pixels[ok] = camera.project(points_c[ok])
        ok[ok] = camera.in_image(pixels[ok], margin_px)
        outward = hole - centroid
        outside = ok & ((ring @ outward) >= 0.0) if np.linalg.norm(outward) > 1e-9 else ok
        pool = np.flatnonzero(outside) if np.sum(outside) >= count else np.flatnonzero(ok)
        if len(pool) < count:
            raise LayoutOutOfView(
                f"view {names[view]}: only {len(pool)} places {distance_mm:g} mm about its hole are imaged "
                f"{margin_px:g} px inside the image; {count} marks need a shorter distance or a smaller margin")
        chosen = _widest(pixels[pool], count)
        per_view.append(tuple(range(len(marks), len(marks) + count)))
        for j, c in enumerate(pool[chosen]):
            marks.append(ReferenceMark(f"{names[view]}-M{j + 1}", candidates[c], sigma_mm))
    return MarkLayout(tuple(marks), tuple(per_view))


def _widest(pixels: np.ndarray, count: int) -> list[int]:
    """Indices of ``count`` of ``pixels`` (n, 2) spread widest: the farthest pair, the largest triangle, then the
    farthest from those chosen."""
    n = len(pixels)
    if count == 2:
        d = np.linalg.norm(pixels[:, None] - pixels[None], axis=2)
        i, j = np.unravel_index(int(np.argmax(d)), d.shape)
        return [int(i), int(j)]
    triples = np.array(list(itertools.combinations(range(n), 3)))
    p, q, r = pixels[triples[:, 0]], pixels[triples[:, 1]], pixels[triples[:, 2]]
    area = np.abs((q - p)[:, 0] * (r - p)[:, 1] - (q - p)[:, 1] * (r - p)[:, 0])
    chosen = [int(i) for i in triples[int(np.argmax(area))]]
    while len(chosen) < count:
        d = np.min(np.linalg.norm(pixels[:, None] - pixels[chosen][None], axis=2), axis=1)
        chosen.append(int(np.argmax(d)))
    return chosen


def _plane_normal(holes_cf: np.ndarray, T_cf_si: Sequence[np.ndarray], normal_cf: np.ndarray | None) -> np.ndarray:
    """The part plane's unit normal, pointing towards the cameras."""
    if normal_cf is not None:
        n = np.asarray(normal_cf, dtype=float)
    elif len(holes_cf) >= 3:
        n = np.linalg.svd(holes_cf - holes_cf.mean(axis=0))[2][-1]
    else:  # one or two holes: the plane faces the cameras' mean line of sight
        n = -np.mean([np.asarray(T)[:3, 2] for T in T_cf_si], axis=0)
    n = n / np.linalg.norm(n)
    cameras = np.mean([np.asarray(T)[:3, 3] for T in T_cf_si], axis=0)
    return n if float(n @ (cameras - holes_cf.mean(axis=0))) >= 0 else -n
