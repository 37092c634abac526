"""Steps 4-7 of ``monoguide calibrate`` (docs/calibration.md): the part frame, the measuring-pose frames SFi
with the camera's mounting on the flange, the verification and the accuracy validation (Table 3).

Every step is ``run_<step>(rig, earlier) -> dict`` over a :class:`~monoguide.daemon.calibrate._rig.CalibrationRig`
(the result dicts of ``earlier`` steps by name; the returned dict is JSON-able and is what the session stores).
The rig's config holds only NOMINAL calibration values (starting guesses); everything measured comes from the
earlier steps: the camera model from ``intrinsics``, tracker readings map into CF with ``cell``'s
``T_cf_tracker``, the robot base from ``base``. A refusal is a :class:`MonoguideError`; a failed Table-3 verdict
is a result (``passed`` false), not a refusal.

- ``part``: the reference part's featured holes measured by the tracker -> ``T_cf_w0`` (best fit, residual per
  hole).
- ``sfi``: per measuring pose, the target placed ``placements`` times; per placement its nests measured by the
  tracker (``T_cf_t``) and ``visits`` fresh stops of the robot at the pose, each imaged (``T_si_t``); Eq. 6
  averaged over all visits (``T_cf_si`` and its spread). Per visit also the camera on the flange,
  ``T_f_c = inv(T_cf_b T_b_f) T_cf_si`` with the flange pose the robot reports, averaged over every visit;
  with it each visit is moved from the reported stop to the pose's taught flange pose before averaging.
- ``verify``: the reference part measured ``repeats`` times by the cycle (measure + solve, no offset written)
  with the NEW calibration; the repeatability beside the planner's predicted sigma; ``T_s1_w0`` is their mean.
- ``accuracy``: a part in ``accuracy_poses`` new poses, its displacement from the reference measured by the
  camera and by the tracker (featured holes); Table 3 and its verdict.
"""

from __future__ import annotations

import threading
from dataclasses import replace
from typing import Any

import numpy as np

from monoguide.daemon.calibrate._rig import (
    PLACE_PART,
    PLACE_SMR,
    PLACE_TARGET,
    REMOVE_TARGET,
    CalibrationRig,
)
from monoguide.daemon.config import CellConfig
from monoguide.daemon.cycle import CycleRunner
from monoguide.daemon.errors import (
    CalibrationMeasurementFailed,
    CalibrationNoTarget,
    CalibrationStepNotReady,
    CycleAborted,
)
from monoguide.drivers.errors import ConfigError, DeviceError
from monoguide.solver.calibration.averaging import mean_pose
from monoguide.solver.calibration.cell import fit_part_frame
from monoguide.solver.calibration.sfi import calibrate_measuring_pose, fit_target_frame, visit_sfi
from monoguide.solver.calibration.target import TargetMarks, default_target_marks, measure_target
from monoguide.solver.calibration.verify import repeatability, table3
from monoguide.solver.camera import CameraModel
from monoguide.solver.errors import MonoguideError
from monoguide.solver.frames import compose, invert, transform_points
from monoguide.solver.planning.prediction import pose_sigmas
from monoguide.solver.record import parse_record
from monoguide.solver.uncertainty import predicted_covariance

# --- step 4: the part frame ---------------------------------------------------------------------


def run_part(rig: CalibrationRig, earlier: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """``T_cf_w0`` from the reference part's featured holes measured by the tracker."""
    T_cf_tracker = _matrix(earlier, "part", "cell", "T_cf_tracker")
    rig.operator.ask(PLACE_PART, "put the reference part in place, as the grasp path was taught", part="reference")
    fit = _measure_part_frame(rig, T_cf_tracker, "reference part")
    residuals = {n: float(r) for n, r in zip(fit.names, fit.residuals_mm, strict=True)}
    rig.progress(f"part frame: T_cf_w0 from {len(residuals)} holes, RMS {fit.rms_mm:.4f} mm")
    return {"T_cf_w0": fit.T.tolist(), "residuals_mm": residuals, "rms_mm": fit.rms_mm}


# --- step 5: the measuring-pose frames SFi and the camera on the flange ------------------------


def run_sfi(rig: CalibrationRig, earlier: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """Each ``T_cf_si`` (Eq. 6, averaged over placements x visits) and ``T_f_c`` (needs ``base``: without it
    the result has no ``T_f_c``, ``T_f_c_spread_mm``, ``T_f_c_spread_deg``).

    With the base known, each visit is also moved from where the robot reported it stopped to the pose's
    reference flange pose (the config's taught ``T_b_f``, else the mean of the reported stops):
    ``T_cf_si = T_cf_t inv(T_si_t) inv(T_f_c) inv(T_b_f_visit) T_b_f_ref T_f_c``, which takes out the
    repeatability the robot's own report sees (the cycle applies the same stand-off, docs/cycle.md)."""
    camera = _camera_model(earlier, "sfi")
    T_cf_tracker = _matrix(earlier, "sfi", "cell", "T_cf_tracker")
    T_cf_b = _matrix(earlier, "sfi", "base", "T_cf_b") if "base" in earlier else None
    cfg, opts = rig.config, rig.options
    targets = [_target(cfg, i) for i in range(len(cfg.measuring_poses))]  # refuse before anything moves
    visits: list[list[tuple[np.ndarray, np.ndarray, np.ndarray, float]]] = []  # T_cf_t, T_si_t, T_b_f, rms px
    last_stop: int | None = None
    n_poses = len(cfg.measuring_poses)
    for i, pose in enumerate(cfg.measuring_poses):
        name_t, nests_t, marks = targets[i]
        guess_cf_si = pose.T_cf_si  # nominal; then the last visit's
        visits.append([])
        for p in range(opts.placements):
            rig.operator.ask(PLACE_TARGET, f"place the calibration target {name_t} under measuring pose {pose.name} "
                             f"(placement {p + 1} of {opts.placements}: a little shifted and turned from the last)",
                             pose=i, placement=p)
            nest_names = [f"{name_t}.{k + 1}" for k in range(len(nests_t))]
            measured = np.array([_tracker_cf(rig, T_cf_tracker, nest, f"nest {nest} of target {name_t}")
                                 for nest in nest_names])
            try:
                T_cf_t = fit_target_frame(nests_t, measured, nest_names).T
            except MonoguideError as exc:
                raise type(exc)(f"{pose.name}, placement {p + 1}: {exc.message}") from exc
            for v in range(opts.visits):
                where = f"{pose.name}, placement {p + 1}, visit {v + 1}"
                if last_stop == i or last_stop is None:  # each visit a fresh stop: go elsewhere first
                    away = (i + 1) % n_poses
                    rig.robot.move_to_measuring_pose(away)
                    last_stop = away
                status = rig.robot.move_to_measuring_pose(i)
                last_stop = i
                image = _full_image(rig, rig.camera.grab(cfg.camera.grab_timeout_s).image)
                try:
                    view = measure_target(image, camera, marks, compose(invert(guess_cf_si), T_cf_t))
                except MonoguideError as exc:
                    raise type(exc)(f"{where}: {exc.message}") from exc
                guess_cf_si = visit_sfi(T_cf_t, view.T_c_t)
                visits[i].append((T_cf_t, view.T_c_t, np.asarray(status.T_b_f, dtype=float), view.rms_px))
                rig.progress(f"sfi {where}: target at {float(np.linalg.norm(view.T_c_t[:3, 3])):.1f} mm, "
                             f"marks RMS {view.rms_px:.3f} px")
        rig.operator.ask(REMOVE_TARGET, f"take the calibration target {name_t} away from measuring pose {pose.name}",
                         pose=i)
    out: dict[str, Any] = {"poses": []}  # T_f_c and its spread only with the base known
    T_f_c = None
    if T_cf_b is not None:
        he = mean_pose([compose(invert(compose(T_cf_b, T_b_f)), visit_sfi(T_cf_t, T_si_t))
                        for pose_visits in visits for T_cf_t, T_si_t, T_b_f, _ in pose_visits])
        T_f_c = he.T
        out.update({"T_f_c": he.T.tolist(), "T_f_c_spread_mm": he.spread_mm, "T_f_c_spread_deg": he.spread_deg})
        rig.progress(f"sfi: camera on the flange T_f_c from {he.n} visits, spread {he.spread_mm:.4f} mm / "
                     f"{he.spread_deg:.5f} deg RMS")
    else:
        rig.progress("sfi: no robot base calibrated yet: the camera's mounting T_f_c is left out, the visits are "
                     "averaged where the robot stopped")
    for pose, pose_visits in zip(cfg.measuring_poses, visits, strict=True):
        pairs = [(T_cf_t, T_si_t) for T_cf_t, T_si_t, _, _ in pose_visits]
        if T_f_c is not None:
            T_b_f_ref = pose.T_b_f if pose.T_b_f is not None else mean_pose([v[2] for v in pose_visits]).T
            # T_cf_si' = T_cf_t inv(T_si_t) C with C = inv(T_f_c) inv(T_b_f) T_b_f_ref T_f_c: T_si_t' = inv(C) T_si_t
            pairs = [(T_cf_t, compose(invert(T_f_c), invert(T_b_f_ref), T_b_f, T_f_c, T_si_t))
                     for T_cf_t, T_si_t, T_b_f, _ in pose_visits]
        m = calibrate_measuring_pose(pairs, pose.name).mean
        out["poses"].append({"name": pose.name, "T_cf_si": m.T.tolist(), "spread_mm": m.spread_mm,
                             "spread_deg": m.spread_deg, "sem_mm": m.sigma_mean_mm, "sem_deg": m.sigma_mean_deg,
                             "visits": m.n, "deviations_mm": m.dev_mm.tolist(), "deviations_deg": m.dev_deg.tolist(),
                             "stand_off_corrected": T_f_c is not None,
                             "marks_rms_px": float(np.sqrt(np.mean([v[3] ** 2 for v in pose_visits])))})
        rig.progress(f"sfi {pose.name}: {m.n} visits spread {m.spread_mm:.4f} mm / {m.spread_deg:.5f} deg RMS "
                     f"(standard error {m.sigma_mean_mm:.4f} mm / {m.sigma_mean_deg:.5f} deg)")
    return out


# --- step 6: verification -------------------------------------------------------------------------


def run_verify(rig: CalibrationRig, earlier: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """Repeated camera measurements of the reference part with the new calibration: repeatability, ``T_s1_w0``
    (their mean) and the planner's predicted sigma for this layout."""
    config = calibrated_config(rig.config, earlier, "verify")
    runner = _runner(rig, config)
    rig.operator.ask(PLACE_PART, "put the reference part in place (no SMR in its holes)", part="reference")
    poses, record = [], None
    for r in range(rig.options.repeats):
        T, record = _camera_measurement(runner, f"verification, measurement {r + 1} of {rig.options.repeats} of "
                                                f"the reference part")
        poses.append(T)
        rig.progress(f"verify: measurement {r + 1} of {rig.options.repeats}: part at "
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


# --- step 7: accuracy validation (Table 3) ---------------------------------------------------------


def run_accuracy(rig: CalibrationRig, earlier: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """Table 3: per part pose k the displacement from the reference as the tracker (``inv(T_cf_w0) T_cf_w_k``)
    and the camera (``inv(T_s1_w0) T_s1_w_k``) measure it; RMS, verdict against the tolerances.

    Table 3's x y z (and dT) are the displacement of the part frame's origin, as the paper prints them; the
    verdict takes dT where the cell's tolerance applies, at the grasp point (the featured holes' centroid, the
    cycle's grasp point), 1-2 m from the origin of a large part (``dT_grasp_mm``), and dR as it is."""
    T_cf_tracker = _matrix(earlier, "accuracy", "cell", "T_cf_tracker")
    T_cf_w0 = _matrix(earlier, "accuracy", "part", "T_cf_w0")
    T_s1_w0 = _matrix(earlier, "accuracy", "verify", "T_s1_w0")
    config = calibrated_config(rig.config, earlier, "accuracy")
    runner = _runner(rig, config)
    opts = rig.options
    lt, mono = [], []
    for k in range(1, opts.accuracy_poses + 1):
        rig.operator.ask(PLACE_PART, f"put the part down in a new pose {k} of {opts.accuracy_poses} (within the "
                         f"cell's deviation range, no SMR in its holes)", part=k)
        T_s1_w, _ = _camera_measurement(runner, f"accuracy validation, part pose {k} of {opts.accuracy_poses}")
        fit = _measure_part_frame(rig, T_cf_tracker, f"part pose {k}")
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


# --- the calibration as the cycle uses it -----------------------------------------------------------


def calibrated_config(config: CellConfig, earlier: dict[str, dict[str, Any]], step: str = "verify") -> CellConfig:
    """``config`` (in memory) with the calibration of the earlier steps: the intrinsics, ``T_f_c`` and each
    ``T_cf_si`` (sfi), ``T_cf_b`` (base), ``T_cf_w0`` (part). The measuring poses' taught flange poses (when
    the config has them) are the robot program's, not calibration values: kept."""
    camera = _camera_model(earlier, step)
    T_cf_b = _matrix(earlier, step, "base", "T_cf_b")
    T_cf_w0 = _matrix(earlier, step, "part", "T_cf_w0")
    sfi = _need(earlier, step, "sfi")
    by_name = {p["name"]: np.asarray(p["T_cf_si"], dtype=float) for p in sfi.get("poses", [])}
    missing = [p.name for p in config.measuring_poses if p.name not in by_name]
    if missing:
        raise CalibrationStepNotReady(f"{step}: the sfi step has no calibration of measuring pose(s) "
                                      f"{', '.join(missing)}; run sfi again")
    T_f_c = sfi.get("T_f_c")
    return replace(
        config,
        camera=replace(config.camera, intrinsics=camera,
                       T_f_c=np.asarray(T_f_c, dtype=float) if T_f_c is not None else config.camera.T_f_c),
        reference=replace(config.reference, T_cf_w0=T_cf_w0, T_cf_b=T_cf_b),
        measuring_poses=tuple(replace(p, T_cf_si=by_name[p.name]) for p in config.measuring_poses),
    )


# --- private ---------------------------------------------------------------------------------------


def _need(earlier: dict[str, dict[str, Any]], step: str, needed: str) -> dict[str, Any]:
    if needed not in earlier:
        raise CalibrationStepNotReady(f"{step}: needs the {needed} step's result; run {needed} first")
    return earlier[needed]


def _matrix(earlier: dict[str, dict[str, Any]], step: str, needed: str, key: str) -> np.ndarray:
    result = _need(earlier, step, needed)
    if result.get(key) is None:
        raise CalibrationStepNotReady(f"{step}: the {needed} step's result has no {key}; run {needed} again")
    return np.asarray(result[key], dtype=float).reshape(4, 4)


def _camera_model(earlier: dict[str, dict[str, Any]], step: str) -> CameraModel:
    intrinsics = _need(earlier, step, "intrinsics")
    return CameraModel(**intrinsics["camera"])


def _target(config: CellConfig, i: int) -> tuple[str, np.ndarray, TargetMarks]:
    """The target used at measuring pose ``i``: its tracker name ``T<i+1>``, its nests (m, 3) in TF and its
    marks; ``[calibration_target]``, else (a simulated cell without one) the simulated target of the pose."""
    name = f"T{i + 1}"
    target = getattr(config, "calibration_target", None)
    if target is not None:
        return name, np.asarray(target.nests_t, dtype=float), target.marks
    sim_targets = config.sim.targets if config.sim is not None else ()
    if i < len(sim_targets):
        return name, np.asarray(sim_targets[i].points_t, dtype=float), default_target_marks()
    raise CalibrationNoTarget(f"{config.path}: no [calibration_target] section: the wizard needs the target's SMR "
                              f"nests and marks to calibrate measuring pose {config.measuring_poses[i].name}")


def _tracker_cf(rig: CalibrationRig, T_cf_tracker: np.ndarray, nest: str, what: str) -> np.ndarray:
    rig.operator.ask(PLACE_SMR, f"place the SMR in {what}", nest=nest)
    point = np.asarray(rig.tracker.measure_point(nest=nest).point_mm, dtype=float).reshape(1, 3)
    return transform_points(T_cf_tracker, point)[0]


def _measure_part_frame(rig: CalibrationRig, T_cf_tracker: np.ndarray, what: str):  # -> RigidFit
    part = rig.config.part
    names = part.point_names or tuple(f"P{k + 1}" for k in range(len(part.points_w)))
    measured = {n: _tracker_cf(rig, T_cf_tracker, n, f"featured hole {n} of the {what}") for n in names}
    try:
        return fit_part_frame(dict(zip(names, part.points_w, strict=True)), measured)
    except MonoguideError as exc:
        raise type(exc)(f"{what}: {exc.message}") from exc


def _full_image(rig: CalibrationRig, image: np.ndarray) -> np.ndarray:
    """A frame of ``[camera] region`` placed in a full-sensor array (the target's marks are sought in full-sensor
    pixels)."""
    region = rig.config.camera.region
    if region is None:
        return image
    ox, oy, w, h = region
    intr = rig.config.camera.intrinsics
    full = np.zeros((intr.height, intr.width), dtype=image.dtype)
    full[oy : oy + h, ox : ox + w] = image[:h, :w]
    return full


def _runner(rig: CalibrationRig, config: CellConfig) -> CycleRunner:
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
