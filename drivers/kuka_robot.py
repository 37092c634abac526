"""The KUKA adapter of the robot port: the XML channel of ``docs/robot-interface.md`` over TCP.

Three layers: :class:`XmlChannel` moves whole XML messages over the socket with a deadline;
:mod:`monoguide.drivers.kuka_protocol` frames, encodes and decodes them; :class:`KukaRobot` gives them their
meaning (reports -> :class:`RobotStatus`, requests with sequence numbers, waiting for in position and for
the acknowledgement). The robot reports continuously (its program's timer interrupt, whether or not a request
came: the daemon never waits for a report it would have to ask for); the adapter keeps the latest report, and a
report older than ``stale_timeout_s`` means the controller has stalled.

EKI serves one client, and after a disconnect only the robot program's ``EKI_Open`` serves again: a connection
refused, or closed before its first report, is tried again until ``connect_timeout_s`` has passed.
"""

from __future__ import annotations

import logging
import socket
import time

import numpy as np

from monoguide.drivers import kuka_protocol as kuka
from monoguide.drivers.errors import (
    DeviceDisconnected,
    DeviceNotFound,
    DeviceTimeout,
)
from monoguide.drivers.robot import (
    COMMAND_OFFSET,
    HandshakeRobot,
    RobotIdentity,
    RobotStatus,
)
from monoguide.solver.frames import T_to_kuka_frame, kuka_frame_to_T

log = logging.getLogger(__name__)

POLL_S = 0.01
RECONNECT_PAUSE_S = 0.05  # between two attempts while the robot program has not yet reopened its channel


class XmlChannel:
    """Bytes on the wire: send one message; receive whole ``<Robot>`` messages before a deadline."""

    def __init__(self, sock: socket.socket, name: str) -> None:
        self._sock = sock
        self._name = name
        self._buffer = bytearray()

    def send(self, message: bytes) -> None:
        try:
            self._sock.sendall(message)
        except OSError as exc:
            raise DeviceDisconnected(f"{self._name}: send failed: {exc}") from exc

    def receive(self, wait_s: float) -> list[bytes]:
        """Every whole message that arrives within ``wait_s`` of the first byte (at least one read; 0: only
        what is there now). Empty when nothing came."""
        messages: list[bytes] = []
        timeout = wait_s
        while True:
            self._sock.settimeout(timeout if timeout > 0 else 0.0)
            try:
                chunk = self._sock.recv(65536)
            except (TimeoutError, BlockingIOError):
                return messages
            except OSError as exc:
                raise DeviceDisconnected(f"{self._name}: receive failed: {exc}") from exc
            if not chunk:
                raise DeviceDisconnected(f"{self._name}: the controller closed the connection")
            self._buffer.extend(chunk)
            messages.extend(kuka.split_messages(self._buffer, kuka.ROBOT_ROOT))
            timeout = 0.0  # then take whatever else is already there, without waiting

    def close(self) -> None:
        try:
            self._sock.close()
        except OSError as exc:
            log.warning("%s: close failed: %s", self._name, exc)


class KukaRobot(HandshakeRobot):
    """:class:`~monoguide.drivers.robot.Robot` for a KUKA controller running ``config/kuka/monoguide.src``."""

    def __init__(self, host: str, port: int = kuka.DEFAULT_PORT, *, connect_timeout_s: float = 3.0,
                 move_timeout_s: float = 30.0, ack_timeout_s: float = 2.0, stale_timeout_s: float = 1.0,
                 T_b_f_taught: tuple[np.ndarray, ...] = (), pose_tolerance_mm: float = 1.0,
                 pose_tolerance_deg: float = 0.1) -> None:
        super().__init__(f"KUKA robot {host}:{port}", host, port, connect_timeout_s=connect_timeout_s,
                         move_timeout_s=move_timeout_s, ack_timeout_s=ack_timeout_s, stale_timeout_s=stale_timeout_s,
                         T_b_f_taught=T_b_f_taught, pose_tolerance_mm=pose_tolerance_mm,
                         pose_tolerance_deg=pose_tolerance_deg)
        self._channel: XmlChannel | None = None
        self._latest: kuka.KukaReport | None = None
        self._latest_at = 0.0

    def status(self) -> RobotStatus:
        if self._channel is None:
            log.warning("%s: reconnecting", self.name)
            self._connect()
        self._pump(0.0)
        if time.monotonic() - self._latest_at > self.stale_timeout_s:
            self._pump(self.stale_timeout_s)
            if time.monotonic() - self._latest_at > self.stale_timeout_s:
                raise DeviceTimeout(f"{self.name}: no report from the controller for "
                                    f"{time.monotonic() - self._latest_at:.1f} s (controller stalled?)")
        assert self._latest is not None
        return report_to_status(self._latest)

    def watch(self) -> None:
        if self._channel is None:
            raise DeviceDisconnected(f"{self.name}: not connected")
        self._pump(0.0)  # what has arrived; the controller's close is DeviceDisconnected
        if (silent := time.monotonic() - self._latest_at) > self.stale_timeout_s:
            raise DeviceTimeout(f"{self.name}: no report from the controller for {silent:.1f} s (controller "
                                "stalled, or its program stopped?)")

    def close(self) -> None:
        if self._channel is not None:
            self._channel.close()
        self._channel = None

    # --- private -------------------------------------------------------------------------------

    def _connect(self) -> None:
        deadline = time.monotonic() + self.connect_timeout_s
        while True:
            try:
                self._open_channel(deadline)
                break
            except (DeviceNotFound, DeviceDisconnected) as exc:
                self.close()
                if time.monotonic() + RECONNECT_PAUSE_S > deadline:
                    raise DeviceNotFound(f"{self.name}: cannot connect within {self.connect_timeout_s:g} s: "
                                         f"{exc.message}") from exc
                time.sleep(RECONNECT_PAUSE_S)  # the program reopens its channel only after it noticed the last close
        assert self._latest is not None
        identity = self._reported_identity or ("KUKA", "unknown", "", "")
        self._identity = RobotIdentity(*identity, address=f"{self.host}:{self.port}")
        # the handshake is synchronised (sequence 0) before the first request: HandshakeRobot._synchronise
        self._connected(report_to_status(self._latest))
        log.info("%s: connected: %s %s, %s", self.name, *identity[:2], identity[3])

    def _open_channel(self, deadline: float) -> None:
        """One connection attempt, until its first report."""
        try:
            sock = socket.create_connection((self.host, self.port),
                                            timeout=max(0.05, min(self.connect_timeout_s, deadline - time.monotonic())))
        except OSError as exc:
            raise DeviceNotFound(f"{self.name}: cannot connect: {exc}") from exc
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._channel = XmlChannel(sock, self.name)
        self._latest = None
        self._reported_identity: tuple[str, str, str, str] | None = None
        while self._latest is None:
            if time.monotonic() > deadline:
                raise DeviceTimeout(f"{self.name}: no report within {self.connect_timeout_s:g} s of connecting")
            self._pump(max(0.0, deadline - time.monotonic()))

    def _pump(self, wait_s: float) -> None:
        assert self._channel is not None
        try:
            messages = self._channel.receive(wait_s)
            for message in messages:
                report = kuka.decode_report(message)
                if report.identity is not None:
                    self._reported_identity = report.identity
                self._latest, self._latest_at = report, time.monotonic()
        except DeviceDisconnected:
            self.close()
            raise

    def _send(self, request: kuka.KukaRequest) -> None:
        assert self._channel is not None
        try:
            self._channel.send(kuka.encode_request(request))
        except DeviceDisconnected:
            self.close()
            raise

    def _send_request(self, sequence: int, command: int, pose_number: int, D_b: np.ndarray) -> None:
        offset = T_to_kuka_frame(D_b) if command == COMMAND_OFFSET else (0.0,) * 6
        self._send(kuka.KukaRequest(sequence, command, pose_number, offset))

    def _pause(self) -> None:
        self._pump(POLL_S)


def report_to_status(report: kuka.KukaReport) -> RobotStatus:
    """A KUKA report in the port's words: the frame (mm, A B C deg) becomes ``T_b_f``."""
    return RobotStatus(
        T_b_f=kuka_frame_to_T(*report.pos), mode=report.mode, safety=report.safety,
        program_running=report.program_running, in_position=report.in_position, ack_sequence=report.ack_sequence,
        program_status=report.program_status, timestamp_s=report.ipoc / 1000.0,
        held_sequence=report.held_sequence, offset_valid=report.offset_valid,
    )
