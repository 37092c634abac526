"""The service's status file, ``<state dir>/status.json`` (docs/status.md): what the running service is
doing, for ``monoguide status`` and anyone else who can read a file.

The service rewrites it on every state change and at least every ``heartbeat_s`` seconds
(:func:`write_status`: a temporary file renamed over the old one, so a reader never sees half a file).
A reader (:func:`read_status`, :func:`liveness`) trusts it only while the writing process is alive and
the file is fresh: a kill -9 leaves the last status behind, which then says "no service running".
"""

from __future__ import annotations

import json
import math
import os
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from monoguide.daemon.cycle import State
from monoguide.daemon.errors import ServiceStatusInvalid
from monoguide.drivers.atomic_file import write_atomic

STATUS_FILE = "status.json"
FORMAT = "monoguide.status/1"
DEFAULT_HEARTBEAT_S = 1.0
STALE_HEARTBEATS = 3  # a file older than this many heartbeats belongs to a service that no longer runs
STATES = tuple(state.value for state in State)


@dataclass(frozen=True)
class DeviceStatus:
    """One device as the service sees it. ``last_error``: ``{"code", "message"}`` of its last failure."""

    connected: bool
    last_error: dict[str, str] | None = None


@dataclass(frozen=True)
class ServiceStatus:
    """The content of ``status.json``; times are Unix seconds."""

    state: str  # a cycle State value: starting, idle, measuring, ..., fault, stopped
    since: float  # when the service entered ``state``
    pid: int
    updated_at: float  # when this was written
    heartbeat_s: float = DEFAULT_HEARTBEAT_S  # the service rewrites the file at least this often
    devices: dict[str, DeviceStatus] = field(default_factory=dict)
    last_result: dict[str, Any] | None = None  # {"cycle", "status", "error_code", "finished_at", ...}
    fault: dict[str, Any] | None = None  # while latched: {"code", "plc_code", "message"} of what latched FAULT
    plc: dict[str, Any] | None = None  # the PLC registers as last read and written (PlcLink.registers); None: none
    calibration_health: dict[str, Any] | None = None  # CalibrationHealth.summary(): the trend monitors, the latch

    def as_dict(self) -> dict[str, Any]:
        return {"format": FORMAT, **asdict(self)}


@dataclass(frozen=True)
class Liveness:
    running: bool
    reason: str  # why the service counts as running or not, for people


def write_status(state_dir: Path | str, status: ServiceStatus) -> Path:
    """Replace ``<state_dir>/status.json`` atomically with ``status``; return its path."""
    path = Path(state_dir) / STATUS_FILE
    return write_atomic(path, json.dumps(status.as_dict(), allow_nan=False, indent=1) + "\n")


def read_status(state_dir: Path | str) -> ServiceStatus | None:
    """The status in ``<state_dir>/status.json``; None when there is none (no service has written one).

    Raises :class:`ServiceStatusInvalid` naming the file and the bad field when it cannot be trusted.
    """
    path = Path(state_dir) / STATUS_FILE
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        return None
    except (OSError, UnicodeDecodeError) as exc:
        raise ServiceStatusInvalid(f"status file {path}: cannot read: {exc}") from exc
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ServiceStatusInvalid(f"status file {path}: not JSON ({exc.msg} at line {exc.lineno})") from exc
    return _parse(path, data)


def liveness(status: ServiceStatus | None, now: float | None = None) -> Liveness:
    """Whether the service that wrote ``status`` still runs: its pid alive and the file fresh."""
    if status is None:
        return Liveness(False, "no service running (no status file)")
    now = time.time() if now is None else now
    age = now - status.updated_at
    if status.state == State.STOPPED.value:
        return Liveness(False, f"no service running (stopped {_ago(now - status.since)})")
    if not _pid_alive(status.pid):
        return Liveness(False, f"no service running (pid {status.pid} is gone; last status {_ago(age)})")
    if age > STALE_HEARTBEATS * status.heartbeat_s:
        return Liveness(False, f"no service running (status file stale: updated {_ago(age)}, the service"
                               f" rewrites it every {status.heartbeat_s:g} s; pid {status.pid} hung?)")
    return Liveness(True, f"running (pid {status.pid})")


# --- private ------------------------------------------------------------------------------------


def _parse(path: Path, data: Any) -> ServiceStatus:
    def bad(why: str) -> ServiceStatusInvalid:
        return ServiceStatusInvalid(f"status file {path}: {why}")

    if not isinstance(data, dict) or data.get("format") != FORMAT:
        found = data.get("format") if isinstance(data, dict) else type(data).__name__
        raise bad(f"format: expected {FORMAT!r}, got {found!r}")
    if data.get("state") not in STATES:
        raise bad(f"state: {data.get('state')!r} is not one of {', '.join(STATES)}")
    times = {}
    for key in ("since", "updated_at", "heartbeat_s"):
        value = data.get(key, DEFAULT_HEARTBEAT_S if key == "heartbeat_s" else None)
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
            raise bad(f"{key}: expected a number, got {value!r}")
        times[key] = float(value)
    if times["heartbeat_s"] <= 0:
        raise bad(f"heartbeat_s: must be > 0, got {times['heartbeat_s']}")
    pid = data.get("pid")
    if isinstance(pid, bool) or not isinstance(pid, int) or pid <= 0:
        raise bad(f"pid: expected a positive whole number, got {pid!r}")
    devices = data.get("devices", {})
    if not isinstance(devices, dict):
        raise bad(f"devices: expected an object, got {devices!r}")
    parsed = {}
    for name, device in devices.items():
        if not isinstance(device, dict) or not isinstance(device.get("connected"), bool):
            raise bad(f"devices.{name}: expected {{\"connected\": true|false, \"last_error\": ...}}, got {device!r}")
        parsed[name] = DeviceStatus(device["connected"], device.get("last_error"))
    last_result = data.get("last_result")
    if last_result is not None and not isinstance(last_result, dict):
        raise bad(f"last_result: expected an object or null, got {last_result!r}")
    fault, plc, health = data.get("fault"), data.get("plc"), data.get("calibration_health")
    for key, value in (("fault", fault), ("plc", plc), ("calibration_health", health)):
        if value is not None and not isinstance(value, dict):
            raise bad(f"{key}: expected an object or null, got {value!r}")
    return ServiceStatus(data["state"], times["since"], pid, times["updated_at"], times["heartbeat_s"], parsed,
                         last_result, fault, plc, health)


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # alive, owned by the service's own user
        return True
    return True


def _ago(seconds: float) -> str:
    if seconds < 0:
        return "in the future (clock?)"
    if seconds < 120:
        return f"{seconds:.0f} s ago"
    if seconds < 7200:
        return f"{seconds / 60:.0f} min ago"
    return f"{seconds / 3600:.1f} h ago"
