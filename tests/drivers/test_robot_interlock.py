"""Issue 23's cases against the simulated UR and KUKA controllers, which play the templates' state machine
(``drivers/robot_program.py``): the genuine ur_rtde client and our RTDE recipe, the XML channel over TCP. Every
test has its own 127.0.23.x address; the grasp go is the controller's ``grasp`` command (sim-cell's relay of the
PLC's go); outcomes are judged on the controller's truth file."""

from __future__ import annotations

import contextlib
import itertools
import socket
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from helpers.robots import make_adapter, sim_cell, truth, wait_for

from monoguide.drivers import kuka_protocol as kuka
from monoguide.drivers import rtde_protocol as rtde
from monoguide.drivers.errors import (
    DeviceDisconnected,
    DeviceError,
    RobotAckTimeout,
    RobotCommandRejected,
    RobotNotReady,
)
from monoguide.drivers.robot import COMMAND_GOTO, COMMAND_NONE, COMMAND_OFFSET, PROGRAM_SYNCHRONISED
from monoguide.drivers.sim.cell import SimCell
from monoguide.drivers.sim.robot_process import ControllerProcess, start_controller
from monoguide.drivers.ur_robot import RtdeInputClient
from monoguide.solver.frames import compose, invert, make_T, rotvec_to_matrix

KINDS = ("ur", "kuka")
_hosts = itertools.count(1)


@pytest.fixture
def cell() -> SimCell:
    return sim_cell()


@pytest.fixture
def spec(cell: SimCell, tmp_path: Path) -> Path:
    return cell.write_robot_spec(tmp_path / "robot.json", part=7)


def start(kind: str, spec: Path, move_time_s: float = 0.05) -> ControllerProcess:
    return start_controller(kind, spec, spec.with_name("truth.json"), f"127.0.23.{next(_hosts)}",
                            move_time_s=move_time_s, commands=True, grasp_time_s=0.05)


@pytest.fixture(params=KINDS)
def kind(request: pytest.FixtureRequest) -> str:
    return str(request.param)


@pytest.fixture
def controller(kind: str, spec: Path) -> Iterator[ControllerProcess]:
    c = start(kind, spec)
    try:
        yield c
    finally:
        c.stop()


def ideal_offset(cell: SimCell) -> np.ndarray:
    return compose(cell.T_b_w_true(), invert(cell.T_b_w0()))


# --- case 1: nothing grasps on a stale or refused offset -------------------------------------------


def test_a_grasp_runs_once_with_the_offset_just_stored(kind: str, controller: ControllerProcess, cell: SimCell) -> None:
    with make_adapter(kind, controller, cell) as robot:
        robot.move_to_measuring_pose(0)
        sequence = robot.write_base_offset(ideal_offset(cell))
        assert (robot.status().held_sequence, robot.status().offset_valid) == (sequence, True)
        ran = controller.grasp()
        again = controller.grasp()  # the flag cleared after the grasp: a second go finds no valid offset
    assert (ran["outcome"], ran["held_sequence"], ran["part"]) == ("ran", sequence, 7)
    assert ran["grasp_error_mm"] < 1e-4 and ran["grasp_error_deg"] < 1e-5  # the right offset on the right part
    assert (again["outcome"], again["reason"], again["held_sequence"]) == ("refused", "stale offset", sequence)
    assert truth(controller)["offset_valid"] is False


def test_a_grasp_after_a_refused_offset_is_refused(kind: str, controller: ControllerProcess, cell: SimCell) -> None:
    far = compose(make_T(np.eye(3), np.array([150.0, 0.0, 0.0])), ideal_offset(cell))  # beyond the program's limit
    with make_adapter(kind, controller, cell) as robot:
        kept = robot.write_base_offset(ideal_offset(cell))  # a valid offset first ...
        with pytest.raises(RobotCommandRejected, match="status -3") as info:
            robot.write_base_offset(far)  # ... then one the program refuses: the old one must not be used
        refused = controller.grasp()
    assert info.value.plc_code == 426
    assert (refused["outcome"], refused["reason"], refused["held_sequence"]) == ("refused", "stale offset", kept)
    assert [o["sequence"] for o in truth(controller)["offsets"]] == [kept]


def test_a_grasp_after_an_ack_timeout_is_refused(kind: str, controller: ControllerProcess, cell: SimCell,
                                                 spec: Path) -> None:
    with make_adapter(kind, controller, cell) as robot:
        robot.move_to_measuring_pose(0)
        first = robot.write_base_offset(ideal_offset(cell))  # part 7 is grasped with its offset
        assert controller.grasp()["outcome"] == "ran"
        cell.new_part()  # the next part lies elsewhere
        cell.write_robot_spec(spec, part=8)
        wait_for(lambda: truth(controller)["part"] == 8, "the controller re-read the spec")
        robot.move_to_measuring_pose(0)  # its cycle: a measuring request (the flag is already clear)
        controller.command("no-ack")
        with pytest.raises(RobotAckTimeout):
            robot.write_base_offset(ideal_offset(cell))
        refused = controller.grasp()
    # refused, though the program still holds part 7's offset, which would miss part 8 by centimetres
    assert (refused["outcome"], refused["reason"], refused["held_sequence"], refused["part"]) == (
        "refused", "stale offset", first, 8)
    assert refused["grasp_error_mm"] > 1.0


def test_a_grasp_after_a_program_restart_is_refused(kind: str, controller: ControllerProcess, cell: SimCell) -> None:
    with make_adapter(kind, controller, cell) as robot:
        robot.write_base_offset(ideal_offset(cell))
        controller.command("restart")  # Stop/Play: every program variable starts again
        wait_for(lambda: truth(controller)["starts"] == 2 and truth(controller)["program_running"],
                 "the program started again")
    refused = controller.grasp()
    assert (refused["outcome"], refused["reason"], refused["held_sequence"]) == ("refused", "no offset", 0)


def test_a_measuring_request_and_sequence_0_clear_the_flag(kind: str, controller: ControllerProcess,
                                                           cell: SimCell) -> None:
    with make_adapter(kind, controller, cell) as robot:
        robot.write_base_offset(ideal_offset(cell))
        robot.move_to_measuring_pose(1)  # a new cycle begins: the offset is stale
        assert (robot.status().offset_valid, truth(controller)["offset_valid"]) == (False, False)
        robot.write_base_offset(ideal_offset(cell))
    with make_adapter(kind, controller, cell) as again:  # a reconnect: sequence 0 at the first request
        again.move_to_measuring_pose(0)
    assert controller.grasp()["outcome"] == "refused"


# --- case 2: Stop/Play mid-cycle replays nothing -----------------------------------------------------


def test_stop_play_mid_move_ends_the_wait_at_once_and_replays_nothing(kind: str, spec: Path, cell: SimCell) -> None:
    controller = start(kind, spec, move_time_s=1.5)
    try:
        with make_adapter(kind, controller, cell, move_timeout_s=10.0) as robot:
            robot.move_to_measuring_pose(0)
            stops = truth(controller)["stops"]
            controller.command("restart")  # while the next move would be under way
            began = time.monotonic()
            with pytest.raises((RobotNotReady, DeviceDisconnected)) as info:  # KUKA: the reset deletes the channel
                robot.move_to_measuring_pose(2)
            assert time.monotonic() - began < 1.0, "a stopped program must not surface only as a move timeout"
            assert info.value.code == ("ROBOT_NOT_READY" if kind == "ur" else "DEVICE_DISCONNECTED")
        wait_for(lambda: truth(controller)["starts"] == 2, "the program started again")
        time.sleep(0.3)  # a replay would start a move now: give it time to show
        after = truth(controller)
        # UR: the registers still hold the last request, the program starts with last_seq = it and leaves it
        assert after["state"] == "IDLE" and after["stops"] == stops and after["in_position"] == 0
        assert after["ack_sequence"] == 0 and after["held_sequence"] == 0
        if kind == "ur":
            assert after["last_seq"] != 0
    finally:
        controller.stop()


def test_an_offset_stored_before_stop_play_is_not_stored_again(kind: str, controller: ControllerProcess,
                                                               cell: SimCell) -> None:
    with make_adapter(kind, controller, cell) as robot:
        sequence = robot.write_base_offset(ideal_offset(cell))
    controller.command("restart")
    wait_for(lambda: truth(controller)["starts"] == 2 and truth(controller)["program_running"], "started again")
    time.sleep(0.2)
    after = truth(controller)
    assert [o["sequence"] for o in after["offsets"]] == [sequence]  # taken once, never replayed
    assert (after["held_sequence"], after["offset_valid"]) == (0, False)


# --- case 3: two messages 1 ms apart are both answered, in order (KUKA: one flag, a FIFO per element) -------


def test_two_kuka_messages_one_ms_apart_are_both_answered_in_order(spec: Path) -> None:
    controller = start("kuka", spec)
    try:
        with socket.create_connection((controller.host, controller.port), timeout=3.0) as s:
            reports = _KukaReports(s)
            reports.next()
            s.sendall(_sensor(0, COMMAND_NONE, 0))
            time.sleep(0.001)
            s.sendall(_sensor(11, COMMAND_GOTO, 2))
            seen = reports.until(lambda r: r.ack_sequence == 11 and r.program_status == 0)
            assert any(r.ack_sequence == 0 and r.program_status == PROGRAM_SYNCHRONISED for r in seen)
            assert seen[-1].in_position == 2
            s.sendall(_sensor(12, COMMAND_OFFSET, 0, (1.5, 0.0, 0.0, 0.0, 0.0, 0.1)))
            time.sleep(0.001)
            s.sendall(_sensor(13, COMMAND_NONE, 0))
            last = reports.until(lambda r: r.ack_sequence == 13)[-1]
        assert (last.held_sequence, last.offset_valid, last.program_status) == (12, True, 0)
        assert [o["sequence"] for o in truth(controller)["offsets"]] == [12]
    finally:
        controller.stop()


# --- case 4: a reconnect during a move takes no stale acknowledgement ---------------------------------------


def test_a_reconnect_during_a_move_takes_no_stale_ack(kind: str, spec: Path, cell: SimCell) -> None:
    controller = start(kind, spec, move_time_s=0.8)
    try:
        # an earlier connection: request 4 (answered), then request 5 (a long move), then gone
        if kind == "ur":
            old = RtdeInputClient(controller.host, rtde.DEFAULT_PORT, 2.0)
            old.open()
            for request in (rtde.RobotRequest(0, COMMAND_NONE, 0, (0.0,) * 6),
                            rtde.RobotRequest(4, COMMAND_GOTO, 1, (0.0,) * 6)):
                old.send_request(request)
                time.sleep(0.05)
            wait_for(lambda: truth(controller)["ack_sequence"] == 4, "request 4 answered")
            old.send_request(rtde.RobotRequest(5, COMMAND_GOTO, 3, (0.0,) * 6))
            wait_for(lambda: truth(controller)["state"] == "MOVING", "the move of request 5 under way")
            old.close()
        else:
            with socket.create_connection((controller.host, controller.port), timeout=3.0) as s:
                reports = _KukaReports(s)
                s.sendall(_sensor(0, COMMAND_NONE, 0) + _sensor(4, COMMAND_GOTO, 1))
                reports.until(lambda r: r.ack_sequence == 4 and r.program_status == 0)
                s.sendall(_sensor(5, COMMAND_GOTO, 3))
                reports.until(lambda r: r.program_status == 1)
        began = time.monotonic()
        with make_adapter(kind, controller, cell, move_timeout_s=5.0) as robot:  # a new daemon, mid-move
            sequence = robot.write_base_offset(ideal_offset(cell))
            status = robot.status()
        waited = time.monotonic() - began
    finally:
        controller.stop()
    after = truth(controller)
    # the bug: the new number sent at once was the one still moving (5); the program ignored it as seen and later
    # answered the move, which the daemon took for its offset's acknowledgement: "stored", and never stored
    assert [o["sequence"] for o in after["offsets"]] == [sequence]  # stored, under its own number
    assert (status.held_sequence, status.ack_sequence, after["held_sequence"]) == (sequence, sequence, sequence)
    assert "3" in after["stops"] and waited > 0.3  # the move ended before the new request was sent


# --- case 6: a dropped EKI channel is opened again -------------------------------------------------------


def test_a_dropped_kuka_channel_is_reopened_and_serves_one_client(spec: Path, cell: SimCell) -> None:
    controller = start("kuka", spec)
    try:
        with make_adapter("kuka", controller, cell) as robot:
            robot.move_to_measuring_pose(0)
            with socket.create_connection((controller.host, controller.port), timeout=2.0) as second:
                second.settimeout(2.0)
                assert second.recv(4096) == b"", "EKI serves one client: a second one is closed at once"
            controller.command("drop")
            with pytest.raises(DeviceDisconnected):
                robot.move_to_measuring_pose(1)
            controller.command("none")
            assert robot.move_to_measuring_pose(2).in_position == 3  # reconnected: the program reopened it
    finally:
        controller.stop()


# --- case 8: an offset with a tiny component is parsed ------------------------------------------------------


def test_an_offset_with_a_tiny_component_is_parsed(spec: Path, cell: SimCell) -> None:
    controller = start("kuka", spec)
    tiny = make_T(rotvec_to_matrix(np.radians([0.0, 0.0, 4e-6])), np.array([3e-05, 0.0, -2e-7]))
    try:
        with make_adapter("kuka", controller, cell) as robot:
            sequence = robot.write_base_offset(tiny)  # repr would send X="3e-05": a REAL read that fails
        received = truth(controller)["offsets"][-1]
        with _kuka_client(controller) as (s, reports):  # the old form, once the program has reopened its channel
            s.sendall(_sensor(0, COMMAND_NONE, 0) + _sensor(99, COMMAND_OFFSET, 0, exponent=True))
            refused = reports.until(lambda r: r.ack_sequence == 99)[-1]
    finally:
        controller.stop()
    assert received["sequence"] == sequence and received["received"][0] == pytest.approx(3e-05, abs=5e-7)
    assert refused.program_status == -1 and refused.held_sequence == sequence  # unreadable: refused, -1


# --- helpers ------------------------------------------------------------------------------------------


@contextlib.contextmanager
def _kuka_client(controller: ControllerProcess) -> Iterator[tuple[socket.socket, _KukaReports]]:
    """A raw client of the KUKA channel, once the program has opened it (after a client went, it reopens it when
    idle: until then a connection is closed at once), with its first report read."""
    deadline = time.monotonic() + 3.0
    while True:
        s = socket.create_connection((controller.host, controller.port), timeout=3.0)
        reports = _KukaReports(s)
        try:
            reports.next()
            break
        except (ConnectionError, DeviceError):
            s.close()
            if time.monotonic() > deadline:
                raise
            time.sleep(0.05)
    with s:
        yield s, reports


def _sensor(sequence: int, command: int, pose: int, offset: tuple[float, ...] = (0.0,) * 6,
            exponent: bool = False) -> bytes:
    message = kuka.encode_request(kuka.KukaRequest(sequence, command, pose, offset))  # type: ignore[arg-type]
    return message.replace(b'X="0.000000"', b'X="3e-05"') if exponent else message


class _KukaReports:
    """The robot's reports on a raw socket, decoded as they come."""

    def __init__(self, sock: socket.socket) -> None:
        self.sock, self.buffer = sock, bytearray()

    def next(self, timeout_s: float = 2.0) -> kuka.KukaReport:
        deadline = time.monotonic() + timeout_s
        while not (messages := kuka.split_messages(self.buffer, kuka.ROBOT_ROOT)):
            self.sock.settimeout(max(0.01, deadline - time.monotonic()))
            chunk = self.sock.recv(65536)
            if not chunk or time.monotonic() > deadline:
                raise DeviceError("no report")
            self.buffer.extend(chunk)
        rest = b"".join(messages[1:])
        self.buffer[:0] = rest
        return kuka.decode_report(messages[0])

    def until(self, condition: object, timeout_s: float = 3.0) -> list[kuka.KukaReport]:
        deadline, seen = time.monotonic() + timeout_s, []
        while time.monotonic() < deadline:
            seen.append(self.next(deadline - time.monotonic()))
            if condition(seen[-1]):  # type: ignore[operator]
                return seen
        pytest.fail(f"no such report within {timeout_s:g} s; last {seen[-1:]}")
