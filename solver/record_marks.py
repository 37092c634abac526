"""The fixed reference marks of a measurement record (docs/measurement-record.md, "Reference marks"): parsed into
:class:`RecordMarks`, solved with the holes (:func:`solve_record_marks`), and the cameras' deviations reported.

A record with marks carries, beside today's keys, ``marks`` (each mark's name and surveyed centre in SF1, its survey
sigma), ``mark_observations`` (view, mark, pixel: the image of the mark's centre, perspective-corrected) and
optionally ``calibration_sigma`` (the calibration's own sigma of each camera pose, per camera axis). Its views may be
named (``views[i].name``), so that a refusal names the measuring pose. The solve is :mod:`solver.marks_check`'s:
the part pose with a 6-DOF correction of every view's camera, the repeatability (``view_sigma``) its prior.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from monoguide.solver.camera import CameraModel
from monoguide.solver.errors import MissingKey, NonFiniteValue, RecordError, UnknownReference
from monoguide.solver.marks import MarksResult, fit_marks
from monoguide.solver.marks_check import (
    DEFAULT_MARKS_FALSE_ALARM_RATE,
    as_pose_result,
    assess_marks,
    view_deviation,
)
from monoguide.solver.marks_problem import CALIBRATION_SIGMA_DEG, CALIBRATION_SIGMA_MM, MarksProblem, ReferenceMark
from monoguide.solver.pose import DEFAULT_FALSE_ALARM_RATE, PoseResult
from monoguide.solver.problem import PoseProblem
from monoguide.solver.record_keys import check_keys

MARKS_KEYS = ("marks", "mark_observations", "calibration_sigma")  # optional top-level keys of the record
MARK_KEYS, MARK_OPTIONAL_KEYS = ("name", "position_s1"), ("sigma_mm",)
MARK_OBSERVATION_KEYS = ("view", "mark", "pixel")
CALIBRATION_SIGMA_KEYS = ("mm", "deg")


@dataclass(frozen=True)
class RecordMarks:
    """The marks of a record: their surveyed centres in SF1 and their sightings (raw px, centre-corrected)."""

    marks: tuple[ReferenceMark, ...]
    mark_view: np.ndarray
    mark_index: np.ndarray
    mark_pixels: np.ndarray
    view_names: tuple[str, ...]
    calibration_sigma_mm: float = CALIBRATION_SIGMA_MM
    calibration_sigma_deg: float = CALIBRATION_SIGMA_DEG

    def problem(self, holes: PoseProblem) -> MarksProblem:
        """The marks problem over ``holes`` (the record's hole problem, at the flange; the marks are in SF1, so
        ``T_cf_s1`` is the identity). The marks' centre noise is the holes'."""
        return MarksProblem(holes, np.eye(4), self.marks, self.mark_view, self.mark_index, self.mark_pixels,
                            self.view_names, holes.sigma_px, self.calibration_sigma_mm, self.calibration_sigma_deg)

    def with_pixels(self, pixels: np.ndarray) -> RecordMarks:
        return replace(self, mark_pixels=np.asarray(pixels, dtype=float).reshape(-1, 2))


def parse_marks(data: dict[str, Any], n_views: int, view_names: tuple[str, ...],
                camera: CameraModel | None = None) -> RecordMarks | None:
    """The record's marks, or None when it has none; :class:`RecordError` subclasses naming the bad field (with
    ``camera``, a sighting outside its image too)."""
    if data.get("marks") is None:
        if data.get("mark_observations"):
            raise MissingKey("marks: missing (the record has mark_observations)")
        return None
    marks_value = data["marks"]
    if not isinstance(marks_value, list) or not marks_value:
        raise RecordError(f"marks: expected a non-empty list, got {marks_value!r}"[:200])
    marks = []
    for i, m in enumerate(marks_value):
        check_keys(m, MARK_KEYS, MARK_OPTIONAL_KEYS, f"marks[{i}]")
        name = m["name"]
        if not isinstance(name, str) or not name.strip():
            raise RecordError(f"marks[{i}].name: expected a non-empty string, got {name!r}"[:200])
        position = _numbers(m["position_s1"], 3, f"marks[{i}].position_s1")
        sigma = 0.025 if m.get("sigma_mm") is None else _positive(m["sigma_mm"], f"marks[{i}].sigma_mm")
        marks.append(ReferenceMark(name, position, sigma))
    observations = data.get("mark_observations") or []
    if not isinstance(observations, list):
        raise RecordError(f"mark_observations: expected a list, got {observations!r}"[:200])
    views, index, pixels = [], [], []
    for j, o in enumerate(observations):
        where = f"mark_observations[{j}]"
        check_keys(o, MARK_OBSERVATION_KEYS, (), where)
        for key, count in (("view", n_views), ("mark", len(marks))):
            value = o[key]
            if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value < count:
                raise UnknownReference(f"{where}.{key}: {value!r} is not one of the record's {count} {key}s"[:200])
        views.append(o["view"])
        index.append(o["mark"])
        pixel = _numbers(o["pixel"], 2, f"{where}.pixel")
        if camera is not None and not camera.in_image(pixel[None])[0]:
            raise RecordError(f"{where}.pixel: {pixel.tolist()} lies outside the {camera.width} x {camera.height} "
                              "image")
        pixels.append(pixel)
    sigma_mm, sigma_deg = CALIBRATION_SIGMA_MM, CALIBRATION_SIGMA_DEG
    if data.get("calibration_sigma") is not None:
        check_keys(data["calibration_sigma"], CALIBRATION_SIGMA_KEYS, (), "calibration_sigma")
        sigma_mm = _positive(data["calibration_sigma"]["mm"], "calibration_sigma.mm")
        sigma_deg = _positive(data["calibration_sigma"]["deg"], "calibration_sigma.deg")
    return RecordMarks(tuple(marks), np.array(views, dtype=int), np.array(index, dtype=int),
                       np.array(pixels, dtype=float).reshape(-1, 2), view_names, sigma_mm, sigma_deg)


def solve_record_marks(
    holes: PoseProblem,
    marks: RecordMarks,
    *,
    false_alarm_rate: float = DEFAULT_MARKS_FALSE_ALARM_RATE,
    consistency_false_alarm_rate: float = DEFAULT_FALSE_ALARM_RATE,
    T_init: np.ndarray | None = None,
) -> tuple[PoseResult, MarksResult]:
    """The part pose with the marks, checked: (the pose as the cycle uses it, the fit with its cameras); raises
    :class:`CalibrationSuspect` (a view's camera, the cameras together, a mark) or :class:`InconsistentMeasurement`,
    carrying the cameras' deviations all the same (``error.camera_deviation``, :func:`camera_deviation`: the journal
    keeps them, a refused cycle is the one that matters most). The holes problem needs the robot's repeatability
    (``view_sigma``): it is the cameras' prior."""
    if not (holes.view_sigma_mm or holes.view_sigma_deg):
        raise RecordError("view_sigma: a record with marks needs the robot's repeatability (view_sigma), the prior "
                          "of where each camera stood")
    result = fit_marks(marks.problem(holes), T_init)
    result.assessment = assess_marks(result, false_alarm_rate, consistency_false_alarm_rate)
    if result.assessment.refusal is not None:
        refusal = result.assessment.refusal
        refusal.camera_deviation = camera_deviation(result)  # type: ignore[attr-defined]
        raise refusal
    return as_pose_result(result), result


def camera_deviation(result: MarksResult) -> list[dict[str, Any]]:
    """Per view: where its camera stood relative to its calibrated pose as the marks measure it (``d_mm``, ``w_deg``
    in the camera's axes, the fit's correction; ``mm``/``deg`` the measured deviation, the prior left out), whether
    it was checked (2 marks or more) and its tolerance in the direction observed (JSON-ready; the journal keeps it
    and ``monoguide health`` plots it)."""
    assessment = result.assessment
    out = []
    for v, camera in enumerate(result.cameras):
        entry: dict[str, Any] = {
            "view": camera.view, "checked": bool(camera.checked), "marks": int(camera.marks),
            "d_mm": [round(float(x), 6) for x in camera.correction[3:]],
            "w_deg": [round(math.degrees(float(x)), 7) for x in camera.correction[:3]],
            "mm": 0.0, "deg": 0.0, "tolerance_mm": None, "tolerance_deg": None}
        test = assessment.test("view", v) if assessment is not None else None
        if camera.checked and test is not None and test.dof > 0:
            [(_, mm, deg)] = view_deviation(result, test)
            scale = math.sqrt(test.threshold / test.statistic) if test.threshold and test.statistic > 0 else None
            entry.update(mm=round(mm, 6), deg=round(deg, 7), statistic=round(test.statistic, 4),
                         threshold=None if test.threshold is None else round(test.threshold, 4))
            if scale is not None:
                entry.update(tolerance_mm=round(scale * mm, 6), tolerance_deg=round(scale * deg, 7))
        out.append(entry)
    return out


def _numbers(value: Any, n: int, where: str) -> np.ndarray:
    ok = isinstance(value, list) and len(value) == n and all(
        isinstance(v, int | float) and not isinstance(v, bool) for v in value)
    if not ok:
        raise RecordError(f"{where}: expected {n} numbers, got {value!r}"[:200])
    arr = np.array(value, dtype=float)
    if not np.all(np.isfinite(arr)):
        raise NonFiniteValue(f"{where}: {value!r} is not finite"[:200])
    return arr


def _positive(value: Any, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value) or value <= 0:
        raise RecordError(f"{where}: expected a positive number, got {value!r}"[:200])
    return float(value)
