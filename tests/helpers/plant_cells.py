"""For the plant's tests and benchmark: a cell's state directory for the plant to read — a journal written by the
real ``Journal`` with seeded cycles (known offsets, errors and timings), a ``status.json`` kept fresh by the real
``write_status`` as a running service keeps it — and the plant file with a user."""

from __future__ import annotations

import os
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from helpers.plant_clients import ClientIdentity
from helpers.plant_npm import machine_vision_nodeset
from monoguide.daemon.errors import CycleAborted
from monoguide.daemon.plant import hash_password
from monoguide.daemon.service import CycleEntry, DeviceStatus, Journal, ServiceStatus, write_status
from monoguide.solver.errors import FeatureNotFound

USER, PASSWORD = "scada", "correct horse battery staple"
# the benchmark's 21 sessions and 41 subscriptions all come from 127.0.0.1: one client to the plant's limits
MANY_SESSIONS = "max_connections_per_client = 32\nmax_sessions_per_client = 32\nmax_subscriptions_per_client = 64"


@dataclass
class PlantCell:
    state_dir: Path
    url: str
    metrics_url: str
    line: str
    client: ClientIdentity  # trusted
    stranger: ClientIdentity  # not in the trust list
    seeded: list[CycleEntry]
    log: Path
    beat: StatusBeat | None = None  # the status file's writer: what the "service" says (state, calibration health)


def seeded_entries(count: int, start: float) -> list[CycleEntry]:
    """``count`` cycles: every fourth fails (FeatureNotFound, every eighth CycleAborted), the rest have offsets that
    tell them apart (x = cycle index + 0.123456, ...)."""
    entries = []
    for i in range(count):
        t0 = start + 10.0 * i
        timings = {"robot_motion": 0.4, "exposure": 1.2, "hole_finding": 0.2, "solve": 0.05, "checks": 0.001,
                   "overhead": 0.05 + 0.01 * i, "cycle": 2.5 + 0.1 * i}
        if i % 4 == 3:
            error = CycleAborted("stopped") if i % 8 == 7 else FeatureNotFound(f"hole P{i % 4 + 1} not found")
            entries.append(CycleEntry(t0, t0 + 2.0, job=1, part_tag=100 + i, error=error, timings_s=timings))
            continue
        offset = [i + 0.123456, -2.5 * i, 0.75, 0.01 * i, -0.02, 0.5]
        result = {"status": "ok", "base_offset_xyzabc": offset, "rms_px": 0.01 + 0.001 * i, "sigma_trans_mm": 0.3,
                  "sigma_rot_deg": 0.02}
        entries.append(CycleEntry(t0, t0 + 2.0, job=1, part_tag=100 + i, result=result, timings_s=timings))
    return entries


def write_journal(state_dir: Path, entries: list[CycleEntry]) -> None:
    with Journal(state_dir) as journal:
        for entry in entries:
            journal.commit_cycle(entry)


class StatusBeat:
    """Rewrites ``status.json`` every 0.5 s with ``state`` (settable), as the service does, until stopped."""

    def __init__(self, state_dir: Path, state: str = "idle") -> None:
        self.state_dir, self.state = state_dir, state
        self.health: dict | None = None  # the status file's calibration_health (CalibrationHealth.summary())
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._beat, daemon=True)
        running_status(state_dir, state)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(5)

    def _beat(self) -> None:
        while not self._stop.wait(0.5):
            running_status(self.state_dir, self.state, self.health)


def running_status(state_dir: Path, state: str = "idle", health: dict | None = None) -> None:
    """A status file of a running service (this test's pid, fresh for 3 s)."""
    now = time.time()
    write_status(state_dir, ServiceStatus(state, now - 5.0, os.getpid(), now, 1.0,
                                          {"plc": DeviceStatus(True), "camera": DeviceStatus(True),
                                           "robot": DeviceStatus(False, {"code": "DEVICE_DISCONNECTED",
                                                                         "message": "robot gone"})},
                                          calibration_health=health))


def plant_file(path: Path, host: str, port: int, extra: str = "") -> Path:
    path.write_text(f'[plant]\nopcua_host = "{host}"\nopcua_port = {port}\nmetrics_host = "{host}"\n'
                    f'metrics_port = {port + 1}\npoll_s = 0.05\nmachine_vision_nodeset = "{machine_vision_nodeset()}"\n'
                    f'{extra}\n'
                    f'[[plant.users]]\nname = "{USER}"\n'
                    f'password_hash = "{hash_password(PASSWORD, iterations=100_000)}"\n')
    return path


