"""The check job (PLC job 65535): the reference part, lying as taught, measured as a part is, and compared with the
calibration (docs/health.md, "The check job"); in a cell whose measuring poses all see fixed reference marks, the
marks alone, no part needed (:func:`marks_check`, ``solver/marks_camera.py``): each view's camera against its
calibrated pose.

Without marks a visit of the measuring poses sees the robot's repeatability as a cycle does (0.23 mm at the roof's
grasp point), so one visit cannot tell a fault of 0.5 mm from it. The check visits them ``[checks] check_visits``
times (default :data:`CHECK_VISITS`) and solves the reference part from every visit's holes together
(:func:`combined_solution`): the repeatability, drawn anew at each stop, averages down by the root of the visits,
the fault does not.

Nothing is written to the robot. The check passes when the solved part lies within ``CHECK_SIGMAS`` of its
predicted σ of the reference (at the grasp point, and its rotation) — with a calibration that still fits, the
reference part is measured where it was taught. It fails with ``CALIBRATION_SUSPECT`` naming how far it was
measured from the reference and, per view, how far the hole's image lies from where the calibration puts the
reference's hole (px, and the camera rotation that offset is: px / f). A check at either limit's σ fails less
than once in 1,000 good checks (a σ here is the root of the covariance's trace: one axis alone at 3.5 σ is
4.7e-4, each of the two limits).
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np

from monoguide.daemon.cycle._record import Measurement, Solution
from monoguide.solver.errors import CalibrationSuspect, InconsistentMeasurement
from monoguide.solver.marks_camera import check_cameras
from monoguide.solver.marks_problem import camera_prior_factor
from monoguide.solver.planning.prediction import pose_sigmas
from monoguide.solver.pose import solve_pose
from monoguide.solver.problem import PoseProblem, reprojection
from monoguide.solver.record_marks import parse_marks

CHECK_SIGMAS = 3.5
CHECK_VISITS = 6  # visits of the measuring poses by a check without marks: 3.5 sigma = 0.33 mm on the roof


def view_offsets(measurement: Measurement, view_names: tuple[str, ...]) -> dict[str, dict[str, float]]:
    """Per view, how far its (farthest) hole's image lies from where the calibration puts the reference part's: px,
    and the camera rotation that offset is (deg)."""
    problem = measurement.parsed.problem
    T0 = problem.T_s1_w0
    offsets, _, _ = reprojection(problem, T0[:3, :3], T0[:3, 3])
    f = float(problem.camera.fx)
    views: dict[str, dict[str, float]] = {}
    for k, (dx, dy) in enumerate(offsets):
        name = view_names[int(problem.view_index[k])]
        px = float(math.hypot(dx, dy))
        if px >= views.get(name, {}).get("px", -1.0):
            views[name] = {"px": round(px, 3), "deg": round(math.degrees(math.atan2(px, f)), 5)}
    return views


def describe_views(views: dict[str, dict[str, float]]) -> str:
    worst = max(views, key=lambda v: views[v]["px"])
    return (f"view {worst}: its hole {views[worst]['px']:.2f} px from where the calibration puts it (the camera "
            f"turned about {views[worst]['deg']:.3f} deg); views: "
            + ", ".join(f"{name} {v['px']:.2f} px" for name, v in views.items()))


def reference_check(measurement: Measurement, solution: Solution, view_names: tuple[str, ...]) -> dict[str, Any]:
    """The check's findings (JSON-able; also on a pass) or :class:`CalibrationSuspect` saying why it failed."""
    displacement = solution.displacement
    assert displacement is not None
    _, sigma_mm, sigma_deg = solution.quality
    shift_mm = float(np.linalg.norm(displacement.grasp_shift_s1))
    rotation_deg = float(displacement.rotation_deg)
    views = view_offsets(measurement, view_names)
    limit_mm, limit_deg = CHECK_SIGMAS * sigma_mm, CHECK_SIGMAS * sigma_deg
    found = {"shift_mm": round(shift_mm, 4), "rotation_deg": round(rotation_deg, 5), "limit_mm": round(limit_mm, 4),
             "limit_deg": round(limit_deg, 5), "views": views, "passed": shift_mm <= limit_mm and
             rotation_deg <= limit_deg, "method": "reference part",
             "summary": f"the reference part within {shift_mm:.3f} mm / {rotation_deg:.4f} deg of its calibration "
                        f"(limits {limit_mm:.3f} mm / {limit_deg:.4f} deg)"}
    if not found["passed"]:
        raise CalibrationSuspect(
            f"check job: the reference part was measured {shift_mm:.3f} mm / {rotation_deg:.4f} deg from where it was "
            f"taught (limits {limit_mm:.3f} mm / {limit_deg:.4f} deg, {CHECK_SIGMAS:g} x its predicted sigma); "
            + describe_views(views))
    return found


def solve_and_check(runner: Any, measurement: Measurement, *more: Measurement) -> tuple[Solution, dict[str, Any]]:
    """The check's solve (``runner.solve`` of each visit, :func:`combined_solution` of them all) and
    :func:`reference_check`: the solution and the findings, or :class:`CalibrationSuspect` (a reference part that does
    not even fit the calibration names every view too). ``more``: the measurements of further visits."""
    if measurement.parsed is None:  # the marks alone
        return marks_check(runner, measurement)
    names = tuple(p.name for p in runner.config.measuring_poses)
    solutions = []
    for visit in (measurement, *more):
        try:
            solutions.append(runner.solve(visit))
        except InconsistentMeasurement as exc:
            raise CalibrationSuspect(f"check job: the reference part does not fit the calibration: {exc.message}; "
                                     + describe_views(view_offsets(visit, names))) from exc
    solution = solutions[0] if not more else combined_solution(runner, [measurement, *more], solutions[0])
    found = reference_check(measurement, solution, names)
    found["visits"] = 1 + len(more)
    solution.result["check"] = found
    return solution, found


def combined_solution(runner: Any, visits: list[Measurement], first: Solution) -> Solution:
    """The reference part solved from every visit's (perspective-corrected) holes together, in the first visit's SF1:
    each visit's views moved into it by where its SF1 stood (``T_cf_b T_b_s1``), its own camera poses kept. The
    first visit's solution with that pose, its displacement and its quality."""
    T_cf_b = runner.config.reference.T_cf_b
    base = visits[0].parsed
    T_s1a_cf = np.linalg.inv(T_cf_b @ base.T_b_s1)
    views, view_index, point_index, pixels = [], [], [], []
    for visit in visits:
        p = visit.parsed.problem
        T_a_b = T_s1a_cf @ T_cf_b @ visit.parsed.T_b_s1
        view_index.append(p.view_index + len(views))
        views.extend(T_a_b @ T for T in p.T_s1_si)
        point_index.append(p.point_index)
        pixels.append(p.pixels)
    h = base.problem
    problem = PoseProblem(h.camera, h.points_w, np.array(views), np.concatenate(view_index),
                          np.concatenate(point_index), np.concatenate(pixels), h.T_s1_w0, h.sigma_px,
                          h.view_sigma_mm, h.view_sigma_deg, h.T_f_c)
    result = solve_pose(problem, "ml", false_alarm_rate=runner.checks.false_alarm_rate)
    sigmas = pose_sigmas(result.covariance, result.T_s1_w, base.grasp_point_w)
    return replace(first, T_s1_w=result.T_s1_w, displacement=base.displacement(result.T_s1_w),
                   quality=(result.rms_px, sigmas.sigma_trans_mm, sigmas.sigma_rot_deg))


def marks_check(runner: Any, measurement: Measurement) -> tuple[Solution, dict[str, Any]]:
    """The check of a cell with marks: every view's camera, from its marks alone, against its calibrated pose
    (:func:`solver.marks_camera.check_cameras`, one false failure per 1,000 good checks); the solution (nothing to
    write: a zero offset) and the findings, or :class:`CalibrationSuspect` naming the views and their deviations."""
    record = measurement.record
    names = tuple(view["name"] for view in record["views"])
    marks = parse_marks(record, len(names), names)
    assert marks is not None, "a check of marks alone measured no marks"
    sigma = record.get("view_sigma") or {"mm": 0.0, "deg": 0.0}
    prior = camera_prior_factor(sigma["mm"], sigma["deg"], runner.config.camera.T_f_c, marks.calibration_sigma_mm,
                                marks.calibration_sigma_deg)
    checked = check_cameras(runner.config.camera.intrinsics, [np.array(v["T_s1_si"]) for v in record["views"]],
                            marks.marks, marks.mark_view, marks.mark_index, marks.mark_pixels, names, prior,
                            float(record["sigma_px"]))
    worst = max(checked.views, key=lambda c: c.statistic / c.threshold)
    found: dict[str, Any] = {
        "method": "marks", "passed": checked.passed, "views": {c.view: c.as_dict() for c in checked.views},
        "statistic": round(checked.statistic, 3), "dof": checked.dof, "threshold": round(checked.threshold, 3),
        "common_mm": round(checked.common_mm, 5), "common_deg": round(checked.common_deg, 6),
        "summary": f"every camera where it was calibrated (the farthest: view {worst.view}, {worst.mm:.3f} mm / "
                   f"{worst.deg:.4f} deg)"}
    if not checked.passed:
        failed = [c for c in checked.views if not c.passed]
        if failed:
            text = "; ".join(f"view {c.view}: its camera stood {c.mm:.3f} mm / {c.deg:.4f} deg from its calibrated "
                             f"pose (its {c.marks} marks: chi-square {c.statistic:.1f} > {c.threshold:.1f} on {c.dof})"
                             for c in failed)
        else:
            text = (f"the cameras of every view moved together by {checked.common_mm:.3f} mm / "
                    f"{checked.common_deg:.4f} deg in their axes, as a camera knocked on its bracket does (chi-square "
                    f"{checked.statistic:.1f} > {checked.threshold:.1f} on {checked.dof}; no view alone beyond its "
                    "own tolerance)")
        raise CalibrationSuspect(f"check job (reference marks): {text}; the camera moved on its bracket, the lens "
                                 "changed or the measuring pose is not where it was calibrated: recalibrate")
    solution = Solution(
        result={"status": "ok", "check": found, "camera_deviation": [
            {**c.as_dict(), "checked": True} for c in checked.views]},
        D_b=np.eye(4), offset=(0.0, 0.0, 0.0, 0.0, 0.0, 0.0), quality=(0.0, 0.0, 0.0),
        timings_s=measurement.timings_s, last_frame_at=measurement.last_frame_at, images=measurement.images)
    return solution, found
