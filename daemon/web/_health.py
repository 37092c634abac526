"""The calibration's health as the service keeps it (docs/health.md): the latch (``CALIBRATION_SUSPECT``), the
warning, each part type's trend monitor against its levels. From the status file's ``calibration_health``, which
the service rewrites every second; when the status file has none (no service has written one, or a monoguide
whose service kept none), from the service's own ``calibration-health.json`` in the state directory (the latch and
each monitor's statistic as last saved: its levels are the running service's to compute); else not available.

Every value is checked for what it is shown as: a status or health file of another monoguide, or half-written by
hand, is shown as far as it goes.
"""

from __future__ import annotations

import json
from typing import Any

from monoguide.daemon.service import HEALTH_FILE
from monoguide.daemon.web._rows import finite, text, whole
from monoguide.daemon.web._source import ServiceView, StateSource

MAX_HEALTH_BYTES = 1_000_000
MAX_MONITORS = 64


def calibration_health(source: StateSource, view: ServiceView) -> dict[str, Any]:
    """From ``view`` (the status file as read now), else the state directory's health file: ``level`` (``ok``,
    ``warning``, ``alarm``; None: not known), ``summary`` (one line), ``latched`` (its code, message, cycle, time,
    job), ``monitors`` (per job), ``source`` (where from) and the calibration's identity."""
    given = view.status.calibration_health if view.status is not None else None
    if isinstance(given, dict):
        running = view.liveness is not None and view.liveness.running
        return _facts(given, "the running service's status file" if running else
                      f"the status file as its service last wrote it ({view.liveness.reason if view.liveness else ''})",
                      levels=True)
    kept = _health_file(source)
    if isinstance(kept, dict):
        return _facts(kept, f"{HEALTH_FILE} (the status file has none)", levels=False)
    why = ("the status file cannot be read" if view.error is not None else
           "no service has written a status file here" if view.status is None else
           "the service's status file carries none")
    extra = f"; {kept}" if isinstance(kept, str) else f"; no {HEALTH_FILE} in the state directory"
    return {"level": None, "summary": f"not available ({why}{extra})", "latched": None, "monitors": [],
            "source": None, "calibration": None}


# --- private ------------------------------------------------------------------------------------


def _facts(data: dict[str, Any], where: str, levels: bool) -> dict[str, Any]:
    latched = data.get("latched")
    latch = None
    if isinstance(latched, dict):
        latch = {"code": text(latched.get("code"), 64) or "CALIBRATION_SUSPECT",
                 "message": text(latched.get("message"), 2000) or "", "cycle": whole(latched.get("cycle"), 0, 2**63),
                 "at": text(latched.get("at"), 40), "job": whole(latched.get("job"), 0, 65535)}
    monitors = []
    found = data.get("monitors")
    for job, m in list(found.items())[:MAX_MONITORS] if isinstance(found, dict) else []:
        if not isinstance(m, dict):
            continue
        monitors.append({
            "job": str(job)[:12], "statistic": finite(m.get("statistic")), "cycles": whole(m.get("cycles"), 0, 2**63),
            "warning_level": finite(m.get("warning_level")) if levels else None,
            "alarm_level": finite(m.get("alarm_level")) if levels else None,
            "warning": m.get("warning") is True, "alarm": m.get("alarm") is True or m.get("alarm_cycle") is not None})
    warning = data.get("warning") is True or any(m["warning"] for m in monitors)
    level = "alarm" if latch is not None else "warning" if warning else "ok" if levels else None
    if latch is not None:
        summary = (f"ALARM latched: {latch['code']}" + (f" since cycle {latch['cycle']}" if latch["cycle"] else "")
                   + (f" ({latch['at']})" if latch["at"] else "") + ": every cycle is refused until a check job "
                   "passes, the cell is calibrated anew or `monoguide health --clear REASON`")
    elif warning:
        summary = "WARNING: the residual's trend is above its warning level (CALIBRATION_WARNING); cycles go on"
    elif levels:
        summary = "ok: every part type's trend below its warning level"
    else:
        summary = "no alarm latched (whether a trend is above its warning level the running service says)"
    return {"level": level, "summary": f"{summary} — from {where}", "latched": latch, "monitors": monitors,
            "source": where, "calibration": text(data.get("calibration"), 40)}


def _health_file(source: StateSource) -> dict[str, Any] | str | None:
    """The health file's content, a sentence why it cannot be read, or None when there is none."""
    path = source.state_dir / HEALTH_FILE
    try:
        with open(path, "rb") as file:
            raw = file.read(MAX_HEALTH_BYTES + 1)
    except FileNotFoundError:
        return None
    except OSError as exc:
        return f"{HEALTH_FILE} cannot be read ({exc.strerror})"
    try:
        data = json.loads(raw)
    except (ValueError, RecursionError):
        return f"{HEALTH_FILE} is not JSON"
    return data if isinstance(data, dict) and len(raw) <= MAX_HEALTH_BYTES else f"{HEALTH_FILE} is not a health file"
