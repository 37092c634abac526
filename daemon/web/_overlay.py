"""What the *One cycle* page draws over each view's image, from the journal's record alone (and the cell config
when it is given): the hole's measured centre, where the solved pose puts it, the residual between them scaled
so that it can be seen, the rim and the region the hole was sought in, each hole's name.

Every coordinate is a raw (distorted) image pixel, as the record keeps them: pixel (0, 0)'s centre is at
(0, 0), so the image itself is drawn from (-0.5, -0.5) (``IMAGE_ORIGIN``). The record keeps centres, not the
fitted ellipses: the rim drawn is the hole's rim circle (``[part] hole_radius_mm``) projected at the solved pose
and moved by the residual, so its centre sits where the detector's ellipse was; without a config there is no
radius and no rim. The search region is the cycle's rule (``solver.planning.search.hole_search``) over the
config's deviation envelope (``[layout]``, else +-50 mm, +-5 deg).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from monoguide.daemon.config import CellConfig
from monoguide.solver import frames
from monoguide.solver.camera import CameraModel
from monoguide.solver.holes import circle_basis
from monoguide.solver.planning.envelope import DeviationEnvelope
from monoguide.solver.planning.search import hole_search, search_extremes

IMAGE_ORIGIN = -0.5  # where the image's top-left corner lies in pixel-centre coordinates
RESIDUAL_SCALE = 200.0  # a 0.1 px residual is drawn 20 px long
RIM_POINTS = 72


@dataclass(frozen=True)
class HoleMark:
    """One hole in one view."""

    name: str
    point: int
    measured_px: tuple[float, float] | None  # the record's centre (perspective-corrected): None when not found
    predicted_px: tuple[float, float] | None  # the image of the hole's centre at the solved pose
    rim_px: tuple[tuple[float, float], ...] = ()  # the rim as fitted (see the module's doc)
    region: tuple[int, int, int, int] | None = None  # x, y, w, h: where it was sought

    @property
    def residual_px(self) -> tuple[float, float] | None:
        if self.measured_px is None or self.predicted_px is None:
            return None
        return (self.measured_px[0] - self.predicted_px[0], self.measured_px[1] - self.predicted_px[1])

    @property
    def residual_end_px(self) -> tuple[float, float] | None:
        """Where the scaled residual arrow ends, drawn from the predicted centre."""
        r = self.residual_px
        if r is None or self.predicted_px is None:
            return None
        return (self.predicted_px[0] + RESIDUAL_SCALE * r[0], self.predicted_px[1] + RESIDUAL_SCALE * r[1])


@dataclass(frozen=True)
class ViewMarks:
    index: int  # 0-based view (measuring pose) index
    name: str  # the measuring pose's name (S1, ...)
    width: int
    height: int
    holes: list[HoleMark] = field(default_factory=list)


def view_marks(record: dict[str, Any] | None, result: dict[str, Any] | None, config: CellConfig | None,
               n_views: int) -> list[ViewMarks]:
    """The marks of each of ``n_views`` views (at least the record's and the config's views)."""
    camera = _camera(record, config)
    names = _point_names(record, config)
    pose_names = [p.name for p in config.measuring_poses] if config is not None else []
    views_in_record = len(record["views"]) if record else 0
    count = max(n_views, views_in_record, len(pose_names))
    out = []
    for i in range(count):
        name = pose_names[i] if i < len(pose_names) else f"S{i + 1}"
        width, height = (camera.width, camera.height) if camera is not None else (0, 0)
        out.append(ViewMarks(i, name, int(width), int(height), _holes(i, record, result, config, camera, names)))
    return out


# --- private ------------------------------------------------------------------------------------


def _camera(record: dict[str, Any] | None, config: CellConfig | None) -> CameraModel | None:
    if record is not None:
        return CameraModel.from_dict(record["camera"])
    return config.camera.intrinsics if config is not None else None


def _point_names(record: dict[str, Any] | None, config: CellConfig | None) -> list[str]:
    if config is not None:
        return list(config.part.point_names)
    return [f"P{j + 1}" for j in range(len(record["points_w"]) if record else 0)]


def _holes(i: int, record: dict[str, Any] | None, result: dict[str, Any] | None, config: CellConfig | None,
           camera: CameraModel | None, names: list[str]) -> list[HoleMark]:
    expected: list[int] = list(config.measuring_poses[i].points) if config and i < len(config.measuring_poses) else []
    measured = {int(o["point"]): (float(o["pixel"][0]), float(o["pixel"][1]))
                for o in (record or {}).get("observations", []) if int(o["view"]) == i}
    points = expected + [j for j in sorted(measured) if j not in expected]
    T_c_w = None
    if record is not None and result is not None and result.get("T_s1_w") is not None and i < len(record["views"]):
        T_c_w = frames.invert(np.asarray(record["views"][i]["T_s1_si"], float)) @ np.asarray(result["T_s1_w"], float)
    holes = []
    for j in points:
        predicted = rim = None
        if T_c_w is not None and camera is not None:
            p_w = np.asarray(record["points_w"][j], float)  # type: ignore[index]
            predicted = _project(camera, T_c_w, p_w[None])[0]
            if config is not None and j in measured:
                shift = np.asarray(measured[j]) - predicted
                rim = _rim(camera, T_c_w, config, j) + shift
        region = _region(config, camera, i, j) if config is not None and camera is not None else None
        holes.append(HoleMark(
            names[j] if j < len(names) else f"P{j + 1}", j, measured.get(j),
            None if predicted is None else (float(predicted[0]), float(predicted[1])),
            () if rim is None else tuple((float(u), float(v)) for u, v in rim), region))
    return holes


def _project(camera: CameraModel, T_c_w: np.ndarray, points_w: np.ndarray) -> np.ndarray:
    return camera.project(frames.transform_points(T_c_w, points_w))


def _rim(camera: CameraModel, T_c_w: np.ndarray, config: CellConfig, j: int) -> np.ndarray:
    part = config.part
    normal = part.normals_w[j] if part.normals_w is not None else np.array([0.0, 0.0, 1.0])
    e1, e2 = circle_basis(normal)
    angles = np.linspace(0.0, 2 * np.pi, RIM_POINTS, endpoint=False)
    circle = part.points_w[j] + part.hole_radius_mm * (np.cos(angles)[:, None] * e1 + np.sin(angles)[:, None] * e2)
    return _project(camera, T_c_w, circle)


def _region(config: CellConfig, camera: CameraModel, i: int, j: int) -> tuple[int, int, int, int] | None:
    if i >= len(config.measuring_poses):
        return None
    part = config.part
    T_c_w0 = frames.invert(config.measuring_poses[i].T_cf_si) @ config.reference.T_cf_w0
    envelope = config.layout.envelope if config.layout is not None else DeviationEnvelope()
    normal = part.normals_w[j] if part.normals_w is not None else np.array([0.0, 0.0, 1.0])
    search = hole_search(camera, T_c_w0, part.points_w[j], normal, part.hole_radius_mm,
                         search_extremes(envelope, part.points_w))
    return None if search is None else search.roi
