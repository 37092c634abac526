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

from monoguide.daemon.service import CycleQuery
from monoguide.daemon.web._health import calibration_health
from monoguide.daemon.web._meanings import meaning
from monoguide.daemon.web._rows import find_rows, finite, read_cycle
from monoguide.daemon.web._source import ServiceView, StateSource
from monoguide.solver.errors import MonoguideError

MAX_DEPTH = 20  # of the status file's objects shown


def now_facts(source: StateSource) -> dict[str, Any]:
    """Everything the *Now* page shows; plain JSON types only (a number that is not finite is null)."""
    now = time.time()
    view = source.service()
    facts: dict[str, Any] = {"now": now, "service": _service(view, now), "journal": _journal(source),
                             "calibration": calibration_age(source, now), "health": calibration_health(source, view)}
    return _plain(facts)


def calibration_age(source: StateSource, now: float) -> dict[str, Any]:
    """The config's ``[calibration] date`` and its age in days (None without a config or a date)."""
    calibration = source.config.calibration if source.config is not None else None
    date = (calibration or {}).get("date")
    if date is None:
        why = "no --config given" if source.config is None else "the config has no [calibration] date"
        return {"date": None, "age_days": None, "note": why}
    try:
        when = date if isinstance(date, datetime) else datetime.fromisoformat(str(date))
        if when.tzinfo is None:
            when = when.replace(tzinfo=UTC)
        age_days = round((now - when.timestamp()) / 86400, 1)
    except (ValueError, OverflowError, OSError):
        return {"date": str(date), "age_days": None, "note": "date not understood"}
    return {"date": when.isoformat(timespec="seconds"), "age_days": age_days, "note": None}


# --- private ------------------------------------------------------------------------------------


def _service(view: ServiceView, now: float) -> dict[str, Any]:
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
            # the newest cycle, also when its row cannot be read (it says so)
            rows, notes = ([read_cycle(journal, counter)], []) if counter and journal.has_cycle(counter) else \
                find_rows(journal, CycleQuery(limit=1))
    except MonoguideError as error:
        return {"error": error.as_dict(), "cycle_counter": None, "last": None, "notes": []}
    last = None
    if rows:
        row = rows[0]
        last = {"number": row.number, "status": row.status, "error_code": row.error_code, "plc_code": row.plc_code,
                "error_message": row.error_message, "meaning": meaning(row.error_code),
                "finished_at": row.finished_at, "job": row.job, "part_tag": row.part_tag,
                "offset": row.offset, "rms_px": row.rms_px, "unreadable": list(row.unreadable)}
    return {"error": None, "cycle_counter": counter, "last": last, "notes": notes}


def _plain(value: Any, depth: int = 0) -> Any:
    """``value`` as JSON takes it: a float that is not finite (a status file may hold NaN) null, keys text."""
    if depth > MAX_DEPTH:
        return None
    if isinstance(value, float):
        return finite(value, float("inf"))
    if isinstance(value, dict):
        return {str(k): _plain(v, depth + 1) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v, depth + 1) for v in value]
    return value
