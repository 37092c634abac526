"""Sub-pixel hole centres in a camera image: find, select, correct for perspective (Sec. 5.3).

- :func:`find_holes` runs the paper's pipeline (:mod:`monoguide.solver.hole_edges`) on every dark blob
  of plausible size and returns the holes most plausible first.
- :func:`measure_hole` is the cycle's call: the one hole expected near a position with a size, picked
  among clutter, or a typed error (not found, cut by the border, ambiguous, low contrast, saturated).
- :func:`perspective_correction` is the offset from the image of a hole's 3-D centre to the centre of
  its imaged ellipse, which the two differ by under perspective and lens distortion.

Pixels are raw image coordinates: x right, y down, pixel centres at integers.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from monoguide.solver.camera import CameraModel
from monoguide.solver.ellipse import Ellipse, fit_ellipse
from monoguide.solver.errors import (
    FeatureNotFound,
    HoleAmbiguous,
    HoleCutByBorder,
    HoleNotFound,
    ImageSaturated,
    LowContrast,
)
from monoguide.solver.hole_edges import (
    DEFAULT_MIN_CONTRAST_TO_NOISE,
    SATURATION_GREY,
    as_grey,
    measure_rim,
    seed_dark_blobs,
)
from monoguide.solver.rim_fit import refine_ellipse_photometric

DEFAULT_MIN_RADIUS_PX = 6.0
DEFAULT_MAX_RADIUS_PX = 80.0
DEFAULT_RADIUS_TOL = 0.25
_SAME_HOLE_PX = 2.0


@dataclass(frozen=True, eq=False)
class HoleCandidate:
    """One measured hole.

    ``center`` (2,) px the centre of the final ellipse (not perspective-corrected); ``axes`` (2,) its
    semi-axes in px, major first; ``angle_deg`` the major axis from +x toward +y; ``score`` in [0, 1],
    higher is more plausible. The rest describe the measurement: ``contrast`` (grey levels),
    ``edge_width_px`` (blur sigma of the rim), ``rms_px`` (edge points about the ellipse),
    ``n_edge_points``.
    """

    center: np.ndarray
    axes: np.ndarray
    angle_deg: float
    score: float
    contrast: float = 0.0
    edge_width_px: float = 0.0
    rms_px: float = 0.0
    n_edge_points: int = 0

    @property
    def mean_radius(self) -> float:
        """Radius of the circle of the same area, sqrt(a b) px."""
        return math.sqrt(float(self.axes[0] * self.axes[1]))

    def as_dict(self) -> dict[str, object]:
        """The JSON shape of `monoguide detect`: center, axes, angle_deg, score."""
        return {
            "center": [round(float(c), 4) for c in self.center],
            "axes": [round(float(a), 4) for a in self.axes],
            "angle_deg": round(self.angle_deg, 3),
            "score": round(self.score, 4),
        }


@dataclass(frozen=True, eq=False)
class RefusedBlob:
    """A dark blob at ``center`` (2,) px of equivalent radius ``radius_px`` that is not a measurable hole,
    and why (a :class:`FeatureNotFound` subclass whose message names the place)."""

    center: np.ndarray
    radius_px: float
    error: FeatureNotFound


@dataclass(frozen=True)
class HoleScan:
    """Everything one search saw: the holes (most plausible first), the refused dark blobs, the fraction
    of saturated pixels in the search region, and the holes refused for their size (``wrong_size``)."""

    holes: list[HoleCandidate]
    refused: list[RefusedBlob]
    saturated_fraction: float
    wrong_size: list[HoleCandidate] = field(default_factory=list)


def find_holes(
    image: np.ndarray,
    roi: Sequence[int] | None = None,
    expected_center: Sequence[float] | None = None,
    expected_radius_px: float | None = None,
    **options: float | bool,
) -> list[HoleCandidate]:
    """All holes whose centre lies in ``roi`` (x, y, w, h) px (the whole image when None), most
    plausible first. ``expected_center`` (2,) and ``expected_radius_px`` raise the score of holes near
    that place and size. ``options`` go to :func:`scan_holes`. Raises :class:`BadImage` only."""
    return scan_holes(image, roi, expected_center, expected_radius_px, **options).holes


def scan_holes(
    image: np.ndarray,
    roi: Sequence[int] | None = None,
    expected_center: Sequence[float] | None = None,
    expected_radius_px: float | None = None,
    *,
    min_radius_px: float = DEFAULT_MIN_RADIUS_PX,
    max_radius_px: float = DEFAULT_MAX_RADIUS_PX,
    min_contrast: float = 15.0,
    max_blur_px: float = 3.0,
    max_saturated_fraction: float = 0.02,
    photometric: bool = True,
    min_contrast_to_noise: float = DEFAULT_MIN_CONTRAST_TO_NOISE,
    bit_depth: int | None = None,
) -> HoleScan:
    """:func:`find_holes` with the refused blobs: the Sec. 5.3 pipeline on each dark blob near ``roi``.

    A hole is listed when its centre lies in ``roi``; it is measured on the whole image, so a ROI smaller
    than the hole still finds it. Its mean radius must lie in 0.6 .. 1.6 times ``expected_radius_px``
    (without it in ``min_radius_px .. max_radius_px``). A hole is refused when its rim is below
    ``min_contrast`` grey levels or ``min_contrast_to_noise`` times the noise sigma, blurred beyond
    ``max_blur_px`` sigma, or more than ``max_saturated_fraction`` saturated. ``photometric=False`` stops
    at the paper's final ellipse instead of refining it on the grey levels. ``bit_depth``: see
    :func:`~monoguide.solver.hole_edges.as_grey` (grey levels are on the 0-255 scale whatever the depth).
    """
    return _scan_grey(as_grey(image, bit_depth), roi, expected_center, expected_radius_px, min_radius_px,
                      max_radius_px, min_contrast, max_blur_px, max_saturated_fraction, photometric,
                      min_contrast_to_noise)


def measure_hole(
    image: np.ndarray,
    expected_center: Sequence[float],
    expected_radius_px: float,
    roi: Sequence[int] | None = None,
    *,
    max_offset_px: float | None = None,
    radius_tol: float = DEFAULT_RADIUS_TOL,
    min_contrast: float = 15.0,
    max_blur_px: float = 3.0,
    max_saturated_fraction: float = 0.02,
    photometric: bool = True,
    min_contrast_to_noise: float = DEFAULT_MIN_CONTRAST_TO_NOISE,
    bit_depth: int | None = None,
) -> HoleCandidate:
    """The one hole expected at ``expected_center`` (2,) px with radius ``expected_radius_px``.

    Candidates are the holes whose centre lies in ``roi`` (x, y, w, h) (default: a square of
    +-(``max_offset_px`` + 2 r) around the expectation), within ``max_offset_px`` of it (default 3 r),
    and whose mean radius is within ``radius_tol`` of the expected one. Exactly one must remain:
    none raises :class:`HoleNotFound` (or, when the blob that would have been it was refused,
    :class:`HoleCutByBorder`, :class:`LowContrast` or :class:`ImageSaturated`); two or more raise
    :class:`HoleAmbiguous` rather than guess. The other options are :func:`scan_holes`'s; the
    photometric refinement runs on the chosen hole only. ``bit_depth`` is the camera's
    (``bit_depth_of(frame.pixel_format)``): a 12-bit image in a uint16 array has full scale 4095.
    """
    ex, ey = float(expected_center[0]), float(expected_center[1])
    r = float(expected_radius_px)
    max_offset = 3.0 * r if max_offset_px is None else float(max_offset_px)
    if roi is None:
        half = max_offset + 2.0 * r
        roi = (math.floor(ex - half), math.floor(ey - half), int(2 * half) + 2, int(2 * half) + 2)
    where = f"hole expected at ({ex:.1f}, {ey:.1f}) r={r:.1f} px"
    located = _coarse_locate(image, roi, (ex, ey), r, max_offset, radius_tol, min_contrast, max_blur_px,
                             max_saturated_fraction, min_contrast_to_noise, bit_depth)
    if located is not None:  # one hole, found fast; anything else is decided by the full search below
        grey, hole = located
        return _refined(grey, hole) if photometric else hole
    # only the part of the frame the search can reach is made grey, not a 5 MP float copy per hole (docs/cycle.md)
    grey = _grey_window(image, roi, r, bit_depth)
    scan = _scan_grey(grey, roi, (ex, ey), r, DEFAULT_MIN_RADIUS_PX, DEFAULT_MAX_RADIUS_PX, min_contrast,
                      max_blur_px, max_saturated_fraction, False, min_contrast_to_noise)
    plausible = [h for h in scan.holes
                 if abs(h.mean_radius / r - 1.0) <= radius_tol and math.hypot(h.center[0] - ex, h.center[1] - ey)
                 <= max_offset]
    if len(plausible) == 1:
        return _refined(grey, plausible[0]) if photometric else plausible[0]
    if len(plausible) > 1:
        listed = "; ".join(
            f"({h.center[0]:.1f}, {h.center[1]:.1f}) r={h.mean_radius:.1f} score {h.score:.2f}" for h in plausible)
        raise HoleAmbiguous(f"{where}: {len(plausible)} candidates within {max_offset:.0f} px and "
                            f"{100 * radius_tol:.0f} % of the radius: {listed}")
    for blob in scan.refused:  # the refused blob that would have been the hole says why
        near = math.hypot(blob.center[0] - ex, blob.center[1] - ey) <= max_offset + r
        if near and isinstance(blob.error, HoleCutByBorder | LowContrast | ImageSaturated):
            raise type(blob.error)(f"{where}: {blob.error.message}")
    if scan.saturated_fraction > 0.5:
        raise ImageSaturated(f"{where}: {100 * scan.saturated_fraction:.0f} % of the search region is saturated")
    faint = _faint_hole(grey, _roi_box(roi, grey.shape), (ex, ey), r, max_offset)
    if faint is not None and faint[2] < min_contrast:
        raise LowContrast(f"{where}: only a faint dark region at ({faint[0]:.1f}, {faint[1]:.1f}), contrast "
                          f"~{faint[2]:.1f} grey levels < {min_contrast:.1f}")
    seen = ", ".join(f"({h.center[0]:.1f}, {h.center[1]:.1f}) r={h.mean_radius:.1f}"
                     for h in [*scan.holes, *scan.wrong_size][:5])
    raise HoleNotFound(f"{where}: no hole within {max_offset:.0f} px and {100 * radius_tol:.0f} % of the radius"
                       + (f"; seen {seen}" if seen else "; nothing dark of that size in the search region"))


def circle_basis(normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two orthonormal vectors (3,) spanning the plane of a circle whose normal is ``normal`` (any length)."""
    n = np.asarray(normal, dtype=float)
    n = n / np.linalg.norm(n)
    helper = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(n, helper)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(n, e1)


def perspective_correction(
    camera: CameraModel,
    T_c_w: np.ndarray,
    center_w: np.ndarray,
    normal_w: np.ndarray,
    radius_mm: float,
    n_points: int = 360,
) -> np.ndarray:
    """(centre of the imaged ellipse) - (image of the 3-D centre), (2,) px.

    Subtract it from a measured ellipse centre to get the image of the hole's centre. The rim circle
    (``center_w`` (3,), ``normal_w`` (3,) in the part frame, ``T_c_w`` (4, 4) an approximate pose) is
    projected exactly, distortion included, at ``n_points`` points, and the same least-squares ellipse
    as the detector's is fitted to them. Without distortion this is the centre of the projected conic.
    """
    center_w = np.asarray(center_w, dtype=float)
    e1, e2 = circle_basis(normal_w)
    t = np.linspace(0.0, 2.0 * math.pi, n_points, endpoint=False)
    rim_w = center_w + radius_mm * (np.cos(t)[:, None] * e1 + np.sin(t)[:, None] * e2)
    R, tr = T_c_w[:3, :3], T_c_w[:3, 3]
    rim_c = rim_w @ R.T + tr
    if np.any(rim_c[:, 2] <= 0):
        raise ValueError(f"hole at {np.round(center_w, 3).tolist()} mm is not in front of the camera")
    ellipse = fit_ellipse(camera.project(rim_c))
    return ellipse.center - camera.project((R @ center_w + tr)[None, :])[0]


# --- private helpers -----------------------------------------------------------------------------


def _scan_grey(
    grey: np.ndarray,
    roi: Sequence[int] | None,
    expected_center: Sequence[float] | None,
    expected_radius_px: float | None,
    min_radius_px: float,
    max_radius_px: float,
    min_contrast: float,
    max_blur_px: float,
    max_saturated_fraction: float,
    photometric: bool,
    min_contrast_to_noise: float,
) -> HoleScan:
    """:func:`scan_holes` on a grey image (h, w) float32 already converted."""
    box = _roi_box(roi, grey.shape)
    if expected_radius_px is not None:
        if not expected_radius_px > 0:
            raise ValueError(f"expected_radius_px must be positive, got {expected_radius_px}")
        r_min, r_max = 0.6 * expected_radius_px, 1.6 * expected_radius_px
    else:
        r_min, r_max = min_radius_px, max_radius_px
    x0, y0, x1, y1 = box
    saturated = float(np.mean(grey[y0:y1, x0:x1] >= SATURATION_GREY))
    holes: list[HoleCandidate] = []
    wrong_size: list[HoleCandidate] = []
    refused: list[RefusedBlob] = []
    # holes are selected by their centre but measured whole: seek blobs in the ROI grown by a hole
    grow = math.ceil(1.6 * r_max) + 16
    h, w = grey.shape
    search = (max(x0 - grow, 0), max(y0 - grow, 0), min(x1 + grow, w), min(y1 + grow, h))
    for seed in seed_dark_blobs(grey, search, r_min, r_max, min_contrast):
        reach = seed.radius_px + 4.0  # the blob's centroid lies near the hole's centre
        if not (x0 - reach <= seed.center[0] < x1 + reach and y0 - reach <= seed.center[1] < y1 + reach):
            continue
        try:
            rim = measure_rim(grey, seed, min_contrast=min_contrast, max_blur_px=max_blur_px,
                              max_saturated_fraction=max_saturated_fraction, photometric=photometric,
                              min_contrast_to_noise=min_contrast_to_noise)
        except FeatureNotFound as exc:  # kept as its reason: without the traceback, whose frames (this one, with
            # `refused` and the image) would make a cycle that holds them until the garbage collector's next pass
            refused.append(RefusedBlob(center=seed.center, radius_px=seed.radius_px, error=exc.with_traceback(None)))
            continue
        c = rim.ellipse.center
        if not (x0 - 0.5 <= c[0] < x1 - 0.5 and y0 - 0.5 <= c[1] < y1 - 0.5):
            continue
        score = _score(rim.rms_px, rim.valid_fraction, rim.contrast, min_contrast, rim.ellipse.mean_radius,
                       c, expected_center, expected_radius_px)
        hole = HoleCandidate(center=c, axes=rim.ellipse.axes, angle_deg=rim.ellipse.angle_deg, score=score,
                             contrast=rim.contrast, edge_width_px=rim.edge_width_px, rms_px=rim.rms_px,
                             n_edge_points=len(rim.edge_points))
        (holes if r_min <= hole.mean_radius <= r_max else wrong_size).append(hole)
    holes.sort(key=lambda hole: -hole.score)
    unique: list[HoleCandidate] = []
    for hole in holes:  # one hole seen from two seeds (a rim split by glare) is kept once
        if all(np.hypot(*(hole.center - kept.center)) > _SAME_HOLE_PX for kept in unique):
            unique.append(hole)
    return HoleScan(holes=unique, refused=refused, saturated_fraction=saturated, wrong_size=wrong_size)


def _refined(grey: np.ndarray, hole: HoleCandidate) -> HoleCandidate:
    """``hole`` with its ellipse refined on the rim's grey levels (:mod:`monoguide.solver.rim_fit`)."""
    start = Ellipse(center=hole.center, axes=hole.axes, angle_deg=hole.angle_deg)
    fitted, _ = refine_ellipse_photometric(grey, start, hole.edge_width_px, SATURATION_GREY)
    return replace(hole, center=fitted.center, axes=fitted.axes, angle_deg=fitted.angle_deg)


def _faint_hole(
    grey: np.ndarray, box: tuple[int, int, int, int], expected: tuple[float, float], r: float, max_offset: float
) -> tuple[float, float, float] | None:
    """(u, v, contrast) of a dark blob of the expected size too faint for the seeds, or None.

    The threshold is five times the noise (from the spread of neighbouring pixel differences, reduced by
    the seeds' downsampling) instead of a fraction of the sheet's brightness.
    """
    x0, y0, x1, y1 = box
    patch = grey[y0:y1, x0:x1]
    noise = 1.4826 * float(np.median(np.abs(np.diff(patch, axis=1)))) / math.sqrt(2.0)
    f = int(np.clip((0.6 * r) // 3, 1, 4))  # the seeds' downsampling, which averages the noise down
    threshold = 5.0 * max(noise, 0.5) / f
    for seed in seed_dark_blobs(grey, box, 0.6 * r, 1.6 * r, 2.0 * threshold, relative_threshold=0.0):
        if math.hypot(seed.center[0] - expected[0], seed.center[1] - expected[1]) > max_offset + r:
            continue
        reach = int(1.6 * seed.radius_px) + 2
        cu, cv = round(float(seed.center[0])), round(float(seed.center[1]))
        py0, py1 = max(cv - reach, 0), min(cv + reach + 1, grey.shape[0])
        px0, px1 = max(cu - reach, 0), min(cu + reach + 1, grey.shape[1])
        vv, uu = np.mgrid[py0:py1, px0:px1]
        dist = np.hypot(uu - seed.center[0], vv - seed.center[1]) / seed.radius_px
        around = grey[py0:py1, px0:px1]
        inside, outside = around[dist < 0.5], around[(dist > 1.3) & (dist < 1.6)]
        if len(inside) == 0 or len(outside) == 0:
            continue
        contrast = float(np.median(outside) - np.median(inside))
        return float(seed.center[0]), float(seed.center[1]), contrast
    return None


COARSE_RADIUS_PX = 3.0  # the coarse search sees the expected hole at about this radius
COARSE_MIN_ROI_RADII = 12.0  # a ROI narrower than this many hole radii is searched at full resolution at once


def _coarse_locate(
    image: np.ndarray, roi: Sequence[int], expected: tuple[float, float], r: float, max_offset: float,
    radius_tol: float, min_contrast: float, max_blur_px: float, max_saturated_fraction: float,
    min_contrast_to_noise: float, bit_depth: int | None,
) -> tuple[np.ndarray, HoleCandidate] | None:
    """The fast path of :func:`measure_hole` for a large ROI: the dark blobs of the hole's size on a copy
    downsampled to a hole radius of ~``COARSE_RADIUS_PX``, then the full-resolution search (the same
    pipeline, the same pixels) in a small window around each. (grey, hole) when exactly one blob is there
    and it gives exactly one plausible hole whose window is not saturated; else None, and the caller
    searches the whole ROI at full resolution (which also gives every error its reason)."""
    if not isinstance(image, np.ndarray) or image.ndim != 2 or len(roi) != 4:
        return None
    h, w = image.shape
    x, y, rw, rh = (int(v) for v in roi)
    x0, y0, x1, y1 = max(x, 0), max(y, 0), min(x + rw, w), min(y + rh, h)
    f = int(r // COARSE_RADIUS_PX)
    if f < 2 or min(x1 - x0, y1 - y0) < COARSE_MIN_ROI_RADII * r:
        return None
    x1, y1 = x0 + (x1 - x0) // f * f, y0 + (y1 - y0) // f * f  # whole f x f blocks: OpenCV's fast path
    small = cv2.resize(image[y0:y1, x0:x1], ((x1 - x0) // f, (y1 - y0) // f), interpolation=cv2.INTER_AREA)
    small_grey = as_grey(small, bit_depth)
    r_s = r / f
    seeds = [seed for seed in seed_dark_blobs(small_grey, (0, 0, small.shape[1], small.shape[0]), 0.6 * r_s,
                                              1.6 * r_s, min_contrast)
             if 0.5 * r <= seed.radius_px * f <= 1.6 * r]
    if len(seeds) != 1:
        return None
    cx, cy = seeds[0].center * f + (f - 1) / 2.0 + np.array([x0, y0])
    if math.hypot(cx - expected[0], cy - expected[1]) > max_offset + r:
        return None
    half = 1.6 * r + 2 * f + 8
    window = (math.floor(cx - half), math.floor(cy - half), int(2 * half) + 2, int(2 * half) + 2)
    window = (max(window[0], x0), max(window[1], y0), min(window[0] + window[2], x1) - max(window[0], x0),
              min(window[1] + window[3], y1) - max(window[1], y0))
    if window[2] < 4 or window[3] < 4:
        return None
    grey = _grey_window(image, window, r, bit_depth)
    scan = _scan_grey(grey, window, expected, r, DEFAULT_MIN_RADIUS_PX, DEFAULT_MAX_RADIUS_PX, min_contrast,
                      max_blur_px, max_saturated_fraction, False, min_contrast_to_noise)
    plausible = [hole for hole in scan.holes
                 if abs(hole.mean_radius / r - 1.0) <= radius_tol
                 and math.hypot(hole.center[0] - expected[0], hole.center[1] - expected[1]) <= max_offset]
    if len(plausible) != 1 or scan.refused or scan.saturated_fraction > max_saturated_fraction:
        return None
    return grey, plausible[0]


def reach(shape: tuple[int, ...], roi: Sequence[int], r: float) -> tuple[int, int, int, int]:
    """(x0, y0, x1, y1): the part of an image of ``shape`` that :func:`measure_hole` can look at for a hole of radius
    ``r`` px sought in ``roi`` (x, y, w, h): the ROI grown by three times the blob search's own growth, clipped. A crop
    of it, with the crop's origin taken off ``roi`` and the expected centre, finds the same hole at the same centre
    (less that origin) without the frame-sized arrays."""
    h, w = shape[:2]
    grow = 3 * (math.ceil(1.6 * 1.6 * r) + 16)
    x, y, rw, rh = (int(v) for v in roi)
    return max(x - grow, 0), max(y - grow, 0), min(x + rw + grow, w), min(y + rh + grow, h)


def _grey_window(image: np.ndarray, roi: Sequence[int], r: float, bit_depth: int | None) -> np.ndarray:
    """:func:`as_grey` of only the part of ``image`` that :func:`measure_hole` can look at for a hole of radius
    ``r`` centred in ``roi``: the ROI grown by three times the blob search's own growth (a hole found there is
    measured whole inside it). The array keeps the frame's size and pixel coordinates; the rest is zeros that
    are never touched (calloc'd pages cost no memory). The whole image when the window would be most of it."""
    if not isinstance(image, np.ndarray) or image.ndim < 2 or len(roi) != 4:
        return as_grey(image, bit_depth)
    h, w = image.shape[:2]
    x0, y0, x1, y1 = reach(image.shape, roi, r)
    if x1 - x0 < 8 or y1 - y0 < 8 or (x1 - x0) * (y1 - y0) > 0.8 * w * h:
        return as_grey(image, bit_depth)
    grey = np.zeros((h, w), dtype=np.float32)
    grey[y0:y1, x0:x1] = as_grey(image[y0:y1, x0:x1], bit_depth)
    return grey


def _roi_box(roi: Sequence[int] | None, shape: tuple[int, ...]) -> tuple[int, int, int, int]:
    """ROI (x, y, w, h) -> (x0, y0, x1, y1) clipped to the image; raises if nothing is left."""
    h, w = shape[:2]
    if roi is None:
        return 0, 0, w, h
    if len(roi) != 4:
        raise ValueError(f"roi must be (x, y, w, h), got {tuple(roi)}")
    x, y, rw, rh = (int(v) for v in roi)
    box = (max(x, 0), max(y, 0), min(x + rw, w), min(y + rh, h))
    if box[2] - box[0] < 4 or box[3] - box[1] < 4:
        raise ValueError(f"roi {tuple(roi)} leaves less than 4 x 4 px of the {w} x {h} image")
    return box


def _score(
    rms_px: float,
    valid_fraction: float,
    contrast: float,
    min_contrast: float,
    radius: float,
    center: np.ndarray,
    expected_center: Sequence[float] | None,
    expected_radius: float | None,
) -> float:
    """Plausibility in [0, 1]: a clean elliptic rim with contrast, near the expected place and size."""
    score = math.exp(-((rms_px / 0.3) ** 2)) * valid_fraction * min(1.0, contrast / (3.0 * min_contrast))
    if expected_radius is not None:
        score *= math.exp(-0.5 * ((radius / expected_radius - 1.0) / 0.15) ** 2)
    if expected_center is not None:
        scale = 3.0 * (expected_radius if expected_radius is not None else radius)
        d = math.hypot(center[0] - expected_center[0], center[1] - expected_center[1])
        score *= math.exp(-0.5 * (d / scale) ** 2)
    return float(score)
