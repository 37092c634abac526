"""Renders calibration targets with exact ground truth (issue 12): a plate of circular marks for the camera's
intrinsics (Zhang) and a target's circular marks for the measuring-pose frames (Eq. 6).

Dark discs on a bright flat board, seen from ``T_c_t`` through :class:`CameraModel` (distortion included).
Anti-aliasing: each pixel near a rim is supersampled (``supersample``² sub-pixels, each back-projected to the
board's plane and tested against the circle), pixels far from the rims take their centre's value. Then a
Gaussian blur (lens and pixel), Gaussian grey noise and 8-bit quantisation, from a seeded generator.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from monoguide.solver.camera import CameraModel
from monoguide.solver.frames import compose, invert, make_T, rotvec_to_matrix, transform_points

_BBOX_MARGIN_PX = 3


@dataclass(frozen=True)
class TargetRenderSettings:
    """Photometry: board, mark and background grey levels (0-255), blur sigma (px), noise sigma (grey levels),
    sub-pixels per pixel side near rims."""

    board_grey: float = 200.0
    mark_grey: float = 35.0
    background_grey: float = 70.0
    blur_sigma_px: float = 0.8
    noise_sigma: float = 2.0
    supersample: int = 4


@dataclass
class RenderedTarget:
    """``image`` (height, width) uint8; ``centers_px`` (n, 2) the exact projections of the marks' 3-D centres;
    ``in_view`` (n,) True when the mark lies wholly inside the image and in front of the camera."""

    image: np.ndarray
    centers_px: np.ndarray
    in_view: np.ndarray


def render_target(camera: CameraModel, T_c_t: np.ndarray, centers_t: np.ndarray, radius_mm: float,
                  rng: np.random.Generator, settings: TargetRenderSettings | None = None,
                  board_t: np.ndarray | None = None) -> RenderedTarget:
    """Image of marks ``centers_t`` (n, 3) mm (on the board plane z = 0 of the target frame) of ``radius_mm``,
    seen from ``T_c_t`` (the target in the camera frame). ``board_t`` (m, 3) is the board's outline polygon in
    the target frame (default: the marks' bounding box plus two radii); outside it the background shows."""
    s = settings or TargetRenderSettings()
    T_c_t = np.asarray(T_c_t, dtype=float)
    centers_t = np.asarray(centers_t, dtype=float).reshape(-1, 3)
    h, w = camera.height, camera.width
    image = np.full((h, w), s.background_grey, dtype=np.float32)
    if board_t is None:
        lo, hi = centers_t.min(axis=0) - 2.5 * radius_mm, centers_t.max(axis=0) + 2.5 * radius_mm
        board_t = np.array([[lo[0], lo[1], 0.0], [hi[0], lo[1], 0.0], [hi[0], hi[1], 0.0], [lo[0], hi[1], 0.0]])
    _fill_board(image, camera, T_c_t, np.asarray(board_t, dtype=float), s)
    n_c = T_c_t[:3, :3] @ np.array([0.0, 0.0, 1.0])
    o_c = T_c_t[:3, 3]
    pts_c = transform_points(T_c_t, centers_t)
    centers_px = np.full((len(centers_t), 2), np.nan)
    in_view = np.zeros(len(centers_t), dtype=bool)
    front = pts_c[:, 2] > 1.0
    centers_px[front] = camera.project(pts_c[front])
    t = np.linspace(0.0, 2.0 * math.pi, 64, endpoint=False)
    circle = np.column_stack([np.cos(t), np.sin(t), np.zeros_like(t)]) * radius_mm
    for k, c_t in enumerate(centers_t):
        rim_c = transform_points(T_c_t, c_t + circle)
        if np.any(rim_c[:, 2] <= 1.0):
            continue
        rim_px = camera.project(rim_c)
        in_view[k] = bool(np.all(camera.in_image(rim_px)))
        x0, y0 = np.floor(rim_px.min(axis=0)).astype(int) - _BBOX_MARGIN_PX
        x1, y1 = np.ceil(rim_px.max(axis=0)).astype(int) + _BBOX_MARGIN_PX
        x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, w - 1), min(y1, h - 1)
        if x1 < x0 or y1 < y0:
            continue
        cov = _coverage(camera, pts_c[k], n_c, o_c, radius_mm, x0, y0, x1, y1, s.supersample)
        patch = image[y0:y1 + 1, x0:x1 + 1]
        patch += (s.mark_grey - patch) * cov.astype(np.float32)
    if s.blur_sigma_px > 0:
        image = cv2.GaussianBlur(image, (0, 0), s.blur_sigma_px)
    if s.noise_sigma > 0:
        image += rng.standard_normal(image.shape, dtype=np.float32) * np.float32(s.noise_sigma)
    out = np.clip(np.rint(image), 0, 255).astype(np.uint8)
    return RenderedTarget(out, centers_px, in_view & front)


def _plane_hits(camera: CameraModel, px: np.ndarray, n_c: np.ndarray, o_c: np.ndarray) -> np.ndarray:
    xy = _undistort(camera, px)
    rays = np.column_stack([xy, np.ones(len(xy))])
    s = float(n_c @ o_c) / (rays @ n_c)
    return rays * s[:, None]


def _undistort(camera: CameraModel, px: np.ndarray) -> np.ndarray:
    """Raw pixels -> ideal normalised coordinates: OpenCV's fixed-point iteration (C++), then one Newton step of
    the project's model with the 2 × 2 inverse written out (numpy's batched solve is ten times slower here)."""
    pts = np.ascontiguousarray(px, dtype=np.float64).reshape(-1, 1, 2)
    criteria = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 20, 1e-12)
    xy = cv2.undistortPoints(pts, camera.K, camera.dist_coeffs, None, None, None, criteria).reshape(-1, 2)
    target = np.column_stack([(px[:, 0] - camera.cx) / camera.fx, (px[:, 1] - camera.cy) / camera.fy])
    err = camera.distort(xy) - target
    J = camera.distort_jacobian(xy)
    det = J[:, 0, 0] * J[:, 1, 1] - J[:, 0, 1] * J[:, 1, 0]
    dx = (J[:, 1, 1] * err[:, 0] - J[:, 0, 1] * err[:, 1]) / det
    dy = (-J[:, 1, 0] * err[:, 0] + J[:, 0, 0] * err[:, 1]) / det
    return xy - np.column_stack([dx, dy])


def _coverage(camera: CameraModel, c_c: np.ndarray, n_c: np.ndarray, o_c: np.ndarray, r: float,
              x0: int, y0: int, x1: int, y1: int, ss: int) -> np.ndarray:
    """Fraction of each pixel of the box inside the circle (centre ``c_c`` in the camera frame, plane normal
    ``n_c`` through ``o_c``), (y1 - y0 + 1, x1 - x0 + 1)."""
    xs, ys = np.arange(x0, x1 + 1, dtype=float), np.arange(y0, y1 + 1, dtype=float)
    gx, gy = np.meshgrid(xs, ys)
    hits = _plane_hits(camera, np.column_stack([gx.ravel(), gy.ravel()]), n_c, o_c).reshape(*gx.shape, 3)
    d = np.linalg.norm(hits - c_c, axis=2)
    # local size of a pixel on the board (mm): the larger of the steps to the neighbours
    step = np.maximum(np.linalg.norm(np.gradient(hits, axis=1), axis=2), np.linalg.norm(np.gradient(hits, axis=0),
                                                                                           axis=2))
    cov = (d < r).astype(float)
    band = np.abs(d - r) < 1.0 * step + 1e-9
    if np.any(band):
        by, bx = np.nonzero(band)
        off = (np.arange(ss) + 0.5) / ss - 0.5
        ox, oy = np.meshgrid(off, off)
        sub = np.column_stack([(bx[:, None] + x0 + ox.ravel()[None, :]).ravel(),
                               (by[:, None] + y0 + oy.ravel()[None, :]).ravel()])
        sub_hits = _plane_hits(camera, sub, n_c, o_c)
        inside = (np.linalg.norm(sub_hits - c_c, axis=1) < r).reshape(len(bx), ss * ss)
        cov[by, bx] = inside.mean(axis=1)
    return cov


def _fill_board(image: np.ndarray, camera: CameraModel, T_c_t: np.ndarray, board_t: np.ndarray,
                s: TargetRenderSettings) -> None:
    """The board's polygon (edges sampled densely so distortion bends them), anti-aliased."""
    edges = []
    for a, b in zip(board_t, np.roll(board_t, -1, axis=0), strict=True):
        f = np.linspace(0.0, 1.0, 40, endpoint=False)[:, None]
        edges.append(a + f * (b - a))
    outline_c = transform_points(T_c_t, np.vstack(edges))
    if np.any(outline_c[:, 2] <= 1.0):
        image[:] = s.board_grey  # the board fills the view (approximation for boards passing the camera)
        return
    px = camera.project(outline_c)
    mask = np.zeros(image.shape, dtype=np.uint8)
    shift = 4
    poly = np.round(px * (1 << shift)).astype(np.int32).reshape(-1, 1, 2)
    cv2.fillPoly(mask, [poly], 255, cv2.LINE_AA, shift)
    image += (s.board_grey - image) * (mask.astype(np.float32) / 255.0)


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray | None = None) -> np.ndarray:
    """``T_t_c``: a camera at ``eye`` (3,) looking at ``target`` (3,) (both in the target frame), its image y axis
    towards ``-up`` (down in the image is ``-up``)."""
    up = np.array([0.0, 1.0, 0.0]) if up is None else up
    z = np.asarray(target, dtype=float) - np.asarray(eye, dtype=float)
    z /= np.linalg.norm(z)
    x = np.cross(z, -np.asarray(up, dtype=float))
    if np.linalg.norm(x) < 1e-6:
        x = np.cross(z, np.array([1.0, 0.0, 0.0]))
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return make_T(np.column_stack([x, y, z]), np.asarray(eye, dtype=float))


def plate_camera_poses(centre_t: np.ndarray, distance_mm: float, n: int, rng: np.random.Generator,
                       max_tilt_deg: float = 40.0, aim_spread_mm: float = 60.0) -> list[np.ndarray]:
    """``n`` well-spread camera poses ``T_c_t`` looking at a plate centred at ``centre_t`` from about
    ``distance_mm``: tilts up to ``max_tilt_deg`` in azimuths around the plate, the aim point and the roll
    varied so that the marks reach the image's corners (Zhang needs tilt, distortion needs the corners)."""
    poses = []
    for k in range(n):
        az = 2.0 * math.pi * k / n + rng.uniform(-0.2, 0.2)
        tilt = math.radians(max_tilt_deg) * (0.35 + 0.65 * ((k * 0.618) % 1.0))
        d = distance_mm * rng.uniform(0.9, 1.1)
        eye = np.asarray(centre_t, dtype=float) + d * np.array(
            [math.sin(tilt) * math.cos(az), math.sin(tilt) * math.sin(az), math.cos(tilt)])
        aim = np.asarray(centre_t, dtype=float) + np.append(rng.uniform(-aim_spread_mm, aim_spread_mm, 2), 0.0)
        roll = rng.uniform(-math.pi, math.pi)
        up = np.array([math.cos(roll), math.sin(roll), 0.0])
        poses.append(invert(look_at(eye, aim, up)))
    return poses


def target_in_camera(T_cf_si: np.ndarray, T_cf_t: np.ndarray) -> np.ndarray:
    """``T_si_t = (T_cf_si)^-1 · T_cf_t``: where the camera at ``T_cf_si`` sees a target at ``T_cf_t``."""
    return compose(invert(T_cf_si), T_cf_t)


# --- simulated calibration measurements (the wizard's inputs on the simulated cell) -----------------------


def tracker_reading(points: np.ndarray, rng: np.random.Generator, noise_mm: float = 0.025) -> np.ndarray:
    """Points (n, 3) as the tracker reads them: ``noise_mm`` is the 3-D RMS error of a point (the tracker's
    spec), so each axis gets ``noise_mm / sqrt(3)``."""
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    return points + rng.normal(0.0, noise_mm / math.sqrt(3.0), points.shape)


def base_calibration_poses(n: int, rng: np.random.Generator, radius_mm: tuple[float, float] = (1200.0, 2400.0),
                           azimuth_deg: tuple[float, float] = (-120.0, 120.0),
                           z_mm: tuple[float, float] = (200.0, 1400.0), max_tilt_deg: float = 35.0) -> list[np.ndarray]:
    """``n`` flange poses ``T_b_f`` spread around the robot (base frame: ``radius_mm`` from its axis, ``azimuth_deg``
    about it, height ``z_mm``), so that the base's origin lies amid them rather than far outside; the flange's z
    axis points down tilted by up to ``max_tilt_deg`` in any direction, turned about it by ± 90° (the SMR offset
    is seen only through these rotations)."""
    poses = []
    down = np.diag([1.0, -1.0, -1.0])
    for k in range(n):
        # azimuths stratified over the range, so that any n covers it
        az_deg = azimuth_deg[0] + (k + rng.uniform(0.2, 0.8)) / n * (azimuth_deg[1] - azimuth_deg[0])
        az, r = math.radians(az_deg), rng.uniform(*radius_mm)
        position = np.array([r * math.cos(az), r * math.sin(az), rng.uniform(*z_mm)])
        tilt_az = rng.uniform(-math.pi, math.pi)
        tilt = math.radians(max_tilt_deg) * math.sqrt(rng.uniform(0.1, 1.0))
        tilted = rotvec_to_matrix(tilt * np.array([math.cos(tilt_az), math.sin(tilt_az), 0.0]))
        R = tilted @ down @ rotvec_to_matrix(np.array([0.0, 0.0, rng.uniform(-math.pi / 2, math.pi / 2)]))
        poses.append(make_T(R, position))
    return poses


def place_target(T_cf_t: np.ndarray, rng: np.random.Generator, shift_mm: float = 30.0, turn_deg: float = 5.0
                 ) -> np.ndarray:
    """The target put down again near ``T_cf_t``: shifted in its plane by up to ``± shift_mm`` and turned about its
    normal by up to ``± turn_deg``."""

    turn = rotvec_to_matrix(np.radians([0.0, 0.0, rng.uniform(-turn_deg, turn_deg)]))
    return compose(np.asarray(T_cf_t, dtype=float),
                   make_T(turn, np.array([rng.uniform(-shift_mm, shift_mm), rng.uniform(-shift_mm, shift_mm), 0.0])))
