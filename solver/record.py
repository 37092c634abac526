"""The measurement record ``monoguide.measurement/1`` (docs/measurement-record.md): a parsed JSON
object in, a :class:`MeasurementRecord` out, and a solve result back to a JSON-ready dict. No I/O."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from monoguide.solver import frames
from monoguide.solver.camera import CameraModel
from monoguide.solver.envelope import DeviationEnvelope
from monoguide.solver.errors import (
    MonoguideError,
    NonFiniteValue,
    PointBehindCamera,
    RecordError,
    UnknownReference,
    UnsupportedFormat,
)
from monoguide.solver.offset import PartDisplacement, check_envelope, describe_displacement
from monoguide.solver.pose import DEFAULT_FALSE_ALARM_RATE, PoseResult, solve_pose
from monoguide.solver.problem import PoseProblem
from monoguide.solver.record_keys import check_keys
from monoguide.solver.record_marks import MARKS_KEYS, RecordMarks, camera_deviation, parse_marks, solve_record_marks

FORMAT = "monoguide.measurement/1"

# Every key the format defines, per object; anything else is refused with the closest known key.
REQUIRED_KEYS = ("format", "camera", "points_w", "views", "T_s1_w0", "observations")
OPTIONAL_KEYS = ("id", "job", "part", "sigma_px", "view_sigma", "T_b_s1", "grasp_point_w", "envelope", "truth",
                 *MARKS_KEYS)
MAX_JOB = 65535  # the PLC's job number (register 1), a uint16
# The spec's default centre noise, px: the covariance and the consistency test use it when a record has none.
DEFAULT_SIGMA_PX = 0.1
VIEW_KEYS, VIEW_OPTIONAL_KEYS = ("T_s1_si",), ("name",)
OBSERVATION_KEYS = ("view", "point", "pixel")
VIEW_SIGMA_KEYS = ("mm", "deg")
ENVELOPE_KEYS, ENVELOPE_OPTIONAL_KEYS = ("translation_mm", "rotation_deg"), ("about_w", "total_mm", "total_deg")
# The envelope's form before it was one definition: totals and per-axis limits, judged at the grasp point.
OLD_ENVELOPE_KEYS, OLD_ENVELOPE_OPTIONAL_KEYS = ("mm", "deg"), ("axis_mm", "axis_deg")
TRUTH_KEYS, TRUTH_OPTIONAL_KEYS = ("T_s1_w",), ("base_offset",)


@dataclass(frozen=True)
class MeasurementRecord:
    """A validated record: its id, the pose problem, where the result is judged (grasp point, envelope),
    the robot base's view of SF1 if known, and the truth of a synthetic record (or None).

    grasp_point_w : (3,) mm in the part frame (the record's, or the featured points' centroid)
    T_b_s1        : (4, 4) SF1 in the robot base frame, or None (then there is no base offset)
    """

    id: str | None
    problem: PoseProblem
    grasp_point_w: np.ndarray
    envelope: DeviationEnvelope = field(default_factory=DeviationEnvelope)
    T_b_s1: np.ndarray | None = None
    truth_T_s1_w: np.ndarray | None = None
    truth_base_offset: np.ndarray | None = None
    marks: RecordMarks | None = None  # the fixed reference marks and their sightings (solver/record_marks.py)
    view_names: tuple[str, ...] = ()  # views[i].name, or S1, S2, ...

    def displacement(self, T_s1_w: np.ndarray) -> PartDisplacement:
        """How the part at ``T_s1_w`` lies off the reference: at this record's grasp point, and about its
        envelope's point."""
        about_w = self.envelope.about(self.problem.points_w)
        return describe_displacement(T_s1_w, self.problem.T_s1_w0, self.grasp_point_w, about_w, self.T_b_s1)


def parse_record(data: Any, T_f_c: np.ndarray | None = None) -> MeasurementRecord:
    """Validate a decoded JSON object; raise a :class:`RecordError` subclass naming the bad field.

    Strict: a missing required key is :class:`MissingKey`, a key the format does not define (at the top
    level or in the camera, views, observations, view_sigma, envelope, truth) is :class:`UnknownKey`.
    The optional keys have the spec's defaults: ``sigma_px`` :data:`DEFAULT_SIGMA_PX`, no view_sigma,
    the centroid as grasp point, the default envelope, no ``T_b_s1``.

    ``T_f_c`` (4, 4): the camera's pose on the robot flange, which the record format has no place for. With it,
    the record's view sigmas (the robot's repeatability) act at the flange, as the cycle takes them
    (:meth:`PoseProblem.with_flange`); the cycle and ``monoguide journal resolve`` both solve through here.
    """
    record = _parse_record(data)
    problem = record.problem
    if T_f_c is None or not (problem.view_sigma_mm or problem.view_sigma_deg):
        return record
    return replace(record, problem=problem.with_flange(T_f_c))


def solve_record(data: Any, method: str = "ml", *, robust: bool = False,
                 false_alarm_rate: float = DEFAULT_FALSE_ALARM_RATE,
                 T_f_c: np.ndarray | None = None) -> tuple[dict[str, Any], tuple[float, float] | None]:
    """Solve one decoded record as ``monoguide solve`` and ``journal resolve`` report it: the result object of
    the spec (an error object naming what was wrong, for a bad record or a refused solve — a pose beyond the
    record's envelope is an error, not "ok") and, when the record carries its truth, the error against it
    (rotation deg, mm at the grasp point)."""
    record_id = data.get("id") if isinstance(data, dict) and isinstance(data.get("id"), str) else None
    try:
        try:
            record = parse_record(data, T_f_c)
            start = time.perf_counter()
            deviation = None
            if record.marks is not None and method == "ml" and not robust:
                result, fit = solve_record_marks(record.problem, record.marks,
                                                 consistency_false_alarm_rate=false_alarm_rate)
                deviation = camera_deviation(fit)
            else:
                result = solve_pose(record.problem, method, robust=robust, false_alarm_rate=false_alarm_rate)
            elapsed_ms = (time.perf_counter() - start) * 1e3
            check_envelope(record.displacement(result.T_s1_w), record.envelope)
        except RecursionError:  # a record nested too deep for Python, caught while reporting on it
            raise RecordError("nested deeper than Python can read (no record is)") from None
    except MonoguideError as error:
        return error_to_dict(record_id, error), None
    truth_error = None
    if record.truth_T_s1_w is not None:  # rotation, and position error where the part is gripped
        grasp = record.grasp_point_w[None, :]
        moved = frames.transform_points(result.T_s1_w, grasp) - frames.transform_points(record.truth_T_s1_w, grasp)
        truth_error = (frames.pose_difference(result.T_s1_w, record.truth_T_s1_w)[0], float(np.linalg.norm(moved)))
    out = result_to_dict(record, result, elapsed_ms)
    if deviation is not None:
        out["camera_deviation"] = deviation
    return out, truth_error


def _parse_record(data: Any) -> MeasurementRecord:
    if not isinstance(data, dict):
        raise RecordError(f"a record must be a JSON object, got {type(data).__name__}")
    if data.get("format") != FORMAT:
        raise UnsupportedFormat(f"format: expected {FORMAT!r}, got {data.get('format')!r}")
    check_keys(data, REQUIRED_KEYS, OPTIONAL_KEYS, "")
    record_id = data.get("id")
    if record_id is not None and not isinstance(record_id, str):
        raise RecordError(f"id: expected a string or null, got {record_id!r}")
    job, part = data.get("job"), data.get("part")
    if job is not None and (isinstance(job, bool) or not isinstance(job, int) or not 1 <= job <= MAX_JOB):
        raise RecordError(f"job: expected the PLC's job number, an integer 1 to {MAX_JOB}, got {job!r}"[:200])
    if part is not None and (not isinstance(part, str) or not part.strip()):
        raise RecordError(f"part: expected the part type's name, a non-empty string, got {part!r}"[:200])
    camera = CameraModel.from_dict(data["camera"])
    points_w = _matrix(data["points_w"], "points_w", columns=3)
    views = data["views"]
    if not isinstance(views, list) or not views:
        raise RecordError(f"views: expected a non-empty list, got {views!r}"[:200])
    for i, view in enumerate(views):
        check_keys(view, VIEW_KEYS, VIEW_OPTIONAL_KEYS, f"views[{i}]")
        if view.get("name") is not None and (not isinstance(view["name"], str) or not view["name"].strip()):
            raise RecordError(f"views[{i}].name: expected a non-empty string, got {view['name']!r}"[:200])
    view_names = tuple(view.get("name") or f"S{i + 1}" for i, view in enumerate(views))
    T_s1_si = np.stack([_transform(view["T_s1_si"], f"views[{i}].T_s1_si") for i, view in enumerate(views)])
    if not np.allclose(T_s1_si[0], np.eye(4), atol=1e-6):
        raise RecordError("views[0].T_s1_si: must be the identity (SF1 is the frame of the first camera pose)")
    T_s1_w0 = _transform(data["T_s1_w0"], "T_s1_w0")
    view_index, point_index, pixels = _observations(data["observations"], len(views), len(points_w))
    outside = ~camera.in_image(pixels)
    if np.any(outside):
        j = int(np.flatnonzero(outside)[0])
        raise RecordError(
            f"observations[{j}].pixel: {pixels[j].tolist()} lies outside the {camera.width} x {camera.height} image"
        )
    sigma_px = DEFAULT_SIGMA_PX if data.get("sigma_px") is None else _positive(data["sigma_px"], "sigma_px")
    view_sigma_mm = view_sigma_deg = 0.0
    if data.get("view_sigma") is not None:
        view_sigma = data["view_sigma"]
        check_keys(view_sigma, VIEW_SIGMA_KEYS, (), "view_sigma")
        view_sigma_mm = _positive(view_sigma["mm"], "view_sigma.mm", allow_zero=True)
        view_sigma_deg = _positive(view_sigma["deg"], "view_sigma.deg", allow_zero=True)
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
    grasp_point_w = points_w.mean(axis=0)
    if data.get("grasp_point_w") is not None:
        grasp_point_w = _matrix([data["grasp_point_w"]], "grasp_point_w", columns=3)[0]
    T_b_s1 = None if data.get("T_b_s1") is None else _transform(data["T_b_s1"], "T_b_s1")
    truth_T_s1_w = truth_base_offset = None
    if data.get("truth") is not None:
        check_keys(data["truth"], TRUTH_KEYS, TRUTH_OPTIONAL_KEYS, "truth")
        truth_T_s1_w = _transform(data["truth"]["T_s1_w"], "truth.T_s1_w")
        if data["truth"].get("base_offset") is not None:
            truth_base_offset = _transform(data["truth"]["base_offset"], "truth.base_offset")
    envelope = _envelope(data.get("envelope"), grasp_point_w).at(points_w)
    marks = parse_marks(data, len(views), view_names, camera)
    return MeasurementRecord(record_id, problem, grasp_point_w, envelope, T_b_s1, truth_T_s1_w, truth_base_offset,
                             marks, view_names)


def result_to_dict(record: MeasurementRecord, result: PoseResult, time_ms: float) -> dict:
    """The result object of the spec (docs/measurement-record.md) for a solved ``record``.

    record  : the parsed record (its id, reference pose, grasp point and ``T_b_s1``)
    result  : the checked pose from :func:`solver.pose.solve_pose` (its ``consistency`` is reported)
    time_ms : the solve time to report

    Reports; does not judge: the caller checks the envelope first
    (``check_envelope(record.displacement(result.T_s1_w), record.envelope)``). ``base_offset`` and
    ``base_offset_xyzabc`` are null when the record has no ``T_b_s1``.
    """
    d = record.displacement(result.T_s1_w)
    xyzabc = None if d.base_offset is None else [round(v, 6) for v in frames.T_to_kuka_frame(d.base_offset)]
    return {
        "id": record.id,
        "status": "ok",
        "T_s1_w": _rounded(result.T_s1_w),
        "displacement_s1": _rounded(d.displacement_s1),
        "grasp_point_w": [round(float(v), 6) for v in d.grasp_point_w],
        "grasp_shift_mm": round(d.grasp_shift_mm, 6),
        "grasp_shift_s1_mm": [round(float(v), 6) for v in d.grasp_shift_s1],
        "rotation_deg": round(d.rotation_deg, 6),
        "base_offset": None if d.base_offset is None else _rounded(d.base_offset),
        "base_offset_xyzabc": xyzabc,
        "rms_px": round(result.rms_px, 6),
        "covariance": [[float(f"{v:.6g}") for v in row] for row in result.covariance],
        "sigma_rot_deg": round(result.sigma_rot_deg, 6),
        "sigma_trans_mm": round(result.sigma_trans_mm, 6),
        "consistency": None if result.consistency is None else _consistency(record, result),
        "method": result.method,
        "iterations": result.iterations,
        "time_ms": round(time_ms, 3),
    }


def error_to_dict(record_id: str | None, error: MonoguideError) -> dict:
    """The result object of the spec for a record that could not be solved."""
    return {"id": record_id, "status": "error", "error": error.as_dict()}


# --- private helpers ----------------------------------------------------------------------------


def _consistency(record: MeasurementRecord, result: PoseResult) -> dict:
    """The chi-square test the result passed, with the centre noise it was held against (the record's
    ``sigma_px`` or the default, so that a reader sees which)."""
    return {**result.consistency.as_dict(), "sigma_px": record.problem.sigma_px}


def _envelope(value: Any, grasp_point_w: np.ndarray) -> DeviationEnvelope:
    """The record's ``envelope`` (None: the default). The old form (``mm``, ``deg``, ``axis_mm``, ``axis_deg``)
    is read as it was judged: about the grasp point, its per-axis limits the totals unless given."""
    if value is None:
        return DeviationEnvelope()
    if isinstance(value, dict) and any(key in value for key in OLD_ENVELOPE_KEYS + OLD_ENVELOPE_OPTIONAL_KEYS):
        mixed = [key for key in ENVELOPE_KEYS + ENVELOPE_OPTIONAL_KEYS if key in value]
        if mixed:
            raise RecordError(f"envelope: {', '.join(mixed)} beside the old form's keys (mm, deg, axis_mm, "
                              "axis_deg): give one form")
        check_keys(value, OLD_ENVELOPE_KEYS, OLD_ENVELOPE_OPTIONAL_KEYS, "envelope")
        total_mm, total_deg = _positive(value["mm"], "envelope.mm"), _positive(value["deg"], "envelope.deg")
        return DeviationEnvelope(_limits(value, "axis_mm", (total_mm,) * 3),
                                 _limits(value, "axis_deg", (total_deg,) * 3),
                                 tuple(float(v) for v in grasp_point_w), total_mm, total_deg)
    check_keys(value, ENVELOPE_KEYS, ENVELOPE_OPTIONAL_KEYS, "envelope")
    about_w = None if value.get("about_w") is None else _matrix([value["about_w"]], "envelope.about_w", columns=3)[0]
    totals = [None if value.get(key) is None else _positive(value[key], f"envelope.{key}")
              for key in ("total_mm", "total_deg")]
    return DeviationEnvelope(_limits(value, "translation_mm"), _limits(value, "rotation_deg"),
                             None if about_w is None else tuple(float(v) for v in about_w), *totals)


def envelope_to_record(envelope: DeviationEnvelope) -> dict[str, Any]:
    """The record's ``envelope`` object for ``envelope``: its per-axis limits, its point (when resolved) and its
    totals (when set; else the reader takes the norms, as the envelope does)."""
    out: dict[str, Any] = {"translation_mm": list(envelope.translation_mm), "rotation_deg": list(envelope.rotation_deg)}
    if envelope.about_w is not None:
        out["about_w"] = list(envelope.about_w)
    for key in ("total_mm", "total_deg"):
        if getattr(envelope, key) is not None:
            out[key] = float(getattr(envelope, key))
    return out


def _limits(value: dict[str, Any], key: str, default: tuple[float, float, float] | None = None
            ) -> tuple[float, float, float]:
    """Three limits > 0 of the envelope's ``key`` (``default`` when absent or null)."""
    if value.get(key) is None and default is not None:
        return default
    row = _matrix([value[key]], f"envelope.{key}", columns=3)[0]
    x, y, z = (_positive(float(v), f"envelope.{key}[{i}]") for i, v in enumerate(row))
    return x, y, z


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
    matrices to a few decimals: up to ``frames.ORTHONORMAL_TOL`` is rounding, beyond it an error)."""
    return frames.rigid_transform(_matrix(value, where, columns=4, rows=4), where)


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
        check_keys(obs, OBSERVATION_KEYS, (), where)
        view, point = obs["view"], obs["point"]
        for name, index, count in (("view", view, n_views), ("point", point, n_points)):
            if isinstance(index, bool) or not isinstance(index, int):
                raise RecordError(f"{where}.{name}: expected an integer index, got {index!r}")
            if not 0 <= index < count:
                raise UnknownReference(f"{where}.{name}: {index} does not exist (the record has {count} {name}s)")
        if (view, point) in seen:
            raise UnknownReference(f"{where}: point {point} is observed twice in view {view}")
        seen.add((view, point))
        pixel = _matrix([obs["pixel"]], f"{where}.pixel", columns=2)[0]
        views.append(view)
        points.append(point)
        pixels.append(pixel)
    return np.array(views, dtype=int), np.array(points, dtype=int), np.array(pixels).reshape(-1, 2)


def _rounded(T: np.ndarray) -> list[list[float]]:
    return [[round(float(v), 9) for v in row] for row in T]
