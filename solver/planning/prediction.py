"""What a measuring layout predicts: the covariance of the part pose (Eq. 29 / the Cramer-Rao bound) and
its standard deviations at the part's grasp point.

A layout is a list of camera poses ``T_w_si`` in the frame of the reference part and the (view, point)
pairs it observes; the prediction is made at the reference part, where the pixels are exact.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from monoguide.solver import frames
from monoguide.solver.camera import CameraModel
from monoguide.solver.problem import PoseProblem
from monoguide.solver.uncertainty import predicted_covariance


@dataclass(frozen=True)
class PoseSigmas:
    """Standard deviations of a predicted part pose (square roots of covariance traces).

    sigma_rot_deg   : rotation, deg
    sigma_trans_mm  : position of the grasp point, mm (the point the robot's offset must get right)
    sigma_origin_mm : position of the part frame's origin, mm (the paper's ``t`` of ``T_s1_w``)
    grasp_variances_mm2, rotation_variances_deg2 : (3,) the principal variances (eigenvalues) of the grasp
                      point's and the rotation's covariance, ascending: their sums are the squared sigmas, their
                      spread the shape of the error (what the RMS of a few grasps scatters by)
    """

    sigma_rot_deg: float
    sigma_trans_mm: float
    sigma_origin_mm: float
    grasp_variances_mm2: tuple[float, float, float] | None = None
    rotation_variances_deg2: tuple[float, float, float] | None = None

    def as_dict(self) -> dict[str, float]:
        return {
            "sigma_rot_deg": self.sigma_rot_deg,
            "sigma_trans_mm": self.sigma_trans_mm,
            "sigma_origin_mm": self.sigma_origin_mm,
        }


def layout_covariance(
    camera: CameraModel,
    points_w: np.ndarray,
    T_w_si: Sequence[np.ndarray],
    sigma_px: float = 1.0,
    view_sigma_mm: float = 0.0,
    view_sigma_deg: float = 0.0,
    T_f_c: np.ndarray | None = None,
) -> np.ndarray:
    """Predicted covariance (6, 6) of ``T_s1_w`` over (w rad, dt mm) for a layout where view i sees point i
    from ``T_w_si[i]`` (the part at its reference pose). ``T_f_c``: the camera on the flange (the view
    sigmas are then the robot's repeatability at the flange; see :class:`~monoguide.solver.problem.PoseProblem`)."""
    points_w = np.asarray(points_w, dtype=float).reshape(-1, 3)
    observed = [(i, i) for i in range(len(points_w))]
    return observed_covariance(camera, points_w, T_w_si, observed, sigma_px, view_sigma_mm, view_sigma_deg, T_f_c)


def observed_covariance(
    camera: CameraModel,
    points_w: np.ndarray,
    T_w_si: Sequence[np.ndarray],
    observed: Sequence[tuple[int, int]],
    sigma_px: float = 1.0,
    view_sigma_mm: float = 0.0,
    view_sigma_deg: float = 0.0,
    T_f_c: np.ndarray | None = None,
) -> np.ndarray:
    """Predicted covariance (6, 6) of ``T_s1_w`` for any layout: ``observed`` lists the (view, point)
    pairs, ``T_w_si`` (k, 4, 4) the camera poses in the reference part's frame, ``T_f_c`` the camera on the
    flange (None: the view sigmas move the camera about its centre).

    Raises :class:`~monoguide.solver.errors.DegenerateGeometry` when the layout leaves a direction of the
    pose unobservable, :class:`~monoguide.solver.errors.PointBehindCamera` when a point is behind its camera.
    """
    points_w = np.asarray(points_w, dtype=float).reshape(-1, 3)
    T_s1_w0 = frames.invert(T_w_si[0])
    T_s1_si = np.stack([T_s1_w0 @ T for T in T_w_si])
    views = np.array([v for v, _ in observed], dtype=int)
    points = np.array([p for _, p in observed], dtype=int)
    pixels = np.empty((len(observed), 2))
    for row, (view, point) in enumerate(observed):
        point_c = frames.transform_points(frames.invert(T_w_si[view]), points_w[point : point + 1])
        pixels[row] = camera.project(point_c)[0]
    problem = PoseProblem(
        camera, points_w, T_s1_si, views, points, pixels, T_s1_w0, sigma_px, view_sigma_mm, view_sigma_deg, T_f_c
    )
    return predicted_covariance(problem, T_s1_w0)


def pose_sigmas(covariance: np.ndarray, T_s1_w: np.ndarray, grasp_point_w: np.ndarray) -> PoseSigmas:
    """Standard deviations of the part pose whose covariance (6, 6) over a left perturbation (w rad, dt mm)
    of ``T_s1_w`` is given, at the grasp point ``grasp_point_w`` (3,) of the part frame.

    The grasp point in SF1 is ``g = R p + t``; a left perturbation moves it by ``w x (R p) + dt``.
    """
    lever = T_s1_w[:3, :3] @ np.asarray(grasp_point_w, dtype=float)
    J = np.hstack([-frames.skew(lever), np.eye(3)])
    grasp = J @ covariance @ J.T
    return PoseSigmas(
        sigma_rot_deg=math.degrees(math.sqrt(max(float(np.trace(covariance[:3, :3])), 0.0))),
        sigma_trans_mm=math.sqrt(max(float(np.trace(grasp)), 0.0)),
        sigma_origin_mm=math.sqrt(max(float(np.trace(covariance[3:, 3:])), 0.0)),
        grasp_variances_mm2=_principal_variances(grasp),
        rotation_variances_deg2=_principal_variances(covariance[:3, :3] * math.degrees(1.0) ** 2),
    )


def _principal_variances(covariance: np.ndarray) -> tuple[float, float, float]:
    """The eigenvalues (3,) of a 3x3 covariance, ascending, rounding's negatives set to 0."""
    a, b, c = (max(float(v), 0.0) for v in np.linalg.eigvalsh(0.5 * (covariance + covariance.T)))
    return a, b, c
