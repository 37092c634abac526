"""The end of the wizard: a finished session's calibration written into the cell config, and its report.

Each records where it wrote in the session's data (``calibration_file``, ``report``); the caller saves the
session. A failed accuracy validation keeps the calibration out of the cell config unless it is accepted (the
session keeps every result, the report is written all the same).
"""

from __future__ import annotations

from importlib import metadata
from pathlib import Path

from monoguide.daemon.calibrate._file import write_calibration
from monoguide.daemon.calibrate._report import write_report
from monoguide.daemon.calibrate._session import CalibrationSession, now_iso
from monoguide.daemon.config import CELL_STEPS
from monoguide.solver.calibration.errors import CalibrationError


def accuracy_failed(session: CalibrationSession) -> bool:
    """The accuracy validation is done and its verdict is FAILED."""
    return session.results().get("accuracy", {}).get("passed") is False


def write_session_calibration(session: CalibrationSession, calibrated_config: Path, sim: bool,
                              accept: bool = False) -> Path:
    """The session's results into ``calibrated_config`` with their provenance (``[calibration]``); returns its
    path. A failed accuracy validation refuses (:class:`CalibrationError`) unless ``accept``."""
    if accuracy_failed(session) and not accept:
        raise CalibrationError("the accuracy validation FAILED (the session keeps every result): look at the "
                               "report, redo a step (--from STEP), or write it anyway with --accept")
    provenance = {"date": now_iso(), "session": str(session.path), "wizard_version": metadata.version("monoguide"),
                  "devices": session.data.get("devices", {}), "sim": sim}
    if session.cell is None:
        path = write_calibration(calibrated_config, session.results(), provenance)
    else:  # a part type's: its own steps' values, its provenance in [calibration.parts.<job>]
        results = session.results()
        part = {"job": session.job, "name": session.data.get("part_name", f"job {session.job}"),
                "cell_steps": {s: results[s]["done"] for s in CELL_STEPS if "done" in results.get(s, {})}}
        path = write_calibration(calibrated_config, {s: results[s] for s in session.done()}, provenance, part)
    session.data["calibration_file"] = str(path)
    return path


def write_session_report(session: CalibrationSession, work_dir: Path) -> Path:
    """The session's report (``calibration-report.md`` and its figures) into ``work_dir``; returns its path."""
    path = write_report(work_dir, session.data)
    session.data["report"] = str(path)
    return path
