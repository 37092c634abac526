"""Cycles found by what a person filters on (status, error code, job, a time window), newest first, a page at a
time: the query of the operator page's *Cycles* list and *Trends*.

Paging is by key, not by offset: a page ends at a cycle number and the next page starts below it
(``before``), so the thousandth page costs what the first does. Each filter has an index of its own
(``_journal_schema.FILTER_INDEX_SCHEMA``: ``(status, number)``, ``(error_code, number)``, ``(job, number)`` and
``finished_at``), walked from the newest number down; a time window is sought through the ``finished_at`` index
(a window far back in a long journal is then found without a scan of the newer rows). The service creates the
indexes when it opens the journal; a reader never does (it opens ``mode=ro``), so a journal the service has not
opened since they came works too, only slower.
"""

from __future__ import annotations

import sqlite3
from dataclasses import dataclass
from typing import Any

from monoguide.daemon.service._journal_rows import JournalRow, row_from, stored_text
from monoguide.daemon.service._journal_schema import MAX_NUMBER, SCHEMA_VERSION, cycle_select

MAX_PAGE = 500  # rows in one answer, whatever is asked


@dataclass(frozen=True)
class CycleQuery:
    """Which cycles: every field None (or 0 for ``before``) means no such condition."""

    status: str | None = None  # "ok" or "error"
    error_code: str | None = None  # e.g. "HOLE_NOT_FOUND"
    job: int | None = None  # PLC register 1 at the trigger
    finished_from: float | None = None  # Unix s, inclusive
    finished_to: float | None = None  # Unix s, exclusive
    before: int = 0  # only cycles numbered below this (the previous page's last); 0: from the newest
    limit: int = 50


def find_cycles(db: sqlite3.Connection, query: CycleQuery, *,
                select: str = cycle_select(SCHEMA_VERSION)) -> list[JournalRow]:
    """The cycles ``query`` asks for, newest first, at most ``query.limit`` (and :data:`MAX_PAGE`).

    Two steps: the page's numbers from the index alone (a window's rows are sorted by number as index entries,
    not as 6 kB rows), then those rows by their key. ``select``: the rows' ``SELECT`` as the journal's schema
    version holds them (``_journal_schema.cycle_select``)."""
    conditions, values = _conditions(query)
    window = query.finished_from is not None or query.finished_to is not None
    hint = " INDEXED BY cycle_finished" if window and _has_index(db, "cycle_finished") else ""
    numbers = [found[0] for found in db.execute(
        f"SELECT number FROM cycle{hint} WHERE {' AND '.join(conditions)} ORDER BY number DESC LIMIT ?",
        (*values, max(1, min(query.limit, MAX_PAGE)))).fetchall()]
    if not numbers:
        return []
    rows = db.execute(f"{select} WHERE cycle.number IN ({', '.join('?' * len(numbers))})"
                      " ORDER BY cycle.number DESC", numbers).fetchall()
    return [row_from(found) for found in rows]


def error_codes(db: sqlite3.Connection) -> list[str]:
    """Every error code the journal holds, sorted (the filter's choices): from the ``(error_code, number)``
    index, one step per distinct code, never a scan of the rows. A code stored as text that is not UTF-8 is
    stepped past by its stored bytes (its replacement characters may sort before them)."""
    codes: list[str] = []
    found = db.execute("SELECT min(error_code) FROM cycle WHERE error_code IS NOT NULL").fetchone()
    while found is not None and found[0] is not None:
        code = found[0]
        if isinstance(code, bytes):  # a blob where a code belongs is no code; blobs sort after every text
            found = db.execute("SELECT min(error_code) FROM cycle WHERE error_code > ?", (code,)).fetchone()
            continue
        codes.append(code)
        found = db.execute("SELECT min(error_code) FROM cycle WHERE error_code > CAST(? AS TEXT)",
                           (stored_text(code),)).fetchone()
    return codes


def _conditions(query: CycleQuery) -> tuple[list[str], list[Any]]:
    before = query.before if 0 < query.before <= MAX_NUMBER else MAX_NUMBER
    conditions, values = ["number < ?" if query.before else "number <= ?"], [before]
    for column, value in (("status", query.status), ("error_code", query.error_code), ("job", query.job)):
        if value is not None:
            conditions.append(f"{column} = ?")
            values.append(value)
    if query.finished_from is not None:
        conditions.append("finished_at >= ?")
        values.append(query.finished_from)
    if query.finished_to is not None:
        conditions.append("finished_at < ?")
        values.append(query.finished_to)
    return conditions, values


def _has_index(db: sqlite3.Connection, name: str) -> bool:
    return db.execute("SELECT 1 FROM sqlite_master WHERE type = 'index' AND name = ?", (name,)).fetchone() is not None
