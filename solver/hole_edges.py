"""The sub-pixel rim of a dark hole on bright sheet: the image processing of Sec. 5.3 (Fig. 7).

Two stages. :func:`seed_dark_blobs` finds where holes may be: dark blobs against a background
estimated by grey-level closing (so uneven light and glare do not move the threshold), on a
downsampled copy for speed. :func:`measure_rim` then runs the paper's pipeline at full resolution
in a window around one seed: threshold and morphology, the connected region of the hole, its one-pixel
edge by erosion, a least-squares ellipse for the initial centre, the grey-level gradient along the ray
from that centre through each edge pixel, the sub-pixel edge point by the gradient's centre of gravity,
and a final least-squares ellipse.

Failures are the typed errors of :mod:`monoguide.solver.errors`; each names the place and the value.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import cv2
import numpy as np

from monoguide.solver.ellipse import Ellipse, fit_ellipse
from monoguide.solver.errors import (
    BadImage,
    FeatureNotFound,
    HoleCutByBorder,
    HoleNotFound,
    ImageSaturated,
    LowContrast,
)
from monoguide.solver.rim_fit import refine_ellipse_photometric

SATURATION_GREY = 254.5
"""Grey value (0-255 scale) at or above which a pixel counts as saturated."""

DEFAULT_MIN_CONTRAST_TO_NOISE = 5.0
"""A hole's rim contrast must be at least this many times the sensor noise sigma: in a frame of pure noise,
dark blobs of a hole's size reach 3-4 sigma."""

DEFAULT_MAX_RIM_RMS_PX = 0.6
"""A hole's sub-pixel edge points lie on an ellipse within this RMS (a clean rim: 0.02-0.2 px)."""

_RAY_STEP_PX = 0.5
_GRAVITY_FLOOR = 0.2  # fraction of the gradient peak below which samples do not vote (noise)
_SQRT_2PI = math.sqrt(2.0 * math.pi)
_BIT_DEPTHS = range(8, 17)
_MONO_FORMAT = re.compile(r"Mono(\d+)(?:p|Packed)?")


@dataclass(frozen=True)
class Seed:
    """Where a hole may be: centre (2,) and the radius of a disc of the blob's area, full-resolution px."""

    center: np.ndarray
    radius_px: float
    box: tuple[int, int, int, int]  # x0, y0, x1, y1 (exclusive ends), full-resolution px


@dataclass(frozen=True, eq=False)
class RimMeasurement:
    """The result of the Sec. 5.3 pipeline for one hole.

    ``ellipse`` the final fit; ``paper`` the final least-squares ellipse of Sec. 5.3 (the same as
    ``ellipse`` unless refined photometrically); ``initial`` the fit to the one-pixel edge; ``edge_points`` (n, 2) the
    sub-pixel rim points used; ``rms_px`` their RMS distance from ``ellipse``; ``contrast`` sheet minus
    hole grey level; ``edge_width_px`` the Gaussian sigma of the rim's grey-level profile (blur);
    ``saturated_fraction`` of the pixels near the rim; ``valid_fraction`` of the rays that gave a point.
    """

    ellipse: Ellipse
    paper: Ellipse
    initial: Ellipse
    edge_points: np.ndarray
    rms_px: float
    contrast: float
    edge_width_px: float
    saturated_fraction: float
    valid_fraction: float


def as_grey(image: np.ndarray, bit_depth: int | None = None) -> np.ndarray:
    """Any supported camera image -> grey (h, w) float32 on the 0-255 scale.

    Accepts (h, w), (h, w, 1), (h, w, 3) BGR and (h, w, 4) BGRA arrays of uint8 or uint16. ``bit_depth``
    is the number of significant bits of the data (the camera's pixel format: Mono10 -> 10, see
    :func:`bit_depth_of`): full scale ``2**bit_depth - 1`` maps to 255. Without it uint8 is 8 bits and
    uint16 is 16 bits (65535 -> 255). uint16 values above ``2**bit_depth - 1`` are refused (the data
    are not what the bit depth says, e.g. MSB-aligned), as is anything else with :class:`BadImage`.
    """
    if not isinstance(image, np.ndarray):
        raise BadImage(f"image must be a numpy array, got {type(image).__name__}")
    if image.dtype not in (np.uint8, np.uint16):
        raise BadImage(f"image dtype must be uint8 or uint16, got {image.dtype}")
    if image.ndim == 3 and image.shape[2] in (1, 3, 4):
        channels = image.shape[2]
    elif image.ndim == 2:
        channels = 1
    else:
        raise BadImage(f"image must be (h, w), (h, w, 3) or (h, w, 4), got shape {image.shape}")
    if image.shape[0] < 8 or image.shape[1] < 8:
        raise BadImage(f"image of shape {image.shape} is empty or too small (8 x 8 px at least)")
    full_scale = _full_scale(image, bit_depth)
    grey = image.reshape(image.shape[0], image.shape[1], channels)[:, :, : min(channels, 3)]
    grey = grey.astype(np.float32)
    grey = cv2.cvtColor(np.ascontiguousarray(grey), cv2.COLOR_BGR2GRAY) if channels >= 3 else grey[:, :, 0]
    if full_scale != 255:
        grey *= np.float32(255.0 / full_scale)
    return np.ascontiguousarray(grey)


def bit_depth_of(pixel_format: str) -> int:
    """Significant bits per pixel of a GenICam mono pixel format (``Frame.pixel_format``): Mono8 -> 8,
    Mono10 / Mono10p -> 10, Mono12 / Mono12p -> 12, Mono14 -> 14, Mono16 -> 16. Others raise
    :class:`BadImage` naming the format."""
    match = _MONO_FORMAT.fullmatch(pixel_format)
    if match is None or int(match.group(1)) not in _BIT_DEPTHS:
        raise BadImage(f"pixel format {pixel_format!r}: expected a mono format, one of Mono8, Mono10, Mono12, "
                       f"Mono14, Mono16")
    return int(match.group(1))


def seed_dark_blobs(
    grey: np.ndarray,
    box: tuple[int, int, int, int],
    r_min: float,
    r_max: float,
    min_contrast: float,
    relative_threshold: float = 0.2,
) -> list[Seed]:
    """Dark blobs of equivalent radius ``r_min / 2 .. 1.5 r_max`` px inside ``box`` (x0, y0, x1, y1).

    The background is the grey-level closing of the image with a square larger than the largest hole
    (the "morphology" of Sec. 5.3), computed on a coarse copy; a pixel is dark when it lies more than
    ``max(min_contrast / 2, relative_threshold * background)`` below it.
    """
    x0, y0, x1, y1 = box
    crop = grey[y0:y1, x0:x1]
    f = int(np.clip(r_min // 3, 1, 4))
    small = crop if f == 1 else cv2.resize(crop, (crop.shape[1] // f, crop.shape[0] // f),
                                           interpolation=cv2.INTER_AREA)
    fb = max(f, math.ceil(r_max / 10.0))  # the background needs no detail: a coarser copy
    coarse = small if fb == f else cv2.resize(crop, (max(crop.shape[1] // fb, 1), max(crop.shape[0] // fb, 1)),
                                              interpolation=cv2.INTER_AREA)
    k = 2 * math.ceil(1.3 * r_max / fb) + 1
    background = cv2.morphologyEx(coarse, cv2.MORPH_CLOSE, cv2.getStructuringElement(cv2.MORPH_RECT, (k, k)),
                                  borderType=cv2.BORDER_REPLICATE)
    if background.shape != small.shape:
        background = cv2.resize(background, (small.shape[1], small.shape[0]), interpolation=cv2.INTER_LINEAR)
    darkness = background - small
    threshold = np.maximum(np.float32(0.5 * min_contrast), np.float32(relative_threshold) * background)
    mask = (darkness > threshold).astype(np.uint8)
    n, _, stats, centroids = cv2.connectedComponentsWithStats(mask, connectivity=8)
    seeds = []
    for i in range(1, n):
        r_eq = math.sqrt(stats[i, cv2.CC_STAT_AREA] / math.pi) * f
        if not 0.5 * r_min <= r_eq <= 1.5 * r_max:
            continue
        bx, by = stats[i, cv2.CC_STAT_LEFT] * f + x0, stats[i, cv2.CC_STAT_TOP] * f + y0
        bw, bh = stats[i, cv2.CC_STAT_WIDTH] * f, stats[i, cv2.CC_STAT_HEIGHT] * f
        center = centroids[i] * f + (f - 1) / 2.0 + np.array([x0, y0])
        seeds.append(Seed(center=center, radius_px=r_eq, box=(bx, by, bx + bw, by + bh)))
    return seeds


def measure_rim(
    grey: np.ndarray,
    seed: Seed,
    min_contrast: float = 15.0,
    max_blur_px: float = 3.0,
    max_saturated_fraction: float = 0.02,
    photometric: bool = True,
    min_contrast_to_noise: float = DEFAULT_MIN_CONTRAST_TO_NOISE,
    max_rim_rms_px: float = DEFAULT_MAX_RIM_RMS_PX,
) -> RimMeasurement:
    """Run the Sec. 5.3 pipeline on the hole at ``seed`` in ``grey`` (h, w) float32; with ``photometric``
    refine its ellipse on the rim's grey levels (:mod:`monoguide.solver.rim_fit`).

    The rim's contrast must reach ``min_contrast_to_noise`` times the sensor noise sigma around the hole
    (:func:`noise_sigma`; below it, noise alone makes such blobs) and ``min_contrast`` grey levels, and
    its sub-pixel edge points must lie on an ellipse within ``max_rim_rms_px`` RMS: a dark patch of noise
    is no hole.

    Raises :class:`HoleCutByBorder`, :class:`ImageSaturated`, :class:`LowContrast` or
    :class:`HoleNotFound` (the dark region is no hole: it runs away, or no ellipse fits it).
    """
    where = f"dark region at ({seed.center[0]:.1f}, {seed.center[1]:.1f}) r~{seed.radius_px:.1f} px"
    region, origin = _hole_region(grey, seed, where)
    edge_yx = np.argwhere(region & ~cv2.erode(region.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool))
    edge_px = edge_yx[:, ::-1].astype(float) + origin
    try:
        initial = fit_ellipse(edge_px)
    except FeatureNotFound as exc:
        raise HoleNotFound(f"{where}: {exc.message}") from exc
    if initial.axes[0] > 3.0 * initial.axes[1]:
        raise HoleNotFound(f"{where}: elongated ({initial.axes[0]:.1f} x {initial.axes[1]:.1f} px), not a hole")
    contrast, saturated = _rim_photometry(grey, initial)
    if saturated > max_saturated_fraction:
        raise ImageSaturated(f"{where}: {100 * saturated:.0f} % of the pixels around the rim are saturated "
                             f"(limit {100 * max_saturated_fraction:.0f} %)")
    noise = noise_sigma(grey, _around(initial, grey.shape))
    if contrast < min_contrast_to_noise * noise:  # what noise alone makes somewhere in a frame
        raise HoleNotFound(f"{where}: contrast {contrast:.1f} grey levels is only {contrast / noise:.1f} times the "
                           f"noise sigma {noise:.1f} (< {min_contrast_to_noise:g}): noise, not a hole")
    if contrast < min_contrast:
        raise LowContrast(f"{where}: contrast {contrast:.1f} grey levels < {min_contrast:.1f}")
    reach = min(max(5.0, 3.0 * max_blur_px + 1.0), 0.7 * float(initial.axes[1]))
    points, widths, valid = _gravity_edge_points(grey, edge_px, initial.center, reach)
    if valid.sum() < max(12, 0.5 * len(valid)):
        raise LowContrast(f"{where}: only {int(valid.sum())} of {len(valid)} rays found a rim gradient")
    edge_width = float(np.median(widths[valid]))
    if edge_width > max_blur_px:
        raise LowContrast(f"{where}: rim blurred over sigma {edge_width:.2f} px > {max_blur_px:.2f} px")
    points = points[valid]
    residual = initial.distances(points)
    residual -= np.median(residual)
    mad = 1.4826 * float(np.median(np.abs(residual)))
    keep = np.abs(residual) <= max(0.5, 4.0 * mad)
    try:
        final = fit_ellipse(points[keep])
    except FeatureNotFound as exc:
        raise HoleNotFound(f"{where}: {exc.message}") from exc
    rms = float(np.sqrt(np.mean(final.distances(points[keep]) ** 2)))
    if rms > max_rim_rms_px:
        raise HoleNotFound(f"{where}: the rim is no ellipse (edge points {rms:.2f} px RMS off it > "
                           f"{max_rim_rms_px:.2f} px)")
    paper = final
    if photometric:
        final, _ = refine_ellipse_photometric(grey, paper, edge_width, SATURATION_GREY)
    return RimMeasurement(ellipse=final, paper=paper, initial=initial, edge_points=points[keep], rms_px=rms,
                          contrast=contrast, edge_width_px=edge_width, saturated_fraction=saturated,
                          valid_fraction=float(keep.sum()) / len(valid))


def noise_sigma(grey: np.ndarray, box: tuple[int, int, int, int]) -> float:
    """Sensor noise sigma (grey levels) in ``box`` (x0, y0, x1, y1): the robust spread of neighbouring
    pixel differences, which edges and slow light changes hardly touch; at least 0.5 (quantisation)."""
    x0, y0, x1, y1 = box
    patch = grey[y0:y1, x0:x1]
    if patch.shape[1] < 2:
        return 0.5
    spread = 1.4826 * float(np.median(np.abs(np.diff(patch, axis=1)))) / math.sqrt(2.0)
    return max(spread, 0.5)


# --- private helpers -----------------------------------------------------------------------------


def _full_scale(image: np.ndarray, bit_depth: int | None) -> int:
    """The grey value of full scale of ``image`` with ``bit_depth`` significant bits (None: its dtype's)."""
    if bit_depth is None:
        return 255 if image.dtype == np.uint8 else 65535
    if isinstance(bit_depth, bool) or int(bit_depth) != bit_depth or int(bit_depth) not in _BIT_DEPTHS:
        raise BadImage(f"bit depth {bit_depth!r}: expected an integer 8..16")
    if image.dtype == np.uint8:
        if bit_depth != 8:
            raise BadImage(f"an 8-bit image cannot hold {bit_depth}-bit data")
        return 255
    full_scale = 2 ** int(bit_depth) - 1
    top = int(image.max())
    if top > full_scale:
        raise BadImage(f"a value of {top} in a {bit_depth}-bit image (full scale {full_scale}): the data are "
                       f"not {bit_depth}-bit (MSB-aligned? then they are 16-bit)")
    return full_scale


def _hole_region(grey: np.ndarray, seed: Seed, where: str) -> tuple[np.ndarray, np.ndarray]:
    """The filled connected region of the hole (bool window) and the window's origin (2,) px.

    Otsu threshold in a window around the seed, opening against noise, the component under the seed.
    The window grows when the region reaches its border; a region reaching the image border is cut.
    """
    h, w = grey.shape
    margin = max(8.0, 0.6 * seed.radius_px)
    for _ in range(3):
        x0, y0 = max(int(seed.box[0] - margin), 0), max(int(seed.box[1] - margin), 0)
        x1, y1 = min(int(seed.box[2] + margin) + 1, w), min(int(seed.box[3] + margin) + 1, h)
        window = cv2.convertScaleAbs(cv2.max(grey[y0:y1, x0:x1], 0.0))
        _, dark = cv2.threshold(window, 0, 1, cv2.THRESH_BINARY_INV | cv2.THRESH_OTSU)
        dark = cv2.morphologyEx(dark, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
        n, labels, stats, centroids = cv2.connectedComponentsWithStats(dark, connectivity=8)
        if n < 2:
            raise HoleNotFound(f"{where}: nothing dark left after threshold and opening")
        cu, cv_ = round(seed.center[0]) - x0, round(seed.center[1]) - y0
        label = int(labels[min(max(cv_, 0), y1 - y0 - 1), min(max(cu, 0), x1 - x0 - 1)])
        if label == 0:  # the seed's centre fell on a bright speck: take the nearest sizeable component
            d = np.hypot(centroids[1:, 0] - cu, centroids[1:, 1] - cv_)
            d[stats[1:, cv2.CC_STAT_AREA] < 0.3 * math.pi * seed.radius_px**2] = np.inf
            if not np.isfinite(d.min()):
                raise HoleNotFound(f"{where}: no dark component under the seed after thresholding")
            label = int(np.argmin(d)) + 1
        left, top = stats[label, cv2.CC_STAT_LEFT], stats[label, cv2.CC_STAT_TOP]
        right, bottom = left + stats[label, cv2.CC_STAT_WIDTH], top + stats[label, cv2.CC_STAT_HEIGHT]
        at_image_border = (left + x0 == 0 or top + y0 == 0 or right + x0 == w or bottom + y0 == h)
        at_window_border = left == 0 or top == 0 or right == x1 - x0 or bottom == y1 - y0
        if at_image_border:
            raise HoleCutByBorder(f"{where}: the dark region touches the image border "
                                  f"(box x {left + x0}..{right + x0 - 1}, y {top + y0}..{bottom + y0 - 1})")
        if not at_window_border:
            break
        margin *= 2.5
    else:
        raise HoleNotFound(f"{where}: the dark region runs on past {margin:.0f} px (part edge or merged holes)")
    region = (labels == label).astype(np.uint8)
    contours, _ = cv2.findContours(region, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    filled = np.zeros_like(region)
    cv2.drawContours(filled, contours, -1, 1, thickness=cv2.FILLED)
    return filled.astype(bool), np.array([x0, y0], dtype=float)


def _around(ellipse: Ellipse, shape: tuple[int, ...]) -> tuple[int, int, int, int]:
    """A box (x0, y0, x1, y1) holding ``ellipse`` and a margin of sheet around it, clipped to ``shape``."""
    reach = float(ellipse.axes[0]) * 1.5 + 8.0
    h, w = shape[:2]
    x0, y0 = max(int(ellipse.center[0] - reach), 0), max(int(ellipse.center[1] - reach), 0)
    return x0, y0, min(int(ellipse.center[0] + reach) + 2, w), min(int(ellipse.center[1] + reach) + 2, h)


def _rim_photometry(grey: np.ndarray, ellipse: Ellipse) -> tuple[float, float]:
    """(sheet minus hole grey level, fraction of saturated pixels within 5 px of the rim)."""
    h, w = grey.shape
    a = float(ellipse.axes[0])
    b = float(ellipse.axes[1])
    outer = a + 4.0 + max(4.0, 0.3 * a)
    x0, y0 = max(int(ellipse.center[0] - outer), 0), max(int(ellipse.center[1] - outer), 0)
    x1, y1 = min(int(ellipse.center[0] + outer) + 2, w), min(int(ellipse.center[1] + outer) + 2, h)
    vv, uu = np.mgrid[y0:y1, x0:x1]
    dist = ellipse.distances(np.stack([uu.ravel(), vv.ravel()], axis=1).astype(float)).reshape(uu.shape)
    patch = grey[y0:y1, x0:x1]
    inside = patch[dist < -min(4.0, 0.4 * b)]
    outside = patch[(dist > 4.0) & (dist < outer - a)]
    near = patch[np.abs(dist) < 5.0]
    if len(inside) == 0 or len(outside) == 0 or len(near) == 0:
        return 0.0, 0.0
    saturated = float(np.mean(near >= SATURATION_GREY))
    return float(np.median(outside) - np.median(inside)), saturated


def _gravity_edge_points(
    grey: np.ndarray, edge_px: np.ndarray, center: np.ndarray, reach: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sub-pixel rim points along rays from ``center`` through each edge pixel (Sec. 5.3, Fig. 7c-d).

    The grey level is sampled bilinearly every ``_RAY_STEP_PX`` within +-``reach`` px of the edge pixel;
    the edge point is the centre of gravity of the positive gradient above ``_GRAVITY_FLOOR`` of its
    peak, over the run of samples around the peak. Returns points (n, 2), the profile's Gaussian sigma
    (n,) px from peak gradient and step height, and a validity mask (n,).
    """
    directions = edge_px - center
    norm = np.linalg.norm(directions, axis=1, keepdims=True)
    directions = directions / np.maximum(norm, 1e-9)
    t = np.arange(-reach, reach + 1e-9, _RAY_STEP_PX)
    samples = edge_px[:, None, :] + t[None, :, None] * directions[:, None, :]
    profile = _bilinear(grey, samples)
    grad = np.zeros_like(profile)
    grad[:, 1:-1] = (profile[:, 2:] - profile[:, :-2]) / (2.0 * _RAY_STEP_PX)
    m = len(t)
    peak_idx = np.argmax(grad, axis=1)
    peak = grad[np.arange(len(grad)), peak_idx]
    floor = _GRAVITY_FLOOR * peak
    idx = np.arange(m)[None, :]
    below = grad <= floor[:, None]
    left = np.where(below & (idx < peak_idx[:, None]), idx, -1).max(axis=1)
    right = np.where(below & (idx > peak_idx[:, None]), idx, m).min(axis=1)
    run = (idx > left[:, None]) & (idx < right[:, None])
    weight = np.where(run, grad - floor[:, None], 0.0)
    total = weight.sum(axis=1)
    offset = (weight * t[None, :]).sum(axis=1) / np.maximum(total, 1e-12)
    step = profile[:, -1] - profile[:, 0]
    sigma = step / np.maximum(peak, 1e-9) / _SQRT_2PI
    valid = (left >= 0) & (right < m) & (peak > 0) & (step > 0)
    valid &= peak > 0.3 * np.median(peak[valid]) if valid.any() else valid
    return edge_px + offset[:, None] * directions, sigma, valid


def _bilinear(grey: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Bilinear interpolation of ``grey`` (h, w) at ``points`` (..., 2) (x, y), clamped to the image."""
    h, w = grey.shape
    x = np.clip(points[..., 0], 0.0, w - 1.000001)
    y = np.clip(points[..., 1], 0.0, h - 1.000001)
    xi = x.astype(np.intp)
    yi = y.astype(np.intp)
    fx = x - xi
    fy = y - yi
    top = grey[yi, xi] * (1.0 - fx) + grey[yi, xi + 1] * fx
    bottom = grey[yi + 1, xi] * (1.0 - fx) + grey[yi + 1, xi + 1] * fx
    return top * (1.0 - fy) + bottom * fy
