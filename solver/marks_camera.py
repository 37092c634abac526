"""Where each camera stood, from its fixed marks alone: the check job of a cell with reference marks (no part needed).

For each view with at least ``MIN_MARKS_PER_VIEW`` marks, the marks' images are compared with where the calibrated
camera pose puts them. Under a good calibration the camera stands off its calibrated pose only by the robot's
repeatability (and the calibration's own sigma): the prior covariance ``S`` of a camera correction
``e = (w rad, d mm)`` (:func:`solver.marks_problem.camera_prior_factor`). The offsets ``r = u_obs - u(0)`` are then
normal with covariance ``C = J S J^T + s_px^2 I + J_m s_mark^2 J_m^T`` (``J`` the images' derivative in ``e``,
``J_m`` in the marks' positions, their survey sigma), so ``r^T C^-1 r`` is chi-square on ``2 n`` degrees of freedom
(n marks). A view fails when it passes the ``1 - rate`` quantile. The cameras together are tested for the move a
camera knocked on its bracket makes: the same correction ``e`` in every view's camera axes (the true camera pose is
``T_cf_si B`` for a bump ``B``), its generalised likelihood ratio ``g^T H^-1 g`` with ``g = sum J_i^T C_i^-1 r_i``,
``H = sum J_i^T C_i^-1 J_i``, chi-square on 6: it adds the views' evidence up, where each view alone sees too
little. The false-alarm rate of a check (default 1e-3 per check, the target of
one false failure per 1,000 good checks) is split evenly over the views and the joint test. The deviation reported
is the posterior mean of ``e`` (Gauss-Newton, a few steps).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from monoguide.solver import frames
from monoguide.solver.camera import CameraModel
from monoguide.solver.consistency import chi2_threshold
from monoguide.solver.marks import shift_mm, turn_deg
from monoguide.solver.marks_problem import MIN_MARKS_PER_VIEW, ReferenceMark

CHECK_FALSE_ALARM_RATE = 1e-3  # per check: one good check in 1,000 fails
_STEP_RAD, _STEP_MM = 1e-6, 1e-4  # numerical derivatives
_ITERATIONS = 3


@dataclass(frozen=True)
class CameraCheck:
    """One view's camera against its calibrated pose: ``correction`` (6,) = (w rad, d mm) in the camera's axes."""

    view: str
    marks: int
    correction: np.ndarray
    statistic: float
    dof: int
    threshold: float

    mm = property(lambda self: shift_mm(self.correction))
    deg = property(lambda self: turn_deg(self.correction))
    passed = property(lambda self: self.statistic <= self.threshold)

    def as_dict(self) -> dict[str, object]:
        return {"view": self.view, "marks": self.marks, "mm": round(self.mm, 5), "deg": round(self.deg, 6),
                "d_mm": [round(float(v), 5) for v in self.correction[3:]],
                "w_deg": [round(math.degrees(float(v)), 6) for v in self.correction[:3]],
                "statistic": round(self.statistic, 3), "dof": self.dof, "threshold": round(self.threshold, 3),
                "passed": self.passed}


@dataclass(frozen=True)
class CamerasCheck:
    """Every checked view, and all of them together."""

    views: tuple[CameraCheck, ...]
    statistic: float  # the common move's (the camera on its bracket)
    dof: int
    threshold: float
    common: np.ndarray  # (6,) its estimate (w rad, d mm), camera axes

    common_mm = property(lambda self: shift_mm(self.common))
    common_deg = property(lambda self: turn_deg(self.common))

    @property
    def passed(self) -> bool:
        return self.statistic <= self.threshold and all(v.passed for v in self.views)


def check_cameras(
    camera: CameraModel,
    T_s1_si: Sequence[np.ndarray],
    marks: Sequence[ReferenceMark],
    mark_view: np.ndarray,
    mark_index: np.ndarray,
    mark_pixels: np.ndarray,
    view_names: Sequence[str],
    prior_factor: np.ndarray,
    sigma_px: float,
    false_alarm_rate: float = CHECK_FALSE_ALARM_RATE,
) -> CamerasCheck:
    """Test every view with enough marks. ``marks[k].position_cf`` are in the frame of ``T_s1_si`` (SF1);
    ``prior_factor`` (6, 6) F with F F^T the prior covariance of a camera correction. ``ValueError`` when no view
    has ``MIN_MARKS_PER_VIEW`` marks."""
    mark_view, mark_index = np.asarray(mark_view, dtype=int), np.asarray(mark_index, dtype=int)
    pixels = np.asarray(mark_pixels, dtype=float).reshape(-1, 2)
    checked = [v for v in range(len(T_s1_si)) if len(set(mark_index[mark_view == v].tolist())) >= MIN_MARKS_PER_VIEW]
    if not checked:
        raise ValueError(f"no view sees {MIN_MARKS_PER_VIEW} marks: the cameras cannot be checked by their marks")
    per_test = false_alarm_rate / (len(checked) + 1)
    S_inv = np.linalg.inv(prior_factor @ prior_factor.T)
    views = []
    g, H = np.zeros(6), np.zeros((6, 6))
    for v in checked:
        rows = np.flatnonzero(mark_view == v)
        X = np.array([marks[mark_index[j]].position_cf for j in rows], dtype=float)
        survey = np.array([marks[mark_index[j]].sigma_mm for j in rows], dtype=float)
        T = np.asarray(T_s1_si[v], dtype=float)
        r0 = (pixels[rows] - _image(camera, T, X, np.zeros(6))).ravel()
        J = _jacobian(camera, T, X, np.zeros(6))
        noise = np.diag(np.full(2 * len(rows), sigma_px**2))
        for k, s in enumerate(survey):  # the survey's sigma, through the image of each mark
            Jm = _point_jacobian(camera, T, X[k])
            noise[2 * k : 2 * k + 2, 2 * k : 2 * k + 2] += s**2 * Jm @ Jm.T
        C = J @ np.linalg.inv(S_inv) @ J.T + noise
        statistic = float(r0 @ np.linalg.solve(C, r0))
        dof = 2 * len(rows)
        views.append(CameraCheck(view_names[v], len(rows), _posterior(camera, T, X, pixels[rows], noise, S_inv),
                                 statistic, dof, chi2_threshold(dof, per_test)))
        g += J.T @ np.linalg.solve(C, r0)
        H += J.T @ np.linalg.solve(C, J)
    joint = float(g @ np.linalg.solve(H, g))
    return CamerasCheck(tuple(views), joint, 6, chi2_threshold(6, per_test), np.linalg.solve(H, g))


def _image(camera: CameraModel, T_s1_si: np.ndarray, X: np.ndarray, e: np.ndarray) -> np.ndarray:
    """The marks ``X`` (n, 3, SF1) imaged by the camera at ``T_s1_si [R(w) | d]``."""
    T = T_s1_si @ frames.make_T(frames.rotvec_to_matrix(e[:3]), e[3:])
    return camera.project(frames.transform_points(frames.invert(T), X))


def _jacobian(camera: CameraModel, T: np.ndarray, X: np.ndarray, e: np.ndarray) -> np.ndarray:
    J = np.zeros((2 * len(X), 6))
    for k in range(6):
        step = np.zeros(6)
        step[k] = _STEP_RAD if k < 3 else _STEP_MM
        J[:, k] = ((_image(camera, T, X, e + step) - _image(camera, T, X, e - step)) / (2 * step[k])).ravel()
    return J


def _point_jacobian(camera: CameraModel, T: np.ndarray, x: np.ndarray) -> np.ndarray:
    J = np.zeros((2, 3))
    for k in range(3):
        step = np.zeros(3)
        step[k] = _STEP_MM
        J[:, k] = (_image(camera, T, (x + step)[None], np.zeros(6)) - _image(camera, T, (x - step)[None],
                                                                             np.zeros(6)))[0] / (2 * _STEP_MM)
    return J


def _posterior(camera: CameraModel, T: np.ndarray, X: np.ndarray, observed: np.ndarray, noise: np.ndarray,
               S_inv: np.ndarray) -> np.ndarray:
    """The posterior mean of the camera correction (Gauss-Newton from the calibrated pose)."""
    e = np.zeros(6)
    W = np.linalg.inv(noise)
    for _ in range(_ITERATIONS):
        r = (observed - _image(camera, T, X, e)).ravel()
        J = _jacobian(camera, T, X, e)
        e = e + np.linalg.solve(J.T @ W @ J + S_inv, J.T @ W @ r - S_inv @ e)
    return e
