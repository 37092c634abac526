"""`monoguide plan` on a cell with fixed marks: the marks' check per measuring pose in its report (a table of mark,
clearance, image margin, ok/why), a mark that a part can hide or that is out of view an error of the plan."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
from typer.testing import CliRunner

from monoguide.daemon.cli import app
from monoguide.daemon.config import load_cell_config
from monoguide.daemon.plan import cell_marks_check
from monoguide.solver.frames import transform_points

ROOT = Path(__file__).parents[3]
SIM_CELL, SIM_CELL_MARKS = ROOT / "config" / "sim-cell.toml", ROOT / "config" / "sim-cell-marks.toml"


def plan(*args: str):
    return CliRunner().invoke(app, ["plan", *args])


def table_rows(stdout: str, view: str) -> list[list[str]]:
    """The body rows of the table titled 'Fixed marks of <view>', as cells."""
    lines = stdout.splitlines()
    start = next(i for i, line in enumerate(lines) if line.strip() == f"Fixed marks of {view}")
    rows = []
    for line in lines[start + 4:]:
        if not line.startswith("│"):
            break
        rows.append([cell.strip() for cell in line.strip("│").split("│")])
    return rows


def test_plan_prints_the_marks_table_of_each_pose_of_the_simulated_cell() -> None:
    run = plan("--config", str(SIM_CELL_MARKS), "--steps", "3")
    assert run.exit_code == 0, run.output
    config = load_cell_config(SIM_CELL_MARKS)
    for pose in config.cell_poses:
        if not pose.marks:
            assert f"Fixed marks of {pose.name}" not in run.stdout  # the hood's poses have none
            continue
        rows = table_rows(run.stdout, pose.name)
        assert [r[0] for r in rows] == [config.reference_marks[k].name for k in pose.marks]
        for mark, clearance, margin, verdict in rows:
            assert verdict == "ok", (mark, verdict)
            assert float(clearance.split()[0]) >= 15.0 and clearance.endswith("(≥15)")
            assert float(margin.split()[0]) >= 100.0 and margin.endswith("(≥100)")
    assert "Fixed marks: all 12 seen" in run.stdout


def test_plan_layout_reports_the_marks_too_and_json_has_them() -> None:
    run = plan("--layout", "--config", str(SIM_CELL_MARKS), "--json")
    assert run.exit_code == 0, run.output
    marks = json.loads(run.stdout)["marks"]
    assert marks["ok"] is True and len(marks["marks"]) == 12 and marks["notes"] == []
    assert all(m["ok"] and m["status"] == "visible" and m["why"] == "" for m in marks["marks"])
    assert min(m["clearance_mm"] for m in marks["marks"]) >= 15.0
    human = plan("--layout", "--config", str(SIM_CELL_MARKS))
    assert human.exit_code == 0 and "Fixed marks of S1" in human.stdout


def test_a_cell_without_marks_prints_no_marks_check() -> None:
    run = plan("--config", str(SIM_CELL), "--steps", "3", "--json")
    assert run.exit_code == 0 and "marks" not in json.loads(run.stdout)
    assert "Fixed marks" not in plan("--config", str(SIM_CELL), "--steps", "3").stdout


def test_a_mark_the_roof_can_hide_fails_the_plan_naming_the_pose_and_the_mark(tmp_path: Path) -> None:
    """S1-M1 moved onto the roof's hole P1 (at the reference roof, under the sheet): the plan fails (exit 1) with
    LAYOUT_OUT_OF_VIEW naming S1 and S1-M1 and the roof; the table says why, the other marks stay ok."""
    config = load_cell_config(SIM_CELL_MARKS)
    roof = config.for_job(1)
    under = transform_points(roof.reference.T_cf_w0, np.array([[100.0, 100.0, -10.0]]))[0]
    text = SIM_CELL_MARKS.read_text()
    block = re.search(r'name = "S1-M1"\nposition_cf = \[[^\]]*\]', text)
    assert block is not None
    moved = text.replace(block.group(0), 'name = "S1-M1"\nposition_cf = [' + ", ".join(f"{v:.3f}" for v in under)
                         + "]")
    cell = tmp_path / "cell.toml"
    cell.write_text(moved)
    run = plan("--config", str(cell), "--steps", "3")
    assert run.exit_code == 1, run.output
    assert "LAYOUT_OUT_OF_VIEW fixed marks:" in run.stderr
    assert "view S1, mark S1-M1: part roof hides it" in run.stderr and "S1-M2" not in run.stderr
    rows = {r[0]: r for r in table_rows(run.stdout, "S1")}
    assert rows["S1-M1"][3].startswith("hidden by roof") and float(rows["S1-M1"][1].split()[0]) < 0
    assert rows["S1-M2"][3] == "ok" and rows["S1-M3"][3] == "ok"
    assert "Fixed marks: 1 of 12 not seen" in run.stdout
    report = json.loads(plan("--config", str(cell), "--steps", "3", "--json").stdout)
    assert report["marks"]["ok"] is False and report["marks"]["error"]["code"] == "LAYOUT_OUT_OF_VIEW"


def test_a_mark_out_of_its_views_image_fails_the_plan(tmp_path: Path) -> None:
    """S2-M3 moved 2 m off to the side of the cell: out of S2's image."""
    text = SIM_CELL_MARKS.read_text()
    block = re.search(r'name = "S2-M3"\nposition_cf = \[([^\]]*)\]', text)
    assert block is not None
    x, y, z = (float(v) for v in block.group(1).split(","))
    cell = tmp_path / "cell.toml"
    cell.write_text(text.replace(block.group(0), f'name = "S2-M3"\nposition_cf = [{x + 2000.0}, {y}, {z}]'))
    run = plan("--config", str(cell), "--steps", "3", "--json")
    assert run.exit_code == 1
    bad = [m for m in json.loads(run.stdout)["marks"]["marks"] if not m["ok"]]
    assert [(m["view"], m["mark"], m["status"]) for m in bad] == [("S2", "S2-M3", "out_of_image")]
    assert "view S2, mark S2-M3: it is imaged" in run.stderr


def test_the_envelope_checked_is_widened_to_what_the_offset_check_accepts(tmp_path: Path) -> None:
    """[checks] envelope_axis_mm = 150 mm per axis lets the cycle accept roofs three times as far off as [layout]'s
    envelope: some roof mark is then hidden, and the check says so."""
    cell = tmp_path / "cell.toml"
    text = SIM_CELL_MARKS.read_text()
    assert text.count("\nmax_rms_px = 1.5\n") == 1
    wider = "\nmax_rms_px = 1.5\nenvelope_axis_mm = [150.0, 150.0, 150.0]\n"
    cell.write_text(text.replace("\nmax_rms_px = 1.5\n", wider))
    check = cell_marks_check(load_cell_config(cell))
    assert check is not None and not check.ok
    assert all(r.status == "hidden" and r.part == "roof" for r in check.failures())
    assert max(abs(v) for r in check.failures() for v in r.deviation_mm) > 100.0
