"""The check job (PLC job 65535): the reference part, lying as taught, measured as a part is, and compared with the
calibration (docs/health.md, "The check job").

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
from typing import Any

import numpy as np

from monoguide.daemon.cycle._record import Measurement, Solution
from monoguide.solver.errors import CalibrationSuspect, InconsistentMeasurement
from monoguide.solver.problem import reprojection

CHECK_SIGMAS = 3.5


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
             rotation_deg <= limit_deg}
    if not found["passed"]:
        raise CalibrationSuspect(
            f"check job: the reference part was measured {shift_mm:.3f} mm / {rotation_deg:.4f} deg from where it was "
            f"taught (limits {limit_mm:.3f} mm / {limit_deg:.4f} deg, {CHECK_SIGMAS:g} x its predicted sigma); "
            + describe_views(views))
    return found


def solve_and_check(runner: Any, measurement: Measurement) -> tuple[Solution, dict[str, Any]]:
    """The check's solve (``runner.solve``) and :func:`reference_check`: the solution and the findings, or
    :class:`CalibrationSuspect` (a reference part that does not even fit the calibration names every view too)."""
    names = tuple(p.name for p in runner.config.measuring_poses)
    try:
        solution = runner.solve(measurement)
    except InconsistentMeasurement as exc:
        raise CalibrationSuspect(f"check job: the reference part does not fit the calibration: {exc.message}; "
                                 + describe_views(view_offsets(measurement, names))) from exc
    found = reference_check(measurement, solution, names)
    solution.result["check"] = found
    return solution, found
