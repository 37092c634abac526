"""What a camera sees of a hole over the whole deviation envelope.

The envelope is :class:`~monoguide.solver.envelope.DeviationEnvelope` (one definition for the planner, the
simulated part supply and the offset check): a rotation vector ``r`` about the part's point ``about_w`` and
the shift ``t`` of that point, per axis of the reference part frame, ``T_w0_w = [R(r) | a - R(r) a + t]``.
A layout must hold every such part, so it is checked at the 64 corners of the per-axis box (a superset of
the envelope when its totals cut the corners off), its centre and a seeded sample of its interior, never at
the reference part alone.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

from monoguide.solver import frames
from monoguide.solver.camera import CameraModel
from monoguide.solver.envelope import DeviationEnvelope, deviation_transform

N_CORNERS = 64


def envelope_deviations(
    envelope: DeviationEnvelope, points_w: np.ndarray, interior: int = 256, seed: int = 0
) -> np.ndarray:
    """``T_w0_w`` (64 + 1 + interior, 4, 4): the envelope's 64 corners, the reference part (identity), then
    ``interior`` parts drawn uniformly inside the envelope (seeded)."""
    limits = np.concatenate([np.radians(envelope.rotation_deg), np.asarray(envelope.translation_mm, dtype=float)])
    corners = np.array(list(itertools.product((-1.0, 1.0), repeat=6))) * limits
    rng = np.random.default_rng(seed)
    inside = rng.uniform(-1.0, 1.0, size=(interior, 6)) * limits
    draws = np.vstack([corners, np.zeros((1, 6)), inside])
    about = envelope.about(points_w)
    return np.stack([deviation_transform(d[:3], d[3:], about) for d in draws])


@dataclass(frozen=True)
class HoleInView:
    """One hole seen from one camera over the envelope's parts (k of them).

    points_c : (k, 3) the hole's centre in the camera frame, mm
    pixels   : (k, 2) its raw pixel (NaN where it lies behind the camera)
    margin_px: (k,) distance of that pixel from the nearest image border (negative: outside; -inf: behind)
    view_angle_deg : (k,) angle between the line of sight and the hole's surface normal
    """

    points_c: np.ndarray
    pixels: np.ndarray
    margin_px: np.ndarray
    view_angle_deg: np.ndarray

    @property
    def depth_mm(self) -> np.ndarray:
        return self.points_c[:, 2]

    @property
    def in_front(self) -> bool:
        return bool(np.all(self.points_c[:, 2] > 0.0))


def hole_in_view(
    camera: CameraModel,
    T_w0_c: np.ndarray,
    deviations: np.ndarray,
    point_w: np.ndarray,
    normal_w: np.ndarray | None = None,
) -> HoleInView:
    """Where camera ``T_w0_c`` sees the hole ``point_w`` (3,) of each part ``deviations`` (k, 4, 4) =
    ``T_w0_w``; ``normal_w`` (3,) is the hole's surface normal (default the part's z axis)."""
    normal_w = np.array([0.0, 0.0, 1.0]) if normal_w is None else np.asarray(normal_w, dtype=float)
    point_w0 = deviations[:, :3, :3] @ np.asarray(point_w, dtype=float) + deviations[:, :3, 3]
    normal_w0 = deviations[:, :3, :3] @ (normal_w / np.linalg.norm(normal_w))
    T_c_w0 = frames.invert(T_w0_c)
    points_c = point_w0 @ T_c_w0[:3, :3].T + T_c_w0[:3, 3]
    pixels = np.full((len(points_c), 2), np.nan)
    margin = np.full(len(points_c), -np.inf)
    front = points_c[:, 2] > 1e-6
    if np.any(front):
        pixels[front] = camera.project(points_c[front])
        margin[front] = pixel_margin(camera, pixels[front])
    to_camera = T_w0_c[:3, 3] - point_w0
    cos_angle = np.sum(to_camera * normal_w0, axis=1) / np.linalg.norm(to_camera, axis=1)
    angle = np.degrees(np.arccos(np.clip(cos_angle, -1.0, 1.0)))
    return HoleInView(points_c, pixels, margin, angle)


def pixel_margin(camera: CameraModel, pixels: np.ndarray) -> np.ndarray:
    """Distance (n,) of raw pixels (n, 2) from the nearest image border, px (negative: outside), with the
    border at the outer edge of the outermost pixels (-0.5 and size - 0.5), as :meth:`CameraModel.in_image`."""
    u, v = pixels[:, 0], pixels[:, 1]
    return np.minimum.reduce([u + 0.5, camera.width - 0.5 - u, v + 0.5, camera.height - 0.5 - v])


def line_of_sight_angle_deg(camera_w: np.ndarray, point_w: np.ndarray, normal_w: np.ndarray) -> float:
    """Angle (deg) between the line of sight from ``point_w`` to the camera centre ``camera_w`` and the
    surface normal ``normal_w`` (all (3,) in one frame)."""
    to_camera = np.asarray(camera_w, dtype=float) - np.asarray(point_w, dtype=float)
    n = np.asarray(normal_w, dtype=float)
    cos_angle = float(to_camera @ n) / (np.linalg.norm(to_camera) * np.linalg.norm(n))
    return math.degrees(math.acos(max(-1.0, min(1.0, cos_angle))))
