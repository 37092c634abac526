"""The SQLite journal: round trip, nothing committed lost to kill -9, bad files refused, images pruned."""

from __future__ import annotations

import json
import os
import signal
import sqlite3
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from monoguide.daemon.errors import (
    JournalEntryInvalid,
    JournalEntryMissing,
    JournalError,
    JournalNotADatabase,
    JournalReplaced,
    JournalSchemaUnknown,
)
from monoguide.daemon.service import CycleEntry, Journal
from monoguide.drivers.errors import DeviceTimeout

EXAMPLE_RECORD = Path(__file__).parents[3] / "examples" / "example-record.json"

# The content of cycle n is a function of n alone, so the parent knows what every committed row must hold
# without trusting anything the child (or the journal) says. Shared verbatim with the child process.
EXPECTED_CYCLE = textwrap.dedent("""
    def expected_entry(n, record):
        from monoguide.daemon.service import CycleEntry
        from monoguide.drivers.errors import DeviceTimeout
        record = dict(record, id=f"part-{n}")
        failed = n % 5 == 0
        return CycleEntry(
            started_at=1_790_000_000.0 + 10 * n, finished_at=1_790_000_004.5 + 10 * n, job=1, part_tag=n % 65536,
            record=record, result=None if failed else {"id": f"part-{n}", "status": "ok", "rms_px": n / 1000},
            error=DeviceTimeout(f"robot: measuring pose {n % 4 + 1} not reached within 10 s") if failed else None,
            timings_s={"measuring": 2.0 + n / 100, "solving": 0.05, "checking": 0.001},
            poses_at_capture=[[[1.0, 0.0, 0.0, 100.0 * n], [0.0, 1.0, 0.0, 1.5], [0.0, 0.0, 1.0, -2.25],
                               [0.0, 0.0, 0.0, 1.0]]] * 4,
            image_paths=[f"images/{n}/view{i}.png" for i in range(4)],
        )
""")
namespace: dict = {}
exec(EXPECTED_CYCLE, namespace)
expected_entry = namespace["expected_entry"]

WRITER = EXPECTED_CYCLE + textwrap.dedent("""
    import json, sys
    from monoguide.daemon.service import Journal
    record = json.load(open(sys.argv[2]))
    journal = Journal(sys.argv[1])
    while True:
        number = journal.cycle_counter() + 1
        assert journal.commit_cycle(expected_entry(number, record)) == number
        print(number, flush=True)  # only after the commit returned
""")


def _record() -> dict:
    return json.loads(EXAMPLE_RECORD.read_text())


def _assert_row_is(journal: Journal, number: int) -> None:
    entry, row = expected_entry(number, _record()), journal.cycle(number)
    assert (row.number, row.started_at, row.finished_at, row.job, row.part_tag) == (
        number, entry.started_at, entry.finished_at, 1, number)
    assert row.record == entry.record and row.result == entry.result
    assert row.timings_s == entry.timings_s and row.poses_at_capture == entry.poses_at_capture
    assert row.image_paths == entry.image_paths
    if entry.error is None:
        assert (row.status, row.error_code, row.plc_code, row.error_message) == ("ok", None, 0, None)
    else:
        assert (row.status, row.error_code, row.plc_code) == ("error", "DEVICE_TIMEOUT", 402)
        assert row.error_message == entry.error.message


def test_round_trip_and_the_counter_survives_reopening(tmp_path: Path) -> None:
    with Journal(tmp_path / "state") as journal:
        assert journal.cycle_counter() == 0
        for number in (1, 2, 3, 4, 5):
            assert journal.commit_cycle(expected_entry(number, _record())) == number
        assert journal.cycle_counter() == 5
    with Journal(tmp_path / "state") as journal:
        for number in (1, 2, 3, 4, 5):
            _assert_row_is(journal, number)
        assert [row.number for row in journal.last_cycles(2)] == [5, 4]
        assert journal.commit_cycle(expected_entry(6, _record())) == 6
        with pytest.raises(JournalEntryMissing, match=r"no cycle 7 \(counter 6\)"):
            journal.cycle(7)
    db = sqlite3.connect(tmp_path / "state" / "journal.sqlite3")
    assert db.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    assert db.execute("PRAGMA user_version").fetchone()[0] == 3


def test_a_contradictory_or_non_json_entry_is_refused_and_nothing_written(tmp_path: Path) -> None:
    with Journal(tmp_path) as journal:
        with pytest.raises(JournalEntryInvalid, match="neither a result nor an error"):
            journal.commit_cycle(CycleEntry(started_at=1.0, finished_at=2.0))
        with pytest.raises(JournalEntryInvalid, match="timings_s is not plain JSON"):
            journal.commit_cycle(CycleEntry(1.0, 2.0, result={"status": "ok"}, timings_s={"solving": float("nan")}))
        assert journal.cycle_counter() == 0


def test_kill_minus_9_loses_nothing_committed(tmp_path: Path) -> None:
    state_dir, record_file = tmp_path / "state", tmp_path / "record.json"
    record_file.write_text(json.dumps(_record()))
    acknowledged: list[int] = []
    for kill_after in (15, 25, 10):  # three lives of the service, each killed while committing more
        child = subprocess.Popen([sys.executable, "-c", WRITER, str(state_dir), str(record_file)],
                                 stdout=subprocess.PIPE, text=True)
        assert child.stdout is not None
        deadline = time.monotonic() + 10
        for _ in range(kill_after):
            line = child.stdout.readline()
            assert line, f"writer ended early with {child.wait()}"
            acknowledged.append(int(line))
            assert time.monotonic() < deadline
        os.kill(child.pid, signal.SIGKILL)  # it is busy committing the next cycles
        child.wait(timeout=5)
        acknowledged += [int(line) for line in child.stdout.read().split()]
        child.stdout.close()
        assert child.returncode == -signal.SIGKILL
    # a commit may land after the last line a life printed, so numbers may skip across lives, never repeat
    assert acknowledged == sorted(set(acknowledged)) and len(acknowledged) >= 50
    with Journal(state_dir) as journal:
        assert journal.integrity_check() == "ok"
        counter = journal.cycle_counter()
        assert counter >= acknowledged[-1]  # a commit may land after the last line the child printed
        for number in range(1, counter + 1):
            _assert_row_is(journal, number)


def test_a_file_that_is_not_sqlite_is_refused_by_name(tmp_path: Path) -> None:
    path = tmp_path / "journal.sqlite3"
    path.write_bytes(b"this is a config file, not a journal\n" * 200)
    with pytest.raises(JournalNotADatabase, match=f"journal {path}: not an SQLite database"):
        Journal(tmp_path)
    assert path.read_bytes() == b"this is a config file, not a journal\n" * 200  # untouched


def test_a_corrupted_journal_is_refused(tmp_path: Path) -> None:
    with Journal(tmp_path) as journal:
        journal.commit_cycle(expected_entry(1, _record()))
    path = tmp_path / "journal.sqlite3"
    data = bytearray(path.read_bytes())
    data[:16] = b"garbage garbage!"  # the header magic
    path.write_bytes(bytes(data))
    with pytest.raises(JournalNotADatabase, match="not an SQLite database"):
        Journal(tmp_path)


def test_another_programs_database_and_an_unknown_version_are_refused(tmp_path: Path) -> None:
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    db = sqlite3.connect(foreign / "journal.sqlite3")
    db.execute("CREATE TABLE recipes (name TEXT)")
    db.commit()
    db.close()
    with pytest.raises(JournalSchemaUnknown, match="not a monoguide journal"):
        Journal(foreign)
    with Journal(tmp_path / "newer"):
        pass
    db = sqlite3.connect(tmp_path / "newer" / "journal.sqlite3")
    db.execute("PRAGMA user_version = 7")
    db.close()
    with pytest.raises(JournalSchemaUnknown,
                       match=r"schema version 7 \(written by a newer monoguide\?\).*versions 1, 2, 3 only"):
        Journal(tmp_path / "newer")


def _cycle_with_images(journal: Journal, number: int, finished_at: float, size: int) -> list[Path]:
    paths = [journal.images_dir / str(number) / f"view{i}.png" for i in range(2)]
    for path in paths:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(b"\x89PNG" + bytes(size - 4))
    entry = CycleEntry(finished_at - 5, finished_at, result={"status": "ok"}, image_paths=[str(p) for p in paths])
    assert journal.commit_cycle(entry) == number
    return paths


def test_prune_keeps_images_under_the_size_and_age_limits(tmp_path: Path) -> None:
    now = 1_790_000_000.0
    with Journal(tmp_path) as journal:
        # cycles 1..6 finished 6, 5, ... 1 hours ago; each has two images of 1000 bytes
        images = {n: _cycle_with_images(journal, n, now - (7 - n) * 3600, 1000) for n in range(1, 7)}
        assert journal.cycle(1).image_paths == ["images/1/view0.png", "images/1/view1.png"]  # relative
        report = journal.prune_images(max_bytes=10**9, max_age_s=4.5 * 3600, now=now)  # age: cycles 1, 2 go
        assert (report.cycles, report.files, report.bytes_freed) == (2, 4, 4000)
        report = journal.prune_images(max_bytes=4500, max_age_s=10**9, now=now)  # size: 8000 -> 4000
        assert (report.cycles, report.files, report.bytes_freed) == (2, 4, 4000)
        gone = {n for n, paths in images.items() if not any(p.exists() for p in paths)}
        assert gone == {1, 2, 3, 4}
        assert all(p.exists() for n in (5, 6) for p in images[n])
        assert journal.cycle(4).images_pruned_at == now and journal.cycle(5).images_pruned_at is None
        assert journal.cycle(4).status == "ok"  # the row itself stays
        assert journal.prune_images(max_bytes=4500, max_age_s=10**9, now=now).cycles == 0


def test_an_error_cycle_keeps_its_code(tmp_path: Path) -> None:
    with Journal(tmp_path) as journal:
        number = journal.commit_cycle(CycleEntry(1.0, 2.0, job=1, part_tag=9,
                                                 error=DeviceTimeout("camera: no frame within 2 s")))
        row = journal.cycle(number)
    assert (row.status, row.error_code, row.plc_code, row.error_message) == (
        "error", "DEVICE_TIMEOUT", 402, "camera: no frame within 2 s")
    assert row.record is None and row.result is None


def test_amend_timings_adds_the_timings_known_after_done_and_nothing_else(tmp_path: Path) -> None:
    with Journal(tmp_path) as journal:
        journal.commit_cycle(expected_entry(1, _record()))
        journal.amend_timings(1, {"plc_journal": 0.004, "cycle": 2.5})
        with pytest.raises(JournalEntryMissing, match="no cycle 2"):
            journal.amend_timings(2, {"cycle": 1.0})
    with Journal(tmp_path) as journal:
        row, entry = journal.cycle(1), expected_entry(1, _record())
        assert row.timings_s == {**entry.timings_s, "plc_journal": 0.004, "cycle": 2.5}
        assert (row.record, row.result, row.image_paths) == (entry.record, entry.result, entry.image_paths)


# --- cycle numbers without end, intents, the file's identity -------------------------------------------------


def _set_counter(state_dir: Path, counter: int) -> None:
    """A journal whose last cycle is ``counter``, as a long-running cell's would be (the row and the sequence)."""
    with Journal(state_dir) as journal:
        journal.commit_cycle(expected_entry(1, _record()))
    db = sqlite3.connect(state_dir / "journal.sqlite3")
    with db:
        db.execute("UPDATE cycle SET number = ? WHERE number = 1", (counter,))
        db.execute("UPDATE sqlite_sequence SET seq = ? WHERE name = 'cycle'", (counter,))
    db.close()


@pytest.mark.parametrize("counter", [65_534, 300_000, 2**31 - 2, 2**40])
def test_cycle_numbers_count_on_past_16_and_32_bits(tmp_path: Path, counter: int) -> None:
    _set_counter(tmp_path, counter)
    with Journal(tmp_path) as journal:
        assert journal.cycle_counter() == counter
        numbers = [journal.commit_cycle(expected_entry(n, _record())) for n in range(1, 4)]
        assert numbers == [counter + 1, counter + 2, counter + 3]
        assert [row.number for row in journal.last_cycles(3)] == [counter + 3, counter + 2, counter + 1]
        assert journal.cycle(counter + 2).part_tag == 2
    with Journal(tmp_path) as journal:  # and after reopening
        assert journal.cycle_counter() == counter + 3
        assert journal.next_number() == counter + 4


def test_an_intent_is_committed_before_and_settled_with_its_cycle(tmp_path: Path) -> None:
    D_b = [[1.0, 0.0, 0.0, 12.5], [0.0, 1.0, 0.0, -3.25], [0.0, 0.0, 1.0, 0.75], [0.0, 0.0, 0.0, 1.0]]
    with Journal(tmp_path) as journal:
        number = journal.next_number()
        journal.commit_intent(number, 41, (12.5, -3.25, 0.75, 0.0, 0.0, 0.0), D_b)
        pending = journal.unsettled_intents()
        assert [(i.cycle, i.sequence, i.registers, i.D_b, i.outcome) for i in pending] == [
            (1, 41, (12.5, -3.25, 0.75, 0.0, 0.0, 0.0), D_b, None)]
        assert journal.commit_cycle(expected_entry(1, _record()), number,
                                    intent_outcome=("acknowledged", "sequence 41 acknowledged")) == 1
        assert journal.unsettled_intents() == []
        intent = journal.intent(1)
        assert intent is not None and (intent.outcome, intent.cleared, intent.detail) == (
            "acknowledged", False, "sequence 41 acknowledged")
        assert intent.settled_at is not None and intent.settled_at >= intent.intended_at
        # an intent left open (the controller lost mid-write), settled later against the robot's report
        journal.commit_intent(2, 42, (1.0,) * 6, D_b)
        journal.commit_cycle(expected_entry(2, _record()), 2)
        assert [i.cycle for i in journal.unsettled_intents()] == [2]
        journal.settle_intent(2, "held", "the robot reported held sequence 42", cleared=True)
        settled = journal.intent(2)
        assert settled is not None and (settled.outcome, settled.cleared) == ("held", True)
        assert journal.last_sequence() == 42
        with pytest.raises(JournalEntryInvalid, match="outcome 'maybe'"):
            journal.settle_intent(2, "maybe", "")
        with pytest.raises(JournalEntryMissing, match="no offset intent for cycle 9"):
            journal.settle_intent(9, "held", "")
        with pytest.raises(JournalError, match="offset intent of cycle 2"):  # one intent per cycle
            journal.commit_intent(2, 43, (0.0,) * 6, D_b)


def test_a_recreated_journal_continues_the_numbering_it_is_given(tmp_path: Path) -> None:
    with Journal(tmp_path) as journal:
        assert journal.continue_numbering(37_856)
        assert journal.commit_cycle(expected_entry(1, _record())) == 37_857
        assert not journal.continue_numbering(5)  # a journal with cycles keeps its own numbers
        assert journal.commit_cycle(expected_entry(2, _record())) == 37_858
    with Journal(tmp_path / "other") as journal:
        assert not journal.continue_numbering(0)
        assert journal.commit_cycle(expected_entry(1, _record())) == 1


@pytest.mark.parametrize("how", ["deleted", "replaced"])
def test_a_journal_deleted_or_replaced_under_the_writer_refuses_every_commit(tmp_path: Path, how: str) -> None:
    journal = Journal(tmp_path)
    try:
        journal.commit_cycle(expected_entry(1, _record()))
        path = tmp_path / "journal.sqlite3"
        for suffix in ("", "-wal", "-shm"):
            Path(str(path) + suffix).unlink(missing_ok=True)
        if how == "replaced":
            with Journal(tmp_path / "elsewhere"):
                pass
            os.replace(tmp_path / "elsewhere" / "journal.sqlite3", path)
        with pytest.raises(JournalReplaced, match=how):
            journal.commit_cycle(expected_entry(2, _record()))
        with pytest.raises(JournalReplaced):
            journal.commit_intent(2, 1, (0.0,) * 6, [])
        with pytest.raises(JournalReplaced):
            journal.settle_intent(1, "held", "")
    finally:
        journal.close()
    with Journal(tmp_path) as reopened:  # a restart opens whatever is there now
        assert reopened.cycle_counter() == 0


def test_the_queries_a_long_journal_runs_between_and_after_cycles_never_scan_the_table(tmp_path: Path) -> None:
    """Their cost stays flat as the journal grows (benchmarks/bench_journal.py measures it)."""
    from monoguide.daemon.service import _journal_schema as schema

    with Journal(tmp_path) as journal:
        journal.commit_cycle(expected_entry(1, _record()))
    db = sqlite3.connect(tmp_path / "journal.sqlite3")
    plans = {
        "prune": db.execute(f"EXPLAIN QUERY PLAN {schema.PRUNE_QUERY}").fetchall(),
        "last cycles": db.execute(f"EXPLAIN QUERY PLAN {schema.LAST_CYCLES_QUERY}", (9, 20)).fetchall(),
        "one cycle": db.execute(f"EXPLAIN QUERY PLAN {schema.CYCLE_QUERY}", (1,)).fetchall(),
    }
    db.close()
    for name, plan in plans.items():
        details = " / ".join(row[3] for row in plan)
        assert "USING INDEX cycle_images_kept" in details or "USING INTEGER PRIMARY KEY" in details, (name, details)
        assert "SCAN offset_intent" not in details, (name, details)  # a row's intent is found by its key too


def test_pruning_touches_only_the_cycles_whose_images_are_kept(tmp_path: Path) -> None:
    with Journal(tmp_path) as journal:
        for n in range(1, 7):
            journal.commit_cycle(expected_entry(n, _record()))
        images = tmp_path / "images"
        for n in range(1, 7):
            (images / str(n)).mkdir(parents=True)
            for i in range(4):
                (images / str(n) / f"view{i}.png").write_bytes(b"x" * 1000)
        report = journal.prune_images(max_bytes=8000, max_age_s=1e12, now=1_790_000_100.0)
        assert (report.cycles, report.files, report.bytes_freed) == (4, 16, 16000)  # the 4 oldest go
        db = sqlite3.connect(tmp_path / "journal.sqlite3")
        kept = db.execute("SELECT number FROM cycle INDEXED BY cycle_images_kept WHERE images_pruned_at IS NULL "
                          "AND images_json <> '[]' ORDER BY number").fetchall()
        db.close()
        assert kept == [(5,), (6,)]  # the index now holds only the two cycles with images on disk
        assert journal.prune_images(max_bytes=8000, max_age_s=1e12).cycles == 0


def test_a_reader_opens_read_only_sees_the_writers_commits_and_cannot_write(tmp_path: Path) -> None:
    record = _record()
    writer = Journal(tmp_path)
    for n in (1, 2):
        writer.commit_cycle(expected_entry(n, record))
    files_before = sorted(p.name for p in tmp_path.iterdir())
    reader = Journal(tmp_path, read_only=True)
    assert reader.cycle_counter() == 2
    _assert_row_is(reader, 2)
    writer.commit_cycle(expected_entry(3, record))  # the writer goes on while the reader is open
    assert reader.cycle_counter() == 3
    _assert_row_is(reader, 3)
    with pytest.raises(JournalError, match=r"readonly|read-only"):
        reader.commit_cycle(expected_entry(4, record))
    assert writer.cycle_counter() == 3 and sorted(p.name for p in tmp_path.iterdir()) == files_before
    reader.close()
    writer.close()
    with Journal(tmp_path, read_only=True) as after:  # the service stopped: its WAL files are gone
        assert [row.number for row in after.last_cycles(5)] == [3, 2, 1]


def test_a_reader_creates_nothing_where_there_is_no_journal(tmp_path: Path) -> None:
    with pytest.raises(JournalError, match="no such file"):
        Journal(tmp_path / "state", read_only=True)
    assert not (tmp_path / "state").exists()
    (tmp_path / "other.sqlite3").touch()
    db = sqlite3.connect(tmp_path / "journal.sqlite3")
    db.execute("CREATE TABLE t (x)")
    db.commit()
    db.close()
    with pytest.raises(JournalSchemaUnknown, match="not a monoguide journal"):
        Journal(tmp_path, read_only=True)
