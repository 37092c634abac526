"""Message encoding of the laser-tracker line protocol (``docs/tracker-protocol.md``), without any I/O.

A request is ``<tag> <COMMAND>[ <arg>...]\\n``; a reply echoes the tag: ``<tag> OK[ <field>...]\\n`` or
``<tag> ERR <code> <text>\\n``. The tag lets the client match replies to requests, so a late reply is
recognised as late and never taken for the answer to the next request. The client
(:mod:`monoguide.drivers.tracker`) and the simulator (:mod:`monoguide.drivers.sim.tracker`) both use
these functions; they can be tested without a port.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from monoguide.drivers.errors import DeviceFault, DeviceProtocolError, DeviceRequestInvalid

MAX_LINE_BYTES = 256
MAX_TAG = 999_999
UNIT_TO_MM = {"MM": 1.0, "M": 1000.0, "IN": 25.4}

CMD_IDENTIFY = "*IDN?"
CMD_SET_UNIT = "UNIT:LEN"
CMD_GET_UNIT = "UNIT:LEN?"
CMD_MEASURE_POINT = "MEAS:POINT?"
CMD_LIST_NESTS = "NEST:LIST?"
CMD_SIM_FAULT = "SIM:FAULT"  # simulator only: a real tracker answers E100

# Error codes of the protocol. E1xx: the request was not understood; E2xx: the tracker could not measure.
E_UNKNOWN_COMMAND = "E100"
E_BAD_ARGUMENT = "E101"
E_MALFORMED = "E102"
E_BEAM_BROKEN = "E200"
E_UNKNOWN_NEST = "E201"
E_UNSTABLE = "E202"


@dataclass(frozen=True)
class Request:
    """One decoded request line."""

    tag: int
    command: str
    args: tuple[str, ...] = ()


@dataclass(frozen=True)
class Reply:
    """One decoded reply line: ``ok`` with ``fields``, or an error ``error_code`` with ``error_text``."""

    tag: int
    ok: bool
    fields: tuple[str, ...] = ()
    error_code: str = ""
    error_text: str = ""


@dataclass(frozen=True)
class TrackerIdentity:
    vendor: str
    model: str
    serial: str
    firmware: str


@dataclass(frozen=True)
class TrackerMeasurement:
    """One measured SMR centre in the tracker's frame: ``point_mm`` (3,), its ``rms_mm``, and the
    tracker's own running ``measurement_number``; ``nest`` is the nest asked for (``None``: where the
    beam was)."""

    point_mm: np.ndarray
    rms_mm: float
    measurement_number: int
    nest: str | None = None


# --- requests ----------------------------------------------------------------------------------


def encode_request(tag: int, command: str, *args: str) -> bytes:
    """``(17, "MEAS:POINT?", "B1")`` -> ``b"17 MEAS:POINT? B1\\n"``. A request the protocol cannot carry
    raises :class:`DeviceRequestInvalid` naming the value (nothing is sent)."""
    if isinstance(tag, bool) or not isinstance(tag, int) or not 1 <= tag <= MAX_TAG:
        raise DeviceRequestInvalid(f"tracker request tag {tag!r} outside 1..{MAX_TAG}")
    for word in (command, *args):
        check_request_word(word)
    line = " ".join((str(tag), command, *args)).encode("ascii") + b"\n"
    if len(line) > MAX_LINE_BYTES:
        raise DeviceRequestInvalid(f"tracker request {line[:40]!r}... longer than {MAX_LINE_BYTES} bytes")
    return line


def check_request_word(word: str) -> str:
    """``word`` if it can be one word of a request (a command, a nest name): non-empty printable ASCII
    without spaces; else :class:`DeviceRequestInvalid` naming it."""
    if (not isinstance(word, str) or not word or not word.isascii() or not word.isprintable()
            or any(c.isspace() for c in word)):
        raise DeviceRequestInvalid(f"tracker request word {word!r} must be non-empty printable ASCII "
                                   f"without spaces")
    return word


def decode_request(line: bytes) -> Request:
    """Decode one request line (without or with its line end); raises :class:`DeviceProtocolError`."""
    words = _ascii_words(line)
    if len(words) < 2:
        raise DeviceProtocolError(f"request needs a tag and a command, got {line!r}")
    tag = _parse_tag(words[0], line)
    if tag == 0:
        raise DeviceProtocolError(f"request tag must be 1..{MAX_TAG}: {line!r}")
    return Request(tag, words[1].upper(), tuple(words[2:]))


# --- replies -----------------------------------------------------------------------------------


def encode_ok(tag: int, *fields: str) -> bytes:
    return " ".join((str(tag), "OK", *fields)).encode("ascii") + b"\n"


def encode_error(tag: int, error_code: str, text: str) -> bytes:
    return f"{tag} ERR {error_code} {text}".encode("ascii", "replace") + b"\n"


def decode_reply(line: bytes) -> Reply:
    """Decode one reply line; anything that is not ``<tag> OK ...`` or ``<tag> ERR <code> <text>`` raises
    :class:`DeviceProtocolError` quoting the line."""
    words = _ascii_words(line)
    if len(words) < 2:
        raise DeviceProtocolError(f"tracker reply is not '<tag> OK|ERR ...': {line!r}")
    tag = _parse_tag(words[0], line)
    if words[1] == "OK":
        return Reply(tag, True, tuple(words[2:]))
    if words[1] == "ERR" and len(words) >= 3:
        return Reply(tag, False, (), words[2], " ".join(words[3:]))
    raise DeviceProtocolError(f"tracker reply is not '<tag> OK|ERR ...': {line!r}")


# --- meaning -----------------------------------------------------------------------------------


def raise_for_error(reply: Reply, command: str) -> None:
    """Turn an error reply into its exception: E1xx (request not understood) -> :class:`DeviceProtocolError`,
    anything else (E2xx: could not measure, e.g. beam broken) -> :class:`DeviceFault`. The tracker's own
    code is in the message."""
    if reply.ok:
        return
    message = f"tracker refused {command}: {reply.error_code} {reply.error_text}".rstrip()
    if reply.error_code.startswith("E1"):
        raise DeviceProtocolError(message)
    raise DeviceFault(message)


def parse_identity(reply: Reply) -> TrackerIdentity:
    """``OK <vendor>,<model>,<serial>,<firmware>`` -> :class:`TrackerIdentity` (words may contain spaces)."""
    parts = [p.strip() for p in " ".join(reply.fields).split(",")]
    if len(parts) != 4 or not all(parts):
        raise DeviceProtocolError(f"identity must be 'vendor,model,serial,firmware', got {reply.fields!r}")
    return TrackerIdentity(*parts)


def parse_unit(reply: Reply) -> str:
    if len(reply.fields) != 1 or reply.fields[0] not in UNIT_TO_MM:
        raise DeviceProtocolError(f"unit reply must be one of {sorted(UNIT_TO_MM)}, got {reply.fields!r}")
    return reply.fields[0]


def parse_measurement(reply: Reply, unit: str, nest: str | None = None) -> TrackerMeasurement:
    """``OK <x> <y> <z> <rms> <n>`` in ``unit`` -> :class:`TrackerMeasurement` in millimetres."""
    if len(reply.fields) != 5:
        raise DeviceProtocolError(f"measurement must be 'x y z rms number', got {reply.fields!r}")
    try:
        x, y, z, rms = (float(f) for f in reply.fields[:4])
        number = int(reply.fields[4])
    except ValueError as exc:
        raise DeviceProtocolError(f"measurement has a non-numeric field: {reply.fields!r}") from exc
    if not all(math.isfinite(v) for v in (x, y, z, rms)) or rms < 0:
        raise DeviceProtocolError(f"measurement must be finite with rms >= 0, got {reply.fields!r}")
    scale = UNIT_TO_MM[unit]
    return TrackerMeasurement(np.array([x, y, z]) * scale, rms * scale, number, nest)


def format_measurement(point_mm: np.ndarray, rms_mm: float, number: int, unit: str) -> tuple[str, ...]:
    """The fields of a measurement reply, in ``unit`` (the simulator's side of :func:`parse_measurement`)."""
    scale = UNIT_TO_MM[unit]
    decimals = 4 if unit == "MM" else 7
    values = [*(float(v) / scale for v in point_mm), rms_mm / scale]
    return (*(f"{v:.{decimals}f}" for v in values), str(number))


# --- private -----------------------------------------------------------------------------------


def _ascii_words(line: bytes) -> list[str]:
    if len(line) > MAX_LINE_BYTES:
        raise DeviceProtocolError(f"line longer than {MAX_LINE_BYTES} bytes: {line[:40]!r}...")
    try:
        text = line.decode("ascii")
    except UnicodeDecodeError as exc:
        raise DeviceProtocolError(f"line is not ASCII: {line!r}") from exc
    if any(not c.isprintable() for c in text.rstrip("\r\n")):
        raise DeviceProtocolError(f"line has control characters: {line!r}")
    return text.split()


def _parse_tag(word: str, line: bytes) -> int:
    # Tag 0 only appears in error replies to a request the tracker could not read (no tag to echo).
    if not word.isdigit() or not 0 <= int(word) <= MAX_TAG:
        raise DeviceProtocolError(f"line does not start with a tag 0..{MAX_TAG}: {line!r}")
    return int(word)
