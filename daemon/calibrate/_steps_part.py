"""Steps 4 and 5 of ``monoguide calibrate`` (docs/calibration.md): the part frame, and the measuring-pose frames
SFi with the camera's mounting on the flange.

Every step is ``run_<step>(rig, earlier) -> dict`` over a :class:`~monoguide.daemon.calibrate._rig.CalibrationRig`
(the result dicts of ``earlier`` steps by name; the returned dict is JSON-able and is what the session stores).
The rig's config holds only NOMINAL calibration values (starting guesses); everything measured comes from the
earlier steps: the camera model from ``intrinsics``, tracker readings map into CF with ``cell``'s
``T_cf_tracker``, the robot base from ``base``. A refusal is a :class:`MonoguideError`.

- ``part``: the reference part's featured holes measured by the tracker -> ``T_cf_w0`` (best fit, residual per
  hole).
- ``sfi``: per measuring pose, the target placed ``placements`` times; per placement its nests measured by the
  tracker (``T_cf_t``) and ``visits`` fresh stops of the robot at the pose, each imaged (``T_si_t``); Eq. 6
  averaged over all visits (``T_cf_si`` and its spread). Per visit also the camera on the flange,
  ``T_f_c = inv(T_cf_b T_b_f) T_cf_si`` with the flange pose the robot reports, averaged over every visit;
  with it each visit is moved from the reported stop to the pose's taught flange pose before averaging.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from monoguide.daemon.calibrate._earlier import earlier_camera, earlier_matrix
from monoguide.daemon.calibrate._rig import PLACE_PART, PLACE_SMR, PLACE_TARGET, REMOVE_TARGET, CalibrationRig
from monoguide.daemon.config import CellConfig
from monoguide.daemon.errors import CalibrationNoTarget
from monoguide.solver.calibration.averaging import mean_pose
from monoguide.solver.calibration.cell import fit_part_frame
from monoguide.solver.calibration.rigid import RigidFit
from monoguide.solver.calibration.sfi import calibrate_measuring_pose, fit_target_frame, visit_sfi
from monoguide.solver.calibration.target import TargetMarks, default_target_marks, measure_target
from monoguide.solver.errors import MonoguideError
from monoguide.solver.frames import compose, invert, transform_points

Visit = tuple[np.ndarray, np.ndarray, np.ndarray, float]  # T_cf_t, T_si_t, T_b_f as reported, marks RMS px


def run_part(rig: CalibrationRig, earlier: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """``T_cf_w0`` from the reference part's featured holes measured by the tracker."""
    T_cf_tracker = earlier_matrix(earlier, "part", "cell", "T_cf_tracker")
    rig.operator.ask(PLACE_PART, "put the reference part in place, as the grasp path was taught", part="reference")
    fit = measure_part_frame(rig, T_cf_tracker, "reference part")
    residuals = {n: float(r) for n, r in zip(fit.names, fit.residuals_mm, strict=True)}
    rig.progress(f"part frame: T_cf_w0 from {len(residuals)} holes, RMS {fit.rms_mm:.4f} mm")
    job = {"job": rig.config.job} if len(rig.config.parts) > 1 else {}  # whose reference: [[parts]] job
    return {"T_cf_w0": fit.T.tolist(), "residuals_mm": residuals, "rms_mm": fit.rms_mm, **job}


def run_sfi(rig: CalibrationRig, earlier: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """Each ``T_cf_si`` (Eq. 6, averaged over placements x visits) and ``T_f_c`` (needs ``base``: without it
    the result has no ``T_f_c``, ``T_f_c_spread_mm``, ``T_f_c_spread_deg``).

    With the base known, each visit is also moved from where the robot reported it stopped to the pose's
    reference flange pose (the config's taught ``T_b_f``, else the mean of the reported stops):
    ``T_cf_si = T_cf_t inv(T_si_t) inv(T_f_c) inv(T_b_f_visit) T_b_f_ref T_f_c``, which takes out the
    repeatability the robot's own report sees (the cycle applies the same stand-off, docs/cycle.md)."""
    camera = earlier_camera(earlier, "sfi")
    T_cf_tracker = earlier_matrix(earlier, "sfi", "cell", "T_cf_tracker")
    T_cf_b = earlier_matrix(earlier, "sfi", "base", "T_cf_b") if "base" in earlier else None
    cfg, opts = rig.config, rig.options
    targets = [_target(cfg, pose.number - 1) for pose in cfg.measuring_poses]  # refuse before anything moves
    visits: list[list[Visit]] = []
    last_stop: int | None = None
    n_poses = len(cfg.measuring_poses)
    for i, pose in enumerate(cfg.measuring_poses):
        name_t, nests_t, marks = targets[i]
        guess_cf_si = pose.T_cf_si  # nominal; then the last visit's
        visits.append([])
        for p in range(opts.placements):
            rig.operator.ask(PLACE_TARGET, f"place the calibration target {name_t} under measuring pose {pose.name} "
                             f"(placement {p + 1} of {opts.placements}: a little shifted and turned from the last)",
                             pose=pose.number - 1, placement=p)
            nest_names = [f"{name_t}.{k + 1}" for k in range(len(nests_t))]
            measured = np.array([tracker_point_cf(rig, T_cf_tracker, nest, f"nest {nest} of target {name_t}")
                                 for nest in nest_names])
            try:
                T_cf_t = fit_target_frame(nests_t, measured, nest_names).T
            except MonoguideError as exc:
                raise type(exc)(f"{pose.name}, placement {p + 1}: {exc.message}") from exc
            for v in range(opts.visits):
                where = f"{pose.name}, placement {p + 1}, visit {v + 1}"
                if last_stop == i or last_stop is None:  # each visit a fresh stop: go elsewhere first
                    away = (i + 1) % n_poses
                    rig.robot.move_to_measuring_pose(cfg.measuring_poses[away].number - 1)
                    last_stop = away
                status = rig.robot.move_to_measuring_pose(pose.number - 1)  # the cell's pose
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
                         pose=pose.number - 1)
    return _sfi_result(rig, visits, T_cf_b)


def measure_part_frame(rig: CalibrationRig, T_cf_tracker: np.ndarray, what: str) -> RigidFit:
    """The part frame (``T_cf_w``) of the part in place, from its featured holes measured by the tracker."""
    part = rig.config.part
    names = part.point_names or tuple(f"P{k + 1}" for k in range(len(part.points_w)))
    measured = {n: tracker_point_cf(rig, T_cf_tracker, n, f"featured hole {n} of the {what}") for n in names}
    try:
        return fit_part_frame(dict(zip(names, part.points_w, strict=True)), measured)
    except MonoguideError as exc:
        raise type(exc)(f"{what}: {exc.message}") from exc


def tracker_point_cf(rig: CalibrationRig, T_cf_tracker: np.ndarray, nest: str, what: str) -> np.ndarray:
    """The SMR placed in ``nest`` (the operator is asked to), measured by the tracker, in CF (3,) mm."""
    rig.operator.ask(PLACE_SMR, f"place the SMR in {what}", nest=nest)
    point = np.asarray(rig.tracker.measure_point(nest=nest).point_mm, dtype=float).reshape(1, 3)
    return transform_points(T_cf_tracker, point)[0]


# --- private ---------------------------------------------------------------------------------------


def _sfi_result(rig: CalibrationRig, visits: list[list[Visit]], T_cf_b: np.ndarray | None) -> dict[str, Any]:
    """Every pose's visits averaged (Eq. 6), with the camera on the flange first when the base is known."""
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
    for pose, pose_visits in zip(rig.config.measuring_poses, visits, strict=True):
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


def _target(config: CellConfig, i: int) -> tuple[str, np.ndarray, TargetMarks]:
    """The target used at the cell's measuring pose ``i`` (robot pose number ``i + 1``): its tracker name ``T<i+1>``,
    its nests (m, 3) in TF and its marks; ``[calibration_target]``, else (a simulated cell without one) the
    simulated target of the pose."""
    name = f"T{i + 1}"
    target = getattr(config, "calibration_target", None)
    if target is not None:
        return name, np.asarray(target.nests_t, dtype=float), target.marks
    sim_targets = config.sim.targets if config.sim is not None else ()
    if i < len(sim_targets):
        return name, np.asarray(sim_targets[i].points_t, dtype=float), default_target_marks()
    raise CalibrationNoTarget(f"{config.path}: no [calibration_target] section: the wizard needs the target's SMR "
                              f"nests and marks to calibrate measuring pose {config.cell_poses[i].name}")


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
