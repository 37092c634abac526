"""The earlier steps' results as a later step of ``monoguide calibrate`` reads them: one of their matrices, the
camera model, the cell config as calibrated so far (its reference marks as surveyed).

``earlier`` is the session's result dicts by step name (docs/calibration.md, "The session file"). Whatever a
step needs and does not find refuses it with :class:`CalibrationStepNotReady` naming the step to run first.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from monoguide.daemon.config import CellConfig
from monoguide.daemon.errors import CalibrationStepNotReady
from monoguide.solver.camera import CameraModel


def earlier_result(earlier: dict[str, dict[str, Any]], step: str, needed: str) -> dict[str, Any]:
    """The result of the ``needed`` step, which ``step`` cannot do without."""
    if needed not in earlier:
        raise CalibrationStepNotReady(f"{step}: needs the {needed} step's result; run {needed} first")
    return earlier[needed]


def earlier_matrix(earlier: dict[str, dict[str, Any]], step: str, needed: str, key: str) -> np.ndarray:
    """The 4x4 ``key`` of the ``needed`` step's result (``T_cf_tracker`` of ``cell``, ...)."""
    result = earlier_result(earlier, step, needed)
    if result.get(key) is None:
        raise CalibrationStepNotReady(f"{step}: the {needed} step's result has no {key}; run {needed} again")
    return np.asarray(result[key], dtype=float).reshape(4, 4)


def earlier_camera(earlier: dict[str, dict[str, Any]], step: str) -> CameraModel:
    """The camera model the ``intrinsics`` step calibrated."""
    return CameraModel(**earlier_result(earlier, step, "intrinsics")["camera"])


def calibrated_config(config: CellConfig, earlier: dict[str, dict[str, Any]], step: str = "verify") -> CellConfig:
    """``config`` (in memory) with the calibration of the earlier steps: the intrinsics, ``T_f_c`` and each
    ``T_cf_si`` (sfi), ``T_cf_b`` (base), ``T_cf_w0`` (part), and on a cell with reference marks each mark's
    ``position_cf`` (marks: the cycle measures where each camera stood from them). The measuring poses' taught
    flange poses (when the config has them) are the robot program's, not calibration values: kept."""
    camera = earlier_camera(earlier, step)
    T_cf_b = earlier_matrix(earlier, step, "base", "T_cf_b")
    T_cf_w0 = earlier_matrix(earlier, step, "part", "T_cf_w0")
    sfi = earlier_result(earlier, step, "sfi")
    by_name = {p["name"]: np.asarray(p["T_cf_si"], dtype=float) for p in sfi.get("poses", [])}
    missing = [p.name for p in config.measuring_poses if p.name not in by_name]
    if missing:
        raise CalibrationStepNotReady(f"{step}: the sfi step has no calibration of measuring pose(s) "
                                      f"{', '.join(missing)}; run sfi again")
    T_f_c = sfi.get("T_f_c")
    marks = config.reference_marks
    if marks:
        surveyed = {m["name"]: np.asarray(m["position_cf"], dtype=float)
                    for m in earlier_result(earlier, step, "marks").get("marks", [])}
        if missing := [m.name for m in marks if m.name not in surveyed]:
            raise CalibrationStepNotReady(f"{step}: the marks step has not surveyed reference mark(s) "
                                          f"{', '.join(missing)}; run marks again")
        marks = tuple(replace(m, position_cf=surveyed[m.name]) for m in marks)
    return replace(
        config,
        camera=replace(config.camera, intrinsics=camera,
                       T_f_c=np.asarray(T_f_c, dtype=float) if T_f_c is not None else config.camera.T_f_c),
        reference=replace(config.reference, T_cf_w0=T_cf_w0, T_cf_b=T_cf_b),
        measuring_poses=tuple(replace(p, T_cf_si=by_name[p.name]) for p in config.measuring_poses),
        reference_marks=marks,
    )
