"""A calibration target's circular marks seen by the camera: their image centres and the target's pose
``T_si_t`` in the camera frame (the "homography" of paper Sec. 2.2, here a full PnP with the lens model).

Each mark is measured with the project's hole detector (:func:`monoguide.solver.holes.measure_hole`: dark
disc on a bright target), its ellipse centre corrected for perspective
(:func:`~monoguide.solver.holes.perspective_correction`) at the current pose, then the pose is solved with
OpenCV (``solvePnP`` then ``solvePnPRefineLM``) with the camera's k1 k2 p1 p2; two rounds of correction.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from monoguide.solver.calibration.errors import CalibrationImageRejected, CalibrationTooFewViews
from monoguide.solver.camera import CameraModel
from monoguide.solver.errors import FeatureNotFound
from monoguide.solver.frames import make_T, matrix_to_rotvec, rotvec_to_matrix, transform_points
from monoguide.solver.holes import measure_hole, perspective_correction

MIN_MARKS = 6
_CORRECTION_ROUNDS = 2


@dataclass(frozen=True, eq=False)
class TargetMarks:
    """Circular marks of a target, calibrated in its frame TF: centres ``centers_t`` (n, 3) mm, common radius
    (mm) and plane normal ``normal_t`` (3,)."""

    centers_t: np.ndarray
    radius_mm: float
    normal_t: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))


def grid_marks(nx: int, ny: int, pitch_mm: float, radius_mm: float, origin_t: tuple[float, float] = (0.0, 0.0)
               ) -> TargetMarks:
    """An ``nx`` × ``ny`` grid of marks at ``pitch_mm`` in the target's xy plane starting at ``origin_t``."""
    x, y = np.meshgrid(np.arange(nx) * pitch_mm + origin_t[0], np.arange(ny) * pitch_mm + origin_t[1])
    centers = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    return TargetMarks(centers, float(radius_mm))


def default_target_marks() -> TargetMarks:
    """The marks of the simulated cell's 300 × 200 mm targets (SMR nests at its corners): 13 × 9 at 20 mm,
    radius 4 mm, from (30, 20) mm (many marks: the pose's precision grows with their number)."""
    return grid_marks(13, 9, 20.0, 4.0, (30.0, 20.0))


@dataclass(frozen=True)
class TargetView:
    """The target's pose in the camera ``T_c_t`` (4, 4), the corrected mark centres (n, 2) px and the
    reprojection residual of each mark (n,) px."""

    T_c_t: np.ndarray
    centers_px: np.ndarray
    residuals_px: np.ndarray

    @property
    def rms_px(self) -> float:
        return float(np.sqrt(np.mean(self.residuals_px**2)))


def _cv_pose(camera: CameraModel, points_t: np.ndarray, pixels: np.ndarray, T_guess: np.ndarray | None
             ) -> np.ndarray:
    obj = np.ascontiguousarray(points_t, dtype=np.float64).reshape(-1, 1, 3)
    img = np.ascontiguousarray(pixels, dtype=np.float64).reshape(-1, 1, 2)
    K, dist = camera.K, camera.dist_coeffs
    if T_guess is not None:
        rvec = matrix_to_rotvec(T_guess[:3, :3]).reshape(3, 1).copy()
        tvec = T_guess[:3, 3].reshape(3, 1).copy()
        ok, rvec, tvec = cv2.solvePnP(obj, img, K, dist, rvec, tvec, True, cv2.SOLVEPNP_ITERATIVE)
    else:
        ok, rvec, tvec = cv2.solvePnP(obj, img, K, dist, flags=cv2.SOLVEPNP_IPPE)
    if not ok:
        raise CalibrationImageRejected("target pose: OpenCV's solvePnP found no pose for the marks")
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 100, 1e-12)
    rvec, tvec = cv2.solvePnPRefineLM(obj, img, K, dist, rvec, tvec, criteria)
    return make_T(rotvec_to_matrix(rvec.ravel()), tvec.ravel())


def target_pose(camera: CameraModel, marks: TargetMarks, centers_px: np.ndarray,
                T_guess: np.ndarray | None = None) -> TargetView:
    """``T_c_t`` from mark centres (n, 2) px that are images of the 3-D centres (already perspective-corrected).
    Rows with NaN are marks not seen; at least :data:`MIN_MARKS` are needed."""
    centers_px = np.asarray(centers_px, dtype=float).reshape(-1, 2)
    seen = np.all(np.isfinite(centers_px), axis=1)
    if int(seen.sum()) < MIN_MARKS:
        raise CalibrationTooFewViews(f"target pose: {int(seen.sum())} mark(s) measured, need {MIN_MARKS}")
    T = _cv_pose(camera, marks.centers_t[seen], centers_px[seen], T_guess)
    res = np.full(len(centers_px), np.nan)
    proj = camera.project(transform_points(T, marks.centers_t[seen]))
    res[seen] = np.linalg.norm(proj - centers_px[seen], axis=1)
    return TargetView(T, centers_px, res)


def measure_mark(image: np.ndarray, expected_px: np.ndarray, radius_px: float, max_offset_px: float,
                 **options: object) -> tuple[np.ndarray, float]:
    """One dark circular mark near ``expected_px`` (2,): its ellipse centre (2,) px (full-image coordinates) and
    rim blur sigma (px), with :func:`~monoguide.solver.holes.measure_hole` on a crop around it (the detector
    converts the whole array it is given; a crop keeps a full frame with dozens of marks fast). Raises the
    detector's :class:`FeatureNotFound`."""
    h, w = image.shape[:2]
    half = math.ceil(max_offset_px + 3.0 * radius_px + 8.0)
    x0, y0 = max(int(expected_px[0]) - half, 0), max(int(expected_px[1]) - half, 0)
    x1, y1 = min(int(expected_px[0]) + half + 1, w), min(int(expected_px[1]) + half + 1, h)
    crop = image[y0:y1, x0:x1]
    hole = measure_hole(crop, (float(expected_px[0]) - x0, float(expected_px[1]) - y0), radius_px,
                        max_offset_px=max_offset_px, **options)
    return hole.center + np.array([x0, y0], dtype=float), float(hole.edge_width_px)


def measure_target(image: np.ndarray, camera: CameraModel, marks: TargetMarks, T_guess: np.ndarray, *,
                   max_offset_px: float | None = None, max_blur_px: float = 3.0) -> TargetView:
    """Measure the target's marks in ``image`` and solve its pose ``T_c_t``.

    ``T_guess`` (4, 4) is the expected pose (from the taught measuring pose and the tracker's reading of the
    target): each mark is looked for where it projects, within ``max_offset_px`` (default 1.5 radii). A mark
    not found is left out (NaN); fewer than :data:`MIN_MARKS` found raises :class:`CalibrationImageRejected`
    with the reasons."""
    T_guess = np.asarray(T_guess, dtype=float)
    pts_c = transform_points(T_guess, marks.centers_t)
    if np.any(pts_c[:, 2] <= 0):
        raise CalibrationImageRejected("target: the expected pose puts marks behind the camera")
    expected = camera.project(pts_c)
    # each mark is searched within 0.45 of the distance to its nearest neighbour in the image: a guess that far
    # off still finds the right mark, never its neighbour
    gaps = np.linalg.norm(expected[:, None, :] - expected[None, :, :], axis=2)
    np.fill_diagonal(gaps, np.inf)
    reach = 0.45 * gaps.min(axis=1) if len(expected) > 1 else np.full(1, np.inf)
    raw = np.full((len(expected), 2), np.nan)
    reasons: list[str] = []
    for k, (e, z) in enumerate(zip(expected, pts_c[:, 2], strict=True)):
        r_px = marks.radius_mm * camera.fx / float(z)
        if not bool(camera.in_image(e[None, :], margin=r_px + 3.0)[0]):
            continue
        try:
            offset = max_offset_px if max_offset_px else max(float(reach[k]), 1.5 * r_px)
            raw[k], _ = measure_mark(image, e, r_px, offset,
                                     radius_tol=0.35, max_blur_px=max_blur_px, photometric=False)
        except FeatureNotFound as exc:
            reasons.append(f"mark {k + 1}: {exc.code}")
    seen = np.all(np.isfinite(raw), axis=1)
    if int(seen.sum()) < MIN_MARKS:
        why = "; ".join(reasons[:4]) if reasons else "no mark in the image"
        raise CalibrationImageRejected(f"target: {int(seen.sum())} of {len(raw)} marks measured, need {MIN_MARKS} "
                                       f"({why})")
    centers = raw.copy()
    T = T_guess
    for _ in range(_CORRECTION_ROUNDS + 1):
        view = target_pose(camera, marks, centers, T)
        T = view.T_c_t
        for k in np.flatnonzero(seen):
            centers[k] = raw[k] - perspective_correction(camera, T, marks.centers_t[k], marks.normal_t,
                                                         marks.radius_mm, n_points=90)
    return target_pose(camera, marks, centers, T)


def angle_deg_between(T_a: np.ndarray, T_b: np.ndarray) -> float:
    """Rotation angle (deg) between the orientations of two poses."""
    return math.degrees(float(np.linalg.norm(matrix_to_rotvec(T_a[:3, :3].T @ T_b[:3, :3]))))
