"""Where the cycle looks for a hole: the region of the image that holds it wherever the part lies inside the
deviation envelope, and its expected centre and radius at the reference part.

The region spans the hole's image at the reference part and at every extreme of the envelope — each corner of
the translation box combined with each rotation vector of -1, 0, +1 times the rotation limits, about the
envelope's centre — plus two hole radii and a margin. Pure geometry: the cycle calls it once per measuring pose
when its runner is built.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

from monoguide.solver import frames
from monoguide.solver.camera import CameraModel
from monoguide.solver.envelope import DeviationEnvelope, deviation_transform

SEARCH_MARGIN_PX = 24.0  # beyond the envelope's spread and the hole's own size


@dataclass(frozen=True)
class HoleSearch:
    """One hole of one view: where it is expected, how large, and the region it is sought in."""

    expected_px: tuple[float, float]  # its centre at the reference part, raw px
    radius_px: float  # its expected radius (standoff and viewing angle)
    roi: tuple[int, int, int, int]  # x, y, w, h in full-sensor px, clipped to the image
    max_offset_px: float  # how far from ``expected_px`` the hole may lie


def search_extremes(envelope: DeviationEnvelope, points_w: np.ndarray) -> np.ndarray:
    """``T_w0_w`` (216, 4, 4) of the envelope's extremes: every corner of the translation box (8) with every
    rotation vector of -1, 0, +1 times the rotation limits (27), about the envelope's point (``about_w``)."""
    c = envelope.about(points_w)
    t_lim, r_lim = np.asarray(envelope.translation_mm, float), np.radians(np.asarray(envelope.rotation_deg, float))
    out = []
    for t_sign in itertools.product((-1.0, 1.0), repeat=3):
        for r_sign in itertools.product((-1.0, 0.0, 1.0), repeat=3):
            out.append(deviation_transform(np.asarray(r_sign) * r_lim, np.asarray(t_sign) * t_lim, c))
    return np.array(out)


def hole_search(camera: CameraModel, T_c_w0: np.ndarray, point_w: np.ndarray, normal_w: np.ndarray,
                hole_radius_mm: float, extremes: np.ndarray, margin_px: float = SEARCH_MARGIN_PX) -> HoleSearch | None:
    """The search of the hole at ``point_w`` (3,) with surface normal ``normal_w`` (3,), for the camera at
    ``T_c_w0`` (4, 4: the reference part in the camera's frame) over the part poses ``extremes`` (k, 4, 4,
    ``T_w0_w``: :func:`search_extremes`). None when the hole is nowhere in the image."""
    p_w = np.asarray(point_w, dtype=float)
    p_c = frames.transform_points(T_c_w0, p_w[None])[0]
    centre = camera.project(p_c[None])[0]
    normal_c = T_c_w0[:3, :3] @ (np.asarray(normal_w, dtype=float) / np.linalg.norm(normal_w))
    cos_view = abs(float(normal_c @ p_c) / float(np.linalg.norm(p_c)))
    r_px = hole_radius_mm * math.sqrt(camera.fx * camera.fy) / p_c[2] * math.sqrt(cos_view)
    q_w0 = np.einsum("kij,j->ki", extremes[:, :3, :3], p_w) + extremes[:, :3, 3]
    q_c = frames.transform_points(T_c_w0, q_w0)
    pts = np.vstack([camera.project(q_c[q_c[:, 2] > 0]).reshape(-1, 2), centre[None]])
    pad = 2.0 * r_px + margin_px
    x0, y0 = np.floor(pts.min(axis=0) - pad)
    x1, y1 = np.ceil(pts.max(axis=0) + pad)
    x0, y0 = max(int(x0), 0), max(int(y0), 0)
    x1, y1 = min(int(x1), camera.width), min(int(y1), camera.height)
    if x1 - x0 < 1 or y1 - y0 < 1:
        return None
    return HoleSearch((float(centre[0]), float(centre[1])), float(r_px), (x0, y0, x1 - x0, y1 - y0),
                      float(np.max(np.linalg.norm(pts - centre, axis=1))) + r_px + margin_px)
