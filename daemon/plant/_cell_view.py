"""What the plant interfaces read of the cell: the service's status file and its journal, read-only, as
``monoguide status`` reads them (``read_status``, ``liveness``; ``Journal(state_dir, read_only=True)``).

:meth:`CellView.poll` runs every ``[plant] poll_s``; its cost does not grow with the journal: the cycle counter
(one row of ``sqlite_sequence``), each new cycle by its primary key, the status file re-read only when it changed.
A new row is held back until the service has added the timings known only after DONE (``cycle``: trigger to DONE;
it does so a few milliseconds after the commit), at most :data:`AMEND_WAIT_S`.
"""

from __future__ import annotations

import contextlib
import logging
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

from monoguide.daemon.errors import JournalReplaced
from monoguide.daemon.plant._results import CycleResult, amended, cycle_result
from monoguide.daemon.service import JOURNAL_FILE, STATUS_FILE, Journal, ServiceStatus, liveness, read_status
from monoguide.solver.errors import MonoguideError

log = logging.getLogger(__name__)

AMEND_WAIT_S = 0.5  # a row without its `cycle` timing is published anyway after this long
CATCH_UP = 1000  # at most this many new cycles are read in one poll (a reader far behind skips the rest)


@dataclass
class CellReading:
    """One poll's findings. ``results``: the cycles finished since the last poll, oldest first."""

    status: ServiceStatus | None
    running: bool
    results: list[CycleResult] = field(default_factory=list)
    counter: int | None = None  # the journal's cycle counter; None: no journal yet
    journal_bytes: int = 0  # journal.sqlite3 and its -wal
    disk_free_bytes: int | None = None  # the state directory's file system: free to the service, and in all
    disk_size_bytes: int | None = None


HEALTH_OK, HEALTH_WARNING, HEALTH_ALARM = 0.0, 1.0, 2.0  # the calibration health level the plant publishes


def health_level(reading: CellReading) -> float | None:
    """The calibration's health as the running service keeps it (docs/health.md): 0 ok, 1 the trend above its
    warning level, 2 its alarm latched (CALIBRATION_SUSPECT); None when no running service says."""
    health = reading.status.calibration_health if reading.status is not None and reading.running else None
    if not isinstance(health, dict):
        return None
    if health.get("latched"):
        return HEALTH_ALARM
    return HEALTH_WARNING if health.get("warning") else HEALTH_OK


class CellView:
    """Reads the state directory of one service; opens the journal once it exists, again when it was replaced."""

    def __init__(self, state_dir: os.PathLike[str] | str) -> None:
        self.state_dir = Path(state_dir)
        self.journal: Journal | None = None
        self.seen = 0  # the newest cycle number published
        self._pending: dict[int, float] = {}  # cycle number -> when first seen without its `cycle` timing
        self._status: ServiceStatus | None = None
        self._status_stamp: tuple[int, int] | None = None

    def close(self) -> None:
        if self.journal is not None:
            self.journal.close()
            self.journal = None

    def start(self, last: int) -> tuple[list[CycleResult], dict[tuple[str, str | None], int]]:
        """The newest ``last`` cycles (newest first) and the journal's cycles by outcome; from then on :meth:`poll`
        reports the cycles after them."""
        journal = self._journal()
        if journal is None:
            return [], {}
        rows = journal.last_cycles(last)
        self.seen = journal.cycle_counter()
        return [cycle_result(row) for row in rows], journal.outcome_counts()

    def poll(self, now: float | None = None) -> CellReading:
        now = time.time() if now is None else now
        status = self._read_status()
        reading = CellReading(status, liveness(status, now).running, journal_bytes=self._journal_bytes())
        with contextlib.suppress(OSError):
            disk = os.statvfs(self.state_dir)
            reading.disk_free_bytes = disk.f_bavail * disk.f_frsize
            reading.disk_size_bytes = disk.f_blocks * disk.f_frsize
        journal = self._journal()
        if journal is None:
            return reading
        try:
            reading.counter = journal.cycle_counter()
            reading.results = self._new_results(journal, reading.counter, now)
        except JournalReplaced:
            log.warning("journal %s was replaced; reading the new one", journal.path)
            self.close()
        if journal.immutable:  # opened without the service's -shm: it would see no later commit
            self.close()
        return reading

    # --- private ------------------------------------------------------------------------------------

    def _journal(self) -> Journal | None:
        if self.journal is not None:
            try:
                self.journal.check_identity()
            except JournalReplaced:
                self.close()
        if self.journal is None and (self.state_dir / JOURNAL_FILE).is_file():
            try:
                self.journal = Journal(self.state_dir, read_only=True)
            except MonoguideError as error:
                log.warning("journal: cannot open it read-only yet: %s %s", error.code, error.message)
        return self.journal

    def _new_results(self, journal: Journal, counter: int, now: float) -> list[CycleResult]:
        if counter < self.seen:  # a new, empty journal: numbering goes on from the PLC's counter
            self.seen = 0
        first = max(self.seen + 1, counter - CATCH_UP + 1)
        results = []
        for number in range(first, counter + 1):
            if not journal.has_cycle(number):  # a number never committed (an intent's, rows deleted by hand)
                self.seen = number
                continue
            row = journal.cycle(number)
            if not amended(row) and now - self._pending.setdefault(number, now) < AMEND_WAIT_S:
                break  # later rows wait for this one: results are published in order
            self._pending.pop(number, None)
            results.append(cycle_result(row))
            self.seen = number
        return results

    def _read_status(self) -> ServiceStatus | None:
        path = self.state_dir / STATUS_FILE
        try:
            stat = path.stat()
            stamp = (stat.st_mtime_ns, stat.st_ino)
        except FileNotFoundError:
            self._status, self._status_stamp = None, None
            return None
        if stamp != self._status_stamp:
            try:
                self._status = read_status(self.state_dir)
            except MonoguideError as error:
                log.warning("status file: %s %s", error.code, error.message)
                self._status = None
            self._status_stamp = stamp
        return self._status

    def _journal_bytes(self) -> int:
        total = 0
        for name in (JOURNAL_FILE, JOURNAL_FILE + "-wal"):
            with contextlib.suppress(FileNotFoundError):
                total += (self.state_dir / name).stat().st_size
        return total
