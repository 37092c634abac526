"""The *Now* page's facts: the service's state as the state machine names it, each device, the PLC link, the
last result with its error explained, the cycle counter, the calibration's age — one dict, rendered as HTML
and sent as JSON to the page's polling script.

The PLC: the service's link to it (connected, its last error) and the registers the status file's ``plc`` holds, as
the service last read and wrote them (control bits, job, part tag and the PLC's heartbeat, registers 0-3; the status
bits and monoguide's heartbeat, registers 10 and 12), at most ``heartbeat_s`` old.
"""

from __future__ import annotations

import time
from datetime import UTC, datetime
from typing import Any

from monoguide.daemon.web._meanings import meaning
from monoguide.daemon.web._source import StateSource
from monoguide.solver.errors import MonoguideError

HEALTH_NOT_AVAILABLE = "not available (this monoguide has no calibration health monitor)"


def now_facts(source: StateSource) -> dict[str, Any]:
    """Everything the *Now* page shows; plain JSON types only."""
    now = time.time()
    facts: dict[str, Any] = {"now": now, "service": _service(source, now), "journal": _journal(source),
                             "calibration": calibration_age(source, now), "health": HEALTH_NOT_AVAILABLE}
    return facts


def calibration_age(source: StateSource, now: float) -> dict[str, Any]:
    """The config's ``[calibration] date`` and its age in days (None without a config or a date)."""
    calibration = source.config.calibration if source.config is not None else None
    date = (calibration or {}).get("date")
    if date is None:
        why = "no --config given" if source.config is None else "the config has no [calibration] date"
        return {"date": None, "age_days": None, "note": why}
    try:
        when = date if isinstance(date, datetime) else datetime.fromisoformat(str(date))
    except ValueError:
        return {"date": str(date), "age_days": None, "note": "date not understood"}
    if when.tzinfo is None:
        when = when.replace(tzinfo=UTC)
    return {"date": when.isoformat(timespec="seconds"), "age_days": round((now - when.timestamp()) / 86400, 1),
            "note": None}


# --- private ------------------------------------------------------------------------------------


def _service(source: StateSource, now: float) -> dict[str, Any]:
    view = source.service()
    if view.error is not None:
        return {"running": False, "reason": view.error.message, "error": view.error.as_dict(), "state": None}
    status = view.status
    out: dict[str, Any] = {"running": view.liveness.running, "reason": view.liveness.reason, "error": None,
                           "state": None if status is None else status.state}
    if status is None:
        return out
    last = dict(status.last_result) if status.last_result else None
    if last is not None:
        last["meaning"] = meaning(last.get("error_code"))
    fault = dict(status.fault) if status.fault else None
    if fault is not None:
        fault["meaning"] = meaning(fault.get("code"))
    out.update({
        "since": status.since, "in_state_s": round(now - status.since, 1), "pid": status.pid,
        "status_age_s": round(now - status.updated_at, 1), "heartbeat_s": status.heartbeat_s,
        "devices": {name: {"connected": d.connected, "last_error": d.last_error}
                    for name, d in status.devices.items()},
        "last_result": last, "fault": fault, "plc": status.plc,
    })
    return out


def _journal(source: StateSource) -> dict[str, Any]:
    try:
        with source.journal() as journal:
            counter = journal.cycle_counter()
            rows = journal.last_cycles(1)
    except MonoguideError as error:
        return {"error": error.as_dict(), "cycle_counter": None, "last": None}
    last = None
    if rows:
        row = rows[0]
        result = row.result or {}
        last = {"number": row.number, "status": row.status, "error_code": row.error_code, "plc_code": row.plc_code,
                "error_message": row.error_message, "meaning": meaning(row.error_code),
                "finished_at": row.finished_at, "job": row.job, "part_tag": row.part_tag,
                "offset": result.get("base_offset_xyzabc"), "rms_px": result.get("rms_px")}
    return {"error": None, "cycle_counter": counter, "last": last}
