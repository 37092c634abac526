"""``monoguide calibrate``: the wizard's rig, session and steps, the calibration file and the report
(docs/calibration.md).
"""

from __future__ import annotations

from monoguide.daemon.calibrate._file import read_calibration_provenance, write_calibration
from monoguide.daemon.calibrate._report import CHART_SIZE, FIGURES, PLAN_SIZE, REPORT_NAME, TRUTH_FIGURE, write_report
from monoguide.daemon.calibrate._rig import (
    ACTIONS,
    MOUNT_FLANGE_SMR,
    PLACE_PART,
    PLACE_SMR,
    PLACE_TARGET,
    REMOVE_TARGET,
    SHOW_PLATE,
    STEPS,
    CalibrationOptions,
    CalibrationRig,
    ConsoleOperator,
)
from monoguide.daemon.calibrate._session import SESSION_FILE, CalibrationSession, now_iso, open_session
from monoguide.daemon.calibrate._sim import open_sim_rig
from monoguide.daemon.calibrate._steps_camera import run_accuracy, run_part, run_sfi, run_verify
from monoguide.daemon.calibrate._steps_frames import CELL_METHODS, run_base, run_cell, run_intrinsics

__all__ = [
    "ACTIONS", "CELL_METHODS", "CHART_SIZE", "FIGURES", "MOUNT_FLANGE_SMR", "PLACE_PART", "PLACE_SMR",
    "PLACE_TARGET", "PLAN_SIZE", "REMOVE_TARGET", "REPORT_NAME", "SESSION_FILE", "SHOW_PLATE", "STEPS",
    "TRUTH_FIGURE", "CalibrationOptions", "CalibrationRig", "CalibrationSession", "ConsoleOperator", "now_iso",
    "open_session", "open_sim_rig", "read_calibration_provenance", "run_accuracy", "run_base", "run_cell",
    "run_intrinsics", "run_part", "run_sfi", "run_verify", "write_calibration", "write_report",
]
