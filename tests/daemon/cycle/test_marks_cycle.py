"""The cycle with fixed reference marks, on the simulated roof cell (config/sim-cell-marks.toml): the runner's own
measure / solve / check against the simulated truth (rendered holes and marks, the hole finder, the joint fit).

The robot stops with its repeatability (0.05 mm / 0.01 deg per axis at the flange) and reports the taught pose, so
the calibrated camera poses are off by what only the marks can see; the service believes the marks where a survey
put them (their truth plus a seeded 0.025 mm per axis).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from monoguide.daemon.assembly import build_sim_cell
from monoguide.daemon.config import CellConfig, load_cell_config
from monoguide.daemon.cycle import CycleRunner
from monoguide.daemon.cycle._check import solve_and_check
from monoguide.drivers.sim.calibration_faults import CalibrationFaults
from monoguide.drivers.sim.camera import SimCamera
from monoguide.drivers.sim.cell import SimCell
from monoguide.solver import frames
from monoguide.solver.errors import CalibrationSuspect, MarkNotFound, MonoguideError
from monoguide.solver.record import solve_record
from monoguide.solver.record_marks import solve_record_marks

REPO = Path(__file__).parents[3]
MARKS_CELL = REPO / "config/sim-cell-marks.toml"


@dataclass
class _Status:
    T_b_f: np.ndarray


class _Robot:
    """The simulated robot: stops with its repeatability, reports the taught pose (the report does not see it)."""

    def __init__(self, cell: SimCell) -> None:
        self.cell = cell

    def move_to_measuring_pose(self, i: int) -> _Status:
        self.cell.move_to_measuring_pose(i)
        return _Status(self.cell.T_b_f_taught(i))


@dataclass
class _Rig:
    config: CellConfig
    cell: SimCell
    camera: SimCamera
    runner: CycleRunner

    def measure(self, holes: bool = True) -> Any:
        return self.runner.measure(1, threading.Event(), lambda: RuntimeError("abort"), holes)

    def grasp_error_mm(self, measurement: Any, T_s1_w: np.ndarray) -> float:
        T_est = self.config.reference.T_cf_b @ np.array(measurement.record["T_b_s1"]) @ T_s1_w
        g = self.config.part.grasp_point_w if self.config.part.grasp_point_w is not None \
            else self.config.part.points_w.mean(axis=0)
        return float(np.linalg.norm(frames.transform_points(T_est, g[None])
                                    - frames.transform_points(self.cell.T_cf_w_true, g[None])))


def _rig(path: Path = MARKS_CELL, seed: int = 3, moved_mark: tuple[int, np.ndarray] | None = None) -> _Rig:
    truth = load_cell_config(path).for_job(1)
    cell = build_sim_cell(truth)
    cell.rng = np.random.default_rng(seed)
    survey = np.random.default_rng(seed + 100)
    marks = [replace(m, position_cf=m.position_cf + survey.normal(0.0, m.sigma_mm, 3)) for m in truth.reference_marks]
    if moved_mark is not None:
        k, delta = moved_mark
        marks[k] = replace(marks[k], position_cf=marks[k].position_cf + delta)
    believed = replace(truth, reference_marks=tuple(marks))
    camera = SimCamera(cell, seed=seed)
    camera.open()
    return _Rig(believed, cell, camera, CycleRunner(believed, camera, _Robot(cell)))


@pytest.fixture(scope="module")
def rig() -> Any:
    r = _rig()
    yield r
    r.runner.close()


def test_marks_measure_where_each_camera_stood_and_take_the_repeatability_out_of_the_grasp(rig: _Rig) -> None:
    rng = np.random.default_rng(8)
    errors = []
    for _ in range(4):
        rig.cell.new_part(rng)
        m = rig.measure()
        assert len(m.record["marks"]) == 12 and len(m.record["mark_observations"]) == 12
        solution = rig.runner.solve(m)
        rig.runner.check(m, solution)
        errors.append(rig.grasp_error_mm(m, solution.T_s1_w))
        # each view's camera as the fit has it, against where the simulated robot truly stopped: within the fit's
        # own covariance (the marks measure four of a camera's six directions well, the prior the rest)
        _, fit = solve_record_marks(m.parsed.problem, m.parsed.marks)
        for i, (entry, camera) in enumerate(zip(solution.result["camera_deviation"], fit.cameras, strict=True)):
            true_e = frames.pose_to_vector(frames.invert(rig.config.measuring_poses[i].T_cf_si)
                                           @ rig.cell.actual_camera_pose(i))
            assert entry["view"] == rig.config.measuring_poses[i].name and entry["checked"]
            assert np.allclose(entry["d_mm"], camera.correction[3:], atol=1e-5)
            miss = camera.correction - true_e
            assert float(miss @ np.linalg.solve(camera.covariance, miss)) < 22.5  # chi-square 6 at 0.999
    rms = float(np.sqrt(np.mean(np.square(errors))))
    # without marks the repeatability alone puts 0.234 mm (predicted) into the grasp; with them 0.054 mm predicted
    assert rms < 0.1, errors


def test_a_camera_bumped_0_3_deg_is_refused_naming_the_views_and_the_deviation(rig: _Rig) -> None:
    rig.camera.set_calibration_faults(CalibrationFaults(bump_deg=0.3, bump_axis="y"))
    try:
        rig.cell.new_part(np.random.default_rng(9))
        m = rig.measure()
        with pytest.raises(CalibrationSuspect) as refused:
            rig.runner.solve(m)
    finally:
        rig.camera.set_calibration_faults(CalibrationFaults())
    text = refused.value.message
    assert refused.value.plc_code == 208 and "Nothing is written to the robot" in text
    assert "from its calibrated pose" in text or "from their calibrated poses" in text
    assert any(f"S{i}" in text for i in range(1, 5)) and " deg" in text
    assert refused.value.residual is not None  # the trend monitor sees the cycle too


def test_the_check_job_measures_the_marks_alone_passes_and_fails_on_a_bump(rig: _Rig) -> None:
    rig.cell.set_part_pose(frames.make_T(np.eye(3), np.array([0.0, 0.0, -5000.0])))  # no part in the cell
    m = rig.measure(holes=False)
    assert m.parsed is None and m.record["observations"] == []
    solution, found = solve_and_check(rig.runner, m)
    assert found["method"] == "marks" and found["passed"] and set(found["views"]) == {"S1", "S2", "S3", "S4"}
    assert solution.result["check"]["passed"] and np.allclose(solution.offset, 0.0)
    rig.camera.set_calibration_faults(CalibrationFaults(bump_deg=0.1, bump_axis="x"))
    try:
        with pytest.raises(CalibrationSuspect) as failed:
            solve_and_check(rig.runner, rig.measure(holes=False))
    finally:
        rig.camera.set_calibration_faults(CalibrationFaults())
    assert "check job (reference marks)" in failed.value.message and "deg" in failed.value.message


def test_the_record_of_a_cycle_with_marks_resolves_to_its_result(rig: _Rig) -> None:
    rig.cell.new_part(np.random.default_rng(10))
    m = rig.measure()
    solution = rig.runner.solve(m)
    again, _ = solve_record(m.record, T_f_c=rig.config.camera.T_f_c)
    assert again["status"] == "ok" and again["method"] == "ml-marks"
    assert np.allclose(np.array(again["T_s1_w"]), np.array(solution.result["T_s1_w"]), atol=1e-4)
    assert [v["view"] for v in again["camera_deviation"]] == ["S1", "S2", "S3", "S4"]


def test_a_mark_off_its_survey_is_refused_naming_that_mark() -> None:
    r = _rig(seed=4, moved_mark=(4, np.array([2.0, -1.0, 0.0])))  # the service believes S2-M2 2.2 mm off
    try:
        r.cell.new_part(np.random.default_rng(11))
        with pytest.raises(CalibrationSuspect) as refused:
            r.runner.solve(r.measure())
    finally:
        r.runner.close()
    name = r.config.reference_marks[4].name
    assert f"mark {name}" in refused.value.message and "surveyed position" in refused.value.message


def test_a_mark_not_where_the_calibration_puts_it_is_not_found_and_named() -> None:
    r = _rig(seed=5, moved_mark=(7, np.array([40.0, 0.0, 0.0])))  # 40 mm: far outside its search region
    try:
        r.cell.new_part(np.random.default_rng(12))
        with pytest.raises(MarkNotFound) as lost:
            r.measure()
    finally:
        r.runner.close()
    assert lost.value.plc_code == 307 and f"mark {r.config.reference_marks[7].name}" in lost.value.message


def test_a_mark_hidden_by_a_bad_part_refuses_the_cycle_naming_the_mark() -> None:
    r = _rig(seed=6)
    try:
        outline = r.cell.spec.outline_w
        assert outline is not None
        grown = outline * 1.0
        grown[:, :2] = (outline[:, :2] - outline[:, :2].mean(axis=0)) * 1.6 + outline[:, :2].mean(axis=0)
        r.cell.spec = replace(r.cell.spec, outline_w=grown)  # a part far larger than the roof, lying where it lies
        r.cell.reference_part()
        with pytest.raises(MonoguideError) as refused:
            r.runner.solve(r.measure())
    finally:
        r.runner.close()
    assert isinstance(refused.value, MarkNotFound), refused.value
    assert "mark S1-M" in refused.value.message and "hiding it" in refused.value.message


def test_a_calibrated_cell_whose_marks_were_never_surveyed_refuses_every_job(tmp_path: Path) -> None:
    from monoguide.daemon.errors import PartNotCalibrated
    from monoguide.daemon.service._cycle_task import Runners

    text = MARKS_CELL.read_text() + (
        '\n[calibration]\ndate = "2026-11-30T10:00:00+00:00"\n'
        '[calibration.steps]\ncell = { done = "2026-11-30T09:00:00+00:00", rms_mm = 0.02 }\n')
    path = tmp_path / "cell.toml"
    path.write_text(text)
    runners = Runners(load_cell_config(path), lambda *a: None)
    with pytest.raises(PartNotCalibrated) as refused:
        runners.check_calibrated(1)
    assert "step marks missing" in refused.value.message and "nothing moved" in refused.value.message
    surveyed = text.replace('cell = { done = "2026-11-30T09:00:00+00:00", rms_mm = 0.02 }',
                            'cell = { done = "2026-11-30T09:00:00+00:00", rms_mm = 0.02 }\n'
                            'marks = { done = "2026-11-30T09:30:00+00:00", marks = 12 }')
    path.write_text(surveyed)
    assert load_cell_config(path).cell_calibration_gap() is None


def test_a_record_whose_mark_lies_outside_the_image_is_refused_naming_it(rig: _Rig) -> None:
    rig.cell.new_part(np.random.default_rng(13))
    record = rig.measure().record
    bad = {**record, "mark_observations": [dict(o) for o in record["mark_observations"]]}
    bad["mark_observations"][2]["pixel"] = [-40.0, 10.0]
    result, _ = solve_record(bad, T_f_c=rig.config.camera.T_f_c)
    assert result["status"] == "error" and result["error"]["code"] == "RECORD_INVALID"
    assert "mark_observations[2].pixel" in result["error"]["message"]
    unknown = {**record, "marks": [{**record["marks"][0], "where": 1}, *record["marks"][1:]]}
    result, _ = solve_record(unknown, T_f_c=rig.config.camera.T_f_c)
    assert result["error"]["code"] == "RECORD_UNKNOWN_KEY" and "where" in result["error"]["message"]
