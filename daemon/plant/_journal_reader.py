"""The journal as the OPC UA methods and HistoryRead read it: a read-only ``Journal`` of its own (not the poll's),
used by one worker thread at a time, so that a read never holds up the server's loop and never shares a
connection with the poll. Opened at the first read, again when the journal was replaced.
"""

from __future__ import annotations

import asyncio
import logging
import threading
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

from monoguide.daemon.errors import JournalReplaced
from monoguide.daemon.service import JOURNAL_FILE, Journal
from monoguide.solver.errors import MonoguideError

log = logging.getLogger(__name__)
T = TypeVar("T")


class JournalReader:
    def __init__(self, state_dir: Path) -> None:
        self.state_dir = state_dir
        self._journal: Journal | None = None
        self._lock = threading.Lock()

    async def read(self, query: Callable[[Journal], T]) -> T | None:
        """``query(journal)`` in a worker thread; None when there is no journal (yet)."""
        return await asyncio.to_thread(self._read, query)

    def close(self) -> None:
        with self._lock:
            self._close()

    def _read(self, query: Callable[[Journal], T]) -> T | None:
        with self._lock:
            for _ in range(2):  # a replaced journal is opened anew, once
                journal = self._open()
                if journal is None:
                    return None
                try:
                    journal.check_identity()
                    return query(journal)
                except JournalReplaced:
                    self._close()
            return None

    def _open(self) -> Journal | None:
        if self._journal is None and (self.state_dir / JOURNAL_FILE).is_file():
            try:
                self._journal = Journal(self.state_dir, read_only=True)
            except MonoguideError as error:
                log.warning("journal: cannot open it read-only: %s %s", error.code, error.message)
        return self._journal

    def _close(self) -> None:
        if self._journal is not None:
            self._journal.close()
            self._journal = None
