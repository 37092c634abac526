"""Steps 4-7 of the calibration wizard (daemon/calibrate/_steps_part.py, _steps_check.py) against the simulated
devices: the simulated tracker process (the real serial adapter over its pty), the simulated UR controller process
(the real UR adapter), a simulated camera that stands where that robot stands and sees the part or a placed target.
The operator acts on the simulated cell's truth. Results are checked against that truth; small counts keep it
short (tolerances sized to them)."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from helpers.sim_processes import start_sim_tracker, stop

from monoguide.daemon.assembly import build_sim_cell
from monoguide.daemon.calibrate import (
    PLACE_PART,
    PLACE_SMR,
    PLACE_TARGET,
    REMOVE_TARGET,
    CalibrationOptions,
    CalibrationRig,
    run_accuracy,
    run_part,
    run_sfi,
    run_verify,
)
from monoguide.daemon.config import CellConfig, load_cell_config
from monoguide.drivers.camera import Frame
from monoguide.drivers.sim.camera import SimCamera
from monoguide.drivers.sim.cell import SimCell, deviated_part
from monoguide.drivers.sim.hole_renderer import RenderSettings
from monoguide.drivers.sim.robot_motion import follow_truth
from monoguide.drivers.sim.robot_process import ControllerProcess, start_controller
from monoguide.drivers.sim.target_renderer import place_target, render_target
from monoguide.drivers.tracker import SerialLaserTracker
from monoguide.drivers.ur_robot import UrRobot
from monoguide.solver.calibration.target import TargetMarks, grid_marks
from monoguide.solver.calibration.verify import euler_xyz_to_matrix
from monoguide.solver.errors import MonoguideError
from monoguide.solver.frames import compose, invert, make_T, pose_difference, rotvec_to_matrix, transform_points

SIM_CELL = Path(__file__).parents[3] / "config" / "sim-cell.toml"
HOST = "127.0.16.1"
# fewer, larger marks than the default target (13 x 9): each image is measured in a fraction of the time
MARKS = grid_marks(5, 4, 40.0, 6.0, (70.0, 40.0))
TRACKER_REREAD_S = 0.25  # the simulated tracker looks at its targets file between waits of 0.2 s


class SceneCamera(SimCamera):
    """The simulated camera, standing where the controller's robot stands (its truth file), seeing the part or,
    while the operator has placed one, the calibration target."""

    def __init__(self, cell: SimCell, truth: Path, marks: TargetMarks) -> None:
        # a sharp lens: rendering the defocus is ten times slower and not what these steps are about
        super().__init__(cell, RenderSettings(focus_distance_mm=600.0, aperture_mm=0.0), seed=11)
        self.truth, self.marks = truth, marks
        self.T_cf_target: np.ndarray | None = None

    def grab(self, timeout_s: float) -> Frame:
        part = self.cell.T_cf_w_true
        follow_truth(self.cell, self.truth)
        self.cell.set_part_pose(part)  # the part is the operator's, not the controller's part supply
        if self.T_cf_target is None:
            return super().grab(timeout_s)
        self._require_open()
        failure = self._failures.pop(0) if self._failures else None
        T_c_t = compose(invert(self.cell.actual_camera_pose()), self.T_cf_target)
        image = render_target(self.cell.camera, T_c_t, self.marks.centers_t, self.marks.radius_mm, self.rng).image
        if failure == "black":
            image[:] = 0
        self._frames += 1
        return Frame(image, self._frames, time.time(), "Mono8")


class SimOperator:
    """Does what the wizard asks on the simulated cell: places the part (the reference or a deviated one), places
    and removes a target (its tracker nests move with it); ``after_smr`` hooks a misdeed in after a nest."""

    def __init__(self, bench: Bench) -> None:
        self.bench = bench
        self.rng = np.random.default_rng(5)
        self.asked: list[tuple[str, dict[str, Any]]] = []
        self.after_smr: dict[str, Any] = {}

    def ask(self, action: str, instruction: str, **detail: Any) -> None:
        self.asked.append((action, detail))
        cell, spec = self.bench.cell, self.bench.cell.spec
        if action == PLACE_PART:
            if detail["part"] == "reference":
                cell.reference_part()
            else:
                cell.set_part_pose(deviated_part(self.rng, spec.T_cf_w0, spec.points_w.mean(axis=0), (20.0, 20.0, 5.0),
                                                 (1.0, 1.0, 2.0)))
            self.bench.rewrite_targets()
        elif action == PLACE_TARGET:
            i = detail["pose"]
            T = place_target(self.bench.truth_targets[i].T_cf_t, self.rng)
            targets = list(spec.targets)
            targets[i] = replace(targets[i], T_cf_t=T)
            cell.spec = replace(spec, targets=tuple(targets))
            self.bench.camera.T_cf_target = T
            self.bench.rewrite_targets()
        elif action == REMOVE_TARGET:
            self.bench.camera.T_cf_target = None
        elif action == PLACE_SMR and detail["nest"] in self.after_smr:
            self.after_smr.pop(detail["nest"])()


@dataclass
class Bench:
    cell: SimCell
    config: CellConfig
    targets_file: Path
    tracker: SerialLaserTracker
    robot: UrRobot
    camera: SceneCamera
    controller: ControllerProcess

    def __post_init__(self) -> None:
        self.truth_targets = self.cell.spec.targets

    def rewrite_targets(self) -> None:
        self.cell.write_tracker_targets(self.targets_file)
        time.sleep(TRACKER_REREAD_S)

    def rig(self, options: CalibrationOptions, config: CellConfig | None = None) -> tuple[CalibrationRig, SimOperator]:
        operator = SimOperator(self)
        self.camera.T_cf_target = None
        self.camera._failures.clear()
        progress: list[str] = []
        rig = CalibrationRig(config or self.config, SIM_CELL, self.tracker, self.robot, self.camera, operator,
                             options, progress.append)
        return rig, operator


def _nominal(config: CellConfig, cell: SimCell, seed: int = 3) -> CellConfig:
    """The truth config as a cell before calibration: each T_cf_si 2 mm / 0.2 deg off, the robot program's taught
    flange poses known, the target's marks ours."""
    rng = np.random.default_rng(seed)

    def off(T: np.ndarray) -> np.ndarray:
        return compose(T, make_T(rotvec_to_matrix(np.radians(rng.normal(0, 0.2 / np.sqrt(3), 3))),
                                 rng.normal(0, 2.0 / np.sqrt(3), 3)))

    assert config.calibration_target is not None
    poses = tuple(replace(p, T_cf_si=off(p.T_cf_si), T_b_f=cell.T_b_f_taught(i))
                  for i, p in enumerate(config.measuring_poses))
    return replace(config, measuring_poses=poses,
                   calibration_target=replace(config.calibration_target, marks=MARKS))


@pytest.fixture(scope="module")
def bench(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Bench]:
    tmp = tmp_path_factory.mktemp("calibrate-camera")
    truth_config = load_cell_config(SIM_CELL)
    cell = build_sim_cell(truth_config)
    targets = cell.write_tracker_targets(tmp / "targets.json")
    tracker_process, port = start_sim_tracker(targets, seed=13)
    spec = cell.write_robot_spec(tmp / "robot.json")
    controller = start_controller("ur", spec, tmp / "truth.json", HOST, move_time_s=0.05, seed=17)
    tracker = SerialLaserTracker(port, timeout_s=2.0)
    taught = tuple(cell.T_b_f_taught(i) for i in range(cell.n_measuring_poses))
    robot = UrRobot(controller.host, controller.port, frequency_hz=50.0, connect_timeout_s=3.0, move_timeout_s=5.0,
                    ack_timeout_s=1.0, stale_timeout_s=1.0, T_b_f_taught=taught, pose_tolerance_mm=0.5,
                    pose_tolerance_deg=0.1)
    camera = SceneCamera(cell, controller.truth, MARKS)
    try:
        tracker.open()
        robot.open()
        camera.open()
        yield Bench(cell, _nominal(truth_config, cell), targets, tracker, robot, camera, controller)
    finally:
        camera.close()
        robot.close()
        tracker.close()
        controller.stop()
        stop(tracker_process)


def _truth_earlier(cell: SimCell) -> dict[str, dict[str, Any]]:
    """The earlier steps' results as the truth has them (each step is tested on its own)."""
    s = cell.spec
    return {"intrinsics": {"camera": s.camera.as_dict()}, "cell": {"T_cf_tracker": s.T_cf_tracker.tolist()},
            "base": {"T_cf_b": s.T_cf_b.tolist()}, "part": {"T_cf_w0": s.T_cf_w0.tolist()},
            "sfi": {"poses": [{"name": f"S{i + 1}", "T_cf_si": T.tolist()} for i, T in enumerate(s.T_cf_si)],
                    "T_f_c": s.T_f_c.tolist()}}


# --- step 4 -------------------------------------------------------------------------------------


def test_part_frame_from_the_featured_holes(bench: Bench) -> None:
    rig, operator = bench.rig(CalibrationOptions())
    result = run_part(rig, _truth_earlier(bench.cell))
    deg, mm = pose_difference(np.array(result["T_cf_w0"]), bench.cell.spec.T_cf_w0)
    assert mm < 0.1 and deg < 0.01  # 4 holes, 0.025 mm tracker
    assert list(result["residuals_mm"]) == ["P1", "P2", "P3", "P4"]
    assert max(result["residuals_mm"].values()) < 0.1
    assert operator.asked[0] == (PLACE_PART, {"part": "reference"})
    assert [d["nest"] for a, d in operator.asked if a == PLACE_SMR] == ["P1", "P2", "P3", "P4"]


def test_a_part_that_moved_while_measured_is_refused_naming_the_hole(bench: Bench) -> None:
    rig, operator = bench.rig(CalibrationOptions())
    cell = bench.cell

    def knock() -> None:  # the part is knocked 1 mm after P1 was measured
        cell.set_part_pose(compose(make_T(np.eye(3), np.array([1.0, 0.0, 0.0])), cell.T_cf_w_true))
        bench.rewrite_targets()

    original_ask = operator.ask

    def ask(action: str, instruction: str, **detail: Any) -> None:
        original_ask(action, instruction, **detail)
        if action == PLACE_SMR and detail["nest"] == "P2":
            knock()

    operator.ask = ask  # type: ignore[method-assign]
    with pytest.raises(MonoguideError) as info:
        run_part(rig, _truth_earlier(cell))
    assert info.value.code == "CALIBRATION_RESIDUAL_TOO_LARGE" and "reference part" in info.value.message


# --- step 5 -------------------------------------------------------------------------------------


def test_sfi_and_the_camera_on_the_flange_against_the_truth(bench: Bench) -> None:
    config = replace(bench.config, measuring_poses=bench.config.measuring_poses[:2])
    rig, operator = bench.rig(CalibrationOptions(placements=2, visits=2), config)
    result = run_sfi(rig, _truth_earlier(bench.cell))
    spec = bench.cell.spec
    assert [p["name"] for p in result["poses"]] == ["S1", "S2"]
    for i, pose in enumerate(result["poses"]):
        deg, mm = pose_difference(np.array(pose["T_cf_si"]), spec.T_cf_si[i])
        # 4 visits: the tracker's reading of the target (~0.06 mm at the camera each) and the robot's
        # repeatability (~0.1 mm at the camera) over sqrt(4); 4 sigma
        assert mm < 0.3 and deg < 0.04, (pose["name"], mm, deg)
        assert pose["visits"] == 4 and 0 < pose["spread_mm"] < 0.5
    deg, mm = pose_difference(np.array(result["T_f_c"]), spec.T_f_c)
    assert mm < 0.2 and deg < 0.03, (mm, deg)  # 8 visits, the robot's reported pose removes its repeatability
    placed = [(d["pose"], d["placement"]) for a, d in operator.asked if a == PLACE_TARGET]
    assert placed == [(0, 0), (0, 1), (1, 0), (1, 1)]
    assert [d["pose"] for a, d in operator.asked if a == REMOVE_TARGET] == [0, 1]


def test_a_target_image_without_marks_is_refused_naming_the_visit(bench: Bench) -> None:
    config = replace(bench.config, measuring_poses=bench.config.measuring_poses[:1])
    rig, _ = bench.rig(CalibrationOptions(placements=1, visits=3), config)
    bench.camera.fail_next("black")
    with pytest.raises(MonoguideError) as info:
        run_sfi(rig, _truth_earlier(bench.cell))
    assert info.value.code == "CALIBRATION_IMAGE_REJECTED"
    assert info.value.message.startswith("S1, placement 1, visit 1:")


def test_sfi_without_a_target_is_refused_before_anything_moves(bench: Bench) -> None:
    assert bench.config.sim is not None
    config = replace(bench.config, calibration_target=None, sim=replace(bench.config.sim, targets=()))
    rig, operator = bench.rig(CalibrationOptions(), config)
    with pytest.raises(MonoguideError) as info:
        run_sfi(rig, _truth_earlier(bench.cell))
    assert info.value.code == "CALIBRATION_NO_TARGET" and operator.asked == []


def test_a_step_without_the_results_it_needs_is_refused(bench: Bench) -> None:
    rig, operator = bench.rig(CalibrationOptions())
    earlier = _truth_earlier(bench.cell)
    for run, missing in ((run_part, "cell"), (run_sfi, "intrinsics"), (run_verify, "sfi"), (run_accuracy, "verify")):
        with pytest.raises(MonoguideError) as info:
            run(rig, {k: v for k, v in earlier.items() if k != missing})
        assert info.value.code == "CALIBRATION_STEP_NOT_READY" and missing in info.value.message
    assert operator.asked == []


# --- steps 6 and 7 --------------------------------------------------------------------------------


def _at_holes(T: np.ndarray, centre_w: np.ndarray) -> np.ndarray:
    return transform_points(T, centre_w.reshape(1, 3))[0]


def test_verify_and_accuracy_against_the_truth(bench: Bench) -> None:
    rig, operator = bench.rig(CalibrationOptions(repeats=2, accuracy_poses=2, tolerance_mm=1e-4, tolerance_deg=1e-5))
    cell, spec = bench.cell, bench.cell.spec
    centre = spec.points_w.mean(axis=0)
    earlier = _truth_earlier(cell)
    threads_before = _runner_threads()
    verify = run_verify(rig, earlier)
    assert _runner_threads() <= threads_before  # the step's cycle runner closed its worker threads
    # the reference part as the camera sees it, in CF; one measurement carries the robot's repeatability and
    # 0.1 px: the planner's 0.19 mm / 0.018 deg at the holes; the mean of 2 within 4 sigma
    T_cf_w0 = compose(spec.T_cf_si[0], np.array(verify["T_s1_w0"]))
    assert np.linalg.norm(_at_holes(T_cf_w0, centre) - _at_holes(spec.T_cf_w0, centre)) < 0.55
    assert pose_difference(T_cf_w0, spec.T_cf_w0)[0] < 0.05
    assert verify["n"] == 2 and 0.1 < verify["predicted_sigma_mm"] < 0.3 and verify["predicted_sigma_deg"] > 0
    assert operator.asked == [(PLACE_PART, {"part": "reference"})]

    truth_moves = []
    original_ask = operator.ask

    def ask(action: str, instruction: str, **detail: Any) -> None:
        original_ask(action, instruction, **detail)
        if action == PLACE_PART:
            truth_moves.append(compose(invert(spec.T_cf_w0), cell.T_cf_w_true))

    operator.ask = ask  # type: ignore[method-assign]
    accuracy = run_accuracy(rig, {**earlier, "verify": verify})
    assert [d["part"] for a, d in operator.asked if a == PLACE_PART] == ["reference", 1, 2] and len(truth_moves) == 2
    assert len(accuracy["rows"]) == 2
    for row, T in zip(accuracy["rows"], truth_moves, strict=True):
        for measured, mm, deg in ((row["lt"], 0.1, 0.01), (row["mono"], 0.9, 0.08)):
            # the tracker: 4 holes at 0.025 mm; the camera: two measurements (the reference's mean of 2 and
            # this one) at 0.19 mm / 0.018 deg each, 4 sigma
            M = make_T(euler_xyz_to_matrix(*measured[:3]), np.array(measured[3:]))
            assert np.linalg.norm(_at_holes(M, centre) - _at_holes(T, centre)) < mm
            assert pose_difference(M, T)[0] < deg
    # dT at the grasp point (the holes' centroid): the camera's and the tracker's displacement of that point
    for row in accuracy["rows"]:
        lt, mono = (make_T(euler_xyz_to_matrix(*v[:3]), np.array(v[3:])) for v in (row["lt"], row["mono"]))
        assert row["dT_grasp_mm"] == pytest.approx(np.linalg.norm(_at_holes(mono, centre) - _at_holes(lt, centre)))
    # a verdict against tolerances nothing meets is a result, not a refusal
    assert accuracy["passed"] is False and "RMS" in accuracy["markdown"]
    assert "grasp point" in accuracy["markdown"]
    assert _runner_threads() <= threads_before


def _runner_threads() -> set[threading.Thread]:
    """The live worker threads of cycle runners (``monoguide-holes``, ``monoguide-images``)."""
    return {t for t in threading.enumerate() if t.name.startswith(("monoguide-holes", "monoguide-images"))}


def test_a_camera_measurement_that_fails_is_refused_with_what_was_being_done(bench: Bench) -> None:
    rig, _ = bench.rig(CalibrationOptions(repeats=2))
    bench.camera.fail_next("occluded")
    with pytest.raises(MonoguideError) as info:
        run_verify(rig, _truth_earlier(bench.cell))
    assert info.value.code == "CALIBRATION_MEASUREMENT_FAILED"
    assert "verification, measurement 1 of 2" in info.value.message
