"""The journal's SQL schema and the rows it holds, as the service writes them and readers read them back.

The tables (``cycle``, ``offset_intent``) and the partial index of the cycles whose images are kept, the queries a
long journal runs without a scan, the typed rows (:class:`CycleEntry` in, :class:`JournalRow` and
:class:`OffsetIntent` out) and their strict JSON encoding. docs/journal.md describes the same columns.
"""

from __future__ import annotations

import json
import sqlite3
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from monoguide.daemon.errors import JournalEntryInvalid, JournalError, JournalNotADatabase
from monoguide.solver.errors import MonoguideError

SCHEMA_VERSION = 2  # 2: the offset_intent table (version 1 journals are upgraded in place when opened)
READABLE_VERSIONS = (1, 2)
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
    images_pruned_at REAL                      -- when prune_images deleted this cycle's image files
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
    detail TEXT
);
"""
INTENT_OUTCOMES = ("acknowledged", "refused", "held", "not_held")

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
class OffsetIntent:
    """An offset committed before it was sent to the robot, and what became of it (``outcome`` None: not
    settled yet — the robot may hold it)."""

    cycle: int
    sequence: int
    registers: tuple[float, ...]  # x, y, z (mm), A, B, C (deg): PLC registers 16-27
    D_b: list[list[float]]
    intended_at: float
    outcome: str | None
    cleared: bool
    settled_at: float | None
    detail: str | None


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


_COLUMNS = ("number, started_at, finished_at, job, part_tag, status, error_code, plc_code, error_message,"
            " record_json, result_json, timings_json, poses_json, images_json, images_pruned_at")


# a search from the newest number down (the primary key), never a scan of the table
LAST_CYCLES_QUERY = f"SELECT {_COLUMNS} FROM cycle WHERE number <= ? ORDER BY number DESC LIMIT ?"
PRUNE_QUERY = f"SELECT number, finished_at, images_json FROM cycle WHERE {_IMAGES_KEPT} ORDER BY number"
_INTENT_COLUMNS = "cycle, sequence, offset_json, intended_at, outcome, cleared, settled_at, detail"


def intent_from_row(found: Sequence[Any]) -> OffsetIntent:
    cycle, sequence, offset, intended_at, outcome, cleared, settled_at, detail = found
    data = json.loads(offset)
    return OffsetIntent(cycle, sequence, tuple(data["registers"]), data["D_b"], intended_at, outcome, bool(cleared),
                        settled_at, detail)


def outcome_of(entry: CycleEntry) -> tuple[str, str | None, int, str | None]:
    if entry.error is not None:
        return "error", entry.error.code, entry.error.plc_code, entry.error.message
    if entry.result is None:
        raise JournalEntryInvalid("cycle entry: neither a result nor an error; a finished cycle has one")
    return "ok", None, 0, None


def dumps(name: str, value: Any) -> str | None:
    """Strict JSON (no NaN, no numpy arrays): the journal is read back by other programs."""
    if value is None:
        return None
    try:
        return json.dumps(value, allow_nan=False)
    except (TypeError, ValueError) as exc:
        raise JournalEntryInvalid(f"cycle entry: {name} is not plain JSON ({exc}); nothing written") from exc


def loads(text: str | None) -> Any:
    return None if text is None else json.loads(text)


def row_from(found: Sequence[Any]) -> JournalRow:
    (number, started_at, finished_at, job, part_tag, status, error_code, plc_code, error_message,
     record, result, timings, poses, images, pruned_at) = found
    return JournalRow(number, started_at, finished_at, job, part_tag, status, error_code, plc_code, error_message,
                      loads(record), loads(result), json.loads(timings), json.loads(poses), json.loads(images),
                      pruned_at)


def file_size(path: Path) -> int:
    try:
        return path.stat().st_size
    except FileNotFoundError:
        return 0
