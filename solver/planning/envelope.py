"""The deviation envelope of the part, and what a camera sees of a hole over all of it.

A part lies off its reference by a rotation vector ``r`` (each component within +- ``rotation_deg``)
about a centre ``centre_w`` and a shift ``t`` (each component within +- ``translation_mm``), both in the
reference part's frame: ``T_w0_w = [R(r) | c - R(r) c + t]`` (the simulated cell draws its parts the same
way). A layout must hold every such part, so it is checked at the 64 corners of that box, its centre and
a seeded sample of its interior, never at the reference part alone.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

from monoguide.solver import frames
from monoguide.solver.camera import CameraModel

N_CORNERS = 64


@dataclass(frozen=True)
class DeviationEnvelope:
    """How far a part may lie off the reference: +- per axis of the part frame.

    translation_mm : (3,) mm; rotation_deg : (3,) deg, components of the rotation vector about ``centre_w``
    (3,) mm in the part frame (None: the featured holes' centroid).
    """

    translation_mm: tuple[float, float, float] = (50.0, 50.0, 50.0)
    rotation_deg: tuple[float, float, float] = (5.0, 5.0, 5.0)
    centre_w: tuple[float, float, float] | None = None

    def centre(self, points_w: np.ndarray) -> np.ndarray:
        """The rotation centre (3,): ``centre_w``, or the centroid of ``points_w`` (n, 3)."""
        if self.centre_w is not None:
            return np.asarray(self.centre_w, dtype=float)
        return np.asarray(points_w, dtype=float).reshape(-1, 3).mean(axis=0)

    def describe(self) -> str:
        t = "/".join(f"{v:g}" for v in self.translation_mm)
        r = "/".join(f"{v:g}" for v in self.rotation_deg)
        return f"±{t} mm, ±{r}°"


def deviation_transform(rotvec_rad: np.ndarray, translation_mm: np.ndarray, centre_w: np.ndarray) -> np.ndarray:
    """``T_w0_w`` (4, 4) of a part turned by ``rotvec_rad`` about ``centre_w`` and shifted by
    ``translation_mm`` (all in the reference part's frame)."""
    R = frames.rotvec_to_matrix(np.asarray(rotvec_rad, dtype=float))
    c = np.asarray(centre_w, dtype=float)
    return frames.make_T(R, c - R @ c + np.asarray(translation_mm, dtype=float))


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
    centre = envelope.centre(points_w)
    return np.stack([deviation_transform(d[:3], d[3:], centre) for d in draws])


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
