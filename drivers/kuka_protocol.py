"""Framing and encoding of the KUKA XML channel (in the style of KUKA.Ethernet KRL), without any I/O.

The robot controller serves one TCP port (EKI ``<EXTERNAL><TYPE>Client``: the daemon is the client). Both
sides send XML documents back to back; a document ends with its root's end tag, which is how EKI finds
message ends too. The robot sends ``<Robot>`` reports; the daemon sends ``<Sensor>`` requests
(``docs/robot-interface.md`` has the schema):

    <Robot><State Mode="AUT" Safety="NORMAL" Program="1"/><Pos X=".." Y=".." Z=".." A=".." B=".." C=".."/>
      <Handshake Ack="17" InPosition="2" Status="0" Held="16" Valid="1"/><Ipoc>123456</Ipoc></Robot>
    <Sensor><Request Seq="18" Command="2" Pose="0"/><Offset X=".." Y=".." Z=".." A=".." B=".." C=".."/></Sensor>

Lengths in mm, angles in degrees, A B C the Z-Y'-X'' Euler angles of KUKA frames. Numbers go out as fixed-point
decimals (``-12.500000``), never in exponent form (``3e-05``), which KRL's REAL reading is not documented to take;
six decimals are 1 nm and 1e-6 deg, finer than the REAL (about 7 significant digits) that stores them. The parser
refuses any
document type declaration (defusedxml, ``forbid_dtd``), so an entity-expansion bomb is refused before it
expands; anything malformed, truncated, oversized or unexpected is :class:`RobotMessageInvalid` quoting it.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from xml.sax.saxutils import quoteattr

import defusedxml.ElementTree as SafeET
from defusedxml import DefusedXmlException

from monoguide.drivers.errors import RobotMessageInvalid

DEFAULT_PORT = 54600
MAX_MESSAGE_BYTES = 2048  # EKI's own limit per message is of this order; ours are a few hundred bytes
ROBOT_ROOT = "Robot"
SENSOR_ROOT = "Sensor"
FRAME_KEYS = ("X", "Y", "Z", "A", "B", "C")
MAX_ABS_MM = 1e5  # no robot reaches 100 m: a bigger number is a broken message
MAX_ABS_DEG = 360.0
REQUEST_DECIMALS = 6  # the daemon's numbers: 1 nm, 1e-6 deg
REPORT_DECIMALS = 9  # the simulated controller's (a real one writes what EKI_SetReal makes of a REAL)


@dataclass(frozen=True)
class KukaRequest:
    """A daemon request: ``sequence``, ``command`` (``robot.COMMAND_*``), ``pose_number`` (1-based; 0 if
    not a move) and ``offset`` the base offset as a KUKA frame (X Y Z mm, A B C deg)."""

    sequence: int
    command: int
    pose_number: int
    offset: tuple[float, float, float, float, float, float] = (0.0,) * 6


@dataclass(frozen=True)
class KukaReport:
    """A robot report: its modes, the actual flange frame ``pos`` (X Y Z mm, A B C deg), the handshake, the
    interpolation clock ``ipoc`` (ms) and, in the first report of a connection, who it is."""

    mode: str
    safety: str
    program_running: bool
    pos: tuple[float, float, float, float, float, float]
    ack_sequence: int
    in_position: int
    program_status: int
    ipoc: int
    identity: tuple[str, str, str, str] | None = None  # vendor, model, serial, software
    held_sequence: int = 0  # the number of the offset the program took last (0: none)
    offset_valid: bool = False  # its grasp interlock


# --- framing -----------------------------------------------------------------------------------


def split_messages(buffer: bytearray, root: str, max_bytes: int = MAX_MESSAGE_BYTES) -> list[bytes]:
    """Take every whole ``<root>...</root>`` document off the front of ``buffer`` (which keeps the rest).
    More than ``max_bytes`` without an end tag, or a message over ``max_bytes``, is
    :class:`RobotMessageInvalid` (the buffer is cleared: the stream is out of step)."""
    end_tag = f"</{root}>".encode()
    messages = []
    while (end := buffer.find(end_tag)) >= 0:
        size = end + len(end_tag)
        message = bytes(buffer[:size])
        del buffer[:size]
        if size > max_bytes:
            buffer.clear()
            raise RobotMessageInvalid(f"message of {size} bytes exceeds {max_bytes}: {message[:60]!r}...")
        message = message.strip()
        if message:
            messages.append(message)
    if len(buffer) > max_bytes:
        junk = bytes(buffer[:60])
        buffer.clear()
        raise RobotMessageInvalid(f"no </{root}> within {max_bytes} bytes: {junk!r}...")
    return messages


# --- encoding ----------------------------------------------------------------------------------


def encode_request(request: KukaRequest) -> bytes:
    for name, value in (("sequence", request.sequence), ("command", request.command),
                        ("pose_number", request.pose_number)):
        if not 0 <= value < 2**31:
            raise ValueError(f"{name} {value} outside 0..2^31-1")
    offset = _checked_frame(request.offset, ValueError, "offset")
    return (f'<{SENSOR_ROOT}><Request Seq="{request.sequence}" Command="{request.command}" '
            f'Pose="{request.pose_number}"/>{_frame_xml("Offset", offset, REQUEST_DECIMALS)}</{SENSOR_ROOT}>'
            ).encode("ascii")


def decode_request(message: bytes) -> KukaRequest:
    """The simulated robot's side of :func:`encode_request`."""
    root = parse(message, SENSOR_ROOT)
    r = _child(root, "Request")
    return KukaRequest(_int(r, "Seq"), _int(r, "Command"), _int(r, "Pose"), _frame(_child(root, "Offset")))


def encode_report(report: KukaReport) -> bytes:
    parts = [f"<{ROBOT_ROOT}>"]
    if report.identity is not None:
        vendor, model, serial, software = (quoteattr(v) for v in report.identity)
        parts.append(f"<Identity Vendor={vendor} Model={model} Serial={serial} Software={software}/>")
    parts += [
        f"<State Mode={quoteattr(report.mode)} Safety={quoteattr(report.safety)} "
        f'Program="{1 if report.program_running else 0}"/>',
        _frame_xml("Pos", report.pos, REPORT_DECIMALS),
        f'<Handshake Ack="{report.ack_sequence}" InPosition="{report.in_position}" Status="{report.program_status}" '
        f'Held="{report.held_sequence}" Valid="{1 if report.offset_valid else 0}"/>',
        f"<Ipoc>{report.ipoc}</Ipoc></{ROBOT_ROOT}>",
    ]
    return "".join(parts).encode("ascii")


def decode_report(message: bytes) -> KukaReport:
    root = parse(message, ROBOT_ROOT)
    state, hs = _child(root, "State"), _child(root, "Handshake")
    ipoc = root.find("Ipoc")
    identity = root.find("Identity")
    try:
        ipoc_value = int((ipoc.text or "").strip()) if ipoc is not None else 0
    except ValueError as exc:
        raise RobotMessageInvalid(f"<Ipoc> is not an integer: {ipoc.text!r}") from exc  # type: ignore[union-attr]
    program = _attr(state, "Program")
    if program not in ("0", "1"):
        raise RobotMessageInvalid(f"<State Program> must be 0 or 1, got {program!r}")
    valid = _attr(hs, "Valid")
    if valid not in ("0", "1"):
        raise RobotMessageInvalid(f"<Handshake Valid> must be 0 or 1, got {valid!r}")
    return KukaReport(
        mode=_attr(state, "Mode"),
        safety=_attr(state, "Safety"),
        program_running=program == "1",
        pos=_frame(_child(root, "Pos")),
        ack_sequence=_int(hs, "Ack"),
        in_position=_int(hs, "InPosition"),
        program_status=_int(hs, "Status"),
        ipoc=ipoc_value,
        identity=None if identity is None else tuple(  # type: ignore[arg-type]
            _attr(identity, k) for k in ("Vendor", "Model", "Serial", "Software")),
        held_sequence=_int(hs, "Held"),
        offset_valid=valid == "1",
    )


def parse(message: bytes, root_tag: str) -> ET.Element:
    """One XML document with root ``root_tag``; no DTD, no entities, no surprises."""
    if len(message) > MAX_MESSAGE_BYTES:
        raise RobotMessageInvalid(f"message of {len(message)} bytes exceeds {MAX_MESSAGE_BYTES}")
    try:
        root = SafeET.fromstring(message, forbid_dtd=True)
    except DefusedXmlException as exc:
        raise RobotMessageInvalid(f"refused XML with a DTD or entities ({type(exc).__name__}): "
                                  f"{message[:60]!r}...") from exc
    except ET.ParseError as exc:
        raise RobotMessageInvalid(f"malformed XML ({exc}): {message[:80]!r}") from exc
    if root.tag != root_tag:
        raise RobotMessageInvalid(f"expected a <{root_tag}> message, got <{root.tag[:40]}>")
    return root


# --- private -----------------------------------------------------------------------------------


def _frame_xml(tag: str, frame: tuple[float, ...], decimals: int) -> str:
    return f"<{tag} " + " ".join(f'{k}="{fixed_point(v, decimals)}"' for k, v in zip(FRAME_KEYS, frame,
                                                                                   strict=True)) + "/>"


def fixed_point(value: float, decimals: int) -> str:
    """``value`` as a fixed-point decimal with ``decimals`` places, never an exponent; -0 is written 0."""
    text = f"{float(value):.{decimals}f}"
    return text[1:] if text.startswith("-") and not text.strip("-0.") else text


def _child(element: ET.Element, tag: str) -> ET.Element:
    child = element.find(tag)
    if child is None:
        raise RobotMessageInvalid(f"<{element.tag}> has no <{tag}>")
    return child


def _attr(element: ET.Element, key: str) -> str:
    value = element.get(key)
    if value is None:
        raise RobotMessageInvalid(f"<{element.tag}> has no attribute {key}")
    if len(value) > 64:
        raise RobotMessageInvalid(f"<{element.tag} {key}> is {len(value)} characters long")
    return value


def _int(element: ET.Element, key: str) -> int:
    text = _attr(element, key)
    try:
        value = int(text)
    except ValueError as exc:
        raise RobotMessageInvalid(f"<{element.tag} {key}={text!r}> is not an integer") from exc
    if not -(2**31) <= value < 2**31:
        raise RobotMessageInvalid(f"<{element.tag} {key}={text}> does not fit 32 bits")
    return value


def _frame(element: ET.Element) -> tuple[float, float, float, float, float, float]:
    values = []
    for key in FRAME_KEYS:
        text = _attr(element, key)
        try:
            values.append(float(text))
        except ValueError as exc:
            raise RobotMessageInvalid(f"<{element.tag} {key}={text!r}> is not a number") from exc
    return _checked_frame(tuple(values), RobotMessageInvalid, f"<{element.tag}>")


def _checked_frame(frame: tuple[float, ...], error: type[Exception], what: str) -> tuple[float, ...]:
    frame = tuple(float(v) for v in frame)
    if len(frame) != 6 or not all(math.isfinite(v) for v in frame):
        raise error(f"{what}: a frame is 6 finite numbers, got {frame!r}")
    if max(abs(v) for v in frame[:3]) > MAX_ABS_MM or max(abs(v) for v in frame[3:]) > MAX_ABS_DEG:
        raise error(f"{what}: {frame!r} outside +-{MAX_ABS_MM:g} mm / +-{MAX_ABS_DEG:g} deg")
    return frame
