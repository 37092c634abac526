"""The journal's SQL schema, its versions, and the entries the service writes into it.

The tables (``cycle``, ``offset_intent``), the upgrades of older schema versions, the partial index of the cycles
whose images are kept, the queries a long journal runs without a scan (as each schema version holds the columns),
the entry the service commits (:class:`CycleEntry`) and its strict JSON encoding (the rows read back are in
``_journal_rows``). docs/journal.md describes the same columns.
"""

from __future__ import annotations

import json
import math
import sqlite3
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from monoguide.daemon.errors import JournalEntryInvalid, JournalError, JournalNotADatabase
from monoguide.solver.errors import MonoguideError

# 2: the offset_intent table; 3: the cycle's duration_s, the intent's job, part_tag, started_at. Older journals are
# upgraded in place when the service opens them (_UPGRADES) and read as they are by the readers (cycle_select)
SCHEMA_VERSION = 3
READABLE_VERSIONS = (1, 2, 3)
APPLICATION_ID = 0x4D4F4E4F  # "MONO": marks the file as a monoguide journal for `file` and for us
JOURNAL_FILE = "journal.sqlite3"
IMAGES_DIR = "images"
MAX_NUMBER = 2**63 - 1  # SQLite INTEGER
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
    images_pruned_at REAL,                     -- when prune_images deleted this cycle's image files
    duration_s REAL                            -- s, the service's monotonic clock; null in rows before version 3
);
"""

_INTENT_SCHEMA = """
CREATE TABLE IF NOT EXISTS offset_intent (
    cycle INTEGER PRIMARY KEY,                 -- the number of the cycle whose offset this is
    sequence INTEGER NOT NULL,                 -- the robot request's sequence number
    offset_json TEXT NOT NULL,                 -- {"registers": [x, y, z mm, A, B, C deg], "D_b": 4x4}
    intended_at REAL NOT NULL,                 -- Unix time, s: committed before the offset was sent
    outcome TEXT CHECK (outcome IN ('acknowledged', 'refused', 'held', 'not_held')),  -- null: not settled
    cleared INTEGER NOT NULL DEFAULT 0,        -- 1: monoguide then cleared the robot's offset (command 3)
    settled_at REAL,
    detail TEXT,
    job INTEGER,                               -- the cycle's PLC register 1 (null in intents before version 3)
    part_tag INTEGER,                          -- its PLC register 3
    started_at REAL                            -- Unix s, the cycle's start
);
"""
INTENT_OUTCOMES = ("acknowledged", "refused", "held", "not_held")

# from each older version to SCHEMA_VERSION, additive only (ALTER TABLE ADD COLUMN rewrites no row: instant on a
# long journal); version 1 had no offset_intent table, created here in its version-3 form
_UPGRADES = {
    1: f"{_INTENT_SCHEMA} ALTER TABLE cycle ADD COLUMN duration_s REAL;",
    2: "ALTER TABLE offset_intent ADD COLUMN job INTEGER; ALTER TABLE offset_intent ADD COLUMN part_tag INTEGER;"
       " ALTER TABLE offset_intent ADD COLUMN started_at REAL; ALTER TABLE cycle ADD COLUMN duration_s REAL;",
}

# prune_images looks only at cycles whose images are still on disk: a partial index over those rows, so its cost
# follows the images kept (bounded by [service] images_max_mb), not the journal's length
_INDEX_SCHEMA = """
CREATE INDEX IF NOT EXISTS cycle_images_kept ON cycle (number)
    WHERE images_pruned_at IS NULL AND images_json <> '[]';
"""
_IMAGES_KEPT = "images_pruned_at IS NULL AND images_json <> '[]'"

# what the operator page filters the cycles on (daemon/service/_journal_query.py), each walked from the newest
# number down; the service creates them at every open (IF NOT EXISTS: once, on a journal written before them)
FILTER_INDEX_SCHEMA = """
CREATE INDEX IF NOT EXISTS cycle_status ON cycle (status, number);
CREATE INDEX IF NOT EXISTS cycle_error_code ON cycle (error_code, number) WHERE error_code IS NOT NULL;
CREATE INDEX IF NOT EXISTS cycle_job ON cycle (job, number);
CREATE INDEX IF NOT EXISTS cycle_finished ON cycle (finished_at);
"""


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
    duration_s: float | None = None  # s, the cycle's duration on a monotonic clock (None: not measured)


@dataclass(frozen=True)
class PruneReport:
    cycles: int
    files: int
    bytes_freed: int



class SqliteErrors:
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


# the cycle's columns, as row_from reads them: qualified, since a cycle's row is read with its intent's offset
_COLUMNS = ", ".join(f"cycle.{name}" for name in (
    "number", "started_at", "finished_at", "job", "part_tag", "status", "error_code", "plc_code", "error_message",
    "record_json", "result_json", "timings_json", "poses_json", "images_json", "images_pruned_at"))


def cycle_select(version: int) -> str:
    """``SELECT`` of a cycle's columns and its intent's offset (``row_from``) in a journal of schema ``version``:
    NULL for what that version does not hold. The intent is found by its key: no scan."""
    if version < 2:
        return f"SELECT {_COLUMNS}, NULL, NULL FROM cycle"
    duration = "cycle.duration_s" if version >= 3 else "NULL"
    return (f"SELECT {_COLUMNS}, {duration}, offset_intent.offset_json FROM cycle"
            " LEFT JOIN offset_intent ON offset_intent.cycle = cycle.number")


def last_cycles_query(version: int) -> str:
    """A search from the newest number down (the primary key), never a scan of the table."""
    return f"{cycle_select(version)} WHERE cycle.number <= ? ORDER BY cycle.number DESC LIMIT ?"


def intent_select(version: int) -> str | None:
    """``SELECT`` of an intent's columns (``intent_from_row``); None for a journal before the table (version 1)."""
    if version < 2:
        return None
    cycle_facts = "job, part_tag, started_at" if version >= 3 else "NULL, NULL, NULL"
    return ("SELECT cycle, sequence, offset_json, intended_at, outcome, cleared, settled_at, detail, "
            f"{cycle_facts} FROM offset_intent")


def upgrade_script(version: int) -> str:
    """The transaction that brings a journal of ``version`` (1 or 2) to :data:`SCHEMA_VERSION`."""
    return f"BEGIN; {_UPGRADES[version]} {_INDEX_SCHEMA} PRAGMA user_version = {SCHEMA_VERSION}; COMMIT;"


CYCLE_QUERY = f"{cycle_select(SCHEMA_VERSION)} WHERE cycle.number = ?"
LAST_CYCLES_QUERY = last_cycles_query(SCHEMA_VERSION)
PRUNE_QUERY = f"SELECT number, finished_at, images_json FROM cycle WHERE {_IMAGES_KEPT} ORDER BY number"


def outcome_of(entry: CycleEntry) -> tuple[str, str | None, int, str | None]:
    if entry.error is not None:
        return "error", entry.error.code, entry.error.plc_code, entry.error.message
    if entry.result is None:
        raise JournalEntryInvalid("cycle entry: neither a result nor an error; a finished cycle has one")
    return "ok", None, 0, None


def checked_duration(entry: CycleEntry) -> float | None:
    """The entry's ``duration_s``: None, or a finite number of seconds >= 0 (else :class:`JournalEntryInvalid`)."""
    d = entry.duration_s
    if d is None:
        return None
    if isinstance(d, bool) or not isinstance(d, int | float) or not math.isfinite(d) or d < 0:
        raise JournalEntryInvalid(f"cycle entry: duration_s {d!r} is not a duration (a finite number of seconds"
                                  " >= 0); nothing written")
    return float(d)


def dumps(name: str, value: Any) -> str | None:
    """Strict JSON (no NaN, no numpy arrays): the journal is read back by other programs."""
    if value is None:
        return None
    try:
        return json.dumps(value, allow_nan=False)
    except (TypeError, ValueError) as exc:
        raise JournalEntryInvalid(f"cycle entry: {name} is not plain JSON ({exc}); nothing written") from exc


def file_size(path: Path) -> int:
    try:
        return path.stat().st_size
    except FileNotFoundError:
        return 0
