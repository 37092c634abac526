"""The problem of a cycle with fixed reference marks: today's hole problem, the marks and their sightings.

Validated on construction: every centre finite, every index known, every sighted mark in front of its camera,
a prior for the camera poses (the repeatability or the calibration's sigma). A view sees enough marks to measure its
camera (``checked``) with ``MIN_MARKS_PER_VIEW``; see docs/cycle-marks.md for why two, and why three name a wrong mark.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from monoguide.solver import frames
from monoguide.solver.errors import NonFiniteValue, PointBehindCamera, UnknownReference
from monoguide.solver.problem import PoseProblem
from monoguide.solver.uncertainty import adjoint

MARK_SIGMA_MM = 0.025  # a mark's position from the laser tracker, per axis (the paper's Sec. 5.1)
MARK_SIGMA_PX = 0.1
CALIBRATION_SIGMA_MM, CALIBRATION_SIGMA_DEG = 0.01, 0.001  # the calibration's own sigma of T_cf_si, per camera axis
# A view's camera pose is measured (and checked) with at least this many marks: two give four equations, the prior
# the rest; one mark's error would go into the camera pose unseen, so a view with one mark falls back to the prior.
MIN_MARKS_PER_VIEW = 2


@dataclass(frozen=True)
class ReferenceMark:
    """A fixed mark of the cell: its name, its centre in the cell frame (3,) mm, its survey sigma per axis, mm."""

    name: str
    position_cf: np.ndarray
    sigma_mm: float = MARK_SIGMA_MM


@dataclass(frozen=True)
class MarksProblem:
    """Today's pose problem (the holes, the calibrated views in SF1, the repeatability) plus the marks.

    holes       : the :class:`PoseProblem` of the cycle (``view_sigma_*`` the robot's repeatability, required)
    T_cf_s1     : (4, 4) the calibrated first measuring pose in the cell frame (puts the marks into SF1)
    marks       : the marks of the cell
    mark_view   : (q,) int, the view of each mark sighting;  mark_index : (q,) int, its mark
    mark_pixels : (q, 2) the observed mark centres, raw px
    view_names  : one name per view (default S1, S2, ...), used in the refusals
    """

    holes: PoseProblem
    T_cf_s1: np.ndarray
    marks: tuple[ReferenceMark, ...]
    mark_view: np.ndarray
    mark_index: np.ndarray
    mark_pixels: np.ndarray
    view_names: tuple[str, ...] = ()
    mark_sigma_px: float = MARK_SIGMA_PX
    calibration_sigma_mm: float = CALIBRATION_SIGMA_MM
    calibration_sigma_deg: float = CALIBRATION_SIGMA_DEG
    marks_s1: np.ndarray = field(init=False, repr=False)  # (M, 3) surveyed centres in SF1
    checked: tuple[bool, ...] = field(init=False, repr=False)  # per view: enough marks to measure its camera

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        k = len(self.holes.T_s1_si)
        names = tuple(self.view_names) or tuple(f"S{i + 1}" for i in range(k))
        if len(names) != k:
            raise UnknownReference(f"{len(names)} view names for {k} views")
        set_(self, "view_names", names)
        set_(self, "T_cf_s1", frames.rigid_transform(self.T_cf_s1, "T_cf_s1"))
        views, index = np.asarray(self.mark_view, dtype=int), np.asarray(self.mark_index, dtype=int)
        pixels = np.asarray(self.mark_pixels, dtype=float).reshape(-1, 2)
        if not (len(views) == len(index) == len(pixels)):
            raise UnknownReference(f"mark sightings disagree: {len(views)} views, {len(index)} marks, "
                                   f"{len(pixels)} pixels")
        for name, idx, count in (("view", views, k), ("mark", index, len(self.marks))):
            bad = [int(i) for i in idx if not 0 <= i < count]
            if bad:
                raise UnknownReference(f"a mark sighting names {name} {bad[0]}, but there are only {count} {name}s")
        bad_hole = np.flatnonzero(~np.all(np.isfinite(self.holes.pixels), axis=1))
        if len(bad_hole):
            j = int(bad_hole[0])
            point, view = int(self.holes.point_index[j]), names[int(self.holes.view_index[j])]
            raise NonFiniteValue(f"hole centre {self.holes.pixels[j].tolist()} of point {point} in view {view} "
                                 "is not finite")
        for j in np.flatnonzero(~np.all(np.isfinite(pixels), axis=1)):
            raise NonFiniteValue(f"centre {pixels[j].tolist()} of mark {self.marks[index[j]].name} in view "
                                 f"{names[views[j]]} is not finite")
        for mark in self.marks:
            p = np.asarray(mark.position_cf, dtype=float)
            if p.shape != (3,) or not np.all(np.isfinite(p)):
                raise NonFiniteValue(f"mark {mark.name}: position_cf {p.tolist()} is not three finite numbers (mm)")
            if not (math.isfinite(mark.sigma_mm) and mark.sigma_mm > 0):
                raise ValueError(f"mark {mark.name}: sigma_mm must be positive, got {mark.sigma_mm!r}")
        if not (math.isfinite(self.mark_sigma_px) and self.mark_sigma_px > 0):
            raise ValueError(f"mark_sigma_px must be positive, got {self.mark_sigma_px!r}")
        if not (self.holes.view_sigma_mm or self.calibration_sigma_mm) or not (
                self.holes.view_sigma_deg or self.calibration_sigma_deg):
            raise ValueError("the camera poses need a prior: give the repeatability (holes.view_sigma_mm/_deg) or the "
                             "calibration's sigma; with neither the marks have nothing to estimate (use solve_pose)")
        T_s1_cf = frames.invert(self.T_cf_s1)
        marks_s1 = np.array([frames.transform_points(T_s1_cf, np.asarray(m.position_cf, float)[None])[0]
                             for m in self.marks]).reshape(-1, 3)
        for v, m in zip(views, index, strict=True):
            z = frames.transform_points(frames.invert(self.holes.T_s1_si[v]), marks_s1[m : m + 1])[0, 2]
            if z <= 1e-6:
                where = np.round(np.asarray(self.marks[m].position_cf, dtype=float), 3).tolist()
                raise PointBehindCamera(f"mark {self.marks[m].name} (position_cf {where}) lies behind the camera of "
                                        f"view {names[v]} (z = {z:.1f} mm)")
        checked = tuple(len(set(index[views == v].tolist())) >= MIN_MARKS_PER_VIEW for v in range(k))
        set_(self, "mark_view", views)
        set_(self, "mark_index", index)
        set_(self, "mark_pixels", pixels)
        set_(self, "marks_s1", marks_s1)
        set_(self, "checked", checked)

    def prior_factor(self) -> np.ndarray:
        """F (6, 6) with ``F F^T`` the prior covariance of a camera correction ``e = (w rad, d mm)``
        (:func:`camera_prior_factor` of the repeatability and the calibration's sigma)."""
        h = self.holes
        return camera_prior_factor(h.view_sigma_mm, h.view_sigma_deg, h.T_f_c, self.calibration_sigma_mm,
                                   self.calibration_sigma_deg)


def camera_prior_factor(view_sigma_mm: float, view_sigma_deg: float, T_f_c: np.ndarray | None,
                        calibration_sigma_mm: float = CALIBRATION_SIGMA_MM,
                        calibration_sigma_deg: float = CALIBRATION_SIGMA_DEG) -> np.ndarray:
    """F (6, 6) with ``F F^T`` the prior covariance of a camera correction ``e = (w rad, d mm)``: the
    repeatability (at the flange when ``T_f_c`` is given, :func:`solver.uncertainty.view_motion_factor`)
    plus the calibration's own sigma per camera axis."""
    F = np.diag([math.radians(view_sigma_deg)] * 3 + [view_sigma_mm] * 3)
    if T_f_c is not None:
        F = adjoint(frames.invert(T_f_c)) @ F
    cal = np.diag([math.radians(calibration_sigma_deg) ** 2] * 3 + [calibration_sigma_mm**2] * 3)
    return np.linalg.cholesky(F @ F.T + cal)
