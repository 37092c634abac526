"""`monoguide journal` on a journal with damaged rows (spoiled in place with sqlite3, every kind of damage once on
rows drawn from a seed; the file's integrity check ok): every other row as written, a damaged one by its number
and what is unreadable; `show` of it what can be read; `export` and `resolve` say which records they cannot use."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from helpers.damaged_journal import DAMAGES, Seeded, damaged_journal
from typer.testing import CliRunner

from monoguide.daemon.cli import app

COUNT = 45


@pytest.fixture(scope="module")
def damaged(tmp_path_factory: pytest.TempPathFactory) -> Seeded:
    return damaged_journal(tmp_path_factory.mktemp("state"), COUNT, 4242)


def _run(seeded: Seeded, *args: str):
    return CliRunner().invoke(app, ["journal", *args, "--state-dir", str(seeded.state_dir)])


def _reason(seeded: Seeded, number: int) -> str:
    return DAMAGES[seeded.damaged[number]].named(None)


def test_list_shows_every_row_and_a_damaged_one_as_unreadable(damaged: Seeded) -> None:
    run = _run(damaged, "list", "--last", "0")
    assert run.exit_code == 0, run.output
    _header, *lines = run.stdout.splitlines()
    assert [int(line.split()[0]) for line in lines] == list(range(1, COUNT + 1))
    for number, line in enumerate(lines, start=1):
        entry = damaged.entries[number]
        if number in damaged.damaged:
            assert line.split(None, 1)[1].startswith(f"unreadable: {_reason(damaged, number)}"), line
            continue
        assert "unreadable" not in line
        cells = line.split()
        assert cells[3:5] == [str(entry.job), "-"] and cells[5] == str(entry.part_tag)  # no part name in the record
        assert (cells[6] == "ok") == (entry.error is None)
        if entry.error is not None:
            assert f"{entry.error.code} ({entry.error.plc_code})" in line
        else:
            x, y, z = damaged.registers[number][:3]
            assert f"{x:.3f} {y:.3f} {z:.3f}," in line and f"{entry.result['rms_px']:.3f}" in line
        assert f"measuring {entry.timings_s['measuring']:.3f}" in line


def test_list_json_carries_what_is_damaged(damaged: Seeded) -> None:
    run = _run(damaged, "list", "--last", "0", "--json")
    assert run.exit_code == 0, run.output
    cycles = [json.loads(line) for line in run.stdout.splitlines()]
    assert [c["number"] for c in cycles] == list(range(1, COUNT + 1))
    for c in cycles:
        entry = damaged.entries[c["number"]]
        if c["number"] in damaged.damaged:
            assert len(c["damaged"]) == 1 and c["damaged"][0].startswith(_reason(damaged, c["number"]))
            continue
        assert c["damaged"] == [] and c["part_tag"] == entry.part_tag and c["duration_s"] == entry.duration_s
        assert c["base_offset_xyzabc"] == damaged.registers.get(c["number"])
        assert c["timings_s"] == entry.timings_s


def test_show_of_a_damaged_row_says_what_is_unreadable_and_shows_the_rest(damaged: Seeded) -> None:
    for number, kind in sorted(damaged.damaged.items()):
        entry, column = damaged.entries[number], DAMAGES[kind].column
        run = _run(damaged, "show", str(number))
        assert run.exit_code == 0, (kind, run.output)
        assert f"  UNREADABLE {_reason(damaged, number)}" in run.stdout, (kind, run.stdout)
        if column != "part_tag":
            assert f"part tag {entry.part_tag}" in run.stdout
        if column != "timings_json":
            assert f"measuring {entry.timings_s['measuring']:.3f}" in run.stdout, kind
        if column == "record_json":
            assert "  record: unreadable" in run.stdout
        elif entry.record is not None:
            assert f"record: id part-{number}, 4 views" in run.stdout, kind
        shown = json.loads(_run(damaged, "show", str(number), "--json").stdout)
        assert len(shown["damaged"]) == 1 and shown["damaged"][0].startswith(_reason(damaged, number))
        assert shown["part_tag"] == entry.part_tag and shown["image_paths"] == (
            [] if column == "images_json" else entry.image_paths)


def test_export_skips_the_unreadable_records_and_names_them(damaged: Seeded, tmp_path: Path) -> None:
    out = tmp_path / "records.jsonl"
    run = _run(damaged, "export", "-o", str(out))
    assert run.exit_code == 0, run.output
    unreadable = sorted(n for n, kind in damaged.damaged.items() if DAMAGES[kind].column == "record_json")
    exported = [json.loads(line) for line in out.read_text().splitlines()]
    assert [r["id"] for r in exported] == [f"part-{n}" for n in range(1, COUNT + 1) if n not in unreadable]
    assert all(r == damaged.entries[int(r["id"].split("-")[1])].record for r in exported)
    assert f"cycles {', '.join(map(str, unreadable))} skipped: their record is unreadable" in run.stderr
    number = unreadable[0]
    run = _run(damaged, "resolve", str(number))
    assert run.exit_code == 1 and run.stderr.startswith("JOURNAL_NO_RECORD")
    assert f"cycle {number}: its measurement record is unreadable (record_json: " in run.stderr


def test_status_lists_the_last_cycles_past_a_damaged_one(damaged: Seeded) -> None:
    run = CliRunner().invoke(app, ["status", "--state-dir", str(damaged.state_dir), "--last", str(COUNT), "--json"])
    assert run.exit_code == 3, run.output  # no service runs there
    last = json.loads(run.stdout)["journal"]["last_cycles"]
    assert [c["number"] for c in last] == list(range(1, COUNT + 1))
    assert sorted(c["number"] for c in last if c["damaged"]) == sorted(damaged.damaged)


def test_resolve_of_a_cycle_whose_stored_result_is_unreadable_solves_its_record(damaged: Seeded) -> None:
    number = min(n for n, kind in damaged.damaged.items() if kind == "result not JSON")
    run = _run(damaged, "resolve", str(number), "--json")
    assert run.exit_code == 0, run.output
    outcome = json.loads(run.stdout)
    assert outcome["stored"]["status"] == "unreadable" and outcome["difference"] is None
    assert outcome["stored"]["damaged"][0].startswith("result_json: not JSON (")
    assert outcome["today"]["status"] == "ok" and outcome["today"]["id"] == f"part-{number}"
    run = _run(damaged, "resolve", str(number))
    assert run.exit_code == 0 and "status          stored unreadable" in run.stdout, run.output
