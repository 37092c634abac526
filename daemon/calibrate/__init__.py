"""``monoguide calibrate``: the wizard's rig, session and steps, the calibration file and the report
(docs/calibration.md).

The modules, each one job: ``_rig`` (the rig, the operator, the options, the steps' names), ``_cell_rig`` and
``_sim`` (opening the rig on a real or the simulated cell; ``_sim_process``, ``_sim_truth``), ``_session`` (the
session file), ``_steps`` (which steps a run does, one step run into the session), ``_steps_frames`` (intrinsics,
cell, marks, base), ``_steps_part`` (part, sfi), ``_steps_check`` (verify, accuracy),
``_earlier`` (the earlier steps' results as a later one reads them), ``_summary`` (what is said about the
results), ``_results`` (the calibration written into the config, the report), ``_file`` (the calibration file),
``_report`` with ``_report_sections``, ``_report_figures``, ``_report_plans`` (the report, its figures).
"""

from __future__ import annotations

from monoguide.daemon.calibrate._cell_rig import open_cell_rig
from monoguide.daemon.calibrate._file import read_calibration_provenance, write_calibration
from monoguide.daemon.calibrate._report import write_report
from monoguide.daemon.calibrate._report_figures import CHART_SIZE
from monoguide.daemon.calibrate._report_plans import PLAN_SIZE
from monoguide.daemon.calibrate._report_sections import FIGURES, REPORT_NAME, TRUTH_FIGURE
from monoguide.daemon.calibrate._results import accuracy_failed, write_session_calibration, write_session_report
from monoguide.daemon.calibrate._rig import (
    ACTIONS,
    MARKS_STEP,
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
from monoguide.daemon.calibrate._steps import plan_steps, run_step
from monoguide.daemon.calibrate._steps_check import run_accuracy, run_verify
from monoguide.daemon.calibrate._steps_frames import CELL_METHODS, run_base, run_cell, run_intrinsics, run_marks
from monoguide.daemon.calibrate._steps_part import run_part, run_sfi
from monoguide.daemon.calibrate._summary import describe, summary

__all__ = [
    "ACTIONS", "CELL_METHODS", "CHART_SIZE", "FIGURES", "MARKS_STEP", "MOUNT_FLANGE_SMR", "PLACE_PART", "PLACE_SMR",
    "PLACE_TARGET", "PLAN_SIZE", "REMOVE_TARGET", "REPORT_NAME", "SESSION_FILE", "SHOW_PLATE", "STEPS",
    "TRUTH_FIGURE", "CalibrationOptions", "CalibrationRig", "CalibrationSession", "ConsoleOperator",
    "accuracy_failed", "describe", "now_iso", "open_cell_rig", "open_session", "open_sim_rig", "plan_steps",
    "read_calibration_provenance", "run_accuracy", "run_base", "run_cell", "run_intrinsics", "run_marks", "run_part",
    "run_sfi", "run_step", "run_verify", "summary", "write_calibration", "write_report", "write_session_calibration",
    "write_session_report",
]
