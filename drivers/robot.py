"""The robot port: what the cycle needs of a robot, in the cell's words, whatever the make.

The robot's own program moves; the daemon only asks and waits. It asks for measuring pose ``i`` and waits
until the robot reports it in position; it reads the actual flange pose at the moment of a capture; it
writes the base offset ``D_b`` as one message carrying a sequence number and waits for the robot to
acknowledge that number. Units change at the adapter only (UR: metres and rotation vectors, KUKA:
millimetres and A, B, C degrees); through this port everything is mm, radians and 4x4 ``T_b_f``.

Measuring poses are indexed from 0 here (``config.measuring_poses[i]``); on the wire the robot sees the
pose *number* ``i + 1`` (``S1`` is 1), so that 0 can mean "none". The handshake is the same for both makes
(``docs/robot-interface.md``): every request carries a new sequence number; the robot answers with a
:class:`RobotStatus` whose ``ack_sequence`` is that number once the request is done (in position, offset
applied) and whose ``program_status`` is 0, or negative when its program refused the request.
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
    RobotAckTimeout,
    RobotCommandRejected,
    RobotNotReady,
    RobotPoseMismatch,
    RobotPositionTimeout,
    RobotProtectiveStop,
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
PROGRAM_STATUS_TEXT = {
    PROGRAM_OK: "ok",
    PROGRAM_BUSY: "busy",
    PROGRAM_UNKNOWN_COMMAND: "unknown command",
    PROGRAM_BAD_POSE: "no such measuring pose",
    PROGRAM_OFFSET_REJECTED: "offset outside the program's limits",
}

# Base-calibration poses (``monoguide calibrate``, step 3): calibration pose k (1..99) is pose number 100 + k on the
# wire, taught in the robot program beside the measuring poses (docs/robot-interface.md)
CALIBRATION_POSE_BASE = 100
MAX_CALIBRATION_POSE = 99

# The commands a request carries (UR: input_int_register_25, KUKA: <Request Command=...>)
COMMAND_NONE = 0
COMMAND_GOTO = 1
COMMAND_OFFSET = 2


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

    @property
    def protective_stop(self) -> bool:
        return self.safety != "NORMAL"

    @property
    def ready(self) -> bool:
        return self.program_running and not self.protective_stop and self.mode in READY_MODES


READY_MODES = ("RUNNING", "AUT", "EXT")


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

    def move_to_measuring_pose(self, i: int, timeout_s: float | None = None) -> RobotStatus:
        """Request measuring pose ``i`` (0-based) and wait until the robot reports it in position; returns
        the status at that moment (its ``T_b_f`` is the actual flange pose to record with the capture)."""
        ...

    def move_to_calibration_pose(self, k: int, timeout_s: float | None = None) -> RobotStatus:
        """Request base-calibration pose ``k`` (1..99; wire pose number ``100 + k``, taught in the robot program)
        and wait until the robot reports it in position; returns the status then (``T_b_f``: the actual flange
        pose). A pose the program does not have -> :class:`RobotCommandRejected` naming it."""
        ...

    def write_base_offset(self, D_b: np.ndarray, timeout_s: float | None = None) -> int:
        """Write the base offset ``D_b`` (4, 4, mm) as one message and wait for the robot's acknowledgement
        of its sequence number; returns that number."""
        ...

    def close(self) -> None: ...


# --- meaning shared by the adapters ------------------------------------------------------------


def next_sequence(sequence: int) -> int:
    """The sequence number after ``sequence``: 1, 2, ..., MAX_SEQUENCE, 1, ... (never 0)."""
    return sequence % MAX_SEQUENCE + 1


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
    """The handshake both adapters share: a request with a new sequence number, then waiting for the robot's
    acknowledgement of exactly that number; and opening, closing and the identity. An adapter supplies
    :meth:`_connect` (which sets ``_identity``), :meth:`close`, :meth:`status`, :meth:`_send_request` (in its
    wire's units) and, if it must, :meth:`_pause`."""

    def __init__(self, name: str, host: str, port: int, *, connect_timeout_s: float, move_timeout_s: float,
                 ack_timeout_s: float, stale_timeout_s: float, T_b_f_taught: tuple[np.ndarray, ...],
                 pose_tolerance_mm: float, pose_tolerance_deg: float) -> None:
        self.host, self.port, self.name = host, port, name
        self.connect_timeout_s, self.move_timeout_s = connect_timeout_s, move_timeout_s
        self.ack_timeout_s, self.stale_timeout_s = ack_timeout_s, stale_timeout_s
        self.T_b_f_taught = T_b_f_taught
        self.pose_tolerance_mm, self.pose_tolerance_deg = pose_tolerance_mm, pose_tolerance_deg
        self._identity: RobotIdentity | None = None
        self._sequence = 0
        self._poll_s = POLL_S  # the pause between status reads of an adapter that polls (see _pause)

    @property
    def identity(self) -> RobotIdentity | None:
        return self._identity

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

    def write_base_offset(self, D_b: np.ndarray, timeout_s: float | None = None) -> int:
        D_b = check_transform(D_b, "base offset D_b")  # a rigid transform, or NotARotation naming the defect
        sequence = self._request(COMMAND_OFFSET, 0, D_b)
        self._poll_s = ACK_POLL_S  # a short wait, and the line waits on it: look more often
        try:
            status = self._wait_for_ack(sequence, self.ack_timeout_s if timeout_s is None else timeout_s,
                                        RobotAckTimeout, "offset acknowledged", lambda s: True)
        finally:
            self._poll_s = POLL_S
        check_program_status(status, self.name, f"offset {sequence}")
        log.info("%s: offset %d acknowledged", self.name, sequence)
        return sequence

    def _send_request(self, sequence: int, command: int, pose_number: int, D_b: np.ndarray) -> None:
        raise NotImplementedError

    def _pause(self) -> None:
        """Between two status reads. An adapter whose status is a cached stream sleeps (``POLL_S``, while
        moving; ``ACK_POLL_S`` while waiting for the offset's acknowledgement); one that can wait on its
        wire (KUKA: the next report) overrides this."""
        time.sleep(self._poll_s)

    def _request(self, command: int, pose_number: int, D_b: np.ndarray) -> int:
        check_ready(self.status(), self.name)
        self._sequence = next_sequence(self._sequence)
        self._send_request(self._sequence, command, pose_number, D_b)
        return self._sequence

    def _wait_for_ack(self, sequence: int, timeout_s: float, timeout_error: type[DeviceError], what: str,
                      done: Callable[[RobotStatus], bool]) -> RobotStatus:
        deadline = time.monotonic() + timeout_s
        while True:
            status = self.status()
            if status.protective_stop:
                raise RobotProtectiveStop(f"{self.name}: safety {status.safety} while waiting for {what} "
                                          f"(request {sequence})")
            if status.ack_sequence == sequence and (status.program_status < 0 or done(status)):
                return status
            if time.monotonic() > deadline:
                raise timeout_error(f"{self.name}: not {what} within {timeout_s:g} s (request {sequence}; robot "
                                    f"acknowledged {status.ack_sequence}, in position at {status.in_position})")
            self._pause()
