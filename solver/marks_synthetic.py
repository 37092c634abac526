"""Synthetic cells with fixed marks and known truth, for the marks' tests and benchmark (seeded, no I/O).

A :class:`MarkedCell` is a :class:`~monoguide.solver.synthetic.SyntheticCell` (the holes, the calibrated views in SF1)
with its marks (:func:`solver.marks_layout.place_marks`) and where SF1 stands in the cell frame. ``observe`` renders
one cycle: the part where it truly is, the cameras where they truly stood, the marks where they truly are (their
survey off by the tracker's noise), the true lens, pixel noise; and returns the problem as the cycle would see it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from monoguide.solver import frames
from monoguide.solver.camera import CameraModel
from monoguide.solver.marks import MARK_SIGMA_PX, MarksProblem, ReferenceMark
from monoguide.solver.marks_layout import MarkLayout, place_marks
from monoguide.solver.synthetic import SyntheticCell, calibrated_cell, paper_roof_cell

REPEATABILITY_MM, REPEATABILITY_DEG = 0.05, 0.01  # the robot's, per axis at the flange (config/sim-cell.toml [sim])


@dataclass(frozen=True)
class MarkedCell:
    """cell: the holes' layout in SF1; T_cf_s1 (4, 4); layout: the marks; T_f_c: the camera on the flange (None:
    the repeatability acts about the camera's centre)."""

    cell: SyntheticCell
    T_cf_s1: np.ndarray
    layout: MarkLayout
    T_f_c: np.ndarray | None = None

    @property
    def view_names(self) -> tuple[str, ...]:
        return tuple(f"S{i + 1}" for i in range(len(self.cell.T_s1_si)))

    def with_marks(self, layout: MarkLayout) -> MarkedCell:
        return MarkedCell(self.cell, self.T_cf_s1, layout, self.T_f_c)

    def observe(
        self,
        rng: np.random.Generator,
        T_s1_w: np.ndarray,
        T_s1_si_true: np.ndarray | None = None,
        camera_true: CameraModel | None = None,
        sigma_px: float = 0.1,
        mark_sigma_px: float = MARK_SIGMA_PX,
        repeatability: tuple[float, float] = (REPEATABILITY_MM, REPEATABILITY_DEG),
    ) -> MarksProblem:
        """One cycle's :class:`MarksProblem` (the estimator told ``repeatability`` mm / deg) of a part truly at
        ``T_s1_w``, cameras truly at ``T_s1_si_true`` (default: as calibrated), the lens ``camera_true``."""
        cell = self.cell
        T_true = cell.T_s1_si if T_s1_si_true is None else T_s1_si_true
        camera = cell.camera if camera_true is None else camera_true
        T_s1_cf = frames.invert(self.T_cf_s1)
        surveyed = np.array([m.position_cf for m in self.layout.marks])
        survey_sigma = np.array([[m.sigma_mm] for m in self.layout.marks])
        truth_s1 = frames.transform_points(T_s1_cf, surveyed + rng.normal(0.0, 1.0, surveyed.shape) * survey_sigma)
        holes = np.empty((len(cell.observed), 2))
        for row, (view, point) in enumerate(cell.observed):
            T_si_w = frames.invert(T_true[view]) @ T_s1_w
            holes[row] = camera.project(frames.transform_points(T_si_w, cell.points_w[point : point + 1]))[0]
        views, index = self.layout.sightings()
        marks = np.array([camera.project(frames.transform_points(frames.invert(T_true[v]), truth_s1[m : m + 1]))[0]
                          for v, m in zip(views, index, strict=True)]).reshape(-1, 2)
        problem = cell.problem(holes + rng.normal(0.0, sigma_px, holes.shape), sigma_px, *repeatability)
        problem = problem.with_flange(self.T_f_c)
        return MarksProblem(problem, self.T_cf_s1, self.layout.marks, views, index,
                            marks + rng.normal(0.0, mark_sigma_px, marks.shape), self.view_names, mark_sigma_px)

    def T_cf(self, T_s1_x: np.ndarray) -> np.ndarray:
        return self.T_cf_s1 @ T_s1_x


def marked_paper_roof_cell(count: int = 3, **placement) -> MarkedCell:
    """The paper's roof cell (:func:`solver.synthetic.paper_roof_cell`, SF1 taken as the cell frame) with ``count``
    marks per view (``placement``: :func:`place_marks`' options)."""
    cell = paper_roof_cell()
    return MarkedCell(cell, np.eye(4), _layout(cell, np.eye(4), count, placement))


def marked_cell(
    camera: CameraModel,
    points_w: np.ndarray,
    T_cf_w0: np.ndarray,
    T_cf_si: list[np.ndarray],
    T_f_c: np.ndarray | None = None,
    count: int = 3,
    **placement,
) -> MarkedCell:
    """A cell as its config states it (view i sees point i) with ``count`` marks per view."""
    cell = calibrated_cell(camera, points_w, T_cf_w0, T_cf_si, [[i] for i in range(len(T_cf_si))])
    T_cf_s1 = np.asarray(T_cf_si[0], dtype=float)
    return MarkedCell(cell, T_cf_s1, _layout(cell, T_cf_s1, count, placement), T_f_c)


def repeatability_at_flange(
    rng: np.random.Generator, T_s1_si: np.ndarray, T_f_c: np.ndarray | None, sigma_mm: float, sigma_deg: float
) -> np.ndarray:
    """Where the cameras truly stood (k, 4, 4): the flange stops at ``T_b_f N``, N of ``sigma_mm`` / ``sigma_deg``
    per flange axis, so the camera at ``T_s1_si T_c_f N T_f_c`` (about the camera's centre when ``T_f_c`` is None)."""
    out = np.empty_like(T_s1_si)
    for i, T in enumerate(T_s1_si):
        N = frames.pose_from_vector(np.concatenate([rng.normal(0.0, math.radians(sigma_deg), 3),
                                                    rng.normal(0.0, sigma_mm, 3)]))
        out[i] = T @ N if T_f_c is None else T @ frames.invert(T_f_c) @ N @ T_f_c
    return out


def _layout(cell: SyntheticCell, T_cf_s1: np.ndarray, count: int, placement: dict) -> MarkLayout:
    T_cf_si = [T_cf_s1 @ T for T in cell.T_s1_si]
    T_cf_w0 = T_cf_s1 @ cell.T_s1_w0
    holes = frames.transform_points(T_cf_w0, cell.points_w[[p for _, p in cell.observed]])
    normal = T_cf_w0[:3, 2]  # the part frame's z: the roof's plane (Table 1's holes are within 2.7 mm of it)
    return place_marks(cell.camera, T_cf_si, holes, count=count, normal_cf=normal, **placement)


__all__ = ["MarkedCell", "ReferenceMark", "marked_cell", "marked_paper_roof_cell", "repeatability_at_flange"]
