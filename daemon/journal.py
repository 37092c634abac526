"""The journal: one SQLite row per finished cycle, committed before the PLC is told DONE.

A row holds the measurement record (``docs/measurement-record.md``) the cycle solved, its result or its
error (code, PLC code, message), the time each stage took, the robot's actual poses at the captures and
the paths of the images. The cycle counter (PLC register 13) is the number of the last committed row, so
it survives restarts.

Durability: WAL mode with ``synchronous=FULL``. WAL already survives a kill -9 of the process at
``NORMAL``; ``FULL`` also fsyncs the WAL at every commit, so a row the PLC was told about survives a power
cut too. The price is one fsync per cycle (cycles are seconds apart) — nothing next to a camera frame.
:meth:`Journal.commit_cycle` returns only after that commit, and returns the cycle number the PLC
is then given: the natural order is journal first, PLC after.

Images live under ``<state dir>/images``; :meth:`Journal.prune_images` deletes those of the oldest
cycles beyond a size or age limit and marks their rows (the row itself is kept).
"""

from __future__ import annotations

import json
import sqlite3
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from monoguide.solver.errors import MonoguideError

SCHEMA_VERSION = 1
APPLICATION_ID = 0x4D4F4E4F  # "MONO": marks the file as a monoguide journal for `file` and for us
JOURNAL_FILE = "journal.sqlite3"
IMAGES_DIR = "images"
BUSY_TIMEOUT_MS = 5000  # every wait has a timeout: another process holding the write lock

_SCHEMA = """
CREATE TABLE cycle (
    number INTEGER PRIMARY KEY AUTOINCREMENT,  -- the cycle counter; never reused
    started_at REAL NOT NULL,                  -- Unix time, s
    finished_at REAL NOT NULL,
    job INTEGER,                               -- PLC register 1
    part_tag INTEGER,                          -- PLC register 3
    status TEXT NOT NULL CHECK (status IN ('ok', 'error')),
    error_code TEXT,
    plc_code INTEGER NOT NULL,                 -- 0 when ok
    error_message TEXT,
    record_json TEXT,                          -- the measurement record; null if the cycle failed before one
    result_json TEXT,                          -- the solve result; null on error before solving
    timings_json TEXT NOT NULL,                -- {"measuring": s, "solving": s, ...}
    poses_json TEXT NOT NULL,                  -- robot's actual T_b_f at each capture, 4x4 lists
    images_json TEXT NOT NULL,                 -- image paths, relative to the state directory when inside it
    images_pruned_at REAL                      -- when prune_images deleted this cycle's image files
);
"""


class JournalError(MonoguideError):
    """The journal could not be opened, read or written; the message names the file and SQLite's words."""

    code = "JOURNAL_ERROR"
    plc_code = 620


class JournalNotADatabase(JournalError):
    """The journal file exists but is not an SQLite database (corrupt, truncated, or some other file)."""

    code = "JOURNAL_NOT_A_DATABASE"
    plc_code = 621


class JournalSchemaUnknown(JournalError):
    """An SQLite file that is not a monoguide journal, or one of a schema version this release cannot read."""

    code = "JOURNAL_SCHEMA_UNKNOWN"
    plc_code = 622


class JournalEntryMissing(JournalError):
    """No cycle with that number in the journal."""

    code = "JOURNAL_ENTRY_MISSING"
    plc_code = 623


class JournalEntryInvalid(JournalError):
    """A cycle entry that contradicts itself (ok without a result, error without a code); nothing written."""

    code = "JOURNAL_ENTRY_INVALID"
    plc_code = 624


@dataclass(frozen=True)
class CycleEntry:
    """One finished cycle as the journal stores it. ``error`` set means the cycle failed."""

    started_at: float
    finished_at: float
    job: int | None = None
    part_tag: int | None = None
    record: dict[str, Any] | None = None
    result: dict[str, Any] | None = None
    error: MonoguideError | None = None
    timings_s: dict[str, float] = field(default_factory=dict)
    poses_at_capture: list[list[list[float]]] = field(default_factory=list)
    image_paths: list[str] = field(default_factory=list)


@dataclass(frozen=True)
class JournalRow:
    """A cycle read back from the journal."""

    number: int
    started_at: float
    finished_at: float
    job: int | None
    part_tag: int | None
    status: str
    error_code: str | None
    plc_code: int
    error_message: str | None
    record: dict[str, Any] | None
    result: dict[str, Any] | None
    timings_s: dict[str, float]
    poses_at_capture: list[list[list[float]]]
    image_paths: list[str]
    images_pruned_at: float | None


@dataclass(frozen=True)
class PruneReport:
    cycles: int
    files: int
    bytes_freed: int


class Journal:
    """The journal of one state directory. Open it once per process; the service is the only writer."""

    def __init__(self, state_dir: Path | str) -> None:
        self.state_dir = Path(state_dir)
        self.path = self.state_dir / JOURNAL_FILE
        self.images_dir = self.state_dir / IMAGES_DIR
        try:
            self.images_dir.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise JournalError(f"journal {self.path}: cannot create {self.images_dir}: {exc}") from exc
        self._db = self._open()

    def close(self) -> None:
        self._db.close()

    def __enter__(self) -> Journal:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()

    # --- writing ------------------------------------------------------------------------------------

    def commit_cycle(self, entry: CycleEntry) -> int:
        """Store one finished cycle and commit it (fsynced); return its number, the new cycle counter.

        Only after this returns may the PLC be told DONE. Raises :class:`JournalEntryInvalid` for an entry
        that contradicts itself and :class:`JournalError` when SQLite fails (nothing is then committed).
        """
        status, error_code, plc_code, message = _outcome(entry)
        row = (
            entry.started_at, entry.finished_at, entry.job, entry.part_tag, status, error_code, plc_code, message,
            _dumps("record", entry.record), _dumps("result", entry.result), _dumps("timings_s", entry.timings_s),
            _dumps("poses_at_capture", entry.poses_at_capture),
            _dumps("image_paths", [self._relative(p) for p in entry.image_paths]),
        )
        with self._sqlite("commit a cycle"), self._db:
            cursor = self._db.execute(
                "INSERT INTO cycle (started_at, finished_at, job, part_tag, status, error_code, plc_code,"
                " error_message, record_json, result_json, timings_json, poses_json, images_json)"
                " VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                row,
            )
        return int(cursor.lastrowid)

    def amend_timings(self, number: int, timings_s: dict[str, float]) -> None:
        """Add timings known only after the commit (``plc_journal``, ``cycle``: they include the commit and
        the PLC's DONE) to cycle ``number``'s row; the rest of the row is never changed."""
        with self._sqlite(f"amend cycle {number}"), self._db:
            found = self._db.execute("SELECT timings_json FROM cycle WHERE number = ?", (number,)).fetchone()
            if found is None:
                raise JournalEntryMissing(f"journal {self.path}: no cycle {number}")
            self._db.execute("UPDATE cycle SET timings_json = ? WHERE number = ?",
                             (_dumps("timings_s", {**json.loads(found[0]), **timings_s}), number))

    # --- reading ------------------------------------------------------------------------------------

    def cycle_counter(self) -> int:
        """The number of the last committed cycle (0 for a new journal): PLC register 13."""
        with self._sqlite("read the cycle counter"):
            found = self._db.execute("SELECT seq FROM sqlite_sequence WHERE name = 'cycle'").fetchone()
        return int(found[0]) if found else 0

    def cycle(self, number: int) -> JournalRow:
        with self._sqlite(f"read cycle {number}"):
            found = self._db.execute(f"SELECT {_COLUMNS} FROM cycle WHERE number = ?", (number,)).fetchone()
        if found is None:
            raise JournalEntryMissing(f"journal {self.path}: no cycle {number} (counter {self.cycle_counter()})")
        return _row(found)

    def last_cycles(self, count: int) -> list[JournalRow]:
        """The ``count`` most recent cycles, newest first."""
        with self._sqlite("list cycles"):
            rows = self._db.execute(f"SELECT {_COLUMNS} FROM cycle ORDER BY number DESC LIMIT ?", (count,)).fetchall()
        return [_row(found) for found in rows]

    def integrity_check(self) -> str:
        """SQLite's ``PRAGMA integrity_check``: ``"ok"`` or the damage it found."""
        with self._sqlite("check integrity"):
            return "\n".join(str(r[0]) for r in self._db.execute("PRAGMA integrity_check").fetchall())

    # --- images -------------------------------------------------------------------------------------

    def prune_images(self, max_bytes: int, max_age_s: float, now: float | None = None) -> PruneReport:
        """Delete the image files of the oldest cycles until the rest are younger than ``max_age_s`` and
        together at most ``max_bytes``; mark those rows ``images_pruned_at``. Call it between cycles.

        Whole cycles go together, oldest first; missing files count as already gone.
        """
        now = time.time() if now is None else now
        with self._sqlite("list images"):
            rows = self._db.execute(
                "SELECT number, finished_at, images_json FROM cycle WHERE images_pruned_at IS NULL ORDER BY number"
            ).fetchall()
        cycles = [(number, finished, [self._absolute(p) for p in json.loads(images)])
                  for number, finished, images in rows]
        sizes = {path: _size(path) for _, _, paths in cycles for path in paths}
        total = sum(sizes.values())
        pruned: list[int] = []
        files = freed = 0
        for number, finished_at, paths in cycles:
            if now - finished_at <= max_age_s and total <= max_bytes:
                break
            for path in paths:
                if sizes[path]:
                    path.unlink(missing_ok=True)
                    files += 1
                    freed += sizes[path]
                    total -= sizes[path]
            pruned.append(number)
        if pruned:
            with self._sqlite("mark pruned images"), self._db:
                self._db.executemany("UPDATE cycle SET images_pruned_at = ? WHERE number = ?",
                                     [(now, number) for number in pruned])
        return PruneReport(len(pruned), files, freed)

    # --- private ------------------------------------------------------------------------------------

    def _open(self) -> sqlite3.Connection:
        try:
            # check_same_thread off: the service commits from a worker thread, one call at a time
            db = sqlite3.connect(self.path, timeout=BUSY_TIMEOUT_MS / 1000, isolation_level="DEFERRED",
                                 check_same_thread=False)
        except sqlite3.Error as exc:
            raise JournalError(f"journal {self.path}: cannot open: {exc}") from exc
        try:
            with self._sqlite("open"):
                version = db.execute("PRAGMA user_version").fetchone()[0]
                application_id = db.execute("PRAGMA application_id").fetchone()[0]
                tables = db.execute("SELECT count(*) FROM sqlite_master").fetchone()[0]
            if version == 0 and application_id == 0 and tables == 0:
                with self._sqlite("create the schema"):
                    db.executescript(f"BEGIN; {_SCHEMA} PRAGMA application_id = {APPLICATION_ID};"
                                     f" PRAGMA user_version = {SCHEMA_VERSION}; COMMIT;")
            elif application_id != APPLICATION_ID:
                raise JournalSchemaUnknown(f"journal {self.path}: an SQLite database but not a monoguide journal"
                                           f" (application_id {application_id:#x}, {tables} objects); refusing to"
                                           " touch it — move it away or point --state-dir elsewhere")
            elif version != SCHEMA_VERSION:
                newer = " (written by a newer monoguide?)" if version > SCHEMA_VERSION else ""
                raise JournalSchemaUnknown(f"journal {self.path}: schema version {version}{newer}; this monoguide"
                                           f" reads version {SCHEMA_VERSION} only")
            with self._sqlite("set WAL mode"):
                mode = db.execute("PRAGMA journal_mode = WAL").fetchone()[0]
                db.execute("PRAGMA synchronous = FULL")
            if mode != "wal":
                raise JournalError(f"journal {self.path}: SQLite refused WAL mode (got {mode!r})")
        except BaseException:
            db.close()
            raise
        return db

    def _sqlite(self, doing: str) -> _SqliteErrors:
        return _SqliteErrors(self.path, doing)

    def _relative(self, path: str | Path) -> str:
        path = Path(path)
        try:
            return str(path.resolve().relative_to(self.state_dir.resolve()))
        except ValueError:
            return str(path)

    def _absolute(self, stored: str) -> Path:
        path = Path(stored)
        return path if path.is_absolute() else self.state_dir / path


class _SqliteErrors:
    """Turns an ``sqlite3.Error`` into a :class:`JournalError` naming the file and what was being done."""

    def __init__(self, path: Path, doing: str) -> None:
        self.path, self.doing = path, doing

    def __enter__(self) -> None:
        return None

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None, _tb: object) -> None:
        if isinstance(exc, sqlite3.DatabaseError) and "not a database" in str(exc):
            raise JournalNotADatabase(f"journal {self.path}: not an SQLite database (SQLite: {exc});"
                                      " corrupt or another file — move it away to start a new journal") from exc
        if isinstance(exc, sqlite3.Error):
            raise JournalError(f"journal {self.path}: cannot {self.doing} (SQLite: {exc})") from exc


_COLUMNS = ("number, started_at, finished_at, job, part_tag, status, error_code, plc_code, error_message,"
            " record_json, result_json, timings_json, poses_json, images_json, images_pruned_at")


def _outcome(entry: CycleEntry) -> tuple[str, str | None, int, str | None]:
    if entry.error is not None:
        return "error", entry.error.code, entry.error.plc_code, entry.error.message
    if entry.result is None:
        raise JournalEntryInvalid("cycle entry: neither a result nor an error; a finished cycle has one")
    return "ok", None, 0, None


def _dumps(name: str, value: Any) -> str | None:
    """Strict JSON (no NaN, no numpy arrays): the journal is read back by other programs."""
    if value is None:
        return None
    try:
        return json.dumps(value, allow_nan=False)
    except (TypeError, ValueError) as exc:
        raise JournalEntryInvalid(f"cycle entry: {name} is not plain JSON ({exc}); nothing written") from exc


def _loads(text: str | None) -> Any:
    return None if text is None else json.loads(text)


def _row(found: Sequence[Any]) -> JournalRow:
    (number, started_at, finished_at, job, part_tag, status, error_code, plc_code, error_message,
     record, result, timings, poses, images, pruned_at) = found
    return JournalRow(number, started_at, finished_at, job, part_tag, status, error_code, plc_code, error_message,
                      _loads(record), _loads(result), json.loads(timings), json.loads(poses), json.loads(images),
                      pruned_at)


def _size(path: Path) -> int:
    try:
        return path.stat().st_size
    except FileNotFoundError:
        return 0
