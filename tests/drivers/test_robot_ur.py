"""The UR adapter (genuine ur_rtde in its worker + our RTDE input recipe) against the simulated UR controller,
each test on its own 127.0.0.x address (ur_rtde's port 30004 is fixed)."""

from __future__ import annotations

import itertools
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from helpers.robots import (
    ADAPTER_OPTIONS,
    FAILURE_MODES,
    SIM_CELL,
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

from monoguide.daemon.assembly import build_sim_cell
from monoguide.daemon.config import load_cell_config
from monoguide.drivers import rtde_protocol as rtde
from monoguide.drivers.errors import (
    DeviceBusy,
    DeviceError,
    DeviceNotFound,
    DeviceTimeout,
    RobotCommandRejected,
    RobotWorkerCrashed,
)
from monoguide.drivers.robot import Robot
from monoguide.drivers.sim.cell import SimCell
from monoguide.drivers.sim.robot_motion import follow_truth
from monoguide.drivers.sim.robot_process import ControllerProcess, start_controller
from monoguide.drivers.ur_robot import RtdeChannel, RtdeInputClient, UrRobot
from monoguide.solver.frames import T_to_ur_pose, compose, invert, make_T

_addresses = itertools.count(50)


def next_host() -> str:
    return f"127.0.25.{next(_addresses)}"


@pytest.fixture(scope="module")
def cell() -> SimCell:
    return sim_cell()


@pytest.fixture
def spec(cell: SimCell, tmp_path: Path) -> Path:
    return cell.write_robot_spec(tmp_path / "robot.json", part=42)


def start(spec: Path, fault: str = "none", host: str | None = None) -> ControllerProcess:
    return start_controller("ur", spec, spec.with_name("truth.json"), host or next_host(), move_time_s=0.15,
                            fault=fault)


@pytest.fixture
def controller(spec: Path) -> Iterator[ControllerProcess]:
    with stopping(start(spec)) as c:
        yield c


def make_robot(cell: SimCell, host: str, **kw: float) -> UrRobot:
    options = {"frequency_hz": 50.0, **ADAPTER_OPTIONS, **kw}
    return UrRobot(host, T_b_f_taught=taught_poses(cell), **options)  # type: ignore[arg-type]


@pytest.fixture
def robot(cell: SimCell, controller: ControllerProcess) -> Iterator[UrRobot]:
    r = make_robot(cell, controller.host)
    r.open()
    try:
        yield r
    finally:
        r.close()


# --- the genuine client ------------------------------------------------------------------------


def test_genuine_ur_rtde_reads_the_simulated_controller_and_sees_not_found(controller: ControllerProcess) -> None:
    # in a process of its own: ur_rtde aborts its process when an interface outlives its controller
    script = f"""
import os, rtde_receive
r = rtde_receive.RTDEReceiveInterface({controller.host!r}, 25.0, {list(rtde.OUTPUT_RECIPE)!r}, False, True)
import time; time.sleep(0.2)
print("POSE", *r.getActualTCPPose()); print("MODES", r.getRobotMode(), r.getSafetyMode(), r.getOutputIntRegister(37))
try:
    rtde_receive.RTDEReceiveInterface({controller.host!r}, 25.0, ["actual_TCP_pose", "no_such_variable"])
except RuntimeError as exc:
    print("REFUSED", str(exc).splitlines()[0])
os._exit(0)
"""
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=30).stdout
    lines = {line.split()[0]: line.split()[1:] for line in out.splitlines() if line[:1].isupper() and " " in line}
    assert "no_such_variable" in " ".join(lines["REFUSED"])
    assert lines["MODES"] == ["7", "1", "0"]  # RUNNING, NORMAL, not yet in position (the program has not moved)
    expected = T_to_ur_pose(np.array(truth(controller)["T_b_f"]))
    np.testing.assert_allclose([float(v) for v in lines["POSE"]], expected, atol=1e-12)


def test_robot_satisfies_the_port(robot: UrRobot) -> None:
    assert isinstance(robot, Robot)
    assert robot.identity is not None and robot.identity.software == "5.15.0.0"


def test_status_is_the_simulated_flange_pose_in_mm(robot: UrRobot, controller: ControllerProcess) -> None:
    status = robot.status()
    assert status.ready and status.mode == "RUNNING" and status.safety == "NORMAL" and status.in_position == 0
    assert (status.held_sequence, status.offset_valid) == (0, False)  # it holds no offset at its start
    np.testing.assert_allclose(status.T_b_f, np.array(truth(controller)["T_b_f"]), atol=1e-9)


def test_move_stops_at_the_taught_pose_within_repeatability(robot: UrRobot, controller: ControllerProcess,
                                                            cell: SimCell) -> None:
    status = robot.move_to_measuring_pose(2)
    assert status.in_position == 3 and status.ack_sequence >= 1
    stop = np.array(truth(controller)["stops"]["3"])
    np.testing.assert_allclose(status.T_b_f, stop, atol=1e-9)  # the pose recorded is where the robot stopped
    assert_within_repeatability(cell, status.T_b_f, 2)
    camera_cell = build_sim_cell(load_cell_config(SIM_CELL))  # the simulated camera's cell, in this process
    assert follow_truth(camera_cell, controller.truth) == 3
    np.testing.assert_allclose(camera_cell.actual_flange_pose(), status.T_b_f, atol=1e-9)
    np.testing.assert_allclose(camera_cell.actual_camera_pose(),
                               compose(cell.spec.T_cf_b, status.T_b_f, cell.spec.T_f_c), atol=1e-9)


def test_offset_arrives_in_one_package_in_metres_and_rotation_vector(robot: UrRobot, controller: ControllerProcess,
                                                                    cell: SimCell) -> None:
    D_ideal = compose(cell.T_b_w_true(), invert(cell.T_b_w0()))
    D_off = compose(make_T(np.eye(3), np.array([0.3, 0.0, 0.0])), D_ideal)  # 0.3 mm off at every point
    s1 = robot.write_base_offset(D_ideal)
    s2 = robot.write_base_offset(D_off)
    offsets = offsets_recorded(controller, [s1, s2], 42, D_ideal)
    np.testing.assert_allclose(offsets[0]["received"], T_to_ur_pose(D_ideal), rtol=0, atol=1e-15)
    assert abs(offsets[0]["received"][0] * 1000.0 - D_ideal[0, 3]) < 1e-9  # metres on the wire
    rotation = Rotation.from_rotvec(offsets[0]["received"][3:]).as_matrix()  # radians, by scipy
    np.testing.assert_allclose(rotation, D_ideal[:3, :3], rtol=0, atol=1e-12)
    assert offsets[1]["grasp_error_mm"] == pytest.approx(0.3, abs=1e-9) and offsets[1]["grasp_error_deg"] < 1e-9


def test_a_second_client_cannot_take_the_input_registers(robot: UrRobot, controller: ControllerProcess) -> None:
    other = RtdeInputClient(controller.host, rtde.DEFAULT_PORT, 1.0)
    with pytest.raises(DeviceBusy, match="in use") as info:
        other.open()
    assert not other.is_open and info.value.code == "DEVICE_BUSY"


def test_unknown_measuring_pose_is_refused_by_the_program(cell: SimCell, controller: ControllerProcess) -> None:
    # no taught poses in the adapter: the robot program is asked, and refuses
    with UrRobot(controller.host, frequency_hz=50.0, move_timeout_s=1.0) as r, \
            pytest.raises(RobotCommandRejected, match="no such measuring pose") as info:
        r.move_to_measuring_pose(8)
    assert info.value.plc_code == 426


# --- crashes and failure modes -----------------------------------------------------------------


def test_adapter_reconnects_after_the_controller_crashed(spec: Path, cell: SimCell) -> None:
    c = start(spec)
    r = make_robot(cell, c.host)
    try:
        r.open()
        os.kill(c.process.pid, signal.SIGKILL)
        c.stop()
        lose_connection(r)
        c = start(spec, host=c.host)
        assert r.move_to_measuring_pose(1).in_position == 2
        assert r.worker_restarts >= 1
    finally:
        r.close()
        c.stop()


def test_worker_crash_is_logged_and_the_worker_restarted(robot: UrRobot, caplog: pytest.LogCaptureFixture) -> None:
    pid = robot._worker.pid
    assert pid is not None
    os.kill(pid, signal.SIGABRT)  # what ur_rtde does to its process when an interface outlives its controller
    time.sleep(0.2)
    assert robot.status().ready  # a new worker answers
    assert robot.worker_restarts == 1 and robot._worker.pid != pid
    assert f"status {-signal.SIGABRT}" in caplog.text and "restart" in caplog.text


def test_worker_dying_during_a_request_is_robot_worker_crashed(robot: UrRobot) -> None:
    pid = robot._worker.pid
    assert pid is not None
    os.kill(pid, signal.SIGKILL)
    time.sleep(0.2)
    with pytest.raises(RobotWorkerCrashed) as info:
        robot._worker.read([36], 1.0)
    assert info.value.plc_code == 425 and "restarted on the next call" in info.value.message
    assert robot.move_to_measuring_pose(3).in_position == 4


def test_absent_controller_is_device_not_found(cell: SimCell) -> None:
    r = make_robot(cell, next_host())
    with pytest.raises(DeviceNotFound):
        r.open()
    r.close()


@pytest.mark.parametrize(("fault", "action", "error"), FAILURE_MODES)
def test_failure_modes(spec: Path, cell: SimCell, fault: str, action: str, error: type[DeviceError]) -> None:
    c = start(spec, fault=fault)
    check_failure_mode(c, make_robot(cell, c.host, move_timeout_s=0.6), action, error)


def test_data_packages_flow_at_the_recipe_frequency_until_paused(controller: ControllerProcess) -> None:
    sock = socket.create_connection((controller.host, rtde.DEFAULT_PORT), timeout=2.0)
    channel = RtdeChannel(sock, "test client")
    try:
        channel.send(rtde.REQUEST_PROTOCOL_VERSION, rtde.encode_protocol_version(2))
        assert rtde.decode_accepted(channel.receive(time.monotonic() + 2)[1], "version")
        channel.send(rtde.CONTROL_PACKAGE_SETUP_OUTPUTS, rtde.encode_setup_outputs(40.0, ["timestamp", "safety_mode"]))
        recipe_id, types = rtde.decode_recipe(channel.receive(time.monotonic() + 2)[1])
        assert recipe_id > 0 and types == ["DOUBLE", "INT32"]
        channel.send(rtde.CONTROL_PACKAGE_START)
        assert rtde.decode_accepted(channel.receive(time.monotonic() + 2)[1], "start")
        stamps = []
        end = time.monotonic() + 1.0
        while time.monotonic() < end:
            kind, payload = channel.receive(time.monotonic() + 1)
            assert kind == rtde.DATA_PACKAGE
            stamps.append(rtde.decode_data_package(payload, types)[1][0])
        assert 30 <= len(stamps) <= 45  # 40 Hz (a loaded machine may lag a little)
        assert np.median(np.diff(stamps)) == pytest.approx(1 / 40.0, abs=0.005)
        channel.send(rtde.CONTROL_PACKAGE_PAUSE)
        while (kind := channel.receive(time.monotonic() + 1)[0]) == rtde.DATA_PACKAGE:
            pass
        assert kind == rtde.CONTROL_PACKAGE_PAUSE
        with pytest.raises(DeviceTimeout):
            channel.receive(time.monotonic() + 0.3)  # paused: nothing more
    finally:
        channel.close()
