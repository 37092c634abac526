"""`monoguide journal list|show|resolve|export` on a journal seeded with real measurement records of the
paper's roof cell (known truth), solved by the solver and committed with the journal API."""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from monoguide.daemon.cli import app
from monoguide.daemon.config import load_cell_config
from monoguide.daemon.service import DEFAULT_STATE_DIR, JOURNAL_FILE, CycleEntry, Journal, state_dir
from monoguide.drivers.errors import DeviceTimeout
from monoguide.solver import frames
from monoguide.solver.pose import solve_pose
from monoguide.solver.record import parse_record, result_to_dict
from monoguide.solver.synthetic import deviated_part, measurement_record, paper_roof_cell

CELL = paper_roof_cell()
T_B_S1 = frames.make_T(frames.rotvec_to_matrix(np.array([0.0, 0.0, 0.3])), np.array([1500.0, -200.0, 900.0]))
STARTED = 1_790_000_000.0
OLD_SOLVER_SHIFT_MM = np.array([0.4, 0.0, 0.0])  # cycle 5's stored pose: today's moved this far in the part frame
POSES = [[[1.0, 0.0, 0.0, 100.0], [0.0, 1.0, 0.0, 200.0], [0.0, 0.0, 1.0, 300.0], [0.0, 0.0, 0.0, 1.0]]]


@dataclasses.dataclass
class Seeded:
    state_dir: Path
    records: dict[int, dict]  # cycle number -> the stored record
    truths: dict[int, np.ndarray]  # cycle number -> the part's true T_s1_w
    results: dict[int, dict]  # cycle number -> the stored result


def _cycle(rng: np.random.Generator, record_id: str | None) -> tuple[dict, np.ndarray, object]:
    T_true = deviated_part(CELL, rng, 2.0, 20.0)
    pixels = CELL.project(T_true) + rng.normal(0, 0.1, (len(CELL.observed), 2))
    record = measurement_record(CELL, pixels, 0.1, record_id, T_B_S1, T_true)
    return record, T_true, solve_pose(parse_record(record).problem)


def _seed(directory: Path) -> Seeded:
    """Cycles 1, 2, 5 ok (2 without an id; 5 stored by an "old solver" 0.4 mm off), 3 failed before a record
    existed, 4 failed after measuring (record kept, no result)."""
    rng = np.random.default_rng(2026)
    seeded = Seeded(directory, {}, {}, {})
    with Journal(directory) as journal:
        for number in range(1, 6):
            started = STARTED + 60 * number
            entry: dict = {"started_at": started, "finished_at": started + 4.25, "job": 1, "part_tag": 100 + number,
                           "timings_s": {"measuring": 3.5, "solving": 0.05}, "poses_at_capture": POSES,
                           "image_paths": [str(directory / "images" / f"{number}-view1.png")]}
            if number == 3:
                journal.commit_cycle(CycleEntry(**entry, error=DeviceTimeout("robot: measuring pose 2 not reached")))
                continue
            record, T_true, result = _cycle(rng, None if number == 2 else f"roof-{number}")
            if number == 5:
                result = dataclasses.replace(result, T_s1_w=result.T_s1_w @ frames.make_T(np.eye(3),
                                                                                        OLD_SOLVER_SHIFT_MM))
            stored = result_to_dict(parse_record(record), result, 12.5)
            error = DeviceTimeout("robot: offset not acknowledged") if number == 4 else None
            journal.commit_cycle(CycleEntry(**entry, record=record, result=None if error else stored, error=error))
            seeded.records[number], seeded.truths[number] = record, T_true
            if error is None:
                seeded.results[number] = stored
    (directory / "images" / "1-view1.png").write_bytes(b"\x89PNG fake")
    return seeded


@pytest.fixture(scope="module")
def seeded(tmp_path_factory: pytest.TempPathFactory) -> Seeded:
    return _seed(tmp_path_factory.mktemp("state"))


def _run(*args: str):
    return CliRunner().invoke(app, list(args))


def _json_lines(text: str) -> list[dict]:
    return [json.loads(line) for line in text.splitlines()]


def _near_truth(T_s1_w: list, T_true: np.ndarray) -> None:
    d_rot, d_mm = frames.pose_difference(np.array(T_s1_w), T_true)
    assert d_rot < 0.05 and d_mm < 1.0


# --- list ---------------------------------------------------------------------------------------


def test_list_json_has_every_cycle_newest_last(seeded: Seeded) -> None:
    run = _run("journal", "list", "--state-dir", str(seeded.state_dir), "--json")
    assert run.exit_code == 0, run.output
    cycles = _json_lines(run.stdout)
    assert [c["number"] for c in cycles] == [1, 2, 3, 4, 5]
    assert [c["status"] for c in cycles] == ["ok", "ok", "error", "error", "ok"]
    assert [c["error_code"] for c in cycles] == [None, None, "DEVICE_TIMEOUT", "DEVICE_TIMEOUT", None]
    assert [c["part_tag"] for c in cycles] == [101, 102, 103, 104, 105]
    assert cycles[0]["finished_at"] == STARTED + 60 + 4.25 and cycles[0]["duration_s"] == pytest.approx(4.25)
    assert cycles[0]["grasp_shift_mm"] == seeded.results[1]["grasp_shift_mm"]
    assert cycles[0]["base_offset_xyzabc"] == seeded.results[1]["base_offset_xyzabc"]


def test_list_last_and_human_table(seeded: Seeded) -> None:
    run = _run("journal", "list", "--state-dir", str(seeded.state_dir), "--last", "2", "--json")
    assert [c["number"] for c in _json_lines(run.stdout)] == [4, 5]
    run = _run("journal", "list", "--state-dir", str(seeded.state_dir))
    assert run.exit_code == 0, run.output
    header, *rows = run.stdout.splitlines()
    assert header.split()[:3] == ["cycle", "finished", "job"]
    assert [row.split()[0] for row in rows] == ["1", "2", "3", "4", "5"]
    assert "DEVICE_TIMEOUT (402)" in rows[2] and "measuring 3.500" in rows[2]
    x, y, z = seeded.results[1]["base_offset_xyzabc"][:3]
    assert f"{x:.3f} {y:.3f} {z:.3f}," in rows[0]


def test_state_dir_comes_from_systemd_then_the_default(seeded: Seeded, monkeypatch: pytest.MonkeyPatch) -> None:
    assert state_dir(None, {}) == DEFAULT_STATE_DIR == Path("/var/lib/monoguide")
    assert state_dir(None, {"STATE_DIRECTORY": "/a:/b"}) == Path("/a")
    assert state_dir("/given", {"STATE_DIRECTORY": "/a"}) == Path("/given")
    monkeypatch.setenv("STATE_DIRECTORY", str(seeded.state_dir))
    run = _run("journal", "list", "--json", "--last", "1")
    assert run.exit_code == 0, run.output
    assert _json_lines(run.stdout)[0]["number"] == 5


# --- show ---------------------------------------------------------------------------------------


def test_show_json_is_the_whole_cycle(seeded: Seeded) -> None:
    run = _run("journal", "show", "1", "--state-dir", str(seeded.state_dir), "--json")
    assert run.exit_code == 0, run.output
    (cycle,) = _json_lines(run.stdout)
    assert cycle["record"] == seeded.records[1] and cycle["result"] == seeded.results[1]
    assert cycle["poses_at_capture"] == POSES and cycle["timings_s"] == {"measuring": 3.5, "solving": 0.05}
    assert cycle["image_paths"] == ["images/1-view1.png"]  # stored relative to the state directory


def test_show_human(seeded: Seeded) -> None:
    run = _run("journal", "show", "1", "--state-dir", str(seeded.state_dir))
    assert run.exit_code == 0, run.output
    assert "cycle 1: ok" in run.stdout and "id roof-1, 4 views, 4 observations" in run.stdout
    assert "capture 1: 100.000 200.000 300.000, " in run.stdout
    assert str(seeded.state_dir / "images" / "1-view1.png") + "\n" in run.stdout  # exists: no "(missing)"
    run = _run("journal", "show", "3", "--state-dir", str(seeded.state_dir))
    assert "cycle 3: DEVICE_TIMEOUT (402): robot: measuring pose 2 not reached" in run.stdout
    assert "record: none" in run.stdout and "3-view1.png (missing)" in run.stdout


def test_show_unknown_cycle_is_a_clear_error(seeded: Seeded) -> None:
    run = _run("journal", "show", "99", "--state-dir", str(seeded.state_dir))
    assert run.exit_code == 1
    assert run.stderr.startswith("JOURNAL_ENTRY_MISSING") and "no cycle 99" in run.stderr and run.stdout == ""


@pytest.mark.parametrize("number", ["0", "-3", "99999999999999999999", str(2**63)])
@pytest.mark.parametrize("command", ["show", "resolve"])
def test_a_number_beyond_any_cycle_is_refused_with_623(seeded: Seeded, command: str, number: str) -> None:
    run = _run("journal", command, "--state-dir", str(seeded.state_dir), "--", number)
    assert run.exit_code == 1, run.output
    assert run.stderr.startswith("JOURNAL_ENTRY_MISSING") and f"no cycle {number}" in run.stderr
    assert "Traceback" not in run.output


@pytest.mark.parametrize("command", [["journal", "list"], ["journal", "show", "1"], ["status"]])
def test_an_empty_state_dir_option_is_a_usage_error(tmp_path: Path, command: list[str],
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)  # where an empty path would have pointed
    run = _run(*command, "--state-dir", "")
    assert run.exit_code == 2, run.output
    assert "STATE_DIR_INVALID" in run.stderr and "--state-dir is empty" in run.stderr


# --- resolve ------------------------------------------------------------------------------------


def test_resolve_reports_how_far_the_stored_pose_lies_from_todays(seeded: Seeded) -> None:
    run = _run("journal", "resolve", "5", "--state-dir", str(seeded.state_dir), "--json")
    assert run.exit_code == 0, run.output
    (outcome,) = _json_lines(run.stdout)
    assert outcome["cycle"] == 5 and outcome["stored"] == seeded.results[5]
    _near_truth(outcome["today"]["T_s1_w"], seeded.truths[5])
    difference = outcome["difference"]  # the "old solver" result was moved 0.4 mm in the part frame
    assert difference["grasp_point_mm"] == pytest.approx(0.4, abs=1e-5)
    assert difference["rotation_deg"] == pytest.approx(0.0, abs=1e-4)
    assert difference["base_offset_mm"] == pytest.approx(0.4, abs=1e-5)
    assert difference["base_offset_deg"] == pytest.approx(0.0, abs=1e-4)


def test_resolve_of_an_unchanged_solver_agrees_and_prints_a_table(seeded: Seeded) -> None:
    run = _run("journal", "resolve", "1", "--state-dir", str(seeded.state_dir), "--json")
    (outcome,) = _json_lines(run.stdout)
    assert outcome["difference"]["grasp_point_mm"] < 1e-5 and outcome["difference"]["base_offset_mm"] < 1e-5
    run = _run("journal", "resolve", "1", "--state-dir", str(seeded.state_dir), "--method", "paper")
    assert run.exit_code == 0, run.output
    assert "cycle 1 solved again" in run.stdout and "today vs the record's truth" in run.stdout
    assert "method          stored ml" in run.stdout and "today paper" in run.stdout


def test_resolve_a_failed_cycle(seeded: Seeded) -> None:
    run = _run("journal", "resolve", "4", "--state-dir", str(seeded.state_dir), "--json")
    assert run.exit_code == 0, run.output
    (outcome,) = _json_lines(run.stdout)
    assert outcome["stored"]["error"]["code"] == "DEVICE_TIMEOUT" and outcome["difference"] is None
    _near_truth(outcome["today"]["T_s1_w"], seeded.truths[4])
    run = _run("journal", "resolve", "3", "--state-dir", str(seeded.state_dir))
    assert run.exit_code == 1 and run.stderr.startswith("JOURNAL_NO_RECORD") and "cycle 3" in run.stderr
    run = _run("journal", "resolve", "1", "--state-dir", str(seeded.state_dir), "--method", "guess")
    assert run.exit_code == 2 and "guess" in run.stderr


# --- export -------------------------------------------------------------------------------------


def test_export_then_solve_gives_the_stored_poses(seeded: Seeded, tmp_path: Path) -> None:
    out = tmp_path / "records.jsonl"
    run = _run("journal", "export", "--state-dir", str(seeded.state_dir), "-o", str(out))
    assert run.exit_code == 0, run.output
    assert "exported 4 records of cycles 1..5" in run.stderr and "1 cycles without a record skipped" in run.stderr
    exported = _json_lines(out.read_text())
    assert [r["id"] for r in exported] == ["roof-1", "cycle-2", "roof-4", "roof-5"]
    assert exported[0] == seeded.records[1] and {**exported[1], "id": None} == seeded.records[2]
    solved = _run("solve", "--json", str(out))
    assert solved.exit_code == 0, solved.output
    results = dict(zip([1, 2, 4, 5], _json_lines(solved.stdout), strict=True))
    for number, result in results.items():
        _near_truth(result["T_s1_w"], seeded.truths[number])
    for number in (1, 2):  # the same solver: the same pose as stored
        np.testing.assert_allclose(results[number]["T_s1_w"], seeded.results[number]["T_s1_w"], atol=1e-6)
        np.testing.assert_allclose(results[number]["base_offset"], seeded.results[number]["base_offset"], atol=1e-6)


def test_export_range_to_stdout(seeded: Seeded) -> None:
    run = _run("journal", "export", "--state-dir", str(seeded.state_dir), "--from", "2", "--to", "4")
    assert run.exit_code == 0, run.output
    assert [r["id"] for r in _json_lines(run.stdout)] == ["cycle-2", "roof-4"]
    run = _run("journal", "export", "--state-dir", str(seeded.state_dir), "--from", "4", "--to", "2")
    assert run.exit_code == 2 and "--from 4 lies after --to 2" in run.stderr


# --- bad state directories ----------------------------------------------------------------------


@pytest.mark.parametrize("command", [["list"], ["show", "1"], ["resolve", "1"], ["export"]])
def test_missing_state_dir_empty_dir_and_corrupt_journal(tmp_path: Path, command: list[str]) -> None:
    run = _run("journal", *command, "--state-dir", str(tmp_path / "absent"))
    assert run.exit_code == 1 and run.stderr.startswith("STATE_DIR_MISSING") and "absent" in run.stderr
    run = _run("journal", *command, "--state-dir", str(tmp_path))
    assert run.exit_code == 1 and run.stderr.startswith("JOURNAL_MISSING")
    assert not (tmp_path / JOURNAL_FILE).exists()  # reading never creates a journal
    garbage = b"this is not a database " * 100
    (tmp_path / JOURNAL_FILE).write_bytes(garbage)
    run = _run("journal", *command, "--state-dir", str(tmp_path))
    assert run.exit_code == 1 and run.stderr.startswith("JOURNAL_NOT_A_DATABASE"), run.output
    assert (tmp_path / JOURNAL_FILE).read_bytes() == garbage and run.stdout == ""


def test_an_empty_journal_lists_nothing(tmp_path: Path) -> None:
    Journal(tmp_path).close()
    run = _run("journal", "list", "--state-dir", str(tmp_path), "--json", "--last", "0")
    assert run.exit_code == 0 and run.stdout == ""
    started = time.monotonic()
    run = _run("journal", "export", "--state-dir", str(tmp_path))
    assert run.exit_code == 0 and run.stdout == "" and "exported 0 records" in run.stderr
    assert time.monotonic() - started < 5


def test_resolve_with_the_cells_config_weights_the_views_at_the_flange_as_the_cycle_did(tmp_path: Path) -> None:
    """A record with the robot's repeatability: the cycle solved it with the camera's mounting on the flange
    (``[camera] T_f_c``), which the record does not carry; ``--config`` gives it back, without it today's
    solve weighs the views about the camera's centre and lands elsewhere."""
    config = Path(__file__).parents[3] / "config" / "sim-cell.toml"
    T_f_c = load_cell_config(config).camera.T_f_c
    rng = np.random.default_rng(77)
    T_true = deviated_part(CELL, rng, 2.0, 20.0)
    pixels = CELL.project(T_true) + rng.normal(0, 0.1, (len(CELL.observed), 2))
    views = np.array([v for v, _ in CELL.observed])
    pixels[views == 1] += rng.normal(0, 1.5, 2)  # one view stopped a little off: its pixels move together
    record = measurement_record(CELL, pixels, 0.1, "flange", T_B_S1, T_true)
    record["view_sigma"] = {"mm": 0.05, "deg": 0.01}
    parsed = parse_record(record)
    flange = dataclasses.replace(parsed, problem=parsed.problem.with_flange(T_f_c))
    stored = result_to_dict(flange, solve_pose(flange.problem), 10.0)
    with Journal(tmp_path) as journal:
        journal.commit_cycle(CycleEntry(started_at=STARTED, finished_at=STARTED + 4.0, job=1, part_tag=1,
                                        timings_s={}, poses_at_capture=POSES, image_paths=[], record=record,
                                        result=stored))
    run = _run("journal", "resolve", "1", "--state-dir", str(tmp_path), "--config", str(config), "--json")
    assert run.exit_code == 0, run.output
    (outcome,) = _json_lines(run.stdout)
    assert outcome["difference"]["grasp_point_mm"] < 1e-6
    run = _run("journal", "resolve", "1", "--state-dir", str(tmp_path), "--json")
    (outcome,) = _json_lines(run.stdout)
    assert outcome["difference"]["grasp_point_mm"] > 1e-4  # the other weighting: not the cycle's answer


def test_list_by_job_pages_through_the_jobs_index_and_names_the_part(tmp_path: Path) -> None:
    """1,203 cycles, every third one job 2 ("hood", the rest job 1 "roof"): --job 2 lists exactly the job-2
    cycles (more than one page of the index's queries), --last counts only them, the part's name is shown."""
    record = json.loads((Path(__file__).parents[3] / "examples" / "example-record.json").read_text())
    with Journal(tmp_path) as journal:
        for number in range(1, 1204):
            job = 2 if number % 3 == 0 else 1
            journal.commit_cycle(CycleEntry(started_at=STARTED + number, finished_at=STARTED + number + 1.0, job=job,
                                            part_tag=number % 65536, record={**record, "job": job,
                                                                             "part": "hood" if job == 2 else "roof"},
                                            error=DeviceTimeout("robot: measuring pose 2 not reached")))
    run = _run("journal", "list", "--state-dir", str(tmp_path), "--job", "2", "--last", "0", "--json")
    assert run.exit_code == 0, run.output
    cycles = _json_lines(run.stdout)
    assert [c["number"] for c in cycles] == list(range(3, 1204, 3))
    assert {(c["job"], c["part"]) for c in cycles} == {(2, "hood")}
    run = _run("journal", "list", "--state-dir", str(tmp_path), "--job", "1", "--last", "3", "--json")
    assert [c["number"] for c in _json_lines(run.stdout)] == [1199, 1201, 1202]
    table = _run("journal", "list", "--state-dir", str(tmp_path), "--job", "1", "--last", "1").stdout
    header, *rows = table.splitlines()
    assert header.split()[:4] == ["cycle", "finished", "job", "part"]
    assert rows[0].split()[0] == "1202" and rows[0].split()[4] == "roof"  # the time is a date and a time
    run = _run("journal", "list", "--state-dir", str(tmp_path), "--job", "1", "--last", "0", "--json")
    assert len(_json_lines(run.stdout)) == 802  # more than a page (500): paged by number


def test_list_and_show_give_every_cycle_the_offset_it_sent(tmp_path: Path) -> None:
    """A good cycle, one rebuilt at start (429, no result: the offset only in its intent), its twin settled later,
    one settled held and one not held after a lost write, one refused by the robot program: `list` and `show`
    (and their --json) give each the offset it computed and sent."""
    from monoguide.daemon.service import OffsetLedger
    from monoguide.drivers.errors import DeviceDisconnected, RobotCommandRejected

    rng = np.random.default_rng(7)
    offsets = {n: [float(v) for v in rng.uniform(-30, 30, 6)] for n in range(1, 7)}  # x y z mm, A B C deg
    D_b = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
    lost = DeviceDisconnected("robot: the controller closed the connection")
    with Journal(tmp_path) as journal:
        for n, offset in offsets.items():
            journal.commit_intent(n, 100 + n, tuple(offset), D_b, job=1, part_tag=n, started_at=STARTED + n)
            result = {"status": "ok", "rms_px": 0.05, "base_offset_xyzabc": [round(v, 6) for v in offset]}
            entry = {"started_at": STARTED + n, "finished_at": STARTED + n + 5, "job": 1, "part_tag": n}
            if n == 1:
                journal.commit_cycle(CycleEntry(**entry, result=result), n, intent_outcome=("acknowledged", "ok"))
            elif n in (4, 5):
                journal.commit_cycle(CycleEntry(**entry, result=result, error=lost), n)
                journal.settle_intent(n, "held" if n == 4 else "not_held", "settled", cleared=True)
            elif n == 6:
                journal.commit_cycle(CycleEntry(**entry, result=result, error=RobotCommandRejected("status -3")), n,
                                     intent_outcome=("refused", "status -3"))
        assert OffsetLedger(journal).recover() == [2, 3]  # the service was killed after their offsets went out
        journal.settle_intent(3, "held", "settled at start", cleared=True)
    listed = {c["number"]: c for c in _json_lines(_run("journal", "list", "--state-dir", str(tmp_path),
                                                       "--json").stdout)}
    table = _run("journal", "list", "--state-dir", str(tmp_path)).stdout.splitlines()[1:]
    assert [c["error_code"] for c in listed.values()] == [None, "ROBOT_OFFSET_UNCONFIRMED", "ROBOT_OFFSET_UNCONFIRMED",
                                                          "DEVICE_DISCONNECTED", "DEVICE_DISCONNECTED",
                                                          "ROBOT_COMMAND_REJECTED"]
    for n, offset in offsets.items():
        (shown,) = _json_lines(_run("journal", "show", str(n), "--state-dir", str(tmp_path), "--json").stdout)
        assert listed[n]["base_offset_xyzabc"] == pytest.approx(offset, abs=1e-6), n
        assert shown["base_offset_xyzabc"] == listed[n]["base_offset_xyzabc"], n
        text = f"{offset[0]:.3f} {offset[1]:.3f} {offset[2]:.3f}, {offset[3]:.4f} {offset[4]:.4f} {offset[5]:.4f}"
        assert text in table[n - 1], (n, table[n - 1])
        human = _run("journal", "show", str(n), "--state-dir", str(tmp_path)).stdout
        assert f"base offset x y z mm, a b c deg: {text}\n" in human, (n, human)


def test_show_of_a_check_job_prints_its_result_without_a_pose(tmp_path: Path) -> None:
    """A check job's result holds the cameras' check, not a pose (nothing written to the robot)."""
    check = {"summary": "every camera where it was calibrated", "passed": True}
    with Journal(tmp_path) as journal:
        journal.commit_cycle(CycleEntry(STARTED, STARTED + 6, 65535, 9, result={"status": "ok", "check": check,
                                                                                "camera_deviation": []}))
    run = _run("journal", "show", "1", "--state-dir", str(tmp_path))
    assert run.exit_code == 0, run.output
    assert "  result: rms - px, rotation - deg, grasp shift - mm, σ - deg - mm, method -\n" in run.stdout
    assert "  base offset x y z mm, a b c deg: -\n" in run.stdout and "  T_s1_w: -\n" in run.stdout
