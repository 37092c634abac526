"""Message encoding of Universal Robots' RTDE protocol (version 2), without any I/O.

A message is a 3-byte header, ``uint16 size`` (header included) and ``uint8 type``, then its payload, all
big-endian. The client asks for the protocol version, the controller version, sets up an output recipe
(frequency + variable names; the controller answers the types, ``NOT_FOUND`` for names it does not know)
and/or an input recipe (names; ``IN_USE`` for registers another client holds), starts, and then data
packages flow: ``uint8 recipe id`` + the packed values. The adapter (:mod:`monoguide.drivers.ur_robot`)
and the simulated controller (:mod:`monoguide.drivers.sim.ur_controller`) both use these functions.

The meaning of our one input recipe (``docs/robot-interface.md``) is at the end: a request is the sequence
number, the command, the measuring pose number and the offset, all in one data package, so the robot never
sees a half-written offset.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from monoguide.drivers.errors import RobotMessageInvalid
from monoguide.solver.frames import T_to_ur_pose

PROTOCOL_VERSION = 2
DEFAULT_PORT = 30004
HEADER = struct.Struct(">HB")
MAX_MESSAGE_BYTES = 4096  # the controller's own limit for a package is about this; ours are far smaller

REQUEST_PROTOCOL_VERSION = ord("V")
GET_URCONTROL_VERSION = ord("v")
TEXT_MESSAGE = ord("M")
DATA_PACKAGE = ord("U")
CONTROL_PACKAGE_SETUP_OUTPUTS = ord("O")
CONTROL_PACKAGE_SETUP_INPUTS = ord("I")
CONTROL_PACKAGE_START = ord("S")
CONTROL_PACKAGE_PAUSE = ord("P")
MESSAGE_TYPES = (REQUEST_PROTOCOL_VERSION, GET_URCONTROL_VERSION, TEXT_MESSAGE, DATA_PACKAGE,
                 CONTROL_PACKAGE_SETUP_OUTPUTS, CONTROL_PACKAGE_SETUP_INPUTS, CONTROL_PACKAGE_START,
                 CONTROL_PACKAGE_PAUSE)

NOT_FOUND = "NOT_FOUND"
IN_USE = "IN_USE"
TYPE_FORMATS = {
    "BOOL": "?", "UINT8": "B", "UINT32": "I", "UINT64": "Q", "INT32": "i", "DOUBLE": "d",
    "VECTOR3D": "3d", "VECTOR6D": "6d", "VECTOR6INT32": "6i", "VECTOR6UINT32": "6I",
}

# Our input recipe: who writes it is the daemon, who reads it the robot program (docs/robot-interface.md)
REQUEST_SEQUENCE = "input_int_register_24"
REQUEST_COMMAND = "input_int_register_25"
REQUEST_POSE_NUMBER = "input_int_register_26"
REQUEST_OFFSET = tuple(f"input_double_register_{k}" for k in range(24, 30))  # x y z (m) rx ry rz (rad)
INPUT_RECIPE = (REQUEST_SEQUENCE, REQUEST_COMMAND, REQUEST_POSE_NUMBER, *REQUEST_OFFSET)
INPUT_RECIPE_TYPES = ("INT32",) * 3 + ("DOUBLE",) * 6
# What the robot program answers in output registers, read through ur_rtde's RTDEReceiveInterface, whose
# getOutputIntRegister() reads only 12-19 or (use_upper_range_registers) 36-43: we use the upper range (24-47 are
# RTDE's own; 0-23 belong to fieldbus adapters). 36 acknowledged number, 37 in position, 38 status, 39 the held
# offset's number, 40 the grasp interlock (1: valid) (monoguide.drivers.robot_program.REPORT)
ANSWER_REGISTERS = (36, 37, 38, 39, 40)
ANSWER_ACK_SEQUENCE, ANSWER_IN_POSITION, ANSWER_PROGRAM_STATUS, ANSWER_HELD_SEQUENCE, ANSWER_OFFSET_VALID = (
    f"output_int_register_{k}" for k in ANSWER_REGISTERS)
OUTPUT_RECIPE = ("timestamp", "actual_TCP_pose", "robot_mode", "safety_mode", "runtime_state",
                 *(f"output_int_register_{k}" for k in ANSWER_REGISTERS))


@dataclass(frozen=True)
class RobotRequest:
    """One request of the daemon: ``sequence`` (1..2^31-1), ``command`` (``robot.COMMAND_*``),
    ``pose_number`` (1-based measuring pose; 0 when not a move), ``offset_ur`` the base offset as a UR pose
    ``[x, y, z (m), rx, ry, rz (rad)]`` (zeros when not an offset)."""

    sequence: int
    command: int
    pose_number: int
    offset_ur: tuple[float, float, float, float, float, float]


# --- header and framing ------------------------------------------------------------------------


def encode_message(message_type: int, payload: bytes = b"") -> bytes:
    size = HEADER.size + len(payload)
    if size > MAX_MESSAGE_BYTES:
        raise ValueError(f"RTDE message of {size} bytes exceeds {MAX_MESSAGE_BYTES}")
    return HEADER.pack(size, message_type) + payload


def decode_header(header: bytes) -> tuple[int, int]:
    """3 header bytes -> (payload length, message type); :class:`RobotMessageInvalid` for a size the
    protocol cannot have or a type it does not know (the stream is then out of step: drop the connection)."""
    if len(header) != HEADER.size:
        raise RobotMessageInvalid(f"RTDE header must be {HEADER.size} bytes, got {header!r}")
    size, message_type = HEADER.unpack(header)
    if not HEADER.size <= size <= MAX_MESSAGE_BYTES:
        raise RobotMessageInvalid(f"RTDE message size {size} outside {HEADER.size}..{MAX_MESSAGE_BYTES}")
    if message_type not in MESSAGE_TYPES:
        raise RobotMessageInvalid(f"RTDE message type {message_type} ({chr(message_type)!r}) is not in the protocol")
    return size - HEADER.size, message_type


# --- payloads ----------------------------------------------------------------------------------


def encode_protocol_version(version: int = PROTOCOL_VERSION) -> bytes:
    return struct.pack(">H", version)


def decode_protocol_version(payload: bytes) -> int:
    return _unpack(">H", payload, "protocol version request")[0]


def encode_accepted(accepted: bool) -> bytes:
    return struct.pack(">B", 1 if accepted else 0)


def decode_accepted(payload: bytes, what: str) -> bool:
    return bool(_unpack(">B", payload, what)[0])


def encode_controller_version(major: int, minor: int, bugfix: int, build: int) -> bytes:
    return struct.pack(">IIII", major, minor, bugfix, build)


def decode_controller_version(payload: bytes) -> tuple[int, int, int, int]:
    return _unpack(">IIII", payload, "controller version")


def encode_setup_outputs(frequency_hz: float, names: Sequence[str]) -> bytes:
    return struct.pack(">d", frequency_hz) + ",".join(names).encode("ascii")


def decode_setup_outputs(payload: bytes) -> tuple[float, list[str]]:
    if len(payload) < 8:
        raise RobotMessageInvalid(f"RTDE output setup too short: {payload!r}")
    return struct.unpack_from(">d", payload)[0], _names(payload[8:])


def encode_setup_inputs(names: Sequence[str]) -> bytes:
    return ",".join(names).encode("ascii")


def decode_setup_inputs(payload: bytes) -> list[str]:
    return _names(payload)


def encode_recipe(recipe_id: int, types: Sequence[str]) -> bytes:
    """The controller's answer to a setup: the recipe id (0 when refused) and one type per name."""
    return struct.pack(">B", recipe_id) + ",".join(types).encode("ascii")


def decode_recipe(payload: bytes) -> tuple[int, list[str]]:
    if not payload:
        raise RobotMessageInvalid("RTDE recipe answer is empty")
    return payload[0], _names(payload[1:])


def encode_text_message(message: str, source: str = "monoguide", level: int = 3) -> bytes:
    text, src = message.encode("ascii", "replace")[:255], source.encode("ascii", "replace")[:255]
    return struct.pack(">B", len(text)) + text + struct.pack(">B", len(src)) + src + struct.pack(">B", level)


def decode_text_message(payload: bytes) -> str:
    if not payload:
        return ""
    n = payload[0]
    return payload[1:1 + n].decode("ascii", "replace")


def recipe_format(types: Sequence[str]) -> struct.Struct:
    """The struct of a data package for a recipe of ``types`` (after the recipe id byte)."""
    try:
        return struct.Struct(">" + "".join(TYPE_FORMATS[t] for t in types))
    except KeyError as exc:
        raise RobotMessageInvalid(f"RTDE recipe has a type we cannot pack: {exc.args[0]!r}") from exc


def encode_data_package(recipe_id: int, types: Sequence[str], values: Sequence[object]) -> bytes:
    """``values`` one per type (a vector type takes a sequence)."""
    flat: list[object] = []
    for t, v in zip(types, values, strict=True):
        flat.extend(v if t.startswith("VECTOR") else [v])  # type: ignore[arg-type]
    return struct.pack(">B", recipe_id) + recipe_format(types).pack(*flat)


def decode_data_package(payload: bytes, types: Sequence[str]) -> tuple[int, list[object]]:
    """-> (recipe id, one value per type; vectors as tuples)."""
    fmt = recipe_format(types)
    if len(payload) != 1 + fmt.size:
        raise RobotMessageInvalid(f"RTDE data package of {len(payload)} bytes, recipe needs {1 + fmt.size}")
    flat = fmt.unpack_from(payload, 1)
    out: list[object] = []
    k = 0
    for t in types:
        n = int(TYPE_FORMATS[t][0]) if TYPE_FORMATS[t][0].isdigit() else 1
        out.append(tuple(flat[k:k + n]) if n > 1 else flat[k])
        k += n
    return payload[0], out


# --- meaning of our input recipe ---------------------------------------------------------------


def encode_request(request: RobotRequest) -> list[object]:
    """The values of :data:`INPUT_RECIPE` for ``request``; refuses what the registers cannot carry."""
    for name, value in (("sequence", request.sequence), ("command", request.command),
                        ("pose_number", request.pose_number)):
        if not -(2**31) <= value < 2**31:
            raise ValueError(f"{name} {value} does not fit an int32 register")
    offset = [float(v) for v in request.offset_ur]
    if len(offset) != 6 or not all(math.isfinite(v) for v in offset):
        raise ValueError(f"offset must be 6 finite numbers, got {request.offset_ur!r}")
    return [request.sequence, request.command, request.pose_number, *offset]


def decode_request(values: Sequence[object]) -> RobotRequest:
    """The simulated controller's side of :func:`encode_request`."""
    if len(values) != len(INPUT_RECIPE):
        raise RobotMessageInvalid(f"request needs {len(INPUT_RECIPE)} values, got {len(values)}")
    seq, command, pose = (int(v) for v in values[:3])  # type: ignore[call-overload]
    offset = tuple(float(v) for v in values[3:])  # type: ignore[arg-type]
    return RobotRequest(seq, command, pose, offset)  # type: ignore[arg-type]


def offset_to_ur(D_b: np.ndarray) -> tuple[float, float, float, float, float, float]:
    """Base offset (4, 4, mm) -> UR pose (m, rotation vector rad): what ``pose_trans`` takes."""
    return tuple(float(v) for v in T_to_ur_pose(np.asarray(D_b, dtype=float)))  # type: ignore[return-value]


# --- private -----------------------------------------------------------------------------------


def _unpack(fmt: str, payload: bytes, what: str) -> tuple[int, ...]:
    try:
        return struct.unpack(fmt, payload)
    except struct.error as exc:
        raise RobotMessageInvalid(f"RTDE {what}: {len(payload)} bytes do not fit {fmt!r}") from exc


def _names(raw: bytes) -> list[str]:
    try:
        text = raw.decode("ascii")
    except UnicodeDecodeError as exc:
        raise RobotMessageInvalid(f"RTDE names are not ASCII: {raw[:40]!r}") from exc
    return [n for n in text.split(",") if n]  # ur_rtde ends its list with a comma
