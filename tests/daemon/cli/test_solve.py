"""`monoguide solve` end to end through the CLI, on records with known truth: the example record (it
carries its truth) and seeded synthetic ones. Inputs that Python or JSON cannot read are each one error,
and the good records of the same batch still get their results."""

import json
import os
import selectors
import subprocess
import sys
import time
from importlib import metadata
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from monoguide.daemon.cli import app
from monoguide.solver import frames
from monoguide.solver.envelope import deviation_transform
from monoguide.solver.synthetic import deviated_part, measurement_record, paper_roof_cell

EXAMPLE = Path(__file__).parents[3] / "examples" / "example-record.json"
SPEC_FIELDS = {"id", "status", "T_s1_w", "displacement_s1", "grasp_point_w", "grasp_shift_mm", "grasp_shift_s1_mm",
               "rotation_deg", "base_offset", "base_offset_xyzabc", "consistency", "rms_px", "covariance",
               "sigma_rot_deg", "sigma_trans_mm", "method", "iterations", "time_ms"}
CLI = [sys.executable, "-m", "monoguide.daemon.cli"]
CELL = paper_roof_cell()


def _synthetic_record(rng, record_id, T_true=None, T_b_s1=None):
    """A seeded record of the paper's roof cell (0.1 px noise) carrying its truth; the part deviates by at
    most 2 deg and 20 mm per axis (well inside the envelope) unless ``T_true`` is given."""
    if T_true is None:
        T_true = deviated_part(CELL, rng, 2.0, 20.0)
    pixels = CELL.project(T_true) + rng.normal(0, 0.1, (len(CELL.observed), 2))
    return measurement_record(CELL, pixels, 0.1, record_id, T_b_s1, T_true), T_true


def _good_file(tmp_path, rng, record_id="good"):
    """A pretty-printed .json record with its truth."""
    record, T_true = _synthetic_record(rng, record_id)
    path = tmp_path / f"{record_id}.json"
    path.write_text(json.dumps(record, indent=1))
    return path, T_true


def _solve(*args, input=None):
    return CliRunner().invoke(app, ["solve", *args], input=input)


def _results(run):
    return [json.loads(line) for line in run.stdout.splitlines()]


def _assert_solved(result, record_id, T_true):
    assert result["status"] == "ok" and result["id"] == record_id, result
    d_rot, d_mm = frames.pose_difference(np.array(result["T_s1_w"]), T_true)
    assert d_rot < 0.05 and d_mm < 1.0


# --- what a file holds ----------------------------------------------------------------------------


def test_the_example_record_solves_against_its_truth():
    example = json.loads(EXAMPLE.read_text())
    run = _solve("--json", str(EXAMPLE))
    assert run.exit_code == 0, run.output
    (result,) = _results(run)
    assert set(result) == SPEC_FIELDS
    _assert_solved(result, example["id"], np.array(example["truth"]["T_s1_w"]))


def test_jsonl_batch_goes_on_past_bad_records(tmp_path):
    rng = np.random.default_rng(41)
    good, truths = [], {}
    for k in range(3):
        record, truths[f"part-{k}"] = _synthetic_record(rng, f"part-{k}")
        good.append(json.dumps(record))
    bad_format = json.dumps({"format": "other/1", "id": "wrong"})
    lines = [good[0], bad_format, "{not json", good[1], "", good[2]]
    path = tmp_path / "batch.jsonl"
    path.write_text("\n".join(lines) + "\n")
    run = _solve("--json", str(path))
    assert run.exit_code == 1, run.output
    results = _results(run)
    assert [r["status"] for r in results] == ["ok", "error", "error", "ok", "ok"]
    assert results[1]["error"]["code"] == "RECORD_FORMAT" and results[1]["id"] == "wrong"
    assert results[2]["error"]["code"] == "RECORD_INVALID" and "line 3" in results[2]["error"]["message"]
    for result in (results[0], results[3], results[4]):
        assert set(result) == SPEC_FIELDS
        _assert_solved(result, result["id"], truths[result["id"]])


def _with_typo(text):
    """``text`` with one character turned into a typo, and the (line, column) of that character."""
    offset = text.index('"sigma_px"') + len('"sigma_px"')  # the colon after the key
    assert text[offset] == ":"
    typo = text[:offset] + ";" + text[offset + 1:]
    return typo, typo.count("\n", 0, offset) + 1, offset - typo.rfind("\n", 0, offset)


def test_a_typo_in_a_pretty_printed_record_is_one_error_at_its_line_and_column(tmp_path):
    rng = np.random.default_rng(44)
    good, T_true = _good_file(tmp_path, rng)
    typo, line, column = _with_typo(good.read_text())
    assert line > 50  # deep inside the record, not on its first line
    path = tmp_path / "typo.json"
    path.write_text(typo)
    run = _solve(str(path), str(good))
    assert run.exit_code == 1
    errors = run.stderr.splitlines()
    assert len(errors) == 1, run.stderr
    assert str(path) in errors[0] and f"line {line}, column {column}" in errors[0] and "RECORD_INVALID" in errors[0]
    assert any(row.split()[:2] == ["good", "ok"] for row in run.stdout.splitlines())  # the rest of the batch
    bad, result = _results(_solve("--json", str(path), str(good)))
    assert bad["status"] == "error" and f"line {line}, column {column}" in bad["error"]["message"]
    _assert_solved(result, "good", T_true)


def test_a_json_file_may_hold_a_list_and_names_jsonl_when_it_holds_lines(tmp_path):
    rng = np.random.default_rng(42)
    (a, T_a), (b, T_b) = _synthetic_record(rng, "a"), _synthetic_record(rng, "b")
    listed = tmp_path / "two.json"
    listed.write_text(json.dumps([a, b], indent=1))
    lines = tmp_path / "lines.json"
    lines.write_text(json.dumps(a) + "\n" + json.dumps(b) + "\n")
    first, second, wrong = _results(_solve("--json", str(listed), str(lines)))
    _assert_solved(first, "a", T_a)
    _assert_solved(second, "b", T_b)
    assert wrong["status"] == "error" and "line 2, column 1" in wrong["error"]["message"]
    assert ".jsonl" in wrong["error"]["message"]


def _deep(depth):
    return "[" * depth + "]" * depth


BAD_INPUTS = {  # name: (file name, content, what its one error line says)
    "binary": ("frame.json", b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR" + bytes(range(256)), "binary"),
    "not UTF-8": ("latin1.json", '{"format": "monoguide.measurement/1", "id": "Dach-Ü"}'.encode("latin-1"),
                  "not UTF-8"),
    "5000 digits": ("huge.json", ('{"sigma_px": ' + "7" * 5000 + "}").encode(), "5000 digits"),
    "10000 deep": ("deep.json", ('{"points_w": ' + _deep(10000) + "}").encode(), "nested deeper"),
    "10000 deep list": ("deep-list.json", _deep(10000).encode(), "nested deeper"),
    "a directory": ("folder.json", None, "cannot read"),
}


@pytest.mark.parametrize("kind", sorted(BAD_INPUTS))
def test_an_unreadable_input_is_one_error_line_and_the_batch_goes_on(tmp_path, kind):
    name, content, says = BAD_INPUTS[kind]
    path = tmp_path / name
    if content is None:
        path.mkdir()
    else:
        path.write_bytes(content)
    good, T_true = _good_file(tmp_path, np.random.default_rng(45))
    run = _solve(str(path), str(good))
    assert run.exit_code == 1
    errors = run.stderr.splitlines()
    assert len(errors) == 1 and str(path) in errors[0] and says in errors[0], run.stderr
    assert "Traceback" not in run.output
    bad, result = _results(_solve("--json", str(path), str(good)))
    assert bad["status"] == "error" and bad["error"]["code"] == "RECORD_INVALID"
    _assert_solved(result, "good", T_true)


def test_jsonl_lines_python_cannot_read_are_each_their_own_error(tmp_path):
    rng = np.random.default_rng(46)
    (a, T_a), (b, T_b) = _synthetic_record(rng, "a"), _synthetic_record(rng, "b")
    path = tmp_path / "mixed.jsonl"
    path.write_text("\n".join([json.dumps(a), '{"sigma_px": ' + "9" * 5000 + "}", _deep(10000), json.dumps(b)]))
    run = _solve("--json", str(path))
    assert run.exit_code == 1
    first, huge, deep, last = _results(run)
    assert "line 2" in huge["error"]["message"] and "5000 digits" in huge["error"]["message"]
    assert "line 3" in deep["error"]["message"] and "nested deeper" in deep["error"]["message"]
    _assert_solved(first, "a", T_a)
    _assert_solved(last, "b", T_b)


@pytest.mark.parametrize("name, content", [("empty.json", ""), ("blank.json", "\n  \n"), ("empty.jsonl", "\n\n"),
                                           ("list.json", "[]")])
def test_an_empty_file_is_an_error(tmp_path, name, content):
    path = tmp_path / name
    path.write_text(content)
    run = _solve("--json", str(path))
    assert run.exit_code == 1
    (result,) = _results(run)
    assert result["status"] == "error" and str(path) in result["error"]["message"]


def test_empty_standard_input_is_an_error():
    run = _solve("-", input="")
    assert run.exit_code == 1 and "no record" in run.stderr


def test_missing_file_is_an_error_line_not_a_traceback(tmp_path):
    good, T_true = _good_file(tmp_path, np.random.default_rng(47))
    run = _solve("--json", str(tmp_path / "nope.json"), str(good))
    assert run.exit_code == 1
    first, second = _results(run)
    assert first["status"] == "error" and "cannot read" in first["error"]["message"]
    _assert_solved(second, "good", T_true)


# --- standard input -------------------------------------------------------------------------------


def test_pretty_printed_records_on_standard_input(tmp_path):
    good, T_true = _good_file(tmp_path, np.random.default_rng(48))
    text = good.read_text().rstrip("\n") + "\n"
    typo, line, column = _with_typo(text)
    run = _solve("--json", "-", input=text + typo + text)
    first, bad, last = _results(run)
    _assert_solved(first, "good", T_true)
    _assert_solved(last, "good", T_true)
    n = text.count("\n")  # the second record starts at line n + 1
    assert bad["error"]["message"].startswith(f"<stdin> line {n + 1}: not JSON at line {n + line}, column {column}")


def test_a_truncated_line_on_standard_input_loses_nothing_after_it():
    rng = np.random.default_rng(49)
    (a, _), (b, T_b) = _synthetic_record(rng, "a"), _synthetic_record(rng, "b")
    run = _solve("--json", "-", input=json.dumps(a)[:300] + "\n" + json.dumps(b) + "\n")
    cut, result = _results(run)
    assert cut["status"] == "error" and "line 1" in cut["error"]["message"]
    _assert_solved(result, "b", T_b)


def test_binary_standard_input_is_one_error_line():
    run = CliRunner().invoke(app, ["solve", "-"], input=b"\x89PNG\r\n\x1a\n\x00\x00" * 50)
    assert run.exit_code == 1
    assert len(run.stderr.splitlines()) == 1 and "not UTF-8" in run.stderr


class _Lines:
    """The child's output line by line, each with a deadline (the old code read all of standard input
    before answering). Reads the pipe's file descriptor itself: a buffered reader could hold a second
    line where ``select`` no longer sees it."""

    def __init__(self, process):
        self.fd, self.pending = process.stdout.fileno(), b""
        self.selector = selectors.DefaultSelector()
        self.selector.register(self.fd, selectors.EVENT_READ)

    def next(self, deadline_s):
        end = time.monotonic() + deadline_s
        while b"\n" not in self.pending:
            if time.monotonic() >= end:
                raise AssertionError(f"no result within {deadline_s} s of writing a record: not streamed")
            if self.selector.select(timeout=end - time.monotonic()):
                chunk = os.read(self.fd, 65536)
                assert chunk, "the solver ended early"
                self.pending += chunk
        line, self.pending = self.pending.split(b"\n", 1)
        return line.decode()


@pytest.mark.parametrize("json_output", [True, False], ids=["json", "table"])
def test_standard_input_is_streamed_a_result_per_record_as_it_arrives(json_output):
    rng = np.random.default_rng(43)
    records = [_synthetic_record(rng, f"stream-{k}") for k in range(3)]
    process = subprocess.Popen([*CLI, "solve", *(["--json"] if json_output else []), "-"], stdin=subprocess.PIPE,
                               stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, bufsize=1)
    lines = _Lines(process)
    try:
        for k, (record, T_true) in enumerate(records):
            process.stdin.write(json.dumps(record) + "\n")
            process.stdin.flush()
            if not json_output and k == 0:
                assert lines.next(60).startswith("record")  # the table's header
            line = lines.next(60)  # before the next record is written
            if json_output:
                _assert_solved(json.loads(line), f"stream-{k}", T_true)
            else:
                assert line.split()[:2] == [f"stream-{k}", "ok"]
        process.stdin.close()
        assert process.wait(timeout=60) == 0
    finally:
        process.kill()
        process.wait()


# --- the human output -----------------------------------------------------------------------------


def test_error_lines_go_to_standard_error_and_results_to_standard_output(tmp_path):
    good, _ = _good_file(tmp_path, np.random.default_rng(50))
    bad = tmp_path / "bad.jsonl"
    bad.write_text('{"format": "monoguide.measurement/1", "id": "no-camera"}\n')
    run = _solve(str(bad), str(good))
    assert run.exit_code == 1
    assert "bad.jsonl line 1" in run.stderr and "missing" in run.stderr
    assert "missing" not in run.stdout and "good" not in run.stderr
    rows = [line.split() for line in run.stdout.splitlines()]
    assert rows[1][0] == "no-camera" and rows[1][1] != "ok"
    assert rows[2][:2] == ["good", "ok"]


def test_piped_table_is_not_cut(tmp_path):
    record, _ = _synthetic_record(np.random.default_rng(51), "BAD_IMAGE_roof_left_front_station_07_" + "x" * 50)
    path = tmp_path / "long.json"
    path.write_text(json.dumps(record))
    missing = tmp_path / ("missing-" + "y" * 60 + ".json")
    run = subprocess.run([*CLI, "solve", str(path), str(missing)], capture_output=True, text=True, timeout=120,
                         env={**os.environ, "COLUMNS": "60"})
    assert run.returncode == 1
    assert "…" not in run.stdout + run.stderr
    rows = [line.split() for line in run.stdout.splitlines()]
    assert rows[1][:2] == [record["id"], "ok"] and len(rows[1]) >= 9
    assert rows[2] == [str(missing), "RECORD_INVALID"]
    assert run.stderr.splitlines() == [f"RECORD_INVALID {missing}: cannot read: No such file or directory"]


def test_table_prints_the_rotation_and_the_grasp_shift_and_the_base_offset(tmp_path):
    """A part turned 3 deg about its grasp point (the featured points' centroid) and moved 10, -20, 5 mm
    along the reference part's axes: the grasp point moved 22.9 mm, whatever the lever arm to SF1."""
    grasp_w = CELL.points_w.mean(axis=0)
    turn = frames.make_T(frames.rotvec_to_matrix(np.radians(3.0) * np.array([0.6, 0.0, 0.8])), np.zeros(3))
    shift_w0 = np.array([10.0, -20.0, 5.0])
    about_grasp = frames.make_T(np.eye(3), grasp_w + shift_w0) @ turn @ frames.make_T(np.eye(3), -grasp_w)
    T_true = CELL.T_s1_w0 @ about_grasp
    T_b_s1 = frames.kuka_frame_to_T(1500.0, -300.0, 1200.0, 90.0, 0.0, 180.0)  # SF1 seen from the robot base
    record, _ = _synthetic_record(np.random.default_rng(52), "turned", T_true, T_b_s1)
    path = tmp_path / "turned.json"
    path.write_text(json.dumps(record))
    run = _solve(str(path))
    assert run.exit_code == 0, run.output
    header, row = run.stdout.splitlines()
    assert "rot deg" in header and "grasp mm" in header and "base offset" in header
    cells = row.replace(",", " ").split()
    assert cells[:2] == ["turned", "ok"]
    assert float(cells[3]) == pytest.approx(3.0, abs=0.02)
    assert float(cells[4]) == pytest.approx(np.linalg.norm(shift_w0), abs=0.5)
    truth_deg, truth_mm = float(cells[7]), float(cells[8])
    assert truth_deg < 0.02 and truth_mm < 0.5
    # the base offset the robot takes: the true motion of the part, seen from the base
    T_b_w, T_b_w0 = T_b_s1 @ T_true, T_b_s1 @ CELL.T_s1_w0
    x, y, z, a, b, c = frames.T_to_kuka_frame(T_b_w @ frames.invert(T_b_w0))
    printed = [float(v) for v in cells[10:16]]
    assert printed[:3] == pytest.approx([x, y, z], abs=1.0)
    assert printed[3:] == pytest.approx([a, b, c], abs=0.02)


# --- options --------------------------------------------------------------------------------------


def test_paper_method_and_unknown_method(tmp_path):
    good, _ = _good_file(tmp_path, np.random.default_rng(53))
    run = _solve("--json", "--method", "paper", str(good))
    assert run.exit_code == 0 and json.loads(run.stdout)["method"] == "paper"
    run = _solve("--method", "magic", str(good))
    assert run.exit_code == 2 and "magic" in run.output


def test_robust_only_with_the_ml_estimator(tmp_path):
    good, _ = _good_file(tmp_path, np.random.default_rng(54))
    run = _solve("--robust", "--method", "paper", str(good))
    assert run.exit_code == 2 and "Huber" in run.output
    run = _solve("--json", "--robust", str(good))
    assert run.exit_code == 0 and json.loads(run.stdout)["method"] == "ml-huber"


@pytest.mark.parametrize("rate", ["0", "1", "nan", "-0.1"])
def test_false_alarm_rate_must_lie_between_zero_and_one(tmp_path, rate):
    run = _solve("--false-alarm-rate", rate, str(tmp_path / "unread.json"))
    assert run.exit_code == 2 and "--false-alarm-rate" in run.output


def test_version():
    run = CliRunner().invoke(app, ["--version"])
    assert run.exit_code == 0 and run.stdout.strip() == f"monoguide {metadata.version('monoguide')}"


# --- the default envelope (issue 19): the cell's, per axis about the holes' centroid ---------------------------


@pytest.mark.parametrize(("shift_w", "refused"), [((45.0, -45.0, 0.0), None), ((0.0, 0.0, 50.6), "along z"),
                                                   ((-50.6, 0.0, 0.0), "along x")])
def test_solve_without_an_envelope_key_holds_the_part_to_50_mm_per_axis_with_the_norm_in_total(shift_w, refused):
    """A part shifted (45, -45, 0) mm: 63.6 mm in total, inside ±50 mm per axis and the default total 86.6 mm
    (the older default, 50 mm in total, refused it); 50.6 mm along one axis is refused naming it."""
    centroid = CELL.points_w.mean(axis=0)
    T_true = CELL.T_s1_w0 @ deviation_transform(np.zeros(3), np.array(shift_w), centroid)
    record, _ = _synthetic_record(np.random.default_rng(5), "shifted", T_true=T_true)
    assert "envelope" not in record
    (result,) = _results(_solve("--json", "-", input=json.dumps(record)))
    if refused is None:
        _assert_solved(result, "shifted", T_true)
    else:
        assert result["error"]["code"] == "OFFSET_OUT_OF_ENVELOPE" and refused in result["error"]["message"]
