"""``[part]``, ``[reference]`` and ``[[measuring_poses]]``: the featured holes, the part the grasp path was taught
on, and the views the camera measures them from."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from monoguide.daemon.config._camera import CameraConfig
from monoguide.daemon.config._reader import ConfigTable
from monoguide.drivers.errors import ConfigError
from monoguide.solver.frames import compose

MAX_MEASURING_POSES = 100  # the robot programs number them 1..100; 101 and up are the base-calibration poses


@dataclass(frozen=True)
class PartConfig:
    points_w: np.ndarray  # (n, 3) featured hole centres, mm
    hole_radius_mm: float
    point_names: tuple[str, ...]
    grasp_point_w: np.ndarray | None = None  # (3,) where the robot grips, mm; None: the holes' centroid
    normals_w: np.ndarray | None = None  # (n, 3) surface normal at each hole; None: the part's z axis
    outline_w: np.ndarray | None = None  # (m, 3) the part's outer edge, a polygon in the part frame; None: not given


def read_part(t: ConfigTable) -> PartConfig:
    points = t.points("points_w")
    names = t.texts("point_names", tuple(f"P{i + 1}" for i in range(len(points))))
    if len(names) != len(points):
        raise ConfigError(f"{t.where}.point_names: {len(names)} names for {len(points)} points_w")
    _unique_names(names, f"{t.where}.point_names")
    normals = t.points("normals_w") if t.has("normals_w") else None
    if normals is not None and (len(normals) != len(points) or np.any(np.linalg.norm(normals, axis=1) < 1e-9)):
        raise ConfigError(f"{t.where}.normals_w: expected one non-zero normal per point of points_w ({len(points)})")
    outline = t.points("outline_w") if t.has("outline_w") else None
    if outline is not None and len(outline) < 3:
        raise ConfigError(f"{t.where}.outline_w: expected a polygon of at least 3 corners, got {len(outline)}")
    out = PartConfig(points, t.number("hole_radius_mm", positive=True), names, t.vector("grasp_point_w", 3, None),
                     normals, outline)
    t.done()
    return out


@dataclass(frozen=True)
class ReferenceConfig:
    T_cf_w0: np.ndarray  # the initial part the grasp path was taught on, in the cell frame
    T_cf_b: np.ndarray | None = None  # robot base in the cell frame


def read_reference(t: ConfigTable, *, with_part: bool = True) -> ReferenceConfig:
    """``[reference]``: ``T_cf_w0`` of the single part and the robot base; in a cell of ``[[parts]]`` each part
    has its own ``T_cf_w0`` and this section holds the robot base alone (``with_part=False``)."""
    if not with_part and t.has("T_cf_w0"):
        raise ConfigError(f"{t.where}.T_cf_w0: in a cell of [[parts]] each part has its own reference: "
                          "[[parts]] T_cf_w0")
    out = ReferenceConfig(t.matrix("T_cf_w0") if with_part else np.eye(4), t.matrix("T_cf_b", None))
    t.done()
    return out


@dataclass(frozen=True)
class MeasuringPose:
    name: str
    T_cf_si: np.ndarray  # calibrated camera pose i in the cell frame (Eq. 6)
    points: tuple[int, ...]  # featured points expected in this view
    T_b_f: np.ndarray | None = None  # taught flange pose, when known
    number: int = 0  # the robot pose number: its place in the cell's [[measuring_poses]] (S1 = 1)
    mark_names: tuple[str, ...] = ()  # the fixed marks it sees ([[reference_marks]] names)
    marks: tuple[int, ...] = ()  # the same, as indices into CellConfig.reference_marks (set by the loader)


def read_measuring_poses(entries: list[ConfigTable], ref: ReferenceConfig, cam: CameraConfig,
                         n_points: int | None) -> tuple[MeasuringPose, ...]:
    """Each ``[[measuring_poses]]`` entry: its camera pose ``T_cf_si`` as written, or composed from its taught
    flange pose, the robot base and the camera mounting. ``n_points``: the single part's holes, which ``points``
    indexes; None in a cell of ``[[parts]]``, where each part says which of its holes a pose sees."""
    if len(entries) > MAX_MEASURING_POSES:
        raise ConfigError(f"{entries[0].file}: [[measuring_poses]]: {len(entries)} poses: must be 1 to "
                          f"{MAX_MEASURING_POSES} (the robot programs' pose numbers 101 and up are base-calibration "
                          "poses)")
    poses: list[MeasuringPose] = []
    for i, t in enumerate(entries):
        name = t.text("name", f"S{i + 1}", nonempty=True)
        if (first := next((j for j, p in enumerate(poses) if p.name == name), None)) is not None:
            raise ConfigError(f"{t.where}.name = {name!r}: already the name of [[measuring_poses]] #{first + 1}; "
                              "each pose's images, taught pose and calibration are filed under its own name")
        if n_points is None:
            if t.has("points"):
                raise ConfigError(f"{t.where}.points: in a cell of [[parts]] each part says which of its holes a "
                                  f"pose sees: [[parts]] measuring_poses = {{ {name} = [\"P1\"] }}")
            T_cf_si, T_b_f = _camera_pose(t, ref, cam)
            marks = t.texts("marks", ())
            t.done()
            poses.append(MeasuringPose(name, T_cf_si, (), T_b_f, i + 1, marks))
            continue
        points = t.ints("points", None, tuple(range(n_points)))
        if not points:
            raise ConfigError(f"{t.where}.points = []: a measuring pose sees at least one featured hole")
        if bad := [p for p in points if not 0 <= p < n_points]:
            raise ConfigError(f"{t.where}.points = {list(points)}: {bad} not among the {n_points} points_w")
        if twice := sorted({p for p in points if points.count(p) > 1}):
            raise ConfigError(f"{t.where}.points = {list(points)}: {twice} listed twice (one image of a hole per view)")
        T_cf_si, T_b_f = _camera_pose(t, ref, cam)
        marks = t.texts("marks", ())
        t.done()
        poses.append(MeasuringPose(name, T_cf_si, points, T_b_f, i + 1, marks))
    return tuple(poses)


def _camera_pose(t: ConfigTable, ref: ReferenceConfig, cam: CameraConfig) -> tuple[np.ndarray, np.ndarray | None]:
    T_cf_si, T_b_f = t.matrix("T_cf_si", None), t.matrix("T_b_f", None)
    if T_cf_si is None:
        if T_b_f is None or ref.T_cf_b is None or cam.T_f_c is None:
            raise ConfigError(f"{t.where}: give T_cf_si, or T_b_f with [reference] T_cf_b and [camera] T_f_c")
        T_cf_si = compose(ref.T_cf_b, T_b_f, cam.T_f_c)
    return T_cf_si, T_b_f


def _unique_names(names: tuple[str, ...], where: str) -> None:
    for i, name in enumerate(names):
        if not name.strip():
            raise ConfigError(f"{where} = {list(names)}: name #{i + 1} is empty")
        if name in names[:i]:
            raise ConfigError(f"{where} = {list(names)}: {name!r} names two points")
