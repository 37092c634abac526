"""A damaged row costs its readers that row, never the journal: rows spoiled in place with sqlite3 (every kind of
damage once, on rows drawn from a seed; the file's integrity check still ok) read with that column empty and
named in ``damaged``, every other column and row as written; the service's own reads and writes go on."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import pytest
from helpers.damaged_journal import D_B, DAMAGES, EMPTY, T0, Seeded, damaged_journal, spoil

from monoguide.daemon.errors import JournalEntryInvalid
from monoguide.daemon.service import CycleEntry, CycleQuery, Journal, OffsetLedger
from monoguide.drivers.errors import DeviceTimeout

COUNT = 60


@pytest.fixture(scope="module")
def damaged(tmp_path_factory: pytest.TempPathFactory) -> Seeded:
    return damaged_journal(tmp_path_factory.mktemp("state"), COUNT, 2027)


def written(seeded: Seeded, number: int) -> dict[str, Any]:
    """The row as it was committed: the ground truth of every column."""
    e = seeded.entries[number]
    failed = e.error is not None
    return {"number": number, "started_at": e.started_at, "finished_at": e.finished_at, "job": e.job,
            "part_tag": e.part_tag, "status": "error" if failed else "ok",
            "error_code": e.error.code if failed else None, "plc_code": e.error.plc_code if failed else 0,
            "error_message": e.error.message if failed else None, "record": e.record, "result": e.result,
            "timings_s": e.timings_s, "poses_at_capture": e.poses_at_capture, "image_paths": e.image_paths,
            "images_pruned_at": None, "duration_s": e.duration_s, "base_offset_xyzabc": seeded.registers.get(number)}


def test_every_row_reads_and_a_damaged_one_names_its_column(damaged: Seeded) -> None:
    assert len(damaged.damaged) == len(DAMAGES)
    with Journal(damaged.state_dir, read_only=True) as journal:
        rows = journal.last_cycles(COUNT)
        paged = journal.find_cycles(CycleQuery(limit=COUNT))  # the operator page's query
        one_by_one = [journal.cycle(n) for n in range(1, COUNT + 1)]
    assert [row.number for row in rows] == [row.number for row in paged] == list(range(COUNT, 0, -1))
    assert sorted(rows, key=lambda row: row.number) == one_by_one
    for row in rows:
        read = dataclasses.asdict(row)
        why = read.pop("damaged")
        expected = written(damaged, row.number)
        kind = damaged.damaged.get(row.number)
        if kind is None:
            assert why == () and read == expected, row.number
            continue
        d = DAMAGES[kind]
        assert len(why) == 1 and why[0].startswith(d.named(None)), (kind, why)
        field, empty = EMPTY[d.column]
        assert read == {**expected, field: empty}, kind  # the rest of the row as written


def test_a_damaged_intent_is_read_and_still_settled_by_its_sequence(tmp_path: Path) -> None:
    with Journal(tmp_path) as journal:
        for cycle in (1, 2):
            journal.commit_intent(cycle, 40 + cycle, (1.0, 2.0, 3.0, 0.0, 0.0, 0.0), D_B, job=2, part_tag=cycle,
                                  started_at=T0)
    spoil(tmp_path, "UPDATE offset_intent SET offset_json = '{\"registers\": [1, 2' WHERE cycle = 1",
          "UPDATE offset_intent SET job = 'two' WHERE cycle = 2")
    with Journal(tmp_path) as journal:
        first, second = journal.unsettled_intents()
        assert (first.sequence, first.registers, first.D_b, first.job) == (41, (), [], 2)
        assert first.damaged == ("offset_json: not JSON (Expecting ',' delimiter at char 19)",)
        assert (second.registers, second.job, second.damaged) == ((1.0, 2.0, 3.0, 0.0, 0.0, 0.0), None,
                                                                  ("job: a string ('two'), not a whole number",))
        ledger = OffsetLedger(journal)
        assert ledger.recover() == [1, 2]  # their rows rebuilt all the same
        rebuilt = journal.cycle(1)
        assert (rebuilt.part_tag, rebuilt.base_offset_xyzabc) == (1, None)
        assert rebuilt.damaged == ("offset_intent.offset_json: not JSON (Expecting ',' delimiter at char 19)",)


def test_pruning_and_amending_go_on_past_a_damaged_row(tmp_path: Path) -> None:
    with Journal(tmp_path) as journal:
        for n in (1, 2):
            (tmp_path / "images" / f"{n}.png").write_bytes(b"x" * 1000)
            journal.commit_cycle(CycleEntry(T0 + n, T0 + n + 1, result={"status": "ok"}, timings_s={"solve": 0.1},
                                            image_paths=[str(tmp_path / "images" / f"{n}.png")]))
    spoil(tmp_path, "UPDATE cycle SET images_json = '[\"1.png\"' WHERE number = 1",
          "UPDATE cycle SET timings_json = '{\"solve\": \"0.1\"}' WHERE number = 2")
    with Journal(tmp_path) as journal:
        report = journal.prune_images(max_bytes=0, max_age_s=0.0, now=T0 + 10)
        assert (report.cycles, report.files) == (2, 1)  # row 1's files unknown: none deleted, the row marked
        assert not (tmp_path / "images" / "2.png").exists() and (tmp_path / "images" / "1.png").exists()
        with pytest.raises(JournalEntryInvalid, match=r"cycle 2: timings_json: 'solve' is a string"):
            journal.amend_timings(2, {"cycle": 1.5})
        assert journal.cycle(2).damaged == ("timings_json: 'solve' is a string ('0.1'), not a number",)


@pytest.mark.timeout(20)
def test_error_codes_step_past_a_code_that_is_not_utf8(tmp_path: Path) -> None:
    with Journal(tmp_path) as journal:
        for n in range(3):
            journal.commit_cycle(CycleEntry(T0 + n, T0 + n + 1, error=DeviceTimeout("robot: no answer")))
    spoil(tmp_path, "UPDATE cycle SET error_code = 'HOLE_NOT_FOUND' WHERE number = 3",
          # one code's bytes spoiled: its replacement character sorts before the byte it replaces
          "UPDATE cycle SET error_code = CAST(X'4445564943455f54494d454fff' AS TEXT) WHERE number = 2")
    with Journal(tmp_path, read_only=True) as journal:
        assert journal.error_codes() == ["DEVICE_TIMEOUT", "DEVICE_TIMEO\N{REPLACEMENT CHARACTER}", "HOLE_NOT_FOUND"]
        assert journal.cycle(2).damaged == ("error_code: not UTF-8 text (byte 0xff at 12)",)
        assert journal.cycle(2).error_code is None and journal.cycle(1).damaged == ()
