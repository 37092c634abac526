"""The wizard's ``marks`` step: the cell's fixed reference marks surveyed with the tracker in their hidden-point
nests, right after ``cell``, on the simulated cell with marks (config/sim-cell-marks.toml: the simulated tracker
process, the operator putting the SMR in each mark's nest); checked against the truth config's marks, written into
``[[reference_marks]] position_cf``. A cell without marks skips the step. Loopback 127.0.37.x."""

from __future__ import annotations

import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from monoguide.daemon.calibrate import (
    PLACE_SMR,
    STEPS,
    CalibrationOptions,
    CalibrationRig,
    describe,
    open_session,
    open_sim_rig,
    plan_steps,
    read_calibration_provenance,
    run_marks,
    run_step,
    write_calibration,
)
from monoguide.daemon.calibrate._earlier import calibrated_config
from monoguide.daemon.calibrate._sim import MARK_PERTURBATION_MM
from monoguide.daemon.cli import app
from monoguide.daemon.config import load_cell_config
from monoguide.daemon.config._calibration import cell_calibration_gap
from monoguide.daemon.errors import CalibrationStepNotReady
from monoguide.drivers.errors import ConfigError
from monoguide.solver.calibration.errors import CalibrationResidualTooLarge
from monoguide.solver.frames import invert, transform_points

CONFIG = Path(__file__).parents[3] / "config"
MARKS_CELL, PLAIN_CELL = CONFIG / "sim-cell-marks.toml", CONFIG / "sim-cell.toml"
# the tracker's noise is 0.025 mm (3-D RMS) per reading: a mark within 0.15 mm of the truth is 6 of them (never by
# chance over 21 marks); a frame error (the reading left in the tracker's frame, the inverse transform) is metres
WITHIN_MM = 0.15


def test_the_step_order_puts_marks_right_after_cell() -> None:
    assert STEPS[STEPS.index("cell") + 1] == "marks"


def test_marks_on_the_simulated_cell_measured_against_the_truth_and_written(tmp_path: Path) -> None:
    truth = load_cell_config(MARKS_CELL)
    lines: list[str] = []
    with open_sim_rig(MARKS_CELL, tmp_path, CalibrationOptions(), seed=3, host="127.0.37.1",
                      progress=lines.append) as rig:
        session, _ = open_session(tmp_path, MARKS_CELL, True, {})
        assert session.steps[:3] == ("intrinsics", "cell", "marks") and session.skipped() == {}
        # the cell before calibration has every mark's nominal off its true centre by the perturbation
        for mark, true_mark in zip(rig.config.reference_marks, truth.reference_marks, strict=True):
            assert np.linalg.norm(mark.position_cf - true_mark.position_cf) == pytest.approx(MARK_PERTURBATION_MM)
        run_step(rig, session, "cell")
        result = run_step(rig, session, "marks")
        asked = [d["nest"] for a, d in rig.operator.log if a == PLACE_SMR]  # type: ignore[attr-defined]
    names = [m.name for m in truth.reference_marks]
    assert asked[-len(names):] == names  # the SMR in each mark's nest, by the mark's name, in the file's order
    assert [m["name"] for m in result["marks"]] == names

    # each mark where the truth has it, in the cell frame as the cell step calibrated it (the tracker's noise
    # alone); in the true cell frame too (with the cell frame's own error, ~0.1 mm 3 m from its benchmarks)
    T_cf_tracker = np.array(session.data["steps"]["cell"]["T_cf_tracker"])
    C = T_cf_tracker @ invert(truth.sim.T_cf_tracker)  # type: ignore[union-attr]
    true_cf = np.array([m.position_cf for m in truth.reference_marks])
    measured = np.array([m["position_cf"] for m in result["marks"]])
    errors = np.linalg.norm(measured - transform_points(C, true_cf), axis=1)
    assert errors.max() < WITHIN_MM, errors
    assert np.linalg.norm(measured - true_cf, axis=1).max() < 2 * WITHIN_MM
    truth_error = result["truth_error"]
    assert truth_error["marks_mm_max"] == pytest.approx(errors.max()) and "marks_mm_max_true_cf" in truth_error
    print(f"marks: {len(names)} marks, against the truth (calibrated CF) max {errors.max():.4f} mm, RMS "
          f"{np.sqrt(np.mean(errors ** 2)):.4f} mm; true CF max {truth_error['marks_mm_max_true_cf']:.4f} mm; "
          f"deviation from the nominal max {result['max_deviation_mm']:.3f} mm")
    # the report: per mark its position, its deviation from the nominal (the perturbation), the tracker's RMS
    for m in result["marks"]:
        assert abs(m["deviation_mm"] - MARK_PERTURBATION_MM) < 2 * WITHIN_MM and 0 < m["tracker_rms_mm"] < 0.2
        assert m["deviation_mm"] == pytest.approx(np.linalg.norm(np.subtract(m["position_cf"], m["nominal_cf"])))
    assert result["tolerance_mm"] == 5.0 and result["max_deviation_mm"] < 5.0
    progress = [line for line in lines if line.startswith("mark ")]
    assert len(progress) == len(names) and progress[0].startswith(f"mark {names[0]} (1/{len(names)}): ")
    assert "mm from its nominal, tracker RMS" in progress[0]
    summary = describe("marks", result)
    assert summary[0].startswith(f"reference marks: {len(names)} surveyed") and len(summary) == len(names) + 2
    assert summary[1].startswith(f"  {names[0]}: ") and "error against the simulated truth" in summary[-1]

    # written into the cell's [[reference_marks]] (reloaded), every other value and comment as it was
    config = tmp_path / "marks-cell.toml"
    text = re.sub(r"(\[\[reference_marks\]\]\nname = .*\nposition_cf = \[.*\])\n", r"\1  # surveyed 2024\n",
                  MARKS_CELL.read_text(), count=1)
    assert "]  # surveyed 2024\n" in text
    config.write_text(text)
    write_calibration(config, {"marks": session.data["steps"]["marks"]}, {"session": str(session.path), "sim": True})
    done = load_cell_config(config)
    np.testing.assert_allclose([m.position_cf for m in done.reference_marks], measured, atol=1e-4, rtol=0)
    assert [(m.name, m.diameter_mm, m.sigma_mm) for m in done.reference_marks] == \
        [(m.name, m.diameter_mm, m.sigma_mm) for m in truth.reference_marks]
    written = config.read_text()
    assert "  # surveyed 2024" in written and "# Edit the generator, not this file." in written
    before_lines, after_lines = text.splitlines(), written[:written.index("[calibration]")].rstrip().splitlines()
    changed = [b for b, a in zip(before_lines, after_lines, strict=False) if a != b]
    assert len(changed) == len(names) and all(b.startswith("position_cf = ") for b in changed)
    provenance = read_calibration_provenance(config)
    assert provenance is not None
    marks_summary = provenance["steps"]["marks"]
    assert marks_summary["marks"] == len(names) and marks_summary["max_deviation_mm"] == result["max_deviation_mm"]
    assert marks_summary["truth_marks_mm_max"] == pytest.approx(errors.max())
    # a calibration of this cell without its marks step is incomplete; one of a cell without marks needs none
    assert cell_calibration_gap(provenance, has_marks=True) is None
    without = {**provenance, "steps": {k: v for k, v in provenance["steps"].items() if k != "marks"}}
    assert "step marks missing" in str(cell_calibration_gap(without, has_marks=True))
    assert cell_calibration_gap(without, has_marks=False) is None
    stale = {**provenance, "steps": {**provenance["steps"], "cell": {"done": "2999-01-01T00:00:00+00:00"}}}
    assert "before the cell frame was redone" in str(cell_calibration_gap(stale, has_marks=True))


def test_a_mark_nest_off_its_nominal_is_refused_naming_the_mark(tmp_path: Path) -> None:
    lines: list[str] = []
    with open_sim_rig(MARKS_CELL, tmp_path, CalibrationOptions(), seed=3, host="127.0.37.2",
                      progress=lines.append) as rig:
        session, _ = open_session(tmp_path, MARKS_CELL, True, {})
        run_step(rig, session, "cell")
        # the nest of S2-M2 is 20 mm from where the config (its nominal, 3 mm off the truth) says
        cell = rig.operator.cell  # type: ignore[attr-defined]
        original = {m.name: m for m in cell.spec.marks}
        off = original["S2-M2"].position_cf + np.array([0.0, 20.0, 0.0])
        moved = {**original, "S2-M2": replace(original["S2-M2"], position_cf=off)}
        cell.spec = replace(cell.spec, marks=tuple(moved.values()))
        n = len(original)
        with pytest.raises(CalibrationResidualTooLarge, match=rf"1 of {n} measured farther than 5 mm") as refused:
            run_step(rig, session, "marks")
        message = str(refused.value)
        assert "S2-M2 " in message and "is the SMR in S2-M2's nest" in message, message
        distance = float(message.split("S2-M2 ")[1].split(" mm")[0])
        assert 20.0 - MARK_PERTURBATION_MM - WITHIN_MM < distance < 20.0 + MARK_PERTURBATION_MM + WITHIN_MM
        assert session.data["refused"]["marks"]["code"] == "CALIBRATION_RESIDUAL_TOO_LARGE"
        assert "marks" not in session.data["steps"]
        assert any(line.startswith("mark S2-M2 ") and "beyond the 5 mm tolerance" in line for line in lines)

        # the SMR in the wrong nest (S1-M3's for S1-M2): the operator is told which nest it may be
        swapped = {**original, "S1-M2": replace(original["S1-M2"], position_cf=original["S1-M3"].position_cf)}
        cell.spec = replace(cell.spec, marks=tuple(swapped.values()))
        with pytest.raises(CalibrationResidualTooLarge) as wrong:
            run_step(rig, session, "marks")
        assert "S1-M2 " in str(wrong.value) and "is the SMR in S1-M3's nest instead of S1-M2's?" in str(wrong.value)
        assert "S2-M2" not in str(wrong.value)


def test_a_cell_without_marks_skips_the_step_and_refuses_it_by_name(tmp_path: Path) -> None:
    session, options = open_session(tmp_path, PLAIN_CELL, False, {})
    assert "marks" not in session.steps and "[[reference_marks]]" in session.skipped()["marks"]
    notes: list[str] = []
    to_run = plan_steps(session, None, None, note=notes.append)
    assert to_run == [s for s in STEPS if s != "marks"] and to_run[:3] == ["intrinsics", "cell", "base"]
    assert any(n.startswith("skipping step 'marks': ") and "has no [[reference_marks]]" in n for n in notes), notes
    for step, from_step, name in (("marks", None, "STEP"), (None, "marks", "--from")):
        with pytest.raises(ConfigError, match=rf"{name} marks: .*sim-cell.toml has no \[\[reference_marks\]\]"):
            plan_steps(session, step, from_step)
    # the step itself, asked on such a cell, says the same
    rig = CalibrationRig(load_cell_config(PLAIN_CELL), PLAIN_CELL, None, None, None, None,  # type: ignore[arg-type]
                         options, lambda _: None)
    with pytest.raises(ConfigError, match=r"step 'marks': .* has no \[\[reference_marks\]\]"):
        run_marks(rig, {})
    # and so does the command, before it opens anything (exit status 2)
    result = CliRunner().invoke(app, ["calibrate", "marks", "--config", str(PLAIN_CELL), "--work-dir",
                                      str(tmp_path / "cli")])
    assert result.exit_code == 2 and "has no [[reference_marks]]" in result.stderr, result.output


def test_marks_is_the_cells_step_not_a_part_types(tmp_path: Path) -> None:
    cell, _ = open_session(tmp_path, MARKS_CELL, False, {})
    notes: list[str] = []
    assert plan_steps(cell, None, None, note=notes.append)[:4] == ["intrinsics", "cell", "marks", "base"]
    assert not [n for n in notes if "skipping" in n]
    assert cell.missing_for("marks") == ["cell"]
    cell.record_result("cell", {"T_cf_tracker": np.eye(4).tolist()})
    cell.record_result("marks", {"marks": []})
    assert plan_steps(cell, "cell", None) == ["cell"] and "marks" not in cell.data["steps"]  # redone with the frame
    part, _ = open_session(tmp_path, MARKS_CELL, False, {}, job=2)
    assert "marks" not in part.steps
    with pytest.raises(ConfigError, match="STEP marks: a step of the cell's session, done once for the cell"):
        plan_steps(part, "marks", None)


def test_the_tolerance_is_an_option_of_the_step(tmp_path: Path) -> None:
    session, options = open_session(tmp_path, MARKS_CELL, False, {"marks_tolerance_mm": 25.0})
    assert options.marks_tolerance_mm == 25.0 and session.data["options"]["marks_tolerance_mm"] == 25.0


def test_verify_and_accuracy_measure_with_the_marks_as_surveyed() -> None:
    """The later steps' cell as calibrated so far has the surveyed marks (the cycle measures each camera's pose
    from them: with the nominals, 3 mm off, the verification would see every camera moved)."""
    cfg = load_cell_config(MARKS_CELL)
    earlier: dict[str, dict[str, object]] = {
        "intrinsics": {"camera": cfg.camera.intrinsics.as_dict()}, "base": {"T_cf_b": cfg.reference.T_cf_b.tolist()},
        "part": {"T_cf_w0": cfg.reference.T_cf_w0.tolist()},
        "sfi": {"poses": [{"name": p.name, "T_cf_si": p.T_cf_si.tolist()} for p in cfg.measuring_poses],
                "T_f_c": cfg.camera.T_f_c.tolist()}}
    with pytest.raises(CalibrationStepNotReady, match="verify: needs the marks step's result"):
        calibrated_config(cfg, earlier)
    surveyed = {m.name: m.position_cf + np.array([0.0, 0.0, 1.0]) for m in cfg.reference_marks}
    earlier["marks"] = {"marks": [{"name": k, "position_cf": v.tolist()} for k, v in surveyed.items()]}
    done = calibrated_config(cfg, earlier)
    assert [m.name for m in done.reference_marks] == [m.name for m in cfg.reference_marks]
    for mark in done.reference_marks:
        np.testing.assert_allclose(mark.position_cf, surveyed[mark.name])
    earlier["marks"] = {"marks": earlier["marks"]["marks"][1:]}  # type: ignore[index]
    with pytest.raises(CalibrationStepNotReady, match=f"not surveyed reference mark.*{cfg.reference_marks[0].name}"):
        calibrated_config(cfg, earlier, "accuracy")
