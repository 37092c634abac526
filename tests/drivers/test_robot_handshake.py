"""The port's handshake over the real transports (issue 17, the robot's half; issue 23, case 4): the offset the
robot holds and clearing it, numbers across the wrap at 2^31-1, the intent before an offset is sent, only the exact
number with status 0 acknowledging, a stopped program ending a wait at once, and the controller lost right after
an offset (cut-after-offset): the truth file says what the program holds, and the adapter settles against it.
Genuine ur_rtde against the simulated UR; the XML channel against the simulated KUKA (and, for what the simulator
never does, a scripted KUKA peer); each test on its own 127.0.24.x address."""

from __future__ import annotations

import itertools
import socket
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest
from helpers.robots import make_adapter, sim_cell, truth, wait_for

from monoguide.drivers import kuka_protocol as kuka
from monoguide.drivers import rtde_protocol as rtde
from monoguide.drivers.errors import (
    DeviceDisconnected,
    DeviceError,
    DeviceNotFound,
    DeviceTimeout,
    RobotAckTimeout,
    RobotNotReady,
    RobotSyncTimeout,
)
from monoguide.drivers.kuka_robot import KukaRobot
from monoguide.drivers.robot import (
    COMMAND_GOTO,
    COMMAND_NONE,
    MAX_SEQUENCE,
    PROGRAM_BUSY,
    PROGRAM_SYNCHRONISED,
    HeldOffset,
    newest_sequence,
    next_sequence,
)
from monoguide.drivers.sim.cell import SimCell
from monoguide.drivers.sim.robot_process import ControllerProcess, start_controller
from monoguide.drivers.ur_robot import RtdeInputClient
from monoguide.solver.frames import compose, invert

KINDS = ("ur", "kuka")
_hosts = itertools.count(1)


@pytest.fixture
def cell() -> SimCell:
    return sim_cell()


@pytest.fixture
def spec(cell: SimCell, tmp_path: Path) -> Path:
    return cell.write_robot_spec(tmp_path / "robot.json", part=3)


@pytest.fixture(params=KINDS)
def kind(request: pytest.FixtureRequest) -> str:
    return str(request.param)


def start(kind: str, spec: Path, move_time_s: float = 0.05) -> ControllerProcess:
    return start_controller(kind, spec, spec.with_name("truth.json"), f"127.0.24.{next(_hosts)}",
                            move_time_s=move_time_s, commands=True)


@pytest.fixture
def controller(kind: str, spec: Path) -> Iterator[ControllerProcess]:
    c = start(kind, spec)
    try:
        yield c
    finally:
        c.stop()


def ideal_offset(cell: SimCell) -> np.ndarray:
    return compose(cell.T_b_w_true(), invert(cell.T_b_w0()))


# --- numbers ------------------------------------------------------------------------------------------


def test_numbers_wrap_to_1_and_the_newest_is_found_across_the_wrap() -> None:
    assert [next_sequence(n) for n in (0, 1, MAX_SEQUENCE - 1, MAX_SEQUENCE)] == [1, 2, MAX_SEQUENCE, 1]
    assert newest_sequence(MAX_SEQUENCE, 2) == 2 and newest_sequence(2, MAX_SEQUENCE) == 2  # 2 came after the wrap
    assert newest_sequence(MAX_SEQUENCE - 1, MAX_SEQUENCE) == MAX_SEQUENCE
    assert newest_sequence(5, 0, 3) == 5 and newest_sequence(0, 0) == 0 and newest_sequence(7) == 7
    assert newest_sequence(10, 10 + MAX_SEQUENCE // 2 + 5) == 10  # more than half the range "ahead" is behind


def test_the_sequence_wraps_at_2_31_minus_1_over_the_wire(kind: str, controller: ControllerProcess,
                                                          cell: SimCell) -> None:
    """An earlier session left the program at 2^31-2: the next numbers are 2^31-1, then 1, 2, never 0."""
    _answered_by_an_earlier_session(kind, controller, MAX_SEQUENCE - 1)
    with make_adapter(kind, controller, cell) as robot:
        assert robot.move_to_measuring_pose(0).ack_sequence == MAX_SEQUENCE
        offset = robot.write_base_offset(ideal_offset(cell))
        assert offset == 1
        assert robot.move_to_measuring_pose(1).ack_sequence == 2
        held = robot.held_offset()
    assert held == HeldOffset(1, False)  # sequence 0 of the synchronisation cleared the validity
    assert [o["sequence"] for o in truth(controller)["offsets"]] == [1]


# --- the held offset, clearing it -------------------------------------------------------------------------


def test_held_offset_and_clear_offset_over_the_real_transports(kind: str, controller: ControllerProcess,
                                                              cell: SimCell) -> None:
    with make_adapter(kind, controller, cell) as robot:
        assert robot.held_offset() == HeldOffset(0, False)  # nothing since the program's start
        sequence = robot.write_base_offset(ideal_offset(cell))
        assert (truth(controller)["held_sequence"], truth(controller)["offset_valid"]) == (sequence, True)
        assert robot.held_offset() == HeldOffset(sequence, False)  # held; sequence 0 cleared the flag
        assert robot.held_offset() == HeldOffset(sequence, False)  # a query again: still held
        cleared = robot.clear_offset()
        assert cleared > sequence and robot.status().ack_sequence == cleared
        assert robot.held_offset() == HeldOffset(0, False)
    assert (truth(controller)["held_sequence"], truth(controller)["offset_valid"]) == (0, False)


def test_held_offset_reconnects_when_the_connection_is_gone(kind: str, controller: ControllerProcess,
                                                            cell: SimCell) -> None:
    with make_adapter(kind, controller, cell) as robot:
        sequence = robot.write_base_offset(ideal_offset(cell))
        controller.command("drop")
        with pytest.raises(DeviceDisconnected):
            robot.move_to_measuring_pose(0)
        controller.command("none")
        assert robot.held_offset() == HeldOffset(sequence, False)


def test_a_stopped_program_cannot_say_what_it_holds(kind: str, controller: ControllerProcess, cell: SimCell) -> None:
    with make_adapter(kind, controller, cell) as robot:
        robot.write_base_offset(ideal_offset(cell))
        controller.command("program-stopped")
        with pytest.raises(RobotNotReady):
            robot.held_offset()
        with pytest.raises(RobotNotReady):
            robot.clear_offset()


# --- the intent before the offset -----------------------------------------------------------------------


def test_before_send_sees_the_number_and_when_it_fails_nothing_is_sent(kind: str, controller: ControllerProcess,
                                                                      cell: SimCell) -> None:
    seen: list[int] = []

    def journal_full(sequence: int) -> None:
        seen.append(sequence)
        raise OSError(28, "No space left on device")

    with make_adapter(kind, controller, cell) as robot:
        robot.move_to_measuring_pose(0)
        last_seq = truth(controller)["last_seq"]
        with pytest.raises(OSError, match="No space"):
            robot.write_base_offset(ideal_offset(cell), before_send=journal_full)
        robot.move_to_measuring_pose(1)  # a request after it: it would have been taken before this one
        after = truth(controller)
        assert after["offsets"] == [] and after["held_sequence"] == 0, "an offset reached the robot unrecorded"
        assert after["last_seq"] == seen[0] + 1 != last_seq  # the number went unused: never sent, never reused
        sequence = robot.write_base_offset(ideal_offset(cell), before_send=seen.append)
    assert seen[-1] == sequence and [o["sequence"] for o in truth(controller)["offsets"]] == [sequence]


# --- only the exact number with status 0 acknowledges (a scripted KUKA peer) ------------------------------


@pytest.mark.parametrize(("answers", "error"), [
    ([(PROGRAM_BUSY, 0.3), (0, None)], None),  # busy first: not an acknowledgement; then status 0
    ([(5, None)], RobotAckTimeout),  # another status with the number: never an acknowledgement
    ([("stale", None)], RobotAckTimeout),  # the number before: a stale acknowledgement never counts
])
def test_only_the_exact_number_with_status_0_acknowledges(answers: list[tuple[object, float | None]],
                                                          error: type[DeviceError] | None) -> None:
    host = f"127.0.24.{next(_hosts)}"
    with _ScriptedKuka(host, answers) as peer:
        robot = KukaRobot(host, peer.port, connect_timeout_s=2.0, ack_timeout_s=0.8, stale_timeout_s=0.5)
        try:
            robot.open()
            began = time.monotonic()
            if error is None:
                sequence = robot.write_base_offset(np.eye(4))
                assert time.monotonic() - began >= 0.3 and sequence == peer.requests[-1]
            else:
                with pytest.raises(error):
                    robot.write_base_offset(np.eye(4))
        finally:
            robot.close()


def test_a_program_that_does_not_answer_sequence_0_is_refused_before_any_request() -> None:
    """A template older than this daemon answers sequence 0 with status 0: no request is sent then."""
    host = f"127.0.24.{next(_hosts)}"
    with _ScriptedKuka(host, [(0, None)], synchronised=0) as peer:
        robot = KukaRobot(host, peer.port, connect_timeout_s=0.5, move_timeout_s=0.5, stale_timeout_s=0.5)
        try:
            robot.open()
            with pytest.raises(RobotSyncTimeout, match="status 2") as info:
                robot.move_to_measuring_pose(0)
        finally:
            robot.close()
    assert info.value.plc_code == 430 and peer.requests == []


# --- a stopped program ends any wait at once ---------------------------------------------------------------


def test_a_program_stopped_during_a_move_ends_the_wait_at_once(kind: str, spec: Path, cell: SimCell) -> None:
    controller = start(kind, spec, move_time_s=3.0)
    try:
        with make_adapter(kind, controller, cell, move_timeout_s=10.0) as robot:
            robot.status()
            timer = threading.Timer(0.4, controller.command, args=("program-stopped",))
            timer.start()
            began = time.monotonic()
            with pytest.raises(RobotNotReady, match="stopped while waiting"):
                robot.move_to_measuring_pose(2)
            timer.join()
            assert time.monotonic() - began < 1.5  # not the 10 s move timeout, nor the 3 s move
    finally:
        controller.stop()


# --- the controller lost right after an offset (issue 17, case 3) ----------------------------------------------


@pytest.mark.parametrize("after_ms", [0, 2, 8, 150])
def test_cut_after_offset_the_program_holds_what_it_took_and_the_adapter_settles_it(
        kind: str, controller: ControllerProcess, cell: SimCell, after_ms: int) -> None:
    down_s = 1.0
    with make_adapter(kind, controller, cell, connect_timeout_s=0.3) as robot:
        robot.move_to_measuring_pose(0)
        controller.command(f"cut-after-offset {after_ms} {down_s}")
        began = time.monotonic()
        try:
            acknowledged: int | None = robot.write_base_offset(ideal_offset(cell), before_send=_remember)
        except (DeviceDisconnected, DeviceTimeout, RobotAckTimeout):
            acknowledged = None  # the connection went before the acknowledgement came
        sent = _remember.last
        # the truth file: the program took the offset, whatever the wire showed
        wait_for(lambda: truth(controller)["held_sequence"] == sent, "the program holds the offset")
        assert truth(controller)["offset_valid"] is True and acknowledged in (None, sent)
        if after_ms == 0:
            assert acknowledged is None, "cut at once: the acknowledgement cannot have reached the wire"
        elif after_ms == 150:
            assert acknowledged == sent  # the program answers within a few ms: seen before the cut
        wait_for(lambda: time.monotonic() - began > after_ms / 1000 + 0.05, "the cut")
        with pytest.raises((DeviceNotFound, DeviceDisconnected, DeviceTimeout)):  # the cable is still out
            robot.held_offset()
        assert time.monotonic() - began < down_s, "the test's own timing: the refusal was not seen in the window"
        held = _settled(robot, began + down_s + 5.0)
    assert held == HeldOffset(sent, False)  # took it; the reconnect's sequence 0 made it invalid for the grasp


# --- helpers ------------------------------------------------------------------------------------------------


class _Remember:
    last = 0

    def __call__(self, sequence: int) -> None:
        self.last = sequence


_remember = _Remember()


def _settled(robot: object, deadline: float) -> HeldOffset:
    """``held_offset()`` once the connection is back (the adapter reconnects on each call)."""
    while True:
        try:
            return robot.held_offset()  # type: ignore[attr-defined, no-any-return]
        except (DeviceNotFound, DeviceDisconnected, DeviceTimeout):
            if time.monotonic() > deadline:
                raise
            time.sleep(0.1)


def _answered_by_an_earlier_session(kind: str, controller: ControllerProcess, sequence: int) -> None:
    """An earlier daemon's connection that sent sequence 0 and a move numbered ``sequence``, answered, then left."""
    if kind == "ur":
        old = RtdeInputClient(controller.host, rtde.DEFAULT_PORT, 2.0)
        old.open()
        old.send_request(rtde.RobotRequest(0, COMMAND_NONE, 0, (0.0,) * 6))
        wait_for(lambda: truth(controller)["program_status"] == PROGRAM_SYNCHRONISED, "sequence 0 answered")
        old.send_request(rtde.RobotRequest(sequence, COMMAND_GOTO, 1, (0.0,) * 6))
        wait_for(lambda: truth(controller)["ack_sequence"] == sequence, f"request {sequence} answered")
        old.close()
        return
    with socket.create_connection((controller.host, controller.port), timeout=3.0) as s:
        s.sendall(kuka.encode_request(kuka.KukaRequest(0, COMMAND_NONE, 0)) +
                  kuka.encode_request(kuka.KukaRequest(sequence, COMMAND_GOTO, 1)))
        wait_for(lambda: truth(controller)["ack_sequence"] == sequence, f"request {sequence} answered")


class _ScriptedKuka:
    """A KUKA peer on a real socket that answers as told, for what the simulated program never does: sequence 0
    with ``synchronised``, then the first numbered request with each (status, seconds) of ``answers`` in turn
    ("stale": the number before it, status 0; seconds None: from then on)."""

    def __init__(self, host: str, answers: list[tuple[object, float | None]],
                 synchronised: int = PROGRAM_SYNCHRONISED) -> None:
        self.server = socket.create_server((host, kuka.DEFAULT_PORT))
        self.port = kuka.DEFAULT_PORT
        self.answers, self.synchronised = answers, synchronised
        self.requests: list[int] = []
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._serve, daemon=True)

    def __enter__(self) -> _ScriptedKuka:
        self.thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop.set()
        self.server.close()
        self.thread.join(5.0)

    def _serve(self) -> None:
        self.server.settimeout(0.1)
        while not self.stop.is_set():
            try:
                conn, _ = self.server.accept()
            except OSError:
                continue
            with conn:
                self._talk(conn)

    def _talk(self, conn: socket.socket) -> None:
        conn.settimeout(0.02)
        buffer, ack, status, script, until = bytearray(), 0, 0, list(self.answers), None
        pending: Callable[[], None] | None = None
        while not self.stop.is_set():
            try:
                chunk = conn.recv(4096)
                if not chunk:
                    return
                buffer.extend(chunk)
            except TimeoutError:
                pass
            except OSError:
                return
            for message in kuka.split_messages(buffer, kuka.SENSOR_ROOT):
                request = kuka.decode_request(message)
                if request.sequence == 0:
                    ack, status = 0, self.synchronised
                else:
                    self.requests.append(request.sequence)
                    sequence = request.sequence

                    def answer(sequence: int = sequence) -> None:
                        nonlocal ack, status, until
                        what, seconds = script.pop(0) if len(script) > 1 else script[0]
                        ack, status = (sequence - 1, 0) if what == "stale" else (sequence, int(what))  # type: ignore[call-overload]
                        until = None if seconds is None else time.monotonic() + seconds

                    pending = answer
                    pending()
            if until is not None and time.monotonic() > until and pending is not None:
                pending()
            report = kuka.KukaReport("AUT", "NORMAL", True, (0.0,) * 6, ack, 0, status, int(time.monotonic() * 1000))
            try:
                conn.sendall(kuka.encode_report(report))
            except OSError:
                return
