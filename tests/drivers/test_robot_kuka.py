"""The KUKA adapter against the simulated KUKA controller over TCP, each test on its own 127.0.0.x address."""

from __future__ import annotations

import itertools
import socket
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from helpers.robots import (
    ADAPTER_OPTIONS,
    FAILURE_MODES,
    assert_within_repeatability,
    check_failure_mode,
    lose_connection,
    offsets_recorded,
    sim_cell,
    stopping,
    taught_poses,
    truth,
)
from scipy.spatial.transform import Rotation

from monoguide.drivers.errors import DeviceError, DeviceNotFound, RobotCommandRejected, RobotPoseMismatch
from monoguide.drivers.kuka_robot import KukaRobot
from monoguide.drivers.robot import Robot
from monoguide.drivers.sim.cell import SimCell
from monoguide.drivers.sim.robot_process import ControllerProcess, start_controller
from monoguide.solver.errors import NotARotation
from monoguide.solver.frames import T_to_kuka_frame, compose, invert, make_T, rotvec_to_matrix

_addresses = itertools.count(90)


@pytest.fixture(scope="module")
def cell() -> SimCell:
    return sim_cell()


@pytest.fixture
def spec(cell: SimCell, tmp_path: Path) -> Path:
    return cell.write_robot_spec(tmp_path / "robot.json", part=5)


def start(spec: Path, fault: str = "none") -> ControllerProcess:
    return start_controller("kuka", spec, spec.with_name("truth.json"), f"127.0.26.{next(_addresses)}",
                            move_time_s=0.15, fault=fault)


@pytest.fixture
def controller(spec: Path) -> Iterator[ControllerProcess]:
    with stopping(start(spec)) as c:
        yield c


def make_robot(cell: SimCell, c: ControllerProcess, **kw: float) -> KukaRobot:
    return KukaRobot(c.host, c.port, T_b_f_taught=taught_poses(cell), **{**ADAPTER_OPTIONS, **kw})  # type: ignore[arg-type]


@pytest.fixture
def robot(cell: SimCell, controller: ControllerProcess) -> Iterator[KukaRobot]:
    with make_robot(cell, controller) as r:
        yield r


def test_identity_status_and_the_port(robot: KukaRobot, controller: ControllerProcess) -> None:
    assert isinstance(robot, Robot)
    assert robot.identity is not None and robot.identity.vendor == "KUKA" and robot.identity.software == "KSS 8.6"
    status = robot.status()
    assert status.ready and status.mode == "AUT" and status.in_position == 0  # the program has not moved yet
    assert (status.held_sequence, status.offset_valid) == (0, False)  # it holds no offset at its start
    np.testing.assert_allclose(status.T_b_f, np.array(truth(controller)["T_b_f"]), atol=1e-9)


def test_move_stops_at_the_taught_pose_within_repeatability(robot: KukaRobot, controller: ControllerProcess,
                                                            cell: SimCell) -> None:
    status = robot.move_to_measuring_pose(3)
    assert status.in_position == 4
    np.testing.assert_allclose(status.T_b_f, np.array(truth(controller)["stops"]["4"]), atol=1e-9)
    assert_within_repeatability(cell, status.T_b_f, 3)


def test_offset_arrives_as_one_frame_in_mm_and_abc_degrees(robot: KukaRobot, controller: ControllerProcess,
                                                          cell: SimCell) -> None:
    D_ideal = compose(cell.T_b_w_true(), invert(cell.T_b_w0()))
    turn = make_T(rotvec_to_matrix(np.radians([0.0, 0.0, 0.01])), np.zeros(3))  # 0.01 deg about base z
    D_off = compose(turn, D_ideal)
    s1, s2 = robot.write_base_offset(D_ideal), robot.write_base_offset(D_off)
    offsets = offsets_recorded(controller, [s1, s2], 5, D_ideal, "kuka")
    # what was sent, as six-decimal fixed-point text: mm, deg
    np.testing.assert_allclose(offsets[0]["received"], T_to_kuka_frame(D_ideal), rtol=0, atol=5e-7)
    x, y, z, a, b, c = offsets[0]["received"]  # by scipy: A B C intrinsic Z-Y'-X'' in degrees
    np.testing.assert_allclose(Rotation.from_euler("ZYX", [a, b, c], degrees=True).as_matrix(), D_ideal[:3, :3],
                               rtol=0, atol=2e-8)
    np.testing.assert_allclose([x, y, z], D_ideal[:3, 3], rtol=0, atol=5e-7)
    assert offsets[1]["grasp_error_deg"] == pytest.approx(0.01, abs=2e-6)
    T_b_g = compose(D_off, cell.T_b_g0())
    T_b_g_ideal = compose(D_ideal, cell.T_b_g0())
    assert offsets[1]["grasp_error_mm"] == pytest.approx(np.linalg.norm(T_b_g[:3, 3] - T_b_g_ideal[:3, 3]), abs=5e-5)


def test_hostile_client_messages_do_not_hurt_the_controller(cell: SimCell, controller: ControllerProcess) -> None:
    # EKI serves one client: the hostile one first, then (once the program has reopened the channel) the daemon
    bomb = b'<!DOCTYPE r [<!ENTITY a "aaaaaaaaaa"><!ENTITY b "&a;&a;&a;&a;&a;&a;">]><Sensor>&b;</Sensor>'
    with socket.create_connection((controller.host, controller.port), timeout=2.0) as s:
        s.sendall(bomb + b"<Sensor><Request Seq='x'/></Sensor>" + b"<" * 5000)
        s.recv(4096)  # its first report: the controller took the connection and read what came
    with make_robot(cell, controller) as robot:
        assert robot.move_to_measuring_pose(1).in_position == 2  # still serving, nothing obeyed
    assert truth(controller)["offsets"] == [] and truth(controller)["ack_sequence"] != 0


def test_unknown_pose_and_pose_mismatch(cell: SimCell, controller: ControllerProcess) -> None:
    with KukaRobot(controller.host, controller.port, move_timeout_s=1.0) as r, \
            pytest.raises(RobotCommandRejected, match="no such measuring pose"):
        r.move_to_measuring_pose(len(taught_poses(cell)))  # one past the last
    wrong = tuple(compose(T, make_T(np.eye(3), np.array([0.0, 0.0, 5.0]))) for T in taught_poses(cell))
    with KukaRobot(controller.host, controller.port, T_b_f_taught=wrong) as r, \
            pytest.raises(RobotPoseMismatch) as info:
        r.move_to_measuring_pose(0)
    assert info.value.plc_code == 427


def test_absent_controller_is_device_not_found(cell: SimCell) -> None:
    with pytest.raises(DeviceNotFound):
        KukaRobot(f"127.0.26.{next(_addresses)}", connect_timeout_s=0.5).open()


def test_reconnects_after_the_controller_restarted(spec: Path, cell: SimCell) -> None:
    c = start(spec)
    r = make_robot(cell, c)
    try:
        r.open()
        c.stop()
        lose_connection(r)
        c = start_controller("kuka", spec, c.truth, c.host, c.port, move_time_s=0.15)
        assert r.move_to_measuring_pose(2).in_position == 3
    finally:
        r.close()
        c.stop()


@pytest.mark.parametrize(("fault", "action", "error"), FAILURE_MODES)
def test_failure_modes(spec: Path, cell: SimCell, fault: str, action: str, error: type[DeviceError]) -> None:
    c = start(spec, fault=fault)
    check_failure_mode(c, make_robot(cell, c, move_timeout_s=0.6), action, error)


def test_an_offset_that_is_not_a_rigid_transform_is_never_sent(robot: KukaRobot, controller: ControllerProcess) -> None:
    sheared = np.eye(4)
    sheared[0, 1] = 0.01
    with pytest.raises(NotARotation, match="base offset"):
        robot.write_base_offset(sheared)
    robot.move_to_measuring_pose(0)  # a request after it: had the offset gone out, it would be answered before
    assert truth(controller)["offsets"] == [] and truth(controller)["held_sequence"] == 0
