"""The measurement record ``monoguide.measurement/1`` (docs/measurement-record.md): a parsed JSON
object in, a :class:`MeasurementRecord` out, and a solve result back to a JSON-ready dict. No I/O."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from monoguide.solver import frames
from monoguide.solver.camera import CameraModel
from monoguide.solver.errors import (
    MonoguideError,
    NonFiniteValue,
    PointBehindCamera,
    RecordError,
    UnknownReference,
    UnsupportedFormat,
)
from monoguide.solver.offset import part_displacement
from monoguide.solver.pose import PoseResult
from monoguide.solver.problem import PoseProblem

FORMAT = "monoguide.measurement/1"
DEFAULT_SIGMA_PX = 0.1


@dataclass(frozen=True)
class MeasurementRecord:
    """A validated record: its id, the pose problem, and the truth of a synthetic record (or None)."""

    id: str | None
    problem: PoseProblem
    truth_T_s1_w: np.ndarray | None = None


def parse_record(data: Any) -> MeasurementRecord:
    """Validate a decoded JSON object; raise a :class:`RecordError` subclass naming the bad field."""
    if not isinstance(data, dict):
        raise RecordError(f"a record must be a JSON object, got {type(data).__name__}")
    if data.get("format") != FORMAT:
        raise UnsupportedFormat(f"format: expected {FORMAT!r}, got {data.get('format')!r}")
    record_id = data.get("id")
    if record_id is not None and not isinstance(record_id, str):
        raise RecordError(f"id: expected a string or null, got {record_id!r}")
    camera = CameraModel.from_dict(_required(data, "camera"))
    points_w = _matrix(_required(data, "points_w"), "points_w", columns=3)
    views = _required(data, "views")
    if not isinstance(views, list) or not views:
        raise RecordError(f"views: expected a non-empty list, got {views!r}")
    T_s1_si = np.stack([_transform(_field(view, "T_s1_si", f"views[{i}]"), f"views[{i}].T_s1_si")
                        for i, view in enumerate(views)])
    if not np.allclose(T_s1_si[0], np.eye(4), atol=1e-6):
        raise RecordError("views[0].T_s1_si: must be the identity (SF1 is the frame of the first camera pose)")
    T_s1_w0 = _transform(_required(data, "T_s1_w0"), "T_s1_w0")
    view_index, point_index, pixels = _observations(_required(data, "observations"), len(views), len(points_w))
    outside = ~camera.in_image(pixels)
    if np.any(outside):
        j = int(np.flatnonzero(outside)[0])
        raise RecordError(
            f"observations[{j}].pixel: {pixels[j].tolist()} lies outside the {camera.width} x {camera.height} image"
        )
    sigma_px = _positive(data.get("sigma_px", DEFAULT_SIGMA_PX), "sigma_px")
    view_sigma_mm = view_sigma_deg = 0.0
    if data.get("view_sigma") is not None:
        view_sigma = data["view_sigma"]
        view_sigma_mm = _positive(_field(view_sigma, "mm", "view_sigma"), "view_sigma.mm", allow_zero=True)
        view_sigma_deg = _positive(_field(view_sigma, "deg", "view_sigma"), "view_sigma.deg", allow_zero=True)
    truth = None
    if data.get("truth") is not None:
        truth = _transform(_field(data["truth"], "T_s1_w", "truth"), "truth.T_s1_w")
    problem = PoseProblem(
        camera, points_w, T_s1_si, view_index, point_index, pixels, T_s1_w0, sigma_px, view_sigma_mm, view_sigma_deg
    )
    depth = problem.points_in_views(T_s1_w0)[:, 2]
    if np.any(depth <= 0):
        j = int(np.argmin(depth))
        raise PointBehindCamera(
            f"observations[{j}]: point {int(point_index[j])} lies behind camera {int(view_index[j])} at the "
            f"reference pose T_s1_w0 (z = {depth[j]:.1f} mm): the views or T_s1_w0 are wrong"
        )
    return MeasurementRecord(record_id, problem, truth)


def result_to_dict(record_id: str | None, result: PoseResult, T_s1_w0: np.ndarray, time_ms: float) -> dict:
    """The result object of the spec for a solved record."""
    return {
        "id": record_id,
        "status": "ok",
        "T_s1_w": _rounded(result.T_s1_w),
        "offset": _rounded(part_displacement(result.T_s1_w, T_s1_w0)),
        "rms_px": round(result.rms_px, 6),
        "covariance": [[float(f"{v:.6g}") for v in row] for row in result.covariance],
        "sigma_rot_deg": round(result.sigma_rot_deg, 6),
        "sigma_trans_mm": round(result.sigma_trans_mm, 6),
        "method": result.method,
        "iterations": result.iterations,
        "time_ms": round(time_ms, 3),
    }


def error_to_dict(record_id: str | None, error: MonoguideError) -> dict:
    """The result object of the spec for a record that could not be solved."""
    return {"id": record_id, "status": "error", "error": error.as_dict()}


# --- private helpers ----------------------------------------------------------------------------


def _required(data: dict, key: str) -> Any:
    if key not in data:
        raise RecordError(f"{key}: missing")
    return data[key]


def _field(data: Any, key: str, where: str) -> Any:
    if not isinstance(data, dict):
        raise RecordError(f"{where}: expected an object, got {data!r}")
    if key not in data:
        raise RecordError(f"{where}.{key}: missing")
    return data[key]


def _number(value: Any, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise RecordError(f"{where}: expected a number, got {value!r}")
    if not math.isfinite(value):
        raise NonFiniteValue(f"{where}: {value!r} is not a finite number")
    return float(value)


def _matrix(value: Any, where: str, columns: int, rows: int | None = None) -> np.ndarray:
    if not isinstance(value, list) or not value or (rows is not None and len(value) != rows):
        shape = f"{rows} x {columns}" if rows else f"n x {columns}"
        raise RecordError(f"{where}: expected a {shape} list of lists, got {value!r}"[:200])
    out = np.empty((len(value), columns))
    for i, row in enumerate(value):
        if not isinstance(row, list) or len(row) != columns:
            raise RecordError(f"{where}[{i}]: expected {columns} numbers, got {row!r}"[:200])
        for j, v in enumerate(row):
            out[i, j] = _number(v, f"{where}[{i}][{j}]")
    return out


def _transform(value: Any, where: str) -> np.ndarray:
    """A checked 4x4 transform, its rotation snapped to the nearest orthonormal one (records print
    matrices to a few decimals)."""
    T = frames.check_transform(_matrix(value, where, columns=4, rows=4), where)
    return frames.make_T(frames.orthonormalize(T[:3, :3]), T[:3, 3])


def _positive(value: Any, where: str, allow_zero: bool = False) -> float:
    v = _number(value, where)
    if v < 0 or (v == 0 and not allow_zero):
        raise RecordError(f"{where}: must be {'non-negative' if allow_zero else 'positive'}, got {v!r}")
    return v


def _observations(value: Any, n_views: int, n_points: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    if not isinstance(value, list):
        raise RecordError(f"observations: expected a list, got {value!r}"[:200])
    views, points, pixels, seen = [], [], [], set()
    for j, obs in enumerate(value):
        where = f"observations[{j}]"
        view, point = _field(obs, "view", where), _field(obs, "point", where)
        for name, index, count in (("view", view, n_views), ("point", point, n_points)):
            if isinstance(index, bool) or not isinstance(index, int):
                raise RecordError(f"{where}.{name}: expected an integer index, got {index!r}")
            if not 0 <= index < count:
                raise UnknownReference(f"{where}.{name}: {index} does not exist (the record has {count} {name}s)")
        if (view, point) in seen:
            raise UnknownReference(f"{where}: point {point} is observed twice in view {view}")
        seen.add((view, point))
        pixel = _matrix([_field(obs, "pixel", where)], f"{where}.pixel", columns=2)[0]
        views.append(view)
        points.append(point)
        pixels.append(pixel)
    return np.array(views, dtype=int), np.array(points, dtype=int), np.array(pixels).reshape(-1, 2)


def _rounded(T: np.ndarray) -> list[list[float]]:
    return [[round(float(v), 9) for v in row] for row in T]
