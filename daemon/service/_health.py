"""The cell's calibration health as the service keeps it: the trend monitor of every part type and the latch.

Every cycle that got as far as a solve adds its whitened residual (the chi-square the consistency test holds
against its threshold, also of a cycle that test refused) to its part type's trend monitor
(``solver.trend.TrendMonitor``: a CUSUM whose alarm level is set for one false alarm per 20,000 good cycles,
measured 0.5 per 10,000, its warning for one per 1,000; docs/health.md). Above the warning level the status
word's ``CALIBRATION_WARNING`` bit is set (the cycle
goes on); at the alarm level the cycle is refused with ``CALIBRATION_SUSPECT`` and the refusal is **latched**:
every later cycle is refused the same way, before the robot moves, until the cell is recalibrated (a config whose
calibration values differ: the monitors and the latch start afresh) or a person who inspected the cell clears it
(``monoguide health --clear REASON``).

Everything lives in ``calibration-health.json`` in the state directory (rewritten atomically after each cycle,
a few hundred bytes whatever the cell's age): the calibration's identity (a digest of its values), each part
type's monitor state, the latch. A file that cannot be read is logged and replaced by a fresh start — the
journal, not this file, is the record of what happened.
"""

from __future__ import annotations

import hashlib
import json
import logging
import threading
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from monoguide.daemon.config import CellConfig
from monoguide.daemon.cycle import Residual
from monoguide.daemon.service._state_dir import CLEAR_REQUEST, HEALTH_FILE
from monoguide.drivers.atomic_file import write_atomic
from monoguide.solver.errors import CalibrationSuspect
from monoguide.solver.trend import SERVICE_ALARM_ARL0, TrendMonitor, TrendReading

log = logging.getLogger(__name__)

HEALTH_FORMAT = "monoguide.calibration-health/1"


def request_clear(state_dir: Path, reason: str) -> Path:
    """Ask the service of ``state_dir`` (running, or at its next start) to clear the latch and start its trend
    monitors afresh, for ``reason`` (logged, and kept in the health file as the last clear)."""
    if not reason.strip():
        raise ValueError("a reason is needed to clear the calibration latch (what was inspected or done)")
    path = Path(state_dir) / CLEAR_REQUEST
    write_atomic(path, json.dumps({"reason": reason.strip(), "at": datetime.now(UTC).isoformat(timespec="seconds")})
                 + "\n", durable=True)
    return path


def calibration_identity(config: CellConfig) -> str:
    """A digest of the calibration values the cycle uses (intrinsics, camera mounting, robot base, every measuring
    pose and every part type's reference): any change is a new calibration."""
    digest = hashlib.sha256()
    cam = config.camera
    digest.update(json.dumps(cam.intrinsics.as_dict(), sort_keys=True).encode())
    for T in (cam.T_f_c, config.reference.T_cf_b, *(p.T_cf_si for p in config.cell_poses),
              *(p.T_cf_w0 for p in config.parts)):
        digest.update(b"-" if T is None else np.round(np.asarray(T, dtype=float), 9).tobytes())
    return digest.hexdigest()[:16]


class CalibrationHealth:
    """The monitors (one per part type: each layout has its own degrees of freedom) and the latch, kept in
    ``state_dir / HEALTH_FILE``."""

    def __init__(self, state_dir: Path, config: CellConfig) -> None:
        self.path = Path(state_dir) / HEALTH_FILE
        self.identity = calibration_identity(config)
        self.monitors: dict[int, TrendMonitor] = {}
        self.latched: dict[str, Any] | None = None
        self.last: dict[int, TrendReading] = {}
        self.cleared: str | None = None  # the last operator's clear (its reason)
        self._reset_pending = False
        self._load_latch()
        # the monitors' levels take a second or two to compute: beside the start, not in READY's way nor in a cycle
        self._ready = threading.Thread(target=self._load_monitors, args=(config,), name="trend-levels", daemon=True)
        self._ready.start()
        self.take_clear_request()  # one left while no service ran

    @property
    def warning(self) -> bool:
        """The status word's CALIBRATION_WARNING: a monitor above its warning level, or the latch set."""
        return self.latched is not None or any(r.warning or r.alarm for r in self.last.values())

    def wait_ready(self, timeout_s: float = 60.0) -> None:
        """The monitors restored or built (the first cycle's solve waits for them, if it comes that soon)."""
        self._ready.join(timeout_s)

    def check_latch(self) -> None:
        """Before a cycle moves anything: a latched alarm refuses it."""
        if self.latched is not None:
            raise CalibrationSuspect(f"{self.latched['message']} (latched since cycle {self.latched['cycle']}, "
                                     f"{self.latched['at']}); nothing moved: a passing check job (65535), a new "
                                     "calibration or `monoguide health --clear REASON` clears it")

    def observe(self, job: int, cycle: int, at: str, residual: Residual) -> TrendReading:
        """Add a cycle's residual to its part type's monitor (saved at once); passing the alarm level latches and
        raises :class:`CalibrationSuspect` naming the statistic, its level and the cycles since the calibration."""
        self.wait_ready()
        monitor = self.monitors.get(job)
        if monitor is None or monitor.levels.dof != residual.dof:
            monitor = self.monitors[job] = TrendMonitor(residual.dof, alarm_arl0=SERVICE_ALARM_ARL0)
        was_alarm = monitor.reading().alarm
        try:
            reading = monitor.update(residual.chi2, residual.dof, residual.per_view or None)
        except ValueError as exc:  # a solve gone wrong (a non-finite residual), or a view's rank changed: left out
            log.error("job %d: cycle %d's residual left out of the trend monitor: %s", job, cycle, exc)
            return monitor.reading()
        self.last[job] = reading
        error = None
        if reading.alarm and not was_alarm:
            error = CalibrationSuspect(
                f"job {job}: the residual's trend passed its alarm level ({reading.statistic:.2f} > "
                f"{reading.alarm_level:.2f}, CUSUM of the chi-square over {reading.cycles} cycles since the "
                f"calibration; one false alarm per {monitor.levels.alarm_arl0:,.0f} good cycles): the calibration no "
                "longer fits what the camera sees")
            self.latched = {"code": error.code, "message": error.message, "cycle": cycle, "at": at, "job": job}
            log.error("%s %s", error.code, error.message)
        elif reading.warning:
            log.warning("job %d: the residual's trend is above its warning level (%.2f > %.2f over %d cycles): "
                        "CALIBRATION_WARNING set", job, reading.statistic, reading.warning_level, reading.cycles)
        self._save()
        if error is not None:
            raise error
        return reading

    def latch(self, error: CalibrationSuspect, cycle: int, at: str, job: int) -> None:
        """A failed check: latch its refusal (saved)."""
        self.latched = {"code": error.code, "message": error.message, "cycle": cycle, "at": at, "job": job}
        log.error("%s %s", error.code, error.message)
        self._save()

    def clear(self, why: str) -> None:
        """The latch and the monitors start afresh (saved): an operator's clear after inspecting the cell, a passing
        check. Never waits: monitors still being restored at start are reset once they are."""
        log.warning("calibration latch %s and trend monitors reset: %s",
                    "cleared" if self.latched is not None else "(none)", why)
        self.latched, self.last, self.cleared = None, {}, why
        if self._ready.is_alive():
            self._reset_pending = True
        else:
            for monitor in self.monitors.values():
                monitor.reset()
        self._save()

    def take_clear_request(self) -> bool:
        """A clear asked for by ``monoguide health --clear`` (:func:`request_clear`): done, and its file removed."""
        path = self.path.with_name(CLEAR_REQUEST)
        try:
            request = json.loads(path.read_text())
        except FileNotFoundError:
            return False
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            request = {"reason": f"(unreadable request: {exc})"}
        request = request if isinstance(request, dict) else {}
        self.clear(f"{request.get('reason') or 'no reason given'} (asked at {request.get('at', '?')} by monoguide "
                   "health --clear)")
        path.unlink(missing_ok=True)
        return True

    def summary(self) -> dict[str, Any]:
        """For the status file: the calibration's identity, the latch, each part type's last reading."""
        return {"calibration": self.identity, "latched": self.latched, "warning": self.warning,
                "monitors": {str(job): {"statistic": round(r.statistic, 4), "warning_level": round(r.warning_level, 4),
                                        "alarm_level": round(r.alarm_level, 4), "cycles": r.cycles,
                                        "warning": r.warning, "alarm": r.alarm}
                             for job, r in sorted(self.last.items())}}

    # --- the file ------------------------------------------------------------------------------------

    def _read(self) -> dict[str, Any] | None:
        """The file's content for this calibration, or None (none, unreadable, another calibration's: logged)."""
        try:
            data = json.loads(self.path.read_text())
        except FileNotFoundError:
            return None
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            log.error("%s: cannot read the calibration health (%s): starting afresh", self.path, exc)
            return None
        if not isinstance(data, dict) or data.get("format") != HEALTH_FORMAT:
            log.error("%s: not a calibration health file: starting afresh", self.path)
            return None
        if data.get("calibration") != self.identity:
            log.warning("%s: the calibration changed (%s -> %s): trend monitors and latch start afresh", self.path,
                        data.get("calibration"), self.identity)
            return None
        return data

    def _load_latch(self) -> None:
        data = self._read()
        latched = data.get("latched") if data is not None else None
        self.latched = dict(latched) if isinstance(latched, dict) and "message" in latched else None
        self._data = data

    def _load_monitors(self, config: CellConfig) -> None:
        monitors: dict[int, TrendMonitor] = {}
        if self._data is not None:
            try:
                monitors = {int(job): TrendMonitor.from_state(state) for job, state in self._data["monitors"].items()}
            except (KeyError, TypeError, ValueError, AttributeError) as exc:
                log.error("%s: the calibration health's monitors are corrupt (%s): they start afresh", self.path, exc)
                monitors = {}
        for job in config.jobs:
            dof = 2 * sum(len(pose.points) for pose in config.for_job(job).measuring_poses) - 6
            if dof > 0 and (job not in monitors or monitors[job].levels.dof != dof):
                monitors[job] = TrendMonitor(dof, alarm_arl0=SERVICE_ALARM_ARL0)
        if self._reset_pending:  # cleared while they were being restored
            for monitor in monitors.values():
                monitor.reset()
        self.monitors = monitors
        self.last = {job: m.reading() for job, m in monitors.items() if m.reading().cycles}

    def _save(self) -> None:
        if self._ready.is_alive():  # the monitors are not restored yet: the latch alone (they are saved later)
            data = self._data or {"format": HEALTH_FORMAT, "calibration": self.identity, "monitors": {}}
            data = {**data, "latched": self.latched, "cleared": self.cleared}
            self._write(data)
            return
        data = {"format": HEALTH_FORMAT, "calibration": self.identity, "latched": self.latched, "cleared": self.cleared,
                "monitors": {str(job): monitor.state for job, monitor in sorted(self.monitors.items())}}
        self._write(data)

    def _write(self, data: dict[str, Any]) -> None:
        try:
            write_atomic(self.path, json.dumps(data, indent=1) + "\n")
        except OSError as exc:  # the journal keeps every cycle; this file is only the monitors' running sums
            log.error("%s: cannot write the calibration health: %s", self.path, exc)
