"""Steps 6 and 7 of ``monoguide calibrate`` (docs/calibration.md): the new calibration checked by the cycle's own
measurement, the verification and the accuracy validation (Table 3).

Each step is ``run_<step>(rig, earlier) -> dict`` as the others (``_steps_part``). It measures the part as the
cycle does (measure + solve with the calibration of the earlier steps, no offset written) with a
:class:`~monoguide.daemon.cycle.CycleRunner` of its own, whose worker threads end with the step. A failed
Table-3 verdict is a result (``passed`` false), not a refusal.

- ``verify``: the reference part measured ``repeats`` times; the repeatability beside the planner's predicted
  sigma; ``T_s1_w0`` is their mean.
- ``accuracy``: a part in ``accuracy_poses`` new poses, its displacement from the reference measured by the
  camera and by the tracker (featured holes); Table 3 and its verdict.
"""

from __future__ import annotations

import threading
from typing import Any

import numpy as np

from monoguide.daemon.calibrate._earlier import calibrated_config, earlier_matrix
from monoguide.daemon.calibrate._rig import PLACE_PART, CalibrationRig
from monoguide.daemon.calibrate._steps_part import measure_part_frame
from monoguide.daemon.config import CellConfig
from monoguide.daemon.cycle import CycleRunner
from monoguide.daemon.errors import CalibrationMeasurementFailed, CycleAborted
from monoguide.drivers.errors import ConfigError, DeviceError
from monoguide.solver.calibration.verify import repeatability, table3
from monoguide.solver.errors import MonoguideError
from monoguide.solver.frames import compose, invert, transform_points
from monoguide.solver.planning.prediction import pose_sigmas
from monoguide.solver.record import parse_record
from monoguide.solver.uncertainty import predicted_covariance


def run_verify(rig: CalibrationRig, earlier: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """Repeated camera measurements of the reference part with the new calibration: repeatability, ``T_s1_w0``
    (their mean) and the planner's predicted sigma for this layout."""
    config = calibrated_config(rig.config, earlier, "verify")
    repeats = rig.options.repeats
    with _runner(rig, config) as runner:
        rig.operator.ask(PLACE_PART, "put the reference part in place (no SMR in its holes)", part="reference")
        poses, record = [], None
        for r in range(repeats):
            T, record = _camera_measurement(runner, f"verification, measurement {r + 1} of {repeats} of the "
                                                    f"reference part")
            poses.append(T)
            rig.progress(f"verify: measurement {r + 1} of {repeats}: part at "
                         f"{np.array2string(T[:3, 3], precision=3)} mm in SF1")
    rep = repeatability(poses)
    assert record is not None
    parsed = parse_record(record)
    problem = parsed.problem.with_flange(config.camera.T_f_c)  # the repeatability acts at the flange
    sig = pose_sigmas(predicted_covariance(problem, rep.T_mean), rep.T_mean, parsed.grasp_point_w)
    grasp = np.array([transform_points(T, parsed.grasp_point_w.reshape(1, 3))[0] for T in poses])
    sigma_grasp = float(np.sqrt(np.sum(grasp.std(axis=0, ddof=1) ** 2)))
    sigma_deg_total = float(np.sqrt(np.sum(rep.sigma_deg**2)))
    rig.progress(f"verify: repeatability {sigma_grasp:.4f} mm at the grasp point / {sigma_deg_total:.5f} deg over "
                 f"{rep.n} measurements; predicted {sig.sigma_trans_mm:.4f} mm / {sig.sigma_rot_deg:.5f} deg")
    return {"T_s1_w0": rep.T_mean.tolist(), "sigma_mm": rep.sigma_mm.tolist(), "sigma_deg": rep.sigma_deg.tolist(),
            "max_mm": rep.max_dev_mm, "max_deg": rep.max_dev_deg, "n": rep.n,
            "predicted_sigma_mm": sig.sigma_trans_mm, "predicted_sigma_deg": sig.sigma_rot_deg,
            "sigma_grasp_mm": sigma_grasp, "sigma_rot_deg": sigma_deg_total,
            "predicted_sigma_origin_mm": sig.sigma_origin_mm}


def run_accuracy(rig: CalibrationRig, earlier: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """Table 3: per part pose k the displacement from the reference as the tracker (``inv(T_cf_w0) T_cf_w_k``)
    and the camera (``inv(T_s1_w0) T_s1_w_k``) measure it; RMS, verdict against the tolerances.

    Table 3's x y z (and dT) are the displacement of the part frame's origin, as the paper prints them; the
    verdict takes dT where the cell's tolerance applies, at the grasp point (the featured holes' centroid, the
    cycle's grasp point), 1-2 m from the origin of a large part (``dT_grasp_mm``), and dR as it is."""
    T_cf_tracker = earlier_matrix(earlier, "accuracy", "cell", "T_cf_tracker")
    T_cf_w0 = earlier_matrix(earlier, "accuracy", "part", "T_cf_w0")
    T_s1_w0 = earlier_matrix(earlier, "accuracy", "verify", "T_s1_w0")
    config = calibrated_config(rig.config, earlier, "accuracy")
    opts = rig.options
    lt, mono = [], []
    with _runner(rig, config) as runner:
        for k in range(1, opts.accuracy_poses + 1):
            rig.operator.ask(PLACE_PART, f"put the part down in a new pose {k} of {opts.accuracy_poses} (within the "
                             f"cell's deviation range, no SMR in its holes)", part=k)
            T_s1_w, _ = _camera_measurement(runner, f"accuracy validation, part pose {k} of {opts.accuracy_poses}")
            fit = measure_part_frame(rig, T_cf_tracker, f"part pose {k}")
            lt.append(compose(invert(T_cf_w0), fit.T))
            mono.append(compose(invert(T_s1_w0), T_s1_w))
            rig.progress(f"accuracy: part pose {k} of {opts.accuracy_poses}: tracker fit RMS {fit.rms_mm:.4f} mm")
    table = table3(lt, mono)
    grasp_w = np.append(config.part.points_w.mean(axis=0), 1.0)
    at_grasp = [float(np.linalg.norm((m @ grasp_w - t @ grasp_w)[:3])) for t, m in zip(lt, mono, strict=True)]
    passed = all(r.dR_deg <= opts.tolerance_deg and g <= opts.tolerance_mm
                 for r, g in zip(table.rows, at_grasp, strict=True))
    rows = [{"lt": r.lt.tolist(), "mono": r.mono.tolist(), "delta": r.delta.tolist(), "dR_deg": r.dR_deg,
             "dT_mm": r.dT_mm, "dT_grasp_mm": g} for r, g in zip(table.rows, at_grasp, strict=True)]
    rms_grasp = float(np.sqrt(np.mean(np.square(at_grasp)))) if at_grasp else float("nan")
    rig.progress(f"accuracy: RMS dR {table.rms_dR_deg:.5f} deg, dT {table.rms_dT_mm:.4f} mm at the part origin, "
                 f"{rms_grasp:.4f} mm at the grasp point over {len(rows)} poses: {'PASSED' if passed else 'FAILED'} "
                 f"(tolerance {opts.tolerance_mm:g} mm at the grasp point / {opts.tolerance_deg:g} deg per pose)")
    markdown = table.markdown() + "\n\ndT at the grasp point (the holes' centroid), per pose: " + ", ".join(
        f"{g:.4f}" for g in at_grasp) + f" mm; RMS {rms_grasp:.4f} mm."
    return {"rows": rows, "rms_dR_deg": table.rms_dR_deg, "rms_dT_mm": table.rms_dT_mm,
            "rms_dT_grasp_mm": rms_grasp, "passed": passed, "tolerance_mm": opts.tolerance_mm,
            "tolerance_deg": opts.tolerance_deg, "markdown": markdown}


# --- private ---------------------------------------------------------------------------------------


def _runner(rig: CalibrationRig, config: CellConfig) -> CycleRunner:
    """The cycle's runner on the rig's camera and robot with the new calibration; the caller closes it."""
    try:
        return CycleRunner(config, rig.camera, rig.robot)
    except ConfigError as exc:  # the calibrated poses do not see a hole
        raise CalibrationMeasurementFailed(f"the new calibration cannot measure the part: {exc.message}") from exc


def _camera_measurement(runner: CycleRunner, what: str) -> tuple[np.ndarray, dict[str, Any]]:
    """The cycle's measure + solve (no checks on the offset, nothing written): ``T_s1_w`` and the record."""
    never = threading.Event()
    try:
        measurement = runner.measure(1, never, lambda: CycleAborted("calibration measurement aborted"))
        solution = runner.solve(measurement)
    except DeviceError:
        raise
    except MonoguideError as exc:
        raise CalibrationMeasurementFailed(f"{what}: the camera measurement failed: {exc.code}: {exc.message}") \
            from exc
    assert solution.T_s1_w is not None
    return np.asarray(solution.T_s1_w, dtype=float), measurement.record
