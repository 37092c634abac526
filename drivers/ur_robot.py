"""The UR adapter of the robot port: state through ur_rtde, requests and offsets through our own RTDE recipe.

Three layers, as in the tracker driver: :class:`RtdeChannel` moves RTDE messages over a TCP socket with a
deadline; :mod:`monoguide.drivers.rtde_protocol` encodes them; :class:`RtdeInputClient` and
:class:`UrRobot` give them their meaning. The robot's state (actual TCP pose, robot and safety mode, the
output registers its program answers in) comes from the genuine ur_rtde ``RTDEReceiveInterface`` in a
supervised worker process (:mod:`monoguide.drivers.ur_rtde_worker`). Requests go out through one input
recipe of ours, because ur_rtde's ``RTDEIOInterface`` writes five doubles, one package each: a request is
sequence number, command, pose number and the 6-DOF offset in ONE data package (``docs/robot-interface.md``).

The robot program must run with the TCP at the flange (``set_tcp(p[0,0,0,0,0,0])``), so that
``actual_TCP_pose`` is the flange pose ``T_b_f``.
"""

from __future__ import annotations

import logging
import select
import socket
import time

import numpy as np

from monoguide.drivers import rtde_protocol as rtde
from monoguide.drivers.errors import (
    DeviceBusy,
    DeviceDisconnected,
    DeviceNotFound,
    DeviceProtocolError,
    DeviceTimeout,
)
from monoguide.drivers.robot import (
    COMMAND_OFFSET,
    HandshakeRobot,
    RobotIdentity,
    RobotStatus,
)
from monoguide.drivers.ur_rtde_worker import RtdeReceiveWorker
from monoguide.solver.frames import ur_pose_to_T

log = logging.getLogger(__name__)

ROBOT_MODES = {-1: "NO_CONTROLLER", 0: "DISCONNECTED", 1: "CONFIRM_SAFETY", 2: "BOOTING", 3: "POWER_OFF",
               4: "POWER_ON", 5: "IDLE", 6: "BACKDRIVE", 7: "RUNNING", 8: "UPDATING_FIRMWARE"}
SAFETY_MODES = {1: "NORMAL", 2: "REDUCED", 3: "PROTECTIVE_STOP", 4: "RECOVERY", 5: "SAFEGUARD_STOP",
                6: "SYSTEM_EMERGENCY_STOP", 7: "ROBOT_EMERGENCY_STOP", 8: "VIOLATION", 9: "FAULT",
                10: "VALIDATE_JOINT_ID", 11: "UNDEFINED_SAFETY_MODE", 12: "AUTOMATIC_MODE_SAFEGUARD_STOP",
                13: "SYSTEM_THREE_POSITION_ENABLING_STOP"}
RUNTIME_PLAYING = 2
POLL_S = 0.01


WATCH_STATUS_S = 0.25  # between cycles: how often watch() asks the receive worker (a lost input link: every call)


class RtdeChannel:
    """Bytes on the wire: one RTDE message out, one in before a deadline, over a TCP socket."""

    def __init__(self, sock: socket.socket, name: str) -> None:
        self._sock = sock
        self._name = name
        self._buffer = bytearray()

    def send(self, message_type: int, payload: bytes = b"") -> None:
        try:
            self._sock.sendall(rtde.encode_message(message_type, payload))
        except OSError as exc:
            raise DeviceDisconnected(f"{self._name}: send failed: {exc}") from exc

    def receive(self, deadline: float) -> tuple[int, bytes]:
        """One whole message (type, payload) received before ``deadline`` (``time.monotonic()``)."""
        while True:
            if len(self._buffer) >= rtde.HEADER.size:
                length, message_type = rtde.decode_header(bytes(self._buffer[: rtde.HEADER.size]))
                end = rtde.HEADER.size + length
                if len(self._buffer) >= end:
                    payload = bytes(self._buffer[rtde.HEADER.size:end])
                    del self._buffer[:end]
                    return message_type, payload
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise DeviceTimeout(f"{self._name}: no answer in time")
            self._sock.settimeout(remaining)
            try:
                chunk = self._sock.recv(65536)
            except TimeoutError as exc:
                raise DeviceTimeout(f"{self._name}: no answer in time") from exc
            except OSError as exc:
                raise DeviceDisconnected(f"{self._name}: receive failed: {exc}") from exc
            if not chunk:
                raise DeviceDisconnected(f"{self._name}: the controller closed the connection")
            self._buffer.extend(chunk)

    def closed_by_peer(self) -> bool:
        """The peer closed the connection (an end of stream waits to be read), looked at without waiting; what it
        sent is left to :meth:`receive`."""
        try:
            readable, _, _ = select.select([self._sock], [], [], 0.0)
            return bool(readable) and self._sock.recv(1, socket.MSG_PEEK) == b""
        except (OSError, ValueError):  # ValueError: a closed socket
            return True

    def close(self) -> None:
        try:
            self._sock.close()
        except OSError as exc:
            log.warning("%s: close failed: %s", self._name, exc)


class RtdeInputClient:
    """The client side of RTDE for our one input recipe: version, setup inputs, start, data packages."""

    def __init__(self, host: str, port: int, timeout_s: float) -> None:
        self.name = f"UR RTDE input {host}:{port}"
        self.host, self.port, self.timeout_s = host, port, timeout_s
        self.controller_version: tuple[int, int, int, int] | None = None
        self._channel: RtdeChannel | None = None
        self._recipe_id = 0

    def open(self) -> tuple[int, int, int, int]:
        try:
            sock = socket.create_connection((self.host, self.port), timeout=self.timeout_s)
        except OSError as exc:
            raise DeviceNotFound(f"{self.name}: cannot connect: {exc}") from exc
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._channel = RtdeChannel(sock, self.name)
        try:
            if not rtde.decode_accepted(self._transact(rtde.REQUEST_PROTOCOL_VERSION,
                                                       rtde.encode_protocol_version()), "protocol version"):
                raise DeviceProtocolError(f"{self.name}: controller refuses RTDE protocol {rtde.PROTOCOL_VERSION}")
            self.controller_version = rtde.decode_controller_version(self._transact(rtde.GET_URCONTROL_VERSION))
            recipe_id, types = rtde.decode_recipe(self._transact(rtde.CONTROL_PACKAGE_SETUP_INPUTS,
                                                                 rtde.encode_setup_inputs(rtde.INPUT_RECIPE)))
            self._check_recipe(recipe_id, types)
            self._recipe_id = recipe_id
            if not rtde.decode_accepted(self._transact(rtde.CONTROL_PACKAGE_START), "start"):
                raise DeviceProtocolError(f"{self.name}: controller refused to start synchronisation")
        except BaseException:
            self.close()
            raise
        return self.controller_version

    @property
    def is_open(self) -> bool:
        return self._channel is not None

    def closed_by_controller(self) -> bool:
        """Whether the controller has closed this connection (looked at without waiting)."""
        return self._channel is not None and self._channel.closed_by_peer()

    def send_request(self, request: rtde.RobotRequest) -> None:
        """One data package carrying the whole request (sequence, command, pose number, offset)."""
        if self._channel is None:
            raise DeviceDisconnected(f"{self.name}: not open")
        payload = rtde.encode_data_package(self._recipe_id, rtde.INPUT_RECIPE_TYPES, rtde.encode_request(request))
        try:
            self._channel.send(rtde.DATA_PACKAGE, payload)
        except DeviceDisconnected:
            self.close()
            raise

    def close(self) -> None:
        if self._channel is not None:
            self._channel.close()
        self._channel = None

    def _transact(self, message_type: int, payload: bytes = b"") -> bytes:
        assert self._channel is not None
        self._channel.send(message_type, payload)
        deadline = time.monotonic() + self.timeout_s
        while True:
            try:
                answer_type, answer = self._channel.receive(deadline)
            except DeviceTimeout as exc:
                raise DeviceTimeout(f"{self.name}: no answer to message {chr(message_type)!r} within "
                                    f"{self.timeout_s:g} s") from exc
            if answer_type == message_type:
                return answer
            if answer_type == rtde.TEXT_MESSAGE:
                log.warning("%s: controller says: %s", self.name, rtde.decode_text_message(answer))
                continue
            raise DeviceProtocolError(f"{self.name}: expected an answer to {chr(message_type)!r}, got "
                                      f"{chr(answer_type)!r}")

    def _check_recipe(self, recipe_id: int, types: list[str]) -> None:
        named = dict(zip(rtde.INPUT_RECIPE, types, strict=False))
        if in_use := [n for n, t in named.items() if t == rtde.IN_USE]:
            raise DeviceBusy(f"{self.name}: input registers already in use by another client (a fieldbus "
                              f"adapter, another RTDE client?): {in_use}")
        if missing := [n for n, t in named.items() if t == rtde.NOT_FOUND]:
            raise DeviceProtocolError(f"{self.name}: controller does not know {missing} (PolyScope too old?)")
        if recipe_id == 0 or list(types) != list(rtde.INPUT_RECIPE_TYPES):
            raise DeviceProtocolError(f"{self.name}: input recipe refused: id {recipe_id}, types {types}")


class UrRobot(HandshakeRobot):
    """:class:`~monoguide.drivers.robot.Robot` for a Universal Robots controller (CB3 / e-Series)."""

    def __init__(self, host: str, port: int = rtde.DEFAULT_PORT, *, frequency_hz: float = 125.0,
                 connect_timeout_s: float = 3.0, move_timeout_s: float = 30.0, ack_timeout_s: float = 2.0,
                 stale_timeout_s: float = 1.0, T_b_f_taught: tuple[np.ndarray, ...] = (),
                 pose_tolerance_mm: float = 1.0, pose_tolerance_deg: float = 0.1) -> None:
        if port != rtde.DEFAULT_PORT:
            raise ValueError(f"RTDE port {port}: ur_rtde connects to {rtde.DEFAULT_PORT} only")
        super().__init__(f"UR robot {host}:{port}", host, port, connect_timeout_s=connect_timeout_s,
                         move_timeout_s=move_timeout_s, ack_timeout_s=ack_timeout_s, stale_timeout_s=stale_timeout_s,
                         T_b_f_taught=T_b_f_taught, pose_tolerance_mm=pose_tolerance_mm,
                         pose_tolerance_deg=pose_tolerance_deg)
        self.frequency_hz = frequency_hz
        self._worker = RtdeReceiveWorker(self.name)
        self._inputs = RtdeInputClient(host, port, connect_timeout_s)
        self._last_timestamp: tuple[float, float] | None = None  # controller's, ours when it last changed
        self._next_status_watch = 0.0  # watch(): when the receive side is asked next

    @property
    def worker_restarts(self) -> int:
        return self._worker.restarts

    def status(self) -> RobotStatus:
        self._ensure_connected()
        answer = self._worker.read(list(rtde.ANSWER_REGISTERS), self.connect_timeout_s)
        timestamp = float(answer["timestamp"])
        now = time.monotonic()
        if self._last_timestamp is None or timestamp != self._last_timestamp[0]:
            self._last_timestamp = (timestamp, now)
        elif now - self._last_timestamp[1] > self.stale_timeout_s:
            raise DeviceTimeout(f"{self.name}: no new data from the controller for "
                                f"{now - self._last_timestamp[1]:.1f} s (controller stalled?)")
        ack, in_position, program_status, held, valid = (int(v) for v in answer["registers"])
        return RobotStatus(
            T_b_f=ur_pose_to_T(np.array(answer["pose"], dtype=float)),
            mode=ROBOT_MODES.get(int(answer["robot_mode"]), f"MODE_{answer['robot_mode']}"),
            safety=SAFETY_MODES.get(int(answer["safety_mode"]), f"SAFETY_{answer['safety_mode']}"),
            program_running=int(answer["runtime_state"]) == RUNTIME_PLAYING,
            in_position=in_position, ack_sequence=ack, program_status=program_status, timestamp_s=timestamp,
            held_sequence=held, offset_valid=valid == 1,
        )

    def watch(self) -> None:
        """The input link at every call (a look at its socket, no wait); the receive side (the worker's state, stale
        data) every :data:`WATCH_STATUS_S`: a question to the worker process costs a millisecond or so."""
        if not self._worker.alive or not self._inputs.is_open:
            raise DeviceDisconnected(f"{self.name}: not connected")
        if self._inputs.closed_by_controller():
            self._inputs.close()
            raise DeviceDisconnected(f"{self.name}: the controller closed the RTDE input connection")
        if (now := time.monotonic()) >= self._next_status_watch:
            self._next_status_watch = now + WATCH_STATUS_S
            self.status()  # both links open: no reconnect; the receive side's loss or stale data raises

    def close(self) -> None:
        self._inputs.close()
        self._worker.stop()

    # --- private -------------------------------------------------------------------------------

    def _connect(self) -> None:
        self._worker.connect(self.host, self.frequency_hz, list(rtde.OUTPUT_RECIPE), self.connect_timeout_s)
        self._last_timestamp = None
        self._inputs.close()
        version = self._inputs.open()
        # the handshake is synchronised (sequence 0) before the first request: HandshakeRobot._synchronise
        self._connected(self._first_status())
        self._identity = RobotIdentity("Universal Robots", f"UR (RTDE, {'e-Series' if version[0] >= 5 else 'CB3'})",
                                       "", ".".join(str(v) for v in version), f"{self.host}:{self.port}")
        log.info("%s: connected, controller %s", self.name, self._identity.software)

    def _first_status(self) -> RobotStatus:
        deadline = time.monotonic() + self.connect_timeout_s
        while True:
            answer = self._worker.read(list(rtde.ANSWER_REGISTERS), self.connect_timeout_s)
            if float(answer["timestamp"]) > 0 or time.monotonic() > deadline:
                return self.status()
            time.sleep(POLL_S)

    def _ensure_connected(self) -> None:
        if not self._worker.alive or not self._inputs.is_open:
            if (ended := self._worker.exit_status) is not None:
                log.error("%s: the ur_rtde worker process ended by itself (status %d); restarting it", self.name,
                          ended)
            log.warning("%s: reconnecting", self.name)
            self._connect()

    def _send_request(self, sequence: int, command: int, pose_number: int, D_b: np.ndarray) -> None:
        offset = rtde.offset_to_ur(D_b) if command == COMMAND_OFFSET else (0.0,) * 6
        self._inputs.send_request(rtde.RobotRequest(sequence, command, pose_number, offset))  # type: ignore[arg-type]
