"""The paper's own planning (Section 4, Fig. 5): cameras looking straight down, where each hole should land
in the image.

The camera stops right above each featured hole (its orientation is fixed by the hole), so only its
position is free: the planner chooses where in the image each hole is seen. Moving the holes from the
image centre outwards makes the lines of sight diverge and shrinks the pose uncertainty (Fig. 5); the
paper recommends about a quarter of the image from the edge.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from monoguide.solver import frames
from monoguide.solver.camera import CameraModel
from monoguide.solver.planning.prediction import layout_covariance

# Camera axes in the part frame when looking straight down onto the sheet: x_c = -x_w, y_c = y_w,
# z_c = -z_w (the orientation of the paper's cell, Sec. 5.2: a 180 deg turn about the part's y axis).
R_W_C_LOOKING_DOWN = np.diag([-1.0, 1.0, -1.0])


def quarter_targets(camera: CameraModel, points_w: np.ndarray, fraction: float = 0.25) -> np.ndarray:
    """Pixel (n, 2) where each hole should be imaged: ``fraction`` of the image from the edge, in the
    image quadrant that points away from the part's centroid (so that the lines of sight diverge).

    points_w : (n, 3) featured points in the part frame, mm.
    """
    points_w = np.asarray(points_w, dtype=float).reshape(-1, 3)
    outward_w = points_w - points_w.mean(axis=0)
    outward_c = outward_w @ R_W_C_LOOKING_DOWN  # R_c_w = R_w_c^T, rows: (R_c_w @ v) = v @ R_w_c
    sign_u = np.where(outward_c[:, 0] >= 0, 1.0, -1.0)
    sign_v = np.where(outward_c[:, 1] >= 0, 1.0, -1.0)
    half_u = (0.5 - fraction) * camera.width
    half_v = (0.5 - fraction) * camera.height
    centre = np.array([(camera.width - 1) / 2.0, (camera.height - 1) / 2.0])
    return centre + np.stack([sign_u * half_u, sign_v * half_v], axis=1)


def look_at_poses(
    points_w: np.ndarray,
    camera: CameraModel,
    standoff_mm: float,
    targets_px: np.ndarray | None = None,
    R_w_c: np.ndarray = R_W_C_LOOKING_DOWN,
) -> list[np.ndarray]:
    """Camera pose ``T_w_si`` (4, 4) above each featured point so that point i is imaged at
    ``targets_px[i]`` (raw pixels, default :func:`quarter_targets`) at depth ``standoff_mm``.

    points_w : (n, 3) mm; targets_px : (n, 2) px; R_w_c : (3, 3) camera orientation in the part frame.
    """
    points_w = np.asarray(points_w, dtype=float).reshape(-1, 3)
    if targets_px is None:
        targets_px = quarter_targets(camera, points_w)
    xy = camera.undistort_pixels(np.asarray(targets_px, dtype=float).reshape(-1, 2))
    poses = []
    for point_w, (x, y) in zip(points_w, xy, strict=True):
        point_c = standoff_mm * np.array([x, y, 1.0])
        poses.append(frames.make_T(R_w_c, point_w - R_w_c @ point_c))
    return poses


@dataclass(frozen=True)
class UncertaintyMap:
    """Fig. 5: predicted pose uncertainty per pixel of centre noise, as the holes move outwards.

    offsets_u_px : (nu,) distance of every hole from the image centre along u (outwards), px
    offsets_v_px : (nv,) the same along v
    sigma_trans_mm, sigma_rot_deg : (nv, nu) square roots of the traces of the covariance blocks of
    ``T_s1_w`` for sigma_px = 1 (they scale linearly with the real centre noise)
    """

    offsets_u_px: np.ndarray
    offsets_v_px: np.ndarray
    sigma_trans_mm: np.ndarray
    sigma_rot_deg: np.ndarray


def uncertainty_map(
    camera: CameraModel,
    points_w: np.ndarray,
    standoff_mm: float,
    steps: int = 25,
    margin_px: float = 40.0,
) -> UncertaintyMap:
    """Predicted uncertainty (Eq. 29 at sigma_px = 1) with every hole moved by the same distance from
    the image centre, outwards (as :func:`quarter_targets`), over a ``steps`` x ``steps`` grid that
    stops ``margin_px`` short of the image border. This is the simulation behind the paper's Fig. 5."""
    points_w = np.asarray(points_w, dtype=float).reshape(-1, 3)
    centre = np.array([(camera.width - 1) / 2.0, (camera.height - 1) / 2.0])
    signs = np.sign(quarter_targets(camera, points_w) - centre)
    # At the centre itself every line of sight is parallel to the sheet normal and the distance to
    # the part is unobservable: the map starts one step out.
    offsets_u = np.linspace(0.0, camera.width / 2.0 - margin_px, steps + 1)[1:]
    offsets_v = np.linspace(0.0, camera.height / 2.0 - margin_px, steps + 1)[1:]
    sigma_trans = np.empty((steps, steps))
    sigma_rot = np.empty((steps, steps))
    for iv, dv in enumerate(offsets_v):
        for iu, du in enumerate(offsets_u):
            targets = centre + signs * np.array([du, dv])
            covariance = layout_covariance(camera, points_w, look_at_poses(points_w, camera, standoff_mm, targets))
            sigma_rot[iv, iu] = math.degrees(math.sqrt(np.trace(covariance[:3, :3])))
            sigma_trans[iv, iu] = math.sqrt(np.trace(covariance[3:, 3:]))
    return UncertaintyMap(offsets_u, offsets_v, sigma_trans, sigma_rot)
