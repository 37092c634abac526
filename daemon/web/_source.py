"""What the operator page reads, and only reads: the service's journal (``Journal(read_only=True)``), its
``status.json`` and, when given, the cell config.

One journal connection is shared by the server's worker threads, one request at a time (a lock). It is opened on
first use and opened anew when the file at the path is another one (the service recreated it) or, opened
``immutable`` while no service ran, when the file changed since (a service started and writes it): an immutable
connection would never see the new rows. A journal that is missing or cannot be read is an error of that request
only; the next request tries again, so the page comes back by itself when the journal does.
"""

from __future__ import annotations

import contextlib
import os
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from monoguide.daemon.config import CellConfig, load_cell_config
from monoguide.daemon.errors import NoJournal, StateDirMissing
from monoguide.daemon.service import JOURNAL_FILE, Journal, ServiceStatus, liveness, read_status
from monoguide.solver.errors import MonoguideError


@dataclass(frozen=True)
class ServiceView:
    """``status.json`` as read now: the status (None: none written), whether its service runs, or why not read."""

    status: ServiceStatus | None
    liveness: Any  # service._status.Liveness (running, reason), None when the file could not be read
    error: MonoguideError | None


class StateSource:
    """The state directory of one service, read-only; :meth:`close` ends the journal's connection."""

    def __init__(self, state_dir: Path, config_path: Path | None = None) -> None:
        self.state_dir = Path(state_dir)
        self.config_path = config_path
        self.config: CellConfig | None = None
        if config_path is not None:
            self.config = load_cell_config(config_path)  # a bad file ends the command: exit 2, naming the key
        self._lock = threading.Lock()
        self._journal: Journal | None = None
        self._seen: tuple[int, int, int, int, bool] | None = None  # dev, inode, mtime, size, -wal present

    @contextlib.contextmanager
    def journal(self) -> Iterator[Journal]:
        """The journal, for one request (raises :class:`NoJournal`, :class:`StateDirMissing` or the
        journal's own errors; a failed connection is dropped, the next request opens it again)."""
        with self._lock:
            journal = self._current()
            try:
                yield journal
            except MonoguideError:
                self._drop()
                raise

    def service(self) -> ServiceView:
        try:
            status = read_status(self.state_dir)
        except MonoguideError as error:
            return ServiceView(None, None, error)
        return ServiceView(status, liveness(status), None)

    def close(self) -> None:
        with self._lock:
            self._drop()

    # --- private ------------------------------------------------------------------------------------

    def _current(self) -> Journal:
        path = self.state_dir / JOURNAL_FILE
        try:
            stat = os.stat(path)
        except FileNotFoundError:
            self._drop()
            if not self.state_dir.is_dir():
                raise StateDirMissing(f"state directory {self.state_dir}: no such directory (the service's "
                                      "--state-dir?)") from None
            raise NoJournal(f"no journal in {self.state_dir} ({JOURNAL_FILE} missing): no cycle has "
                                 "finished here yet") from None
        seen = (stat.st_dev, stat.st_ino, stat.st_mtime_ns, stat.st_size, path.with_name(path.name + "-wal").exists())
        if self._journal is not None and self._seen is not None:
            replaced = seen[:2] != self._seen[:2]
            if replaced or (self._journal.immutable and seen != self._seen):
                self._drop()
        if self._journal is None:
            self._journal = Journal(self.state_dir, read_only=True)
        self._seen = seen
        return self._journal

    def _drop(self) -> None:
        if self._journal is not None:
            with contextlib.suppress(Exception):
                self._journal.close()
        self._journal = None
        self._seen = None
