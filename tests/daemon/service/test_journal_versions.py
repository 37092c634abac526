"""Journals of the earlier schema versions, as those releases wrote them (1: the cycles; 2: and the offset
intents): read as they are by the readers, upgraded in place to version 3 when the service opens them. And the
cycle's duration (version 3): the service's own measure, or for an older row its wall time when that is one."""

from __future__ import annotations

import json
import sqlite3
from pathlib import Path

import pytest
from typer.testing import CliRunner

from monoguide.daemon.cli import app
from monoguide.daemon.errors import JournalEntryInvalid
from monoguide.daemon.service import CycleEntry, Journal, OffsetLedger
from monoguide.drivers.errors import DeviceTimeout, RobotOffsetUnconfirmed

# the tables as the releases of schema versions 1 and 2 created them (their comments left out)
V1_CYCLE = """CREATE TABLE cycle (number INTEGER PRIMARY KEY AUTOINCREMENT, started_at REAL NOT NULL,
    finished_at REAL NOT NULL, job INTEGER, part_tag INTEGER, status TEXT NOT NULL CHECK (status IN ('ok', 'error')),
    error_code TEXT, plc_code INTEGER NOT NULL, error_message TEXT, record_json TEXT, result_json TEXT,
    timings_json TEXT NOT NULL, poses_json TEXT NOT NULL, images_json TEXT NOT NULL, images_pruned_at REAL);"""
V2_INTENT = """CREATE TABLE IF NOT EXISTS offset_intent (cycle INTEGER PRIMARY KEY, sequence INTEGER NOT NULL,
    offset_json TEXT NOT NULL, intended_at REAL NOT NULL,
    outcome TEXT CHECK (outcome IN ('acknowledged', 'refused', 'held', 'not_held')),
    cleared INTEGER NOT NULL DEFAULT 0, settled_at REAL, detail TEXT);"""
APPLICATION_ID = 0x4D4F4E4F
T0 = 1_790_000_000.0
OFFSET = [12.5, -3.25, 0.75, 1.5, -0.5, 0.125]
D_B = [[1.0, 0.0, 0.0, 12.5], [0.0, 1.0, 0.0, -3.25], [0.0, 0.0, 1.0, 0.75], [0.0, 0.0, 0.0, 1.0]]
# (number, started_at, finished_at, job, part_tag, status, error_code, plc_code, message, result): cycle 2 across a
# clock step back (its wall time is negative), cycle 3 failed; in version 2 cycle 4's intent has no row (kill -9)
OLD_ROWS = [
    (1, T0, T0 + 4.5, 1, 101, "ok", None, 0, None, {"status": "ok", "rms_px": 0.05, "base_offset_xyzabc": OFFSET}),
    (2, T0 + 60, T0 + 60 - 3600 + 4.0, 1, 102, "ok", None, 0, None, {"status": "ok", "rms_px": 0.06}),
    (3, T0 + 120, T0 + 125.25, 2, 103, "error", "DEVICE_TIMEOUT", 402, "robot: measuring pose 2 not reached", None),
]


def _old_journal(directory: Path, version: int) -> None:
    db = sqlite3.connect(directory / "journal.sqlite3")
    db.executescript(f"BEGIN; {V1_CYCLE} {V2_INTENT if version == 2 else ''}"
                     f" PRAGMA application_id = {APPLICATION_ID}; PRAGMA user_version = {version}; COMMIT;")
    db.execute("PRAGMA journal_mode = WAL")
    with db:
        for number, started, finished, job, tag, status, code, plc, message, result in OLD_ROWS:
            db.execute("INSERT INTO cycle (number, started_at, finished_at, job, part_tag, status, error_code,"
                       " plc_code, error_message, record_json, result_json, timings_json, poses_json, images_json)"
                       " VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, NULL, ?, ?, '[]', '[]')",
                       (number, started, finished, job, tag, status, code, plc, message,
                        None if result is None else json.dumps(result), json.dumps({"measuring": 3.5})))
        if version == 2:
            offset = json.dumps({"registers": OFFSET, "D_b": D_B})
            db.execute("INSERT INTO offset_intent VALUES (1, 41, ?, ?, 'acknowledged', 0, ?, 'request 41"
                       " acknowledged')", (offset, T0 + 4.0, T0 + 4.5))
            db.execute("INSERT INTO offset_intent (cycle, sequence, offset_json, intended_at) VALUES (4, 42, ?, ?)",
                       (offset, T0 + 184.0))
    db.close()


def _schema(directory: Path) -> tuple[int, dict[str, list[str]]]:
    db = sqlite3.connect(directory / "journal.sqlite3")
    try:
        version = db.execute("PRAGMA user_version").fetchone()[0]
        tables = [name for (name,) in db.execute("SELECT name FROM sqlite_master WHERE type = 'table'"
                                                 " AND name <> 'sqlite_sequence'")]
        return version, {t: [c[1] for c in db.execute(f"PRAGMA table_info({t})")] for t in sorted(tables)}
    finally:
        db.close()


def _assert_old_rows(journal: Journal) -> None:
    rows = {row.number: row for row in journal.last_cycles(10)}
    for number, started, finished, job, tag, status, code, plc, message, result in OLD_ROWS:
        row = rows[number]
        assert (row.started_at, row.finished_at, row.job, row.part_tag, row.status) == (started, finished, job, tag,
                                                                                        status)
        assert (row.error_code, row.plc_code, row.error_message, row.result) == (code, plc, message, result)
        assert row.timings_s == {"measuring": 3.5} and row.damaged == ()
    # no measured duration in an older row: its wall time, and none where the clock stepped back
    assert [rows[n].duration_s for n in (1, 2, 3)] == [pytest.approx(4.5), None, pytest.approx(5.25)]
    assert rows[1].base_offset_xyzabc == OFFSET


@pytest.mark.parametrize("version", [1, 2])
def test_an_older_journal_is_read_as_it_is_by_a_reader(tmp_path: Path, version: int) -> None:
    _old_journal(tmp_path, version)
    before = _schema(tmp_path)
    with Journal(tmp_path, read_only=True) as reader:
        assert reader.version == version
        _assert_old_rows(reader)
        if version == 1:  # no intents yet
            assert reader.intent(1) is None and reader.unsettled_intents() == [] and reader.last_sequence() == 0
        else:
            intent = reader.intent(1)
            assert intent is not None and (intent.sequence, list(intent.registers), intent.outcome) == (
                41, OFFSET, "acknowledged")
            assert (intent.job, intent.part_tag, intent.started_at, intent.damaged) == (None, None, None, ())
            assert [i.cycle for i in reader.unsettled_intents()] == [4] and reader.last_sequence() == 42
    for args in (["list", "--json"], ["show", "1", "--json"], ["show", "3"]):
        run = CliRunner().invoke(app, ["journal", *args, "--state-dir", str(tmp_path)])
        assert run.exit_code == 0, (args, run.output)
    shown = json.loads(CliRunner().invoke(app, ["journal", "show", "1", "--json", "--state-dir",
                                                str(tmp_path)]).stdout)
    assert shown["duration_s"] == pytest.approx(4.5) and shown["base_offset_xyzabc"] == OFFSET
    assert _schema(tmp_path) == before  # nothing upgraded, nothing created by a reader


@pytest.mark.parametrize("version", [1, 2])
def test_an_older_journal_is_upgraded_in_place_when_the_service_opens_it(tmp_path: Path, version: int) -> None:
    _old_journal(tmp_path, version)
    with Journal(tmp_path) as journal:
        _assert_old_rows(journal)
        if version == 2:  # its kill -9 window: the rebuilt row has what the older intent carried
            assert OffsetLedger(journal).recover() == [4]
            rebuilt = journal.cycle(4)
            assert (rebuilt.error_code, rebuilt.started_at, rebuilt.job, rebuilt.part_tag) == (
                RobotOffsetUnconfirmed.code, T0 + 184.0, None, None)
            assert rebuilt.base_offset_xyzabc == OFFSET
        number = journal.next_number()
        journal.commit_intent(number, 43, tuple(OFFSET), D_B, job=2, part_tag=105, started_at=T0 + 300)
        journal.commit_cycle(CycleEntry(T0 + 300, T0 + 307, 2, 105, result={"status": "ok"}, duration_s=6.75), number)
    version_now, tables = _schema(tmp_path)
    assert version_now == 3
    assert tables["cycle"][-1] == "duration_s" and tables["offset_intent"][-3:] == ["job", "part_tag", "started_at"]
    with Journal(tmp_path, read_only=True) as reader:
        _assert_old_rows(reader)
        intent = reader.intent(number)
        assert intent is not None and (intent.job, intent.part_tag, intent.started_at) == (2, 105, T0 + 300)
        assert reader.cycle(number).duration_s == 6.75
    db = sqlite3.connect(tmp_path / "journal.sqlite3")
    assert db.execute("SELECT count(*) FROM cycle WHERE duration_s IS NULL").fetchone()[0] == 3 + (version == 2)
    assert db.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    db.close()


def test_the_duration_is_the_services_measure_not_the_wall_clocks(tmp_path: Path) -> None:
    """A cycle across a clock step: its wall time says 3601 s or -7199 s; the measured duration is the truth."""
    steps = [(3600.0 + 1.25, 1.25), (-7200.0 + 0.5, 0.5), (4.0, 4.0)]  # (finished - started, measured)
    with Journal(tmp_path) as journal:
        for i, (wall, measured) in enumerate(steps):
            journal.commit_cycle(CycleEntry(T0 + 60 * i, T0 + 60 * i + wall, 1, i, result={"status": "ok"},
                                            duration_s=measured))
        journal.commit_cycle(CycleEntry(T0 + 200, T0 + 190, 1, 9, error=DeviceTimeout("camera: no frame")))
        for bad in (float("nan"), float("inf"), -0.5):
            with pytest.raises(JournalEntryInvalid, match=rf"duration_s {bad!r} is not a duration"):
                journal.commit_cycle(CycleEntry(T0, T0 + 1, result={"status": "ok"}, duration_s=bad))
        assert journal.cycle_counter() == 4  # nothing written for those
        assert [row.duration_s for row in journal.last_cycles(4)[::-1]] == [1.25, 0.5, 4.0, None]
    run = CliRunner().invoke(app, ["journal", "list", "--json", "--state-dir", str(tmp_path)])
    assert [json.loads(line)["duration_s"] for line in run.stdout.splitlines()] == [1.25, 0.5, 4.0, None]
    run = CliRunner().invoke(app, ["journal", "list", "--state-dir", str(tmp_path)])
    header, *lines = run.stdout.splitlines()
    end = header.index("total s") + len("total s")  # the column is right-aligned under its header
    assert run.exit_code == 0 and [line[end - 8:end].strip() for line in lines] == ["1.25", "0.50", "4.00", "-"]
    run = CliRunner().invoke(app, ["journal", "show", "2", "--state-dir", str(tmp_path)])
    assert "(0.50 s)" in run.stdout, run.stdout
