"""Camera intrinsics by Zhang's method (step 1): images of a plate of circular marks from several poses.

Per image: OpenCV's ``findCirclesGrid`` finds the grid and orders the marks; each mark is then measured with
the project's hole detector (ellipse of its rim, :func:`~monoguide.solver.holes.measure_hole`) and the image's
blur is the marks' median rim width. An image whose grid is not found or whose rims are blurred beyond
``max_blur_px`` is rejected with the reason. ``cv2.calibrateCamera`` (k3 fixed at 0: the project's model is
k1 k2 p1 p2, Eq. 8) gives the intrinsics and each plate pose; the ellipse centres are then corrected for
perspective at those poses (:func:`~monoguide.solver.holes.perspective_correction`: the centre of an imaged
circle is not the image of its centre) and the calibration repeated. Result: a :class:`CameraModel`, the
reprojection RMS and each image's residual.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np

from monoguide.solver.calibration.errors import (
    CalibrationImageRejected,
    CalibrationResidualTooLarge,
    CalibrationTooFewViews,
)
from monoguide.solver.calibration.target import measure_mark
from monoguide.solver.camera import CameraModel
from monoguide.solver.errors import FeatureNotFound
from monoguide.solver.frames import make_T, rotvec_to_matrix
from monoguide.solver.holes import perspective_correction

MIN_IMAGES = 6
DEFAULT_MAX_BLUR_PX = 3.0
DEFAULT_MAX_RMS_PX = 0.5
_CORRECTION_ROUNDS = 2


@dataclass(frozen=True)
class CirclePlate:
    """A symmetric grid of ``cols`` × ``rows`` dark circles of ``radius_mm`` at ``pitch_mm`` on a bright plate
    (plate frame: z = 0 on the plate, first circle at the origin)."""

    cols: int = 7
    rows: int = 5
    pitch_mm: float = 50.0
    radius_mm: float = 10.0

    def points(self) -> np.ndarray:
        """Circle centres (rows · cols, 3) mm in the order ``findCirclesGrid`` returns them (row by row)."""
        x, y = np.meshgrid(np.arange(self.cols) * self.pitch_mm, np.arange(self.rows) * self.pitch_mm)
        return np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])

    def centre(self) -> np.ndarray:
        return np.array([(self.cols - 1) * self.pitch_mm / 2, (self.rows - 1) * self.pitch_mm / 2, 0.0])


@dataclass(frozen=True)
class PlateDetection:
    """Ellipse centres (n, 2) px of the plate's circles (plate order, not perspective-corrected) and the median
    rim blur sigma (px)."""

    centers_px: np.ndarray
    blur_px: float


@dataclass
class IntrinsicsResult:
    """The calibrated camera, the reprojection RMS (px) over all used images, each used image's RMS (index ->
    px), the rejected images (index -> reason), and the plate pose ``T_c_plate`` of each used image."""

    camera: CameraModel
    rms_px: float
    per_image_rms_px: dict[int, float]
    rejected: dict[int, str] = field(default_factory=dict)
    T_c_plate: dict[int, np.ndarray] = field(default_factory=dict)

    def as_dict(self) -> dict[str, object]:
        return {"camera": self.camera.as_dict(), "rms_px": self.rms_px,
                "per_image_rms_px": {str(k): v for k, v in self.per_image_rms_px.items()},
                "rejected": {str(k): v for k, v in self.rejected.items()}}


def _blob_detector(image_shape: tuple[int, ...]) -> cv2.SimpleBlobDetector:
    params = cv2.SimpleBlobDetector_Params()
    params.minArea = 30.0
    params.maxArea = float(image_shape[0] * image_shape[1]) / 20.0
    params.filterByConvexity = False
    params.filterByInertia = True
    params.minInertiaRatio = 0.2
    params.minDistBetweenBlobs = 5.0
    return cv2.SimpleBlobDetector_create(params)


def detect_plate(image: np.ndarray, plate: CirclePlate, max_blur_px: float = DEFAULT_MAX_BLUR_PX) -> PlateDetection:
    """The plate's circles in ``image`` (uint8 grey); raises :class:`CalibrationImageRejected` with the reason
    (grid not found, a circle not measurable, rims blurred beyond ``max_blur_px``)."""
    image = np.asarray(image)
    if image.ndim != 2 or image.size == 0:
        raise CalibrationImageRejected(f"plate: expected a grey image, got shape {image.shape}")
    grey = image if image.dtype == np.uint8 else cv2.normalize(image, None, 0, 255, cv2.NORM_MINMAX, cv2.CV_8U)
    # the grid is found on a half-size copy (four times faster; the centres are re-measured at full size)
    scale = 2 if min(grey.shape) >= 1000 else 1
    small = cv2.pyrDown(grey) if scale == 2 else grey
    found, centres = False, None
    for extra in (0, cv2.CALIB_CB_CLUSTERING):  # the graph search first; clustering copes with strong perspective
        found, centres = cv2.findCirclesGrid(small, (plate.cols, plate.rows), flags=cv2.CALIB_CB_SYMMETRIC_GRID | extra,
                                             blobDetector=_blob_detector(small.shape))
        if found:
            break
    if not found or centres is None:
        raise CalibrationImageRejected(f"plate: the {plate.cols} × {plate.rows} circle grid was not found "
                                       "(plate not wholly in view, occluded, or too blurred)")
    centres = (centres.reshape(-1, 2).astype(float) + 0.5) * scale - 0.5
    spacing = float(np.median(np.linalg.norm(np.diff(centres.reshape(plate.rows, plate.cols, 2), axis=1), axis=2)))
    r_guess = spacing * plate.radius_mm / plate.pitch_mm
    measured, blurs = [], []
    for k, c in enumerate(centres):
        try:
            centre, blur = measure_mark(grey, c, r_guess, 0.5 * r_guess, radius_tol=0.5, max_blur_px=50.0,
                                        photometric=False)
        except FeatureNotFound as exc:
            raise CalibrationImageRejected(f"plate: circle {k + 1} at ({c[0]:.0f}, {c[1]:.0f}) px not measurable: "
                                           f"{exc.message}") from exc
        measured.append(centre)
        blurs.append(blur)
    blur = float(np.median(blurs))
    if blur > max_blur_px:
        raise CalibrationImageRejected(f"plate: blurred, the circles' rims are {blur:.1f} px wide (sigma), more "
                                       f"than {max_blur_px:g} px: refocus or hold still")
    return PlateDetection(np.array(measured), blur)


def _calibrate(obj: list[np.ndarray], img: list[np.ndarray], size: tuple[int, int], guess: CameraModel | None
               ) -> tuple[float, np.ndarray, np.ndarray, list[np.ndarray]]:
    flags = cv2.CALIB_FIX_K3
    K0, d0 = None, None
    if guess is not None:
        flags |= cv2.CALIB_USE_INTRINSIC_GUESS
        K0, d0 = guess.K.copy(), np.append(guess.dist_coeffs, 0.0)
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 200, 1e-12)
    rms, K, dist, rvecs, tvecs = cv2.calibrateCamera(
        [o.astype(np.float32).reshape(-1, 1, 3) for o in obj], [i.astype(np.float32).reshape(-1, 1, 2) for i in img],
        size, K0, d0, flags=flags, criteria=criteria)
    poses = [make_T(rotvec_to_matrix(np.asarray(r).ravel()), np.asarray(t).ravel()) for r, t in
             zip(rvecs, tvecs, strict=True)]
    return float(rms), K, np.asarray(dist).ravel(), poses


def _model(K: np.ndarray, dist: np.ndarray, width: int, height: int) -> CameraModel:
    return CameraModel(width=width, height=height, fx=float(K[0, 0]), fy=float(K[1, 1]), cx=float(K[0, 2]),
                       cy=float(K[1, 2]), k1=float(dist[0]), k2=float(dist[1]), p1=float(dist[2]),
                       p2=float(dist[3]))


def calibrate_from_centres(centres: dict[int, np.ndarray], plate: CirclePlate, width: int, height: int, *,
                           min_images: int = MIN_IMAGES, max_rms_px: float | None = DEFAULT_MAX_RMS_PX,
                           rejected: dict[int, str] | None = None, correct_perspective: bool = True
                           ) -> IntrinsicsResult:
    """Zhang's calibration from measured ellipse centres: image index -> (n, 2) px in plate order."""
    rejected = dict(rejected or {})
    if len(centres) < min_images:
        listed = "; ".join(f"image {k + 1}: {why}" for k, why in sorted(rejected.items()))
        raise CalibrationTooFewViews(f"intrinsics: {len(centres)} usable image(s), need {min_images}"
                                     + (f" (rejected: {listed})" if listed else ""))
    keys = sorted(centres)
    obj = [plate.points() for _ in keys]
    raw = [np.asarray(centres[k], dtype=float) for k in keys]
    img = [r.copy() for r in raw]
    rms, K, dist, poses = _calibrate(obj, img, (width, height), None)
    for _ in range(_CORRECTION_ROUNDS if correct_perspective else 0):
        cam = _model(K, dist, width, height)
        img = [r - np.array([perspective_correction(cam, T, p, np.array([0.0, 0.0, 1.0]), plate.radius_mm, 90)
                             for p in plate.points()]) for r, T in zip(raw, poses, strict=True)]
        rms, K, dist, poses = _calibrate(obj, img, (width, height), cam)
    cam = _model(K, dist, width, height)
    per_image = {}
    for k, o, i, T in zip(keys, obj, img, poses, strict=True):
        proj = cam.project(o @ T[:3, :3].T + T[:3, 3])
        per_image[k] = float(np.sqrt(np.mean(np.sum((proj - i) ** 2, axis=1))))
    result = IntrinsicsResult(cam, rms, per_image, rejected, dict(zip(keys, poses, strict=True)))
    if max_rms_px is not None and rms > max_rms_px:
        worst = max(per_image, key=per_image.get)
        raise CalibrationResidualTooLarge(f"intrinsics: reprojection RMS {rms:.3f} px > {max_rms_px:g} px; worst "
                                          f"image {worst + 1} at {per_image[worst]:.3f} px")
    return result


def calibrate_intrinsics(images: Sequence[np.ndarray], plate: CirclePlate, *, min_images: int = MIN_IMAGES,
                         max_blur_px: float = DEFAULT_MAX_BLUR_PX, max_rms_px: float | None = DEFAULT_MAX_RMS_PX
                         ) -> IntrinsicsResult:
    """Calibrate from plate images (uint8 grey, all the same size). Rejected images are listed in
    ``result.rejected`` with the reason; fewer than ``min_images`` usable raises :class:`CalibrationTooFewViews`."""
    if not images:
        raise CalibrationTooFewViews("intrinsics: no images")
    height, width = np.asarray(images[0]).shape[:2]
    centres: dict[int, np.ndarray] = {}
    rejected: dict[int, str] = {}
    for k, image in enumerate(images):
        try:
            centres[k] = detect_plate(image, plate, max_blur_px).centers_px
        except CalibrationImageRejected as exc:
            rejected[k] = exc.message
    return calibrate_from_centres(centres, plate, width, height, min_images=min_images, max_rms_px=max_rms_px,
                                  rejected=rejected)
