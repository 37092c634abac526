"""The robot port: what the cycle needs of a robot, in the cell's words, whatever the make.

The robot's own program moves; the daemon only asks and waits. It asks for measuring pose ``i`` and waits
until the robot reports it in position; it reads the actual flange pose at the moment of a capture; it
writes the base offset ``D_b`` as one message carrying a sequence number and waits for the robot to
acknowledge that number. Units change at the adapter only (UR: metres and rotation vectors, KUKA:
millimetres and A, B, C degrees); through this port everything is mm, radians and 4x4 ``T_b_f``.

Measuring poses are indexed from 0 here (``config.measuring_poses[i]``); on the wire the robot sees the
pose *number* ``i + 1`` (``S1`` is 1), so that 0 can mean "none". The handshake is the same for both makes
(``docs/robot-interface.md``, the table in :mod:`monoguide.drivers.robot_program`): every request carries a
new sequence number; the robot answers with a :class:`RobotStatus` whose ``ack_sequence`` is that number once the
request is done (in position, offset stored) and whose ``program_status`` is 0, or negative when its program
refused the request. Only that exact number with status 0 is an acknowledgement: a busy status, a stale number
or an answer left from an earlier connection never is.

After every (re)connect the adapter synchronises before its first request: it sends sequence 0, which the program
answers with ``ack_sequence`` 0 and status 2 once it has finished whatever it was doing (a move under way), and
continues numbering after the newest of its own last number, the program's last acknowledged number and the
number of the offset the program holds, so that no number is taken for another request's answer and none whose
offset the robot may still hold is used again.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol, Self, runtime_checkable

import numpy as np

from monoguide.drivers.errors import (
    DeviceError,
    DeviceProtocolError,
    RobotAckTimeout,
    RobotCommandRejected,
    RobotNotReady,
    RobotPoseMismatch,
    RobotPositionTimeout,
    RobotProtectiveStop,
    RobotSyncTimeout,
)
from monoguide.solver.frames import check_transform, pose_difference

log = logging.getLogger(__name__)

POLL_S = 0.01
ACK_POLL_S = 0.002  # while waiting for the offset's acknowledgement: on the cycle's overhead path
MAX_SEQUENCE = 2**31 - 1  # an int32 register; the sequence wraps to 1, never 0 (0: nothing requested)

# What the robot program answers in its status (UR: output_int_register_38, KUKA: <Handshake Status=...>)
PROGRAM_OK = 0
PROGRAM_BUSY = 1
PROGRAM_UNKNOWN_COMMAND = -1
PROGRAM_BAD_POSE = -2
PROGRAM_OFFSET_REJECTED = -3
PROGRAM_SYNCHRONISED = 2  # the answer to sequence 0 (with ack 0): the program is idle and takes any new number
PROGRAM_STATUS_TEXT = {
    PROGRAM_OK: "ok",
    PROGRAM_BUSY: "busy",
    PROGRAM_SYNCHRONISED: "synchronised (sequence 0 answered)",
    PROGRAM_UNKNOWN_COMMAND: "unknown command or unreadable request",
    PROGRAM_BAD_POSE: "no such measuring pose",
    PROGRAM_OFFSET_REJECTED: "offset outside the program's limits",
}

# Base-calibration poses (``monoguide calibrate``, step 3): calibration pose k (1..99) is pose number 100 + k on the
# wire, taught in the robot program beside the measuring poses (docs/robot-interface.md)
CALIBRATION_POSE_BASE = 100
MAX_CALIBRATION_POSE = 99

# The commands a request carries (UR: input_int_register_25, KUKA: <Request Command=...>)
COMMAND_NONE = 0  # with sequence 0: the daemon (re)connected; with a new number: synchronise (answered, no effect)
COMMAND_GOTO = 1
COMMAND_OFFSET = 2
COMMAND_CLEAR = 3  # forget the held offset: validity flag cleared, held sequence 0 (settling an unconfirmed offset)


@dataclass(frozen=True)
class RobotIdentity:
    vendor: str
    model: str
    serial: str
    software: str  # controller software version ("5.15.0.0", "KSS 8.6")
    address: str  # where the daemon reaches it ("127.0.0.50:30004")


@dataclass(frozen=True)
class RobotStatus:
    """One snapshot of the robot as its controller reports it.

    ``T_b_f`` is the actual flange pose (4, 4, mm); ``mode`` and ``safety`` are the controller's own words
    (UR: ``RUNNING`` / ``NORMAL``; KUKA: ``AUT`` / ``NORMAL``); ``program_running`` that the robot program
    that answers the daemon runs; ``in_position`` the measuring pose number the robot stands at (0: none,
    moving); ``ack_sequence`` the sequence number of the last request the program finished;
    ``program_status`` its answer to it (``PROGRAM_*``).
    """

    T_b_f: np.ndarray
    mode: str
    safety: str
    program_running: bool
    in_position: int
    ack_sequence: int
    program_status: int
    timestamp_s: float = 0.0
    held_sequence: int = 0  # the sequence number of the offset request the program holds (0: none)
    offset_valid: bool = False  # the program's grasp interlock: it would grasp with the offset it holds

    @property
    def protective_stop(self) -> bool:
        return self.safety != "NORMAL"

    @property
    def ready(self) -> bool:
        return self.program_running and not self.protective_stop and self.mode in READY_MODES


READY_MODES = ("RUNNING", "AUT", "EXT")


@dataclass(frozen=True)
class HeldOffset:
    """Which offset the robot program says it holds: the sequence number of the request that carried it (0:
    none) and whether its grasp interlock would use it."""

    sequence: int
    valid: bool


@runtime_checkable
class Robot(Protocol):
    """What the cycle and ``monoguide probe robot`` need from a robot."""

    def open(self) -> RobotIdentity:
        """Connect and say who the robot is (does not require it to be ready)."""
        ...

    @property
    def identity(self) -> RobotIdentity | None: ...

    def status(self) -> RobotStatus:
        """The robot's state now (actual flange pose, modes, handshake registers)."""
        ...

    def watch(self) -> None:
        """Between cycles: a :class:`DeviceError` when the link to the controller is gone or its reports have
        stopped (``DeviceDisconnected``, ``DeviceTimeout``); never reconnects and never waits for a report."""
        ...

    def move_to_measuring_pose(self, i: int, timeout_s: float | None = None) -> RobotStatus:
        """Request measuring pose ``i`` (0-based) and wait until the robot reports it in position; returns
        the status at that moment (its ``T_b_f`` is the actual flange pose to record with the capture)."""
        ...

    def move_to_calibration_pose(self, k: int, timeout_s: float | None = None) -> RobotStatus:
        """Request base-calibration pose ``k`` (1..99; wire pose number ``100 + k``, taught in the robot program)
        and wait until the robot reports it in position; returns the status then (``T_b_f``: the actual flange
        pose). A pose the program does not have -> :class:`RobotCommandRejected` naming it."""
        ...

    def write_base_offset(self, D_b: np.ndarray, timeout_s: float | None = None, *,
                          before_send: Callable[[int], None] | None = None) -> int:
        """Write the base offset ``D_b`` (4, 4, mm) as one message and wait for the robot's acknowledgement
        of its sequence number (status 0, exactly that number); returns that number. ``before_send(sequence)``
        is called after the ready check and before anything goes on the wire (the journal's intent); when it
        raises, nothing is sent and its exception propagates."""
        ...

    def held_offset(self, timeout_s: float | None = None) -> HeldOffset:
        """Synchronise with the program so that no request sent before this call can still be taken (sequence
        0 answered, the program not busy), then say which offset it holds. Reconnects when needed; a
        :class:`DeviceError` when it cannot know."""
        ...

    def clear_offset(self, timeout_s: float | None = None) -> int:
        """Command 3: the program forgets its offset (validity flag cleared, held sequence 0); waits for the
        acknowledgement (status 0, exactly this number) and returns the sequence number."""
        ...

    def close(self) -> None: ...


# --- meaning shared by the adapters ------------------------------------------------------------


def next_sequence(sequence: int) -> int:
    """The sequence number after ``sequence``: 1, 2, ..., MAX_SEQUENCE, 1, ... (never 0)."""
    return sequence % MAX_SEQUENCE + 1


def newest_sequence(*sequences: int) -> int:
    """The newest of ``sequences`` in wrap order (1..MAX_SEQUENCE, then 1 again): a number is newer than another
    when it lies less than half the range after it; 0 (none) counts for nothing. 0 when all are 0."""
    newest = 0
    for sequence in sequences:
        if not 1 <= sequence <= MAX_SEQUENCE:
            continue
        if newest == 0 or 0 < (sequence - newest) % MAX_SEQUENCE < MAX_SEQUENCE // 2:
            newest = sequence
    return newest


def check_ready(status: RobotStatus, robot: str) -> None:
    """Raise :class:`RobotProtectiveStop` or :class:`RobotNotReady` when the robot cannot take a request."""
    if status.protective_stop:
        raise RobotProtectiveStop(f"{robot}: safety mode {status.safety} (protective or emergency stop)")
    if not status.ready:
        raise RobotNotReady(f"{robot}: not ready: mode {status.mode}, program "
                            f"{'running' if status.program_running else 'not running'}")


def check_program_status(status: RobotStatus, robot: str, request: str) -> None:
    """A negative ``program_status`` for the acknowledged request -> :class:`RobotCommandRejected`."""
    if status.program_status < 0:
        text = PROGRAM_STATUS_TEXT.get(status.program_status, "unknown status")
        raise RobotCommandRejected(f"{robot}: program refused {request}: status {status.program_status} ({text})")


def check_at_taught_pose(T_b_f: np.ndarray, T_b_f_taught: np.ndarray | None, tolerance_mm: float,
                         tolerance_deg: float, robot: str, pose_name: str) -> None:
    """The robot says in position: is its actual flange pose within tolerance of the taught one?"""
    if T_b_f_taught is None:
        return
    angle_deg, distance_mm = pose_difference(T_b_f, T_b_f_taught)
    if distance_mm > tolerance_mm or angle_deg > tolerance_deg:
        raise RobotPoseMismatch(
            f"{robot}: in position at {pose_name} but {distance_mm:.3f} mm / {angle_deg:.4f} deg from the taught "
            f"flange pose (tolerance {tolerance_mm:g} mm / {tolerance_deg:g} deg)")


class HandshakeRobot:
    """The handshake both adapters share: synchronising after a (re)connect, a request with a new sequence
    number, then waiting for the robot's acknowledgement of exactly that number with status 0; the held offset,
    clearing it; opening, closing and the identity. An adapter supplies :meth:`_connect` (which sets
    ``_identity`` and calls :meth:`_connected`), :meth:`close`, :meth:`status` (reconnecting when the connection
    is gone), :meth:`_send_request` (in its wire's units) and, if it must, :meth:`_pause`."""

    def __init__(self, name: str, host: str, port: int, *, connect_timeout_s: float, move_timeout_s: float,
                 ack_timeout_s: float, stale_timeout_s: float, T_b_f_taught: tuple[np.ndarray, ...],
                 pose_tolerance_mm: float, pose_tolerance_deg: float) -> None:
        self.host, self.port, self.name = host, port, name
        self.connect_timeout_s, self.move_timeout_s = connect_timeout_s, move_timeout_s
        self.ack_timeout_s, self.stale_timeout_s = ack_timeout_s, stale_timeout_s
        self.T_b_f_taught = T_b_f_taught
        self.pose_tolerance_mm, self.pose_tolerance_deg = pose_tolerance_mm, pose_tolerance_deg
        self._identity: RobotIdentity | None = None
        self._sequence = 0  # the newest number this adapter knows of: sent by it, or seen in the robot's report
        self._synchronised = False  # sequence 0 answered on this connection: the next number is the program's new
        self._poll_s = POLL_S  # the pause between status reads of an adapter that polls (see _pause)

    @property
    def identity(self) -> RobotIdentity | None:
        return self._identity

    @property
    def last_sequence(self) -> int:
        """The newest sequence number this adapter has sent or seen acknowledged or held (0: none yet)."""
        return self._sequence

    def open(self) -> RobotIdentity:
        try:
            self._connect()
        except BaseException:
            self.close()
            raise
        assert self._identity is not None
        return self._identity

    def close(self) -> None:
        raise NotImplementedError

    def __enter__(self) -> Self:
        self.open()
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def status(self) -> RobotStatus:
        raise NotImplementedError

    def _connect(self) -> None:
        raise NotImplementedError

    def move_to_measuring_pose(self, i: int, timeout_s: float | None = None) -> RobotStatus:
        if i < 0 or (self.T_b_f_taught and i >= len(self.T_b_f_taught)):
            raise RobotCommandRejected(f"{self.name}: measuring pose index {i} does not exist "
                                       f"(the cell has {len(self.T_b_f_taught)})")
        number = i + 1
        sequence = self._request(COMMAND_GOTO, number, np.eye(4))
        status = self._wait_for_ack(sequence, self.move_timeout_s if timeout_s is None else timeout_s,
                                    RobotPositionTimeout, f"in position at S{number}",
                                    lambda s: s.in_position == number)
        check_program_status(status, self.name, f"measuring pose S{number}")
        check_at_taught_pose(status.T_b_f, self.T_b_f_taught[i] if self.T_b_f_taught else None,
                             self.pose_tolerance_mm, self.pose_tolerance_deg, self.name, f"S{number}")
        return status

    def move_to_calibration_pose(self, k: int, timeout_s: float | None = None) -> RobotStatus:
        if not 1 <= k <= MAX_CALIBRATION_POSE:
            raise RobotCommandRejected(f"{self.name}: calibration pose {k} does not exist (1..{MAX_CALIBRATION_POSE}, "
                                       f"wire pose numbers {CALIBRATION_POSE_BASE + 1}..)")
        number = CALIBRATION_POSE_BASE + k
        name = f"calibration pose {k} (pose number {number})"
        sequence = self._request(COMMAND_GOTO, number, np.eye(4))
        status = self._wait_for_ack(sequence, self.move_timeout_s if timeout_s is None else timeout_s,
                                    RobotPositionTimeout, f"in position at {name}",
                                    lambda s: s.in_position == number)
        check_program_status(status, self.name, name)
        return status

    def write_base_offset(self, D_b: np.ndarray, timeout_s: float | None = None, *,
                          before_send: Callable[[int], None] | None = None) -> int:
        D_b = check_transform(D_b, "base offset D_b")  # a rigid transform, or NotARotation naming the defect
        sequence = self._request(COMMAND_OFFSET, 0, D_b, before_send)
        self._poll_s = ACK_POLL_S  # a short wait, and the line waits on it: look more often
        try:
            status = self._wait_for_ack(sequence, self.ack_timeout_s if timeout_s is None else timeout_s,
                                        RobotAckTimeout, "offset acknowledged", lambda s: True)
        finally:
            self._poll_s = POLL_S
        check_program_status(status, self.name, f"offset {sequence}")
        log.info("%s: offset %d acknowledged", self.name, sequence)
        return sequence

    def held_offset(self, timeout_s: float | None = None) -> HeldOffset:
        """See :class:`Robot`. The synchronisation's sequence 0 clears the program's validity flag (the grasp
        interlock): ``valid`` comes back False, and the robot grasps with nothing until the next offset."""
        # sequence 0 first (the program answers it only once it has finished what it was doing, and forgets the
        # validity of its offset), then a numbered no-op whose exact acknowledgement proves that everything sent
        # before it has been taken or is gone for good (UR: overwritten in the registers; KUKA: answered before it)
        self._synchronised = False
        sequence = self._request(COMMAND_NONE, 0, np.eye(4))  # reconnects when the connection is gone
        status = self._wait_for_ack(sequence, self.ack_timeout_s if timeout_s is None else timeout_s,
                                    RobotAckTimeout, "synchronised (the held offset)", lambda s: True)
        check_program_status(status, self.name, f"synchronisation {sequence}")
        held = HeldOffset(status.held_sequence, status.offset_valid)
        self._sequence = newest_sequence(self._sequence, held.sequence)
        log.info("%s: holds offset %d (%s)", self.name, held.sequence, "valid" if held.valid else "not valid")
        return held

    def clear_offset(self, timeout_s: float | None = None) -> int:
        sequence = self._request(COMMAND_CLEAR, 0, np.eye(4))
        status = self._wait_for_ack(sequence, self.ack_timeout_s if timeout_s is None else timeout_s,
                                    RobotAckTimeout, "offset cleared", lambda s: True)
        check_program_status(status, self.name, f"clear {sequence}")
        if status.held_sequence != 0 or status.offset_valid:
            raise DeviceProtocolError(f"{self.name}: the program acknowledged clear {sequence} but still holds offset "
                                      f"{status.held_sequence} ({'valid' if status.offset_valid else 'not valid'})")
        log.info("%s: offset cleared (request %d)", self.name, sequence)
        return sequence

    def _send_request(self, sequence: int, command: int, pose_number: int, D_b: np.ndarray) -> None:
        raise NotImplementedError

    def _pause(self) -> None:
        """Between two status reads. An adapter whose status is a cached stream sleeps (``POLL_S``, while
        moving; ``ACK_POLL_S`` while waiting for the offset's acknowledgement); one that can wait on its
        wire (KUKA: the next report) overrides this."""
        time.sleep(self._poll_s)

    def _connected(self, status: RobotStatus) -> None:
        """A new connection: what its first report says (the program's last answer and held offset) counts for the
        numbering; the handshake is synchronised before the first request."""
        self._synchronised = False
        self._sequence = newest_sequence(self._sequence, status.ack_sequence, status.held_sequence)

    def _request(self, command: int, pose_number: int, D_b: np.ndarray,
                 before_send: Callable[[int], None] | None = None) -> int:
        status = self.status()  # reconnects when the connection is gone
        check_ready(status, self.name)
        if not self._synchronised:
            self._synchronise()
        self._sequence = next_sequence(self._sequence)  # taken even when before_send fails: never used twice
        if before_send is not None:
            before_send(self._sequence)
        self._send_request(self._sequence, command, pose_number, D_b)
        return self._sequence

    def _synchronise(self) -> None:
        """Sequence 0, then wait until the program answers it (ack 0, status 2); it does once it is idle, after any
        move under way has ended: no answer of that move is taken for a new request."""
        self._send_request(0, COMMAND_NONE, 0, np.eye(4))
        timeout_s = self.connect_timeout_s + self.move_timeout_s  # a move under way ends first
        deadline = time.monotonic() + timeout_s
        while True:
            status = self.status()
            self._check_running(status, "sequence 0 answered", 0)
            self._sequence = newest_sequence(self._sequence, status.ack_sequence, status.held_sequence)
            if status.ack_sequence == 0 and status.program_status == PROGRAM_SYNCHRONISED:
                break
            if time.monotonic() > deadline:
                raise RobotSyncTimeout(
                    f"{self.name}: the robot program did not answer sequence 0 within {timeout_s:g} s (it reports "
                    f"ack {status.ack_sequence}, status {status.program_status}; a program older than this daemon "
                    f"answers status 0, this one expects status {PROGRAM_SYNCHRONISED}: load the templates of this "
                    f"version)")
            self._pause()
        self._synchronised = True
        log.info("%s: synchronised; requests continue after %d", self.name, self._sequence)

    def _check_running(self, status: RobotStatus, what: str, sequence: int) -> None:
        """A stopped program or a safety stop ends any wait at once, with its own code."""
        if status.protective_stop:
            raise RobotProtectiveStop(f"{self.name}: safety {status.safety} while waiting for {what} "
                                      f"(request {sequence})")
        if not status.program_running:
            raise RobotNotReady(f"{self.name}: the robot program stopped while waiting for {what} (request "
                                f"{sequence}; mode {status.mode})")

    def _wait_for_ack(self, sequence: int, timeout_s: float, timeout_error: type[DeviceError], what: str,
                      done: Callable[[RobotStatus], bool]) -> RobotStatus:
        """Until the robot answers exactly ``sequence``: a refusal (negative status) is returned for the caller to
        raise; status 0 with ``done`` true is the acknowledgement; busy, another status or another number is not."""
        deadline = time.monotonic() + timeout_s
        while True:
            status = self.status()
            self._check_running(status, what, sequence)
            if status.ack_sequence == sequence and (
                    status.program_status < 0 or (status.program_status == PROGRAM_OK and done(status))):
                return status
            if time.monotonic() > deadline:
                raise timeout_error(f"{self.name}: not {what} within {timeout_s:g} s (request {sequence}; robot "
                                    f"acknowledged {status.ack_sequence} with status {status.program_status}, in "
                                    f"position at {status.in_position})")
            self._pause()
