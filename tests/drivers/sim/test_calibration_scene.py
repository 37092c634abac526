"""The simulated cell for ``monoguide calibrate --sim``: base-calibration poses over the real UR and KUKA clients,
the tracker's flange SMR following the simulated robot, and the simulated operator's scene as the camera renders
it (a placed target found at its true pose, plate images that calibrate the focal length). Loopback 127.0.14.1-9."""

from __future__ import annotations

import json
import select
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from helpers.robots import ADAPTER_OPTIONS, SIM_CELL, stopping

from monoguide.daemon.assembly import build_sim_cell
from monoguide.daemon.config import load_cell_config
from monoguide.drivers.errors import RobotCommandRejected
from monoguide.drivers.kuka_robot import KukaRobot
from monoguide.drivers.sim.calibration_scene import SimOperator
from monoguide.drivers.sim.camera import SimCamera
from monoguide.drivers.sim.cell import SimCell
from monoguide.drivers.sim.robot_process import start_controller, stop_process
from monoguide.drivers.sim.target_renderer import RenderedTarget
from monoguide.drivers.sim.tracker import load_targets
from monoguide.drivers.tracker import SerialLaserTracker
from monoguide.drivers.ur_robot import UrRobot
from monoguide.solver.calibration.intrinsics import CirclePlate, calibrate_intrinsics
from monoguide.solver.calibration.target import measure_target
from monoguide.solver.frames import compose, invert, make_T, pose_difference, rotvec_to_matrix, transform_points

TRACKER_NOISE_MM = 0.025  # 3-D RMS of a point ([sim] tracker_noise_mm)


@pytest.fixture
def cell() -> SimCell:
    return build_sim_cell(load_cell_config(SIM_CELL))


def start_tracker(targets: Path) -> tuple[subprocess.Popen[str], str]:
    process = subprocess.Popen([sys.executable, "-m", "monoguide.drivers.sim.tracker", "--targets", str(targets),
                                "--seed", "5"], stdout=subprocess.PIPE, text=True)
    assert process.stdout is not None
    ready, _, _ = select.select([process.stdout], [], [], 15.0)
    words = process.stdout.readline().split() if ready else []
    if words[:2] != ["LISTEN", "tracker"]:
        stop_process(process)
        pytest.fail(f"simulated tracker did not start: {words}")
    return process, words[2]


def assert_near_taught(cell: SimCell, T_b_f: np.ndarray, k: int) -> None:
    """The robot stopped at calibration pose k as taught, within its repeatability (6 sigma per axis)."""
    deg, mm = pose_difference(T_b_f, cell.calibration_flange_poses()[k - 1])
    assert mm < 6 * cell.spec.repeatability_mm * np.sqrt(3) and deg < 6 * cell.spec.repeatability_deg * np.sqrt(3)


def test_ur_calibration_poses_and_the_tracker_measures_the_smr_where_the_robot_stands(cell: SimCell,
                                                                                        tmp_path: Path) -> None:
    spec, truth = cell.write_robot_spec(tmp_path / "robot.json"), tmp_path / "truth.json"
    with stopping(start_controller("ur", spec, truth, "127.0.14.1", move_time_s=0.05)) as controller:
        operator = SimOperator(cell, tmp_path / "targets.json", truth, seed=2)
        operator.ask("mount_flange_smr", "fit the SMR tool on the flange")
        tracker_process, port = start_tracker(tmp_path / "targets.json")
        robot = UrRobot(controller.host, controller.port, frequency_hz=50.0, **ADAPTER_OPTIONS)
        try:
            robot.open()
            tracker = SerialLaserTracker(port, timeout_s=3.0)
            tracker.open()
            T_tracker_b = compose(invert(cell.spec.T_cf_tracker), cell.spec.T_cf_b)
            for k in (2, 16):
                status = robot.move_to_calibration_pose(k)
                assert status.in_position == 100 + k
                assert_near_taught(cell, status.T_b_f, k)
                # the truth: where the flange really stopped (the tracker reads the controller's truth file)
                T_b_f_true = np.array(json.loads(truth.read_text())["stops"][str(100 + k)])
                expected = transform_points(compose(T_tracker_b, T_b_f_true), cell.spec.tool_smr_f.reshape(1, 3))[0]
                measured = tracker.measure_point(nest="TCP").point_mm
                assert np.linalg.norm(measured - expected) < 6 * TRACKER_NOISE_MM
            tracker.close()
            with pytest.raises(RobotCommandRejected, match=r"calibration pose 25 \(pose number 125\)"):
                robot.move_to_calibration_pose(25)  # the program has 24
            with pytest.raises(RobotCommandRejected, match="calibration pose 0 does not exist"):
                robot.move_to_calibration_pose(0)
        finally:
            robot.close()
            stop_process(tracker_process)


def test_kuka_calibration_poses(cell: SimCell, tmp_path: Path) -> None:
    spec, truth = cell.write_robot_spec(tmp_path / "robot.json"), tmp_path / "truth.json"
    with stopping(start_controller("kuka", spec, truth, "127.0.14.2", move_time_s=0.05)) as controller:
        robot = KukaRobot(controller.host, controller.port, **ADAPTER_OPTIONS)
        try:
            robot.open()
            status = robot.move_to_calibration_pose(1)
            assert status.in_position == 101
            assert_near_taught(cell, status.T_b_f, 1)
            assert robot.move_to_measuring_pose(1).in_position == 2  # the measuring poses as before
            with pytest.raises(RobotCommandRejected, match="pose number 125"):
                robot.move_to_calibration_pose(25)
        finally:
            robot.close()
    assert "101" in json.loads(truth.read_text())["stops"]


def test_a_placed_target_is_rendered_where_it_lies_and_the_tracker_sees_its_nests(cell: SimCell,
                                                                                 tmp_path: Path) -> None:
    operator = SimOperator(cell, tmp_path / "targets.json", seed=4)
    camera = SimCamera(cell)
    camera.open()
    operator.ask("place_target", "place target T2 under S2", pose=1, placement=3)
    T_cf_t = cell.scene.targets[1]  # type: ignore[union-attr]
    # put down near its nominal place, a little shifted and turned
    deg, mm = pose_difference(T_cf_t, cell.spec.targets[1].T_cf_t)
    assert 0 < deg <= 5.0 and 0 < mm <= 30.0 * np.sqrt(2)
    nests, _, _ = load_targets(tmp_path / "targets.json")
    expected = transform_points(invert(cell.spec.T_cf_tracker), transform_points(T_cf_t, cell.spec.targets[1].points_t))
    assert np.allclose([nests[f"T2.{k + 1}"] for k in range(4)], expected, atol=1e-6)
    assert "T1.1" not in nests and "TCP" not in nests  # not placed; the SMR tool not on the flange

    cell.move_to_measuring_pose(1)
    image = camera.grab(2.0).image
    assert isinstance(camera.last_view, RenderedTarget)
    T_c_t = compose(invert(cell.actual_camera_pose(1)), T_cf_t)  # the truth
    guess = compose(T_c_t, make_T(rotvec_to_matrix(np.radians([0.2, -0.2, 0.1])), np.array([2.0, -3.0, 2.0])))
    view = measure_target(image, cell.camera, cell.target_marks, guess)
    deg, mm = pose_difference(view.T_c_t, T_c_t)
    assert deg < 0.002 and mm < 0.02

    operator.ask("remove_target", "take it away", pose=1)
    camera.grab(2.0)
    assert not isinstance(camera.last_view, RenderedTarget)  # the part's holes again
    assert "T2.1" not in load_targets(tmp_path / "targets.json")[0]


def test_the_plate_images_calibrate_the_focal_length(cell: SimCell) -> None:
    operator = SimOperator(cell, seed=3)
    camera = SimCamera(cell)
    camera.open()
    n = 6
    images = []
    for k in range(n):
        operator.ask("show_plate", f"position {k + 1} of {n}", k=k, n=n)
        images.append(camera.grab(2.0).image)
    operator.ask("clear_view", "take the plate away")
    result = calibrate_intrinsics(images, CirclePlate())
    assert not result.rejected
    assert abs(result.camera.fx / cell.camera.fx - 1) < 1e-3 and abs(result.camera.fy / cell.camera.fy - 1) < 1e-3


def test_the_operator_places_parts_and_the_flange_smr(cell: SimCell, tmp_path: Path) -> None:
    operator = SimOperator(cell, tmp_path / "targets.json", robot_truth=tmp_path / "truth.json", seed=9)
    operator.ask("place_part", "a part in a new pose", part=2)
    deviated = cell.T_cf_w_true
    assert pose_difference(deviated, cell.spec.T_cf_w0)[1] > 1.0
    nests = load_targets(tmp_path / "targets.json")[0]
    assert np.allclose(nests["P1"], transform_points(invert(cell.spec.T_cf_tracker), cell.points_cf_true())[0])
    again = SimOperator(build_sim_cell(load_cell_config(SIM_CELL)), seed=9)
    again.ask("place_part", "the same part", part=2)
    assert np.allclose(again.cell.T_cf_w_true, deviated)  # seeded
    operator.ask("place_part", "the reference part", part="reference")
    assert np.allclose(cell.T_cf_w_true, cell.spec.T_cf_w0)

    operator.ask("mount_flange_smr", "fit the SMR tool")
    flange = json.loads((tmp_path / "targets.json").read_text())["flange"]
    assert flange["nest"] == "TCP" and flange["truth"] == str((tmp_path / "truth.json").resolve())
    assert np.allclose(flange["smr_f"], cell.spec.tool_smr_f)
    operator.ask("place_smr", "beam on B2", nest="B2")
    assert load_targets(tmp_path / "targets.json")[2] == "B2"
    operator.ask("unmount_flange_smr", "take it off")
    assert "flange" not in json.loads((tmp_path / "targets.json").read_text())
    with pytest.raises(ValueError, match="unknown operator action"):
        operator.ask("dance", "no")
    assert [a for a, _ in operator.log] == ["place_part", "place_part", "mount_flange_smr", "place_smr",
                                            "unmount_flange_smr"]
