"""A calibration target's circular marks seen by the camera: their image centres and the target's pose
``T_si_t`` in the camera frame (the "homography" of paper Sec. 2.2, here a full PnP with the lens model).

Each mark is measured in its own window of the image, where the expected pose puts it, with the project's hole
detector (:mod:`monoguide.solver.hole_edges`' rim fit, the pipeline of
:func:`monoguide.solver.holes.measure_hole`: dark disc on a bright target) run on the mark's own blob only; its
ellipse centre is corrected for perspective (:func:`perspective_corrections`, all marks at once) at the current
pose, then the pose is solved with OpenCV (``solvePnP`` then ``solvePnPRefineLM``) with the camera's
k1 k2 p1 p2; two rounds of correction. ``benchmarks/bench_target.py`` times it against the search it replaced.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np

from monoguide.solver.calibration.errors import CalibrationImageRejected, CalibrationTooFewViews
from monoguide.solver.camera import CameraModel
from monoguide.solver.errors import FeatureNotFound
from monoguide.solver.frames import make_T, matrix_to_rotvec, rotvec_to_matrix, transform_points
from monoguide.solver.hole_edges import (
    DEFAULT_MIN_CONTRAST_TO_NOISE,
    SATURATION_GREY,
    as_grey,
    measure_rim,
    seed_dark_blobs,
)
from monoguide.solver.holes import DEFAULT_RADIUS_TOL, circle_basis, measure_hole
from monoguide.solver.rim_fit import refine_ellipse_photometric

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
                 **options: Any) -> tuple[np.ndarray, float]:
    """One dark circular mark near ``expected_px`` (2,): its ellipse centre (2,) px (full-image coordinates) and
    rim blur sigma (px), measured in a window (a crop) around it at full resolution.

    Fast path: the window's dark blobs are found once (:func:`~monoguide.solver.hole_edges.seed_dark_blobs`)
    and the rim fit (:func:`~monoguide.solver.hole_edges.measure_rim`, the hole detector's Sec. 5.3 pipeline)
    runs on the blobs near the expectation only, not on the neighbouring marks the window also holds. When that
    gives anything but exactly one plausible mark, :func:`~monoguide.solver.holes.measure_hole` searches the
    whole window (same pixels, same fit) and decides, or raises the detector's :class:`FeatureNotFound` with
    the reason. ``options``: :func:`measure_hole`'s keywords."""
    crop, origin = _mark_window(image, expected_px, radius_px, max_offset_px)
    local = (float(expected_px[0]) - origin[0], float(expected_px[1]) - origin[1])
    unknown = set(options) - _MARK_OPTIONS
    found = None if unknown else _one_mark(crop, local, float(radius_px), float(max_offset_px), **options)
    if found is None:
        hole = measure_hole(crop, local, radius_px, max_offset_px=max_offset_px, **options)
        found = (hole.center, float(hole.edge_width_px))
    return found[0] + origin, found[1]


_MARK_OPTIONS = frozenset({"radius_tol", "min_contrast", "max_blur_px", "max_saturated_fraction", "photometric",
                           "min_contrast_to_noise", "bit_depth"})


def _mark_window(image: np.ndarray, expected_px: np.ndarray, radius_px: float, max_offset_px: float
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The crop of ``image`` around the expectation that holds the mark wherever the search may find it (with
    room for its rim fit), and the crop's origin (2,) px in the image."""
    h, w = image.shape[:2]
    half = math.ceil(max_offset_px + 3.0 * radius_px + 8.0)
    x0, y0 = max(int(expected_px[0]) - half, 0), max(int(expected_px[1]) - half, 0)
    x1, y1 = min(int(expected_px[0]) + half + 1, w), min(int(expected_px[1]) + half + 1, h)
    return image[y0:y1, x0:x1], np.array([x0, y0], dtype=float)


def _one_mark(crop: np.ndarray, expected: tuple[float, float], r: float, max_offset: float, *,
              radius_tol: float = DEFAULT_RADIUS_TOL, min_contrast: float = 15.0, max_blur_px: float = 3.0,
              max_saturated_fraction: float = 0.02, photometric: bool = True,
              min_contrast_to_noise: float = DEFAULT_MIN_CONTRAST_TO_NOISE, bit_depth: int | None = None
              ) -> tuple[np.ndarray, float] | None:
    """The fast path of :func:`measure_mark`: :func:`measure_hole`'s search of the window (the same grey
    image, the same blobs, the same rim fit and the same plausibility: radius within ``radius_tol``, centre
    within ``max_offset``) with the rim fitted only on the blobs whose centre lies within ``max_offset`` plus
    their radius plus 4 px of the expectation (the detector's own reach from a blob to its hole), not on the
    neighbouring marks the window also holds. (centre in the crop, blur sigma) when exactly one mark is
    plausible, else None (the full search decides, and names the reason)."""
    if r <= 0 or crop.shape[0] < 8 or crop.shape[1] < 8:
        return None
    grey = as_grey(crop, bit_depth)
    ex, ey = expected
    h, w = grey.shape
    # measure_hole's ROI and its blob search region (the ROI grown by 1.6 of the largest radius + 16 px)
    half = max_offset + 2.0 * r
    bx0, by0 = max(math.floor(ex - half), 0), max(math.floor(ey - half), 0)
    bx1, by1 = min(math.floor(ex - half) + int(2 * half) + 2, w), min(math.floor(ey - half) + int(2 * half) + 2, h)
    if bx1 - bx0 < 4 or by1 - by0 < 4:
        return None
    r_min, r_max = 0.6 * r, 1.6 * r
    grow = math.ceil(1.6 * r_max) + 16
    search = (max(bx0 - grow, 0), max(by0 - grow, 0), min(bx1 + grow, w), min(by1 + grow, h))
    plausible = []
    for seed in seed_dark_blobs(grey, search, r_min, r_max, min_contrast):
        if math.hypot(seed.center[0] - ex, seed.center[1] - ey) > max_offset + seed.radius_px + 4.0:
            continue  # a neighbouring mark (or anything else) the window also holds
        try:
            rim = measure_rim(grey, seed, min_contrast=min_contrast, max_blur_px=max_blur_px,
                              max_saturated_fraction=max_saturated_fraction, photometric=False,
                              min_contrast_to_noise=min_contrast_to_noise)
        except FeatureNotFound:
            continue  # refused (as the detector's search refuses it); if it was the mark, the full search says why
        c, radius = rim.ellipse.center, rim.ellipse.mean_radius
        if (bx0 - 0.5 <= c[0] < bx1 - 0.5 and by0 - 0.5 <= c[1] < by1 - 0.5 and r_min <= radius <= r_max
                and abs(radius / r - 1.0) <= radius_tol and math.hypot(c[0] - ex, c[1] - ey) <= max_offset):
            plausible.append(rim)
    if len(plausible) != 1:
        return None
    rim = plausible[0]
    ellipse = rim.ellipse
    if photometric:
        ellipse, _ = refine_ellipse_photometric(grey, ellipse, rim.edge_width_px, SATURATION_GREY)
    return np.asarray(ellipse.center, dtype=float), float(rim.edge_width_px)


def perspective_corrections(camera: CameraModel, T_c_t: np.ndarray, centers_t: np.ndarray, normal_t: np.ndarray,
                            radius_mm: float, n_points: int = 90) -> np.ndarray:
    """:func:`~monoguide.solver.holes.perspective_correction` of many circles at once: (n, 2) px, row k the
    centre of circle k's imaged ellipse minus the image of its 3-D centre, for circles of ``radius_mm`` centred
    at ``centers_t`` (n, 3) in the plane of normal ``normal_t`` (3,), seen at ``T_c_t``. The same rim points
    and the same ellipse fit (Halir and Flusser's form of Fitzgibbon's, on points centred and scaled to unit
    spread), batched: one projection and one stack of 3 × 3 eigenproblems instead of a fit per circle."""
    centers_t = np.asarray(centers_t, dtype=float).reshape(-1, 3)
    if len(centers_t) == 0:
        return np.zeros((0, 2))
    e1, e2 = circle_basis(normal_t)
    t = np.linspace(0.0, 2.0 * math.pi, n_points, endpoint=False)
    ring = radius_mm * (np.cos(t)[:, None] * e1 + np.sin(t)[:, None] * e2)  # (m, 3)
    R, tr = T_c_t[:3, :3], T_c_t[:3, 3]
    rim_c = (centers_t[:, None, :] + ring[None, :, :]) @ R.T + tr  # (n, m, 3)
    if np.any(rim_c[..., 2] <= 0):
        raise ValueError("perspective correction: a circle is not in front of the camera")
    rim = camera.project(rim_c.reshape(-1, 3)).reshape(len(centers_t), n_points, 2)
    mean = rim.mean(axis=1)
    d = rim - mean[:, None, :]
    scale = np.sqrt(np.mean(np.sum(d**2, axis=2), axis=1))
    x, y = d[..., 0] / scale[:, None], d[..., 1] / scale[:, None]
    D1 = np.stack([x * x, x * y, y * y], axis=2)
    D2 = np.stack([x, y, np.ones_like(x)], axis=2)
    S1 = np.einsum("nki,nkj->nij", D1, D1)
    S2 = np.einsum("nki,nkj->nij", D1, D2)
    S3 = np.einsum("nki,nkj->nij", D2, D2)
    T = -np.linalg.solve(S3, np.swapaxes(S2, 1, 2))
    M = S1 + S2 @ T
    M = np.stack([M[:, 2] / 2.0, -M[:, 1], M[:, 0] / 2.0], axis=1)
    _, vecs = np.linalg.eig(M)
    vecs = np.real(vecs)
    cond = 4.0 * vecs[:, 0, :] * vecs[:, 2, :] - vecs[:, 1, :] ** 2
    if not np.all(np.any(cond > 0, axis=1)):
        raise ValueError("perspective correction: a circle's image is no ellipse")
    a1 = vecs[np.arange(len(vecs)), :, np.argmax(cond > 0, axis=1)]  # (n, 3) A B C
    A, B, C = a1[:, 0], a1[:, 1], a1[:, 2]
    Dc, Ec = np.einsum("nij,nj->ni", T, a1)[:, :2].T
    det = 4.0 * A * C - B * B
    centre = np.column_stack([(B * Ec - 2.0 * C * Dc) / det, (B * Dc - 2.0 * A * Ec) / det])
    centre = centre * scale[:, None] + mean
    return centre - camera.project(centers_t @ R.T + tr)


def measure_target(image: np.ndarray, camera: CameraModel, marks: TargetMarks, T_guess: np.ndarray, *,
                   max_offset_px: float | None = None, max_blur_px: float = 3.0) -> TargetView:
    """Measure the target's marks in ``image`` and solve its pose ``T_c_t``.

    ``T_guess`` (4, 4) is the expected pose (from the taught measuring pose and the tracker's reading of the
    target): each mark is looked for where it projects, within ``max_offset_px`` (default 0.45 of the distance
    to its nearest neighbour in the image, at least 1.5 radii), in its own window of the image at full
    resolution, the rim fitted on the mark's own blob only (:func:`measure_mark`'s fast path). Coarse to fine:
    marks missed there are looked for again where the pose of the marks found puts them (a guess off by most of
    the reach in the direction of the wider spacing), and the marks still missing get the detector's full
    search of their window, which finds them or says why not. A mark not found is left out (NaN); fewer than
    :data:`MIN_MARKS` found raises :class:`CalibrationImageRejected` with the reasons."""
    T_guess = np.asarray(T_guess, dtype=float)
    if np.any(transform_points(T_guess, marks.centers_t)[:, 2] <= 0):
        raise CalibrationImageRejected("target: the expected pose puts marks behind the camera")
    raw = np.full((len(marks.centers_t), 2), np.nan)
    expected, inside = _measure_marks(image, camera, marks, T_guess, raw, None, max_offset_px, max_blur_px, None)
    seen = np.all(np.isfinite(raw), axis=1)
    T_expected = T_guess
    if MIN_MARKS <= int(seen.sum()) < int(inside.sum()):  # the marks found place the others within a pixel or so
        T_found = target_pose(camera, marks, raw, T_guess).T_c_t
        moved = np.linalg.norm(camera.project(transform_points(T_found, marks.centers_t)) - expected, axis=1)
        _measure_marks(image, camera, marks, T_found, raw, ~seen & (moved > _RETRY_MOVED_PX), max_offset_px,
                       max_blur_px, None)
        T_expected = T_found
    reasons: dict[int, str] = {}
    _measure_marks(image, camera, marks, T_expected, raw, ~np.all(np.isfinite(raw), axis=1), max_offset_px,
                   max_blur_px, reasons)
    seen = np.all(np.isfinite(raw), axis=1)
    if int(seen.sum()) < MIN_MARKS:
        why = "; ".join(reasons[k] for k in sorted(reasons)[:4]) if reasons else "no mark in the image"
        raise CalibrationImageRejected(f"target: {int(seen.sum())} of {len(raw)} marks measured, need {MIN_MARKS} "
                                       f"({why})")
    centers = raw.copy()
    T = T_guess
    for _ in range(_CORRECTION_ROUNDS + 1):
        view = target_pose(camera, marks, centers, T)
        T = view.T_c_t
        centers[seen] = raw[seen] - perspective_corrections(camera, T, marks.centers_t[seen], marks.normal_t,
                                                            marks.radius_mm)
    return target_pose(camera, marks, centers, T)


_RETRY_MOVED_PX = 2.0  # a missed mark is looked for again when the marks found move its expectation this far


def _measure_marks(image: np.ndarray, camera: CameraModel, marks: TargetMarks, T: np.ndarray, raw: np.ndarray,
                   which: np.ndarray | None, max_offset_px: float | None, max_blur_px: float,
                   reasons: dict[int, str] | None) -> tuple[np.ndarray, np.ndarray]:
    """Measure the marks ``which`` (n,) bool (None: all) that lie wholly in the image where ``T`` projects them,
    each in its own window, into ``raw`` (n, 2) (ellipse centres). ``reasons`` None: the fast path only (a mark
    it does not find is left NaN, unexplained); else :func:`measure_mark` (the full search when the fast path
    fails), and ``reasons`` gets why each mark was not found. Returns the expected centres (n, 2) px and which
    marks were in the image (n,)."""
    pts_c = transform_points(T, marks.centers_t)
    expected = camera.project(pts_c)
    # each mark is searched within 0.45 of the distance to its nearest neighbour in the image: a guess that far
    # off still finds the right mark, never its neighbour
    gaps = np.linalg.norm(expected[:, None, :] - expected[None, :, :], axis=2)
    np.fill_diagonal(gaps, np.inf)
    reach = 0.45 * gaps.min(axis=1) if len(expected) > 1 else np.full(1, np.inf)
    r_px = marks.radius_mm * camera.fx / pts_c[:, 2]
    inside = camera.in_image(expected, margin=r_px + 3.0)  # each mark's own margin
    todo = inside if which is None else inside & which
    options = {"radius_tol": 0.35, "max_blur_px": max_blur_px, "photometric": False}
    for k in np.flatnonzero(todo):
        offset = max_offset_px if max_offset_px else max(float(reach[k]), 1.5 * float(r_px[k]))
        if reasons is None:
            crop, origin = _mark_window(image, expected[k], float(r_px[k]), offset)
            found = _one_mark(crop, (expected[k, 0] - origin[0], expected[k, 1] - origin[1]), float(r_px[k]),
                              offset, **options)
            if found is not None:
                raw[k] = found[0] + origin
            continue
        try:
            raw[k], _ = measure_mark(image, expected[k], float(r_px[k]), offset, **options)
        except FeatureNotFound as exc:
            reasons[int(k)] = f"mark {k + 1}: {exc.code}"
    return expected, inside


def angle_deg_between(T_a: np.ndarray, T_b: np.ndarray) -> float:
    """Rotation angle (deg) between the orientations of two poses."""
    return math.degrees(float(np.linalg.norm(matrix_to_rotvec(T_a[:3, :3].T @ T_b[:3, :3]))))
