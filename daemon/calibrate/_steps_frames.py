"""Steps 1-3 of ``monoguide calibrate``: camera intrinsics, the cell frame CF (and, on a cell with
``[[reference_marks]]``, its fixed marks surveyed in it: the ``marks`` step), the robot base BF.

Each step gathers its measurements through the rig's devices, asking the operator for what a person must
do, and calls the solver (``monoguide.solver.calibration``); a solver refusal (degenerate geometry, too few
views, a residual above tolerance) leaves the step as the session's refusal. Results are JSON-able dicts
(docs/calibration.md, "The session file").
"""

from __future__ import annotations

from typing import Any

import numpy as np

from monoguide.daemon.calibrate._earlier import earlier_matrix
from monoguide.daemon.calibrate._rig import (
    CLEAR_VIEW,
    MOUNT_FLANGE_SMR,
    PLACE_SMR,
    SHOW_PLATE,
    UNMOUNT_FLANGE_SMR,
    CalibrationRig,
    no_marks_message,
)
from monoguide.drivers.errors import ConfigError
from monoguide.solver.calibration.base import fit_robot_base
from monoguide.solver.calibration.cell import DEFAULT_MAX_RESIDUAL_MM, cell_frame_321, fit_cell_frame
from monoguide.solver.calibration.errors import CalibrationImageRejected, CalibrationResidualTooLarge
from monoguide.solver.calibration.intrinsics import CirclePlate, calibrate_from_centres, detect_plate
from monoguide.solver.frames import transform_points
from monoguide.solver.hole_edges import bit_depth_of

CELL_METHODS = ("best-fit", "3-2-1")
FLANGE_NEST = "TCP"  # the tracker's name of the SMR on the flange tool


def run_intrinsics(rig: CalibrationRig, earlier: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """Step 1: ``plate_images`` images of the circle plate, each detected as it comes (rejected ones with the
    reason), then Zhang's calibration (:func:`calibrate_from_centres`)."""
    plate = CirclePlate()
    n = rig.options.plate_images
    timeout_s = rig.config.camera.grab_timeout_s
    centres: dict[int, np.ndarray] = {}
    rejected: dict[int, str] = {}
    width = height = 0
    for k in range(n):
        rig.operator.ask(SHOW_PLATE, f"hold the circle plate in view, position {k + 1} of {n} (tilt it up to 40 deg, "
                         "let it reach the image's corners)", k=k, n=n)
        frame = rig.camera.grab(timeout_s)
        image = _grey8(frame.image, frame.pixel_format)
        height, width = image.shape[:2]
        try:
            centres[k] = detect_plate(image, plate).centers_px
            rig.progress(f"plate image {k + 1}/{n}: ok, {len(centres[k])} circles")
        except CalibrationImageRejected as exc:
            rejected[k] = exc.message
            rig.progress(f"plate image {k + 1}/{n}: rejected: {exc.message}")
    rig.operator.ask(CLEAR_VIEW, "take the circle plate out of the camera's view")
    if not n:
        raise CalibrationImageRejected("intrinsics: no plate images asked for (--plate-images 0)")
    result = calibrate_from_centres(centres, plate, width, height, rejected=rejected)
    used = sorted(result.per_image_rms_px)
    return {"camera": result.camera.as_dict(), "rms_px": float(result.rms_px),
            "per_image_rms_px": [float(result.per_image_rms_px[k]) for k in used],
            "used_images": [k + 1 for k in used],
            "rejected": {str(k + 1): why for k, why in sorted(result.rejected.items())}, "images": n,
            "plate": {"cols": plate.cols, "rows": plate.rows, "pitch_mm": plate.pitch_mm,
                      "radius_mm": plate.radius_mm}}


def run_cell(rig: CalibrationRig, earlier: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """Step 2: the tracker measures each benchmark nest; ``T_cf_tracker`` by the best fit onto their nominal
    coordinates, or 3-2-1 (origin at the first benchmark, x towards the second, xy plane through the third)."""
    method = rig.options.cell_method
    if method not in CELL_METHODS:
        raise ConfigError(f"cell frame: method {method!r} is not one of {', '.join(CELL_METHODS)}")
    nominal = benchmark_nominals(rig)
    measured: dict[str, np.ndarray] = {}
    for k, name in enumerate(nominal, start=1):
        rig.operator.ask(PLACE_SMR, f"place the SMR in benchmark nest {name}", nest=name)
        reading = rig.tracker.measure_point(nest=name)
        measured[name] = np.asarray(reading.point_mm, dtype=float).reshape(3)
        x, y, z = measured[name]
        rig.progress(f"benchmark {name} ({k}/{len(nominal)}): {x:.3f} {y:.3f} {z:.3f} mm (tracker frame)")
    if method == "best-fit":
        fit = fit_cell_frame(nominal, measured)
        T_cf_tracker = fit.T
    else:
        names = list(nominal)[:3]
        T_cf_tracker = cell_frame_321(measured, *names) if len(names) == 3 else fit_cell_frame(nominal, measured).T
    residuals = {n: float(np.linalg.norm(transform_points(T_cf_tracker, measured[n].reshape(1, 3))[0] - nominal[n]))
                 for n in measured}
    worst = max(residuals, key=residuals.__getitem__)
    if method == "3-2-1" and residuals[worst] > DEFAULT_MAX_RESIDUAL_MM:
        listed = ", ".join(f"{n} {r:.3f}" for n, r in residuals.items())
        raise CalibrationResidualTooLarge(
            f"cell frame (3-2-1): benchmark {worst} is {residuals[worst]:.3f} mm from its nominal coordinates "
            f"(tolerance {DEFAULT_MAX_RESIDUAL_MM:g} mm; residuals mm: {listed}): a nest or a nominal is wrong")
    rms = float(np.sqrt(np.mean(np.square(list(residuals.values())))))
    return {"method": method, "T_cf_tracker": T_cf_tracker.tolist(), "residuals_mm": residuals, "rms_mm": rms}


# --- the marks step: right after cell, on a cell with [[reference_marks]] only ----------------------------------
#
# Each mark has an SMR nest of its own name, a hidden-point nest: the SMR set in it has its centre at the mark's
# centre. The tracker's reading (its own frame) goes into CF with the cell step's T_cf_tracker and is checked
# against the mark's nominal position_cf: an SMR in the wrong nest gives a wrong mark, which would shift every
# cycle's view of it, so a mark farther than marks_tolerance_mm (5 mm) refuses the step, naming it, the distance
# and the nominal the reading is nearest to. The measured positions are written into [[reference_marks]]
# position_cf (docs/calibration.md, "The marks step").


def run_marks(rig: CalibrationRig, earlier: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """The tracker measures each reference mark's hidden-point nest (by the mark's name); each reading in CF
    (``T_cf_tracker`` of ``cell``) against the mark's nominal ``position_cf``. Refused
    (:class:`CalibrationResidualTooLarge`) when a mark is more than ``marks_tolerance_mm`` from its nominal, after
    every mark is measured (the progress says so at once, mark by mark)."""
    marks = rig.config.reference_marks
    if not marks:
        raise ConfigError(f"step 'marks': {no_marks_message(str(rig.config_path))}")
    T_cf_tracker = earlier_matrix(earlier, "marks", "cell", "T_cf_tracker")
    tolerance = float(rig.options.marks_tolerance_mm)
    nominals = {m.name: np.asarray(m.position_cf, dtype=float).reshape(3) for m in marks}
    measured: list[dict[str, Any]] = []
    n = len(marks)
    for k, mark in enumerate(marks, start=1):
        rig.operator.ask(PLACE_SMR, f"place the SMR in the nest of reference mark {mark.name} ({k} of {n}; its "
                         "hidden-point nest: the SMR's centre at the mark's centre)", nest=mark.name)
        reading = rig.tracker.measure_point(nest=mark.name)
        point = np.asarray(reading.point_mm, dtype=float).reshape(3)
        p_cf = transform_points(T_cf_tracker, point.reshape(1, 3))[0]
        offset = p_cf - nominals[mark.name]
        deviation = float(np.linalg.norm(offset))
        entry = {"name": mark.name, "position_cf": p_cf.tolist(), "nominal_cf": nominals[mark.name].tolist(),
                 "deviation_cf": offset.tolist(), "deviation_mm": deviation, "tracker_rms_mm": float(reading.rms_mm),
                 "point_tracker": point.tolist()}
        measured.append(entry)
        x, y, z = p_cf
        line = (f"mark {mark.name} ({k}/{n}): {x:.3f} {y:.3f} {z:.3f} mm (CF), {deviation:.3f} mm from its nominal, "
                f"tracker RMS {reading.rms_mm:.4f} mm")
        if deviation > tolerance:
            line += f": beyond the {tolerance:g} mm tolerance: {_which_nest(mark.name, p_cf, nominals)}"
        rig.progress(line)
    wrong = [e for e in measured if e["deviation_mm"] > tolerance]
    if wrong:
        listed = "; ".join(f"{e['name']} {e['deviation_mm']:.3f} mm: "
                           f"{_which_nest(e['name'], np.asarray(e['position_cf']), nominals)}" for e in wrong)
        raise CalibrationResidualTooLarge(
            f"reference marks: {len(wrong)} of {n} measured farther than {tolerance:g} mm from their nominal "
            f"position_cf: {listed} (put the SMR in the right nest and redo the step, monoguide calibrate marks; "
            "or correct the nominal; a mark moved on purpose: --values with a larger marks-tolerance-mm)")
    deviations = np.array([e["deviation_mm"] for e in measured])
    worst = measured[int(np.argmax(deviations))]
    return {"marks": measured, "tolerance_mm": tolerance, "max_deviation_mm": float(deviations.max()),
            "max_deviation_mark": worst["name"], "rms_deviation_mm": float(np.sqrt(np.mean(deviations ** 2))),
            "max_tracker_rms_mm": max(e["tracker_rms_mm"] for e in measured)}


def _which_nest(name: str, p_cf: np.ndarray, nominals: dict[str, np.ndarray]) -> str:
    """What an operator makes of a reading far from its mark: the nominal it is nearest to, if another's."""
    distances = {other: float(np.linalg.norm(p_cf - p)) for other, p in nominals.items()}
    nearest = min(distances, key=distances.__getitem__)
    if nearest != name:
        return (f"the reading is {distances[nearest]:.3f} mm from mark {nearest}'s nominal: is the SMR in "
                f"{nearest}'s nest instead of {name}'s?")
    return f"is the SMR in {name}'s nest, and is its nominal position_cf right?"


def run_base(rig: CalibrationRig, earlier: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """Step 3: the robot carries the SMR on its flange to calibration poses 1..``base_poses``; at each the
    controller's flange pose and the tracker's reading (mapped into CF) go into :func:`fit_robot_base`."""
    T_cf_tracker = earlier_matrix(earlier, "base", "cell", "T_cf_tracker")
    n = rig.options.base_poses
    rig.operator.ask(MOUNT_FLANGE_SMR, f"fit the SMR tool on the robot flange (nest {FLANGE_NEST}); the robot will "
                     f"then move to its {n} base-calibration poses: keep the cell clear")
    flange: list[np.ndarray] = []
    smr_cf: list[np.ndarray] = []
    for k in range(1, n + 1):
        status = rig.robot.move_to_calibration_pose(k)
        reading = rig.tracker.measure_point(nest=FLANGE_NEST)
        p_cf = transform_points(T_cf_tracker, np.asarray(reading.point_mm, dtype=float).reshape(1, 3))[0]
        flange.append(np.asarray(status.T_b_f, dtype=float))
        smr_cf.append(p_cf)
        x, y, z = p_cf
        rig.progress(f"base pose {k}/{n}: SMR at {x:.3f} {y:.3f} {z:.3f} mm (CF)")
    rig.operator.ask(UNMOUNT_FLANGE_SMR, "take the SMR tool off the robot flange")
    fit = fit_robot_base(flange, np.array(smr_cf).reshape(-1, 3))
    return {"T_cf_b": fit.T_cf_b.tolist(), "smr_f": fit.smr_f.tolist(), "residuals_mm": fit.residuals_mm.tolist(),
            "rms_mm": fit.rms_mm, "sigma_mm": fit.sigma_mm, "sigma_deg": fit.sigma_deg,
            "flange_poses": [T.tolist() for T in flange]}


def benchmark_nominals(rig: CalibrationRig) -> dict[str, np.ndarray]:
    """The benchmark nests' nominal CF coordinates: ``[cell_frame] benchmarks``, on a simulated cell config
    without it ``[sim.benchmarks]``."""
    cell_frame = getattr(rig.config, "cell_frame", None)
    benchmarks = getattr(cell_frame, "benchmarks", None) if cell_frame is not None else None
    if not benchmarks and rig.config.sim is not None:
        benchmarks = rig.config.sim.benchmarks
    if not benchmarks:
        raise ConfigError(f"{rig.config.path}: no [cell_frame] section: the cell frame needs the benchmark nests' "
                          "nominal coordinates ([cell_frame] benchmarks = { B1 = [x, y, z], ... }, mm in CF)")
    return {str(k): np.asarray(v, dtype=float).reshape(3) for k, v in benchmarks.items()}


def _grey8(image: np.ndarray, pixel_format: str) -> np.ndarray:
    """The frame as 8-bit grey (the plate detector's input): deeper mono formats shifted down."""
    if image.dtype == np.uint8:
        return image
    shift = max(bit_depth_of(pixel_format) - 8, 0)
    return np.clip(np.asarray(image, dtype=np.uint32) >> shift, 0, 255).astype(np.uint8)
