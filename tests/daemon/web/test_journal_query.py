"""The journal's paged, filtered query (``Journal.find_cycles``) against a journal written by the real ``Journal``
with seeded statuses, codes, jobs and times: every filter gives exactly the seeded cycles, pages neither overlap
nor leave a gap, each filter walks an index (never a scan of the table), and a journal written before the
indexes gets them when the service opens it."""

from __future__ import annotations

import sqlite3
from pathlib import Path

import pytest

from monoguide.daemon.service import CycleEntry, CycleQuery, Journal
from monoguide.daemon.service._journal_query import find_cycles
from monoguide.drivers.errors import DeviceTimeout
from monoguide.solver.errors import HoleNotFound

T0 = 1_800_000_000.0
N = 230


def _seeded(n: int) -> tuple[str | None, int]:
    """(error code or None, job) of cycle n: a rule the test knows, not read back from the journal."""
    code = HoleNotFound if n % 7 == 0 else DeviceTimeout if n % 11 == 0 else None
    return (None if code is None else code.code), 1 + n % 3


@pytest.fixture(scope="module")
def journal_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    state = tmp_path_factory.mktemp("query")
    with Journal(state) as journal:
        for n in range(1, N + 1):
            code, job = _seeded(n)
            error = None if code is None else (HoleNotFound if code == HoleNotFound.code else DeviceTimeout)("seeded")
            journal.commit_cycle(CycleEntry(T0 + 10 * n, T0 + 10 * n + 5, job, n, result=None if error else {"n": n},
                                            error=error))
    return state


def _numbers(rows: list) -> list[int]:
    return [r.number for r in rows]


@pytest.mark.parametrize(("query", "expected"), [
    (CycleQuery(limit=500), list(range(N, 0, -1))),
    (CycleQuery(status="error", limit=500), [n for n in range(N, 0, -1) if _seeded(n)[0]]),
    (CycleQuery(status="ok", limit=500), [n for n in range(N, 0, -1) if not _seeded(n)[0]]),
    (CycleQuery(error_code="DEVICE_TIMEOUT", limit=500),
     [n for n in range(N, 0, -1) if _seeded(n)[0] == "DEVICE_TIMEOUT"]),
    (CycleQuery(job=2, status="error", limit=500),
     [n for n in range(N, 0, -1) if _seeded(n)[1] == 2 and _seeded(n)[0]]),
    (CycleQuery(finished_from=T0 + 10 * 50, finished_to=T0 + 10 * 60, limit=500), list(range(59, 49, -1))),
    (CycleQuery(error_code="NO_SUCH_CODE"), []),
])
def test_each_filter_gives_the_seeded_cycles(journal_dir: Path, query: CycleQuery, expected: list[int]) -> None:
    with Journal(journal_dir, read_only=True) as journal:
        assert _numbers(journal.find_cycles(query)) == expected


def test_pages_follow_on_without_overlap_or_gap(journal_dir: Path) -> None:
    seen: list[int] = []
    with Journal(journal_dir, read_only=True) as journal:
        before = 0
        while True:
            page = journal.find_cycles(CycleQuery(status="ok", before=before, limit=17))
            seen += _numbers(page)
            if len(page) < 17:
                break
            before = page[-1].number
    assert seen == [n for n in range(N, 0, -1) if not _seeded(n)[0]]


def test_error_codes_are_the_seeded_ones(journal_dir: Path) -> None:
    with Journal(journal_dir, read_only=True) as journal:
        assert journal.error_codes() == ["DEVICE_TIMEOUT", "HOLE_NOT_FOUND"]


@pytest.mark.parametrize(("query", "walk"), [
    (CycleQuery(), "INTEGER PRIMARY KEY"), (CycleQuery(status="error"), "INDEX cycle_status"),
    (CycleQuery(error_code="X"), "INDEX cycle_error_code"), (CycleQuery(job=2), "INDEX cycle_job"),
    (CycleQuery(finished_from=T0, finished_to=T0 + 100), "INDEX cycle_finished")])
def test_each_filter_walks_an_index(journal_dir: Path, query: CycleQuery, walk: str) -> None:
    db = sqlite3.connect(journal_dir / "journal.sqlite3")
    plans: list[str] = []
    original = db.execute

    class Explaining:
        def execute(self, sql: str, values: tuple = ()) -> sqlite3.Cursor:
            if sql.startswith("SELECT"):
                plans.extend(str(row[3]) for row in original(f"EXPLAIN QUERY PLAN {sql}", values).fetchall())
            return original(sql, values)

    find_cycles(Explaining(), query)  # type: ignore[arg-type]
    db.close()
    assert any(p.startswith("SEARCH cycle USING") and walk in p for p in plans), plans
    assert not any(p.startswith("SCAN cycle") for p in plans), plans


def test_a_journal_written_before_the_indexes_gets_them_when_the_service_opens_it(tmp_path: Path) -> None:
    with Journal(tmp_path) as journal:
        journal.commit_cycle(CycleEntry(T0, T0 + 1, 1, 1, result={}))
    db = sqlite3.connect(tmp_path / "journal.sqlite3")
    for name in ("cycle_status", "cycle_error_code", "cycle_job", "cycle_finished"):
        db.execute(f"DROP INDEX {name}")
    db.commit()
    with Journal(tmp_path, read_only=True) as reader:  # a reader creates nothing, and still finds the cycle
        assert _numbers(reader.find_cycles(CycleQuery(status="ok"))) == [1]
    assert not db.execute("SELECT name FROM sqlite_master WHERE name LIKE 'cycle_status'").fetchall()
    Journal(tmp_path).close()
    names = {r[0] for r in db.execute("SELECT name FROM sqlite_master WHERE type = 'index'").fetchall()}
    db.close()
    assert {"cycle_status", "cycle_error_code", "cycle_job", "cycle_finished"} <= names
