"""The laser-tracker port and its serial adapter (pyserial, line protocol of ``docs/tracker-protocol.md``).

Three layers with one job each: :class:`SerialLineChannel` moves lines over the wire with a deadline;
:mod:`monoguide.drivers.tracker_protocol` encodes and decodes them; :class:`SerialLaserTracker` gives
them their meaning (identify, set units, measure a point). Every read and every write has a deadline;
replies are matched to requests by tag, and a late reply to an earlier (timed-out) request is logged and
dropped. The port is opened exclusively (a second client gets :class:`DeviceBusy`, not garbled replies),
and one lock per tracker keeps calls from worker threads from interleaving their requests.
"""

from __future__ import annotations

import errno
import logging
import math
import threading
import time
from typing import Protocol, runtime_checkable

import serial

from monoguide.drivers.errors import (
    DeviceBusy,
    DeviceDisconnected,
    DeviceNotFound,
    DeviceProtocolError,
    DeviceRequestInvalid,
    DeviceSettingRejected,
    DeviceTimeout,
)
from monoguide.drivers.tracker_protocol import (
    CMD_IDENTIFY,
    CMD_MEASURE_POINT,
    CMD_SET_UNIT,
    MAX_LINE_BYTES,
    MAX_TAG,
    Reply,
    TrackerIdentity,
    TrackerMeasurement,
    check_request_word,
    decode_reply,
    encode_request,
    parse_identity,
    parse_measurement,
    parse_unit,
    raise_for_error,
)

log = logging.getLogger(__name__)

DEFAULT_BAUD = 115200
DEFAULT_TIMEOUT_S = 2.0


@runtime_checkable
class LaserTracker(Protocol):
    """What the cycle and the calibration wizard need from a laser tracker. Points are in the tracker's
    own frame, in millimetres."""

    def open(self) -> TrackerIdentity:
        """Connect, identify the tracker and set millimetres; returns its identity."""
        ...

    @property
    def identity(self) -> TrackerIdentity | None: ...

    def measure_point(self, nest: str | None = None, timeout_s: float | None = None) -> TrackerMeasurement:
        """Measure the SMR in ``nest`` (``None``: wherever the beam is locked)."""
        ...

    def close(self) -> None: ...


class SerialLineChannel:
    """Bytes on the wire: write one line, read one line, each before a deadline, over an open
    ``serial.Serial``."""

    def __init__(self, port: serial.Serial, name: str) -> None:
        self._port = port
        self._name = name
        self._buffer = bytearray()

    def write_line(self, line: bytes, deadline: float) -> None:
        """Send ``line`` and wait until it has left the output buffer, both before ``deadline``
        (``time.monotonic()``); else :class:`DeviceTimeout` (flow control held off, nobody reading).
        Unlike ``serial.Serial.flush()`` (``tcdrain``, no timeout), the wait polls the output queue."""
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            raise DeviceTimeout(f"{self._name}: no time left to send {line[:40]!r}")
        try:
            self._port.write_timeout = remaining
            self._port.write(line)
            while self._port.out_waiting > 0:
                if time.monotonic() >= deadline:
                    self._port.reset_output_buffer()
                    raise DeviceTimeout(f"{self._name}: {line[:40]!r} did not leave the output buffer in time "
                                        f"(flow control held off?)")
                time.sleep(0.002)
        except serial.SerialTimeoutException as exc:
            raise DeviceTimeout(f"{self._name}: writing {line[:40]!r} timed out (nobody reading?)") from exc
        except (serial.SerialException, OSError) as exc:
            raise DeviceDisconnected(f"{self._name}: write failed: {exc}") from exc

    def read_line(self, deadline: float) -> bytes:
        """One line (without its end) received before ``deadline`` (``time.monotonic()``), else
        :class:`DeviceTimeout`."""
        while True:
            end = self._buffer.find(b"\n")
            if end >= 0:
                line = bytes(self._buffer[:end]).rstrip(b"\r")
                del self._buffer[: end + 1]
                return line
            if len(self._buffer) > MAX_LINE_BYTES:
                junk = bytes(self._buffer[:40])
                self._buffer.clear()
                raise DeviceProtocolError(f"{self._name}: no line end within {MAX_LINE_BYTES} bytes: {junk!r}...")
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise DeviceTimeout(f"{self._name}: no reply in time")
            try:
                self._port.timeout = min(remaining, 0.2)
                chunk = self._port.read(max(1, self._port.in_waiting))
            except (serial.SerialException, OSError) as exc:
                raise DeviceDisconnected(f"{self._name}: read failed (device gone?): {exc}") from exc
            self._buffer.extend(chunk)

    def discard_input(self) -> None:
        self._buffer.clear()
        try:
            self._port.reset_input_buffer()
        except (serial.SerialException, OSError) as exc:
            raise DeviceDisconnected(f"{self._name}: {exc}") from exc


class SerialLaserTracker:
    """:class:`LaserTracker` over a serial line (RS-232 or a USB adapter; a pty for the simulator).
    Thread-safe: each call holds the tracker's lock for its whole request/reply exchange."""

    def __init__(self, port: str, baud: int = DEFAULT_BAUD, timeout_s: float = DEFAULT_TIMEOUT_S) -> None:
        self.port = port
        self.baud = baud
        self.timeout_s = timeout_s
        self._serial: serial.Serial | None = None
        self._channel: SerialLineChannel | None = None
        self._identity: TrackerIdentity | None = None
        self._unit = "MM"
        self._last_tag = 0
        self._lock = threading.RLock()

    @property
    def identity(self) -> TrackerIdentity | None:
        return self._identity

    def open(self) -> TrackerIdentity:
        with self._lock:
            if self._serial is not None:
                raise DeviceBusy(f"tracker on {self.port}: already open")
            self._serial = _open_exclusively(self.port, self.baud, self.timeout_s)
            self._channel = SerialLineChannel(self._serial, f"tracker on {self.port}")
            try:
                self._channel.discard_input()  # stale replies from an earlier client are not ours
                self._identity = parse_identity(self._transact(CMD_IDENTIFY))
                self._unit = parse_unit(self._transact(CMD_SET_UNIT, "MM"))
            except BaseException:
                self.close()
                raise
            log.info("tracker on %s: %s", self.port, self._identity)
            return self._identity

    def measure_point(self, nest: str | None = None, timeout_s: float | None = None) -> TrackerMeasurement:
        """The SMR in ``nest`` (``None``: wherever the beam is locked). A nest name the protocol cannot carry
        (empty, a space, not ASCII) is :class:`DeviceRequestInvalid`, and nothing is sent."""
        args = () if nest is None else (check_request_word(nest),)
        with self._lock:
            reply = self._transact(CMD_MEASURE_POINT, *args, timeout_s=timeout_s)
            return parse_measurement(reply, self._unit, nest)

    def close(self) -> None:
        with self._lock:
            if self._serial is not None:
                try:
                    self._serial.close()
                except (serial.SerialException, OSError) as exc:
                    log.warning("tracker on %s: close failed: %s", self.port, exc)
            self._serial = None
            self._channel = None

    def __enter__(self) -> SerialLaserTracker:
        self.open()
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    # --- private -------------------------------------------------------------------------------

    def _transact(self, command: str, *args: str, timeout_s: float | None = None) -> Reply:
        """Send one request and return its reply (error replies raised); replies with another tag are
        late answers to earlier requests and are dropped."""
        if self._channel is None:
            raise DeviceDisconnected(f"tracker on {self.port}: not open")
        self._last_tag = self._last_tag % MAX_TAG + 1
        tag = self._last_tag
        timeout = self.timeout_s if timeout_s is None else timeout_s
        if not isinstance(timeout, int | float) or not math.isfinite(timeout) or timeout <= 0:
            raise DeviceRequestInvalid(f"tracker on {self.port}: timeout {timeout!r} s must be a finite number > 0")
        deadline = time.monotonic() + timeout
        self._channel.write_line(encode_request(tag, command, *args), deadline)
        while True:
            try:
                line = self._channel.read_line(deadline)
            except DeviceTimeout as exc:
                raise DeviceTimeout(f"tracker on {self.port}: no reply to {command} within {timeout:g} s") from exc
            reply = decode_reply(line)
            if reply.tag == 0 and not reply.ok:
                raise_for_error(reply, command)  # the tracker could not read our request
            if reply.tag != tag:
                log.warning("tracker on %s: dropping late reply %r (waiting for tag %d)", self.port, line, tag)
                continue
            raise_for_error(reply, command)
            return reply


def _open_exclusively(port: str, baud: int, timeout_s: float) -> serial.Serial:
    """Open ``port`` with an exclusive lock (``flock``): a second client gets :class:`DeviceBusy`."""
    try:
        return serial.Serial(port, baud, timeout=0.2, write_timeout=timeout_s, exclusive=True)
    except ValueError as exc:  # pyserial's word for an impossible setting (baud rate, ...)
        raise DeviceSettingRejected(f"tracker on {port}: baud {baud!r}: {exc}") from exc
    except (serial.SerialException, OSError) as exc:
        if getattr(exc, "errno", None) in (errno.EAGAIN, errno.EWOULDBLOCK) or "exclusively lock" in str(exc):
            raise DeviceBusy(f"tracker on {port}: the port is in use by another client (locked); close it "
                             f"there first") from exc
        raise DeviceNotFound(f"tracker on {port}: cannot open the port: {exc}") from exc
