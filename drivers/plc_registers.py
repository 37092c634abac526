"""Register encoding of the PLC contract (``docs/plc-interface.md``), without any I/O.

The PLC holds a block of 34 holding registers; every address here is relative to ``[plc] base``.
Registers 0-3 are written by the PLC, 10-33 by monoguide. Integer registers are uint16 (0..65535);
a float32 takes two registers, high word first (``word_order = "big"``); ``word_order = "little"``
swaps the two words (the bytes inside a word stay big-endian, as Modbus sends them). The adapter
(:mod:`monoguide.drivers.modbus_plc`) and the simulated PLC (:mod:`monoguide.drivers.sim.plc`) both use
these functions; they can be tested without a socket.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Collection, Sequence
from dataclasses import dataclass
from enum import IntFlag
from typing import Literal

from monoguide.drivers.errors import DeviceProtocolError, DeviceRequestInvalid, PlcUnknownJob, PlcValueInvalid

WordOrder = Literal["big", "little"]
WORD_ORDERS: tuple[WordOrder, ...] = ("big", "little")

# --- the register map (relative to base) -------------------------------------------------------
CONTROL = 0  # PLC: control word (Control bits)
JOB = 1  # PLC: job number, the part type, numbered from 1
PLC_HEARTBEAT = 2  # PLC: changes at least once per heartbeat_timeout_s
PART_TAG = 3  # PLC: any 16-bit id of the part, echoed back
STATUS = 10  # monoguide: status word (Status bits)
ERROR_CODE = 11  # monoguide: plc_code of the last cycle's error (0: none)
HEARTBEAT = 12  # monoguide: incremented every 0.5 s while healthy
CYCLE_COUNTER = 13  # monoguide: finished cycles
ECHO_JOB = 14  # monoguide: the job number of the result
ECHO_PART_TAG = 15  # monoguide: the part tag of the result
OFFSET = 16  # monoguide: 6 float32 (16-27): x, y, z mm, A, B, C deg (KUKA Z-Y'-X'') of the base offset
QUALITY = 28  # monoguide: 3 float32 (28-33): reprojection RMS px, sigma position mm, sigma rotation deg

INPUT_COUNT = 4  # registers 0-3, read in one request
RESULT_FIRST = ERROR_CODE  # registers 11-33 are written in one request (12, the heartbeat, rewritten as is)
BLOCK_SIZE = 34  # registers 0-33
OFFSET_NAMES = ("x_mm", "y_mm", "z_mm", "a_deg", "b_deg", "c_deg")
QUALITY_NAMES = ("rms_px", "sigma_position_mm", "sigma_rotation_deg")
UINT16_MAX = 0xFFFF

REGISTER_NAMES = {
    CONTROL: "control word", JOB: "job number", PLC_HEARTBEAT: "PLC heartbeat", PART_TAG: "part tag",
    STATUS: "status word", ERROR_CODE: "error code", HEARTBEAT: "monoguide heartbeat",
    CYCLE_COUNTER: "cycle counter", ECHO_JOB: "echoed job number", ECHO_PART_TAG: "echoed part tag",
    **{OFFSET + 2 * i: f"offset {name}" for i, name in enumerate(OFFSET_NAMES)},
    **{QUALITY + 2 * i: f"quality {name}" for i, name in enumerate(QUALITY_NAMES)},
}


class Control(IntFlag):
    """Bits of the control word (register 0), written by the PLC."""

    TRIGGER = 1 << 0
    RESULT_ACK = 1 << 1
    FAULT_RESET = 1 << 2


class Status(IntFlag):
    """Bits of the status word (register 10), written by monoguide."""

    READY = 1 << 0
    BUSY = 1 << 1
    DONE = 1 << 2
    RESULT_OK = 1 << 3
    ERROR = 1 << 4
    FAULT = 1 << 5
    CALIBRATION_WARNING = 1 << 6  # the calibration's trend monitor above its warning level, or its alarm latched


CONTROL_DEFINED = int(Control.TRIGGER | Control.RESULT_ACK | Control.FAULT_RESET)
STATUS_DEFINED = int(Status.READY | Status.BUSY | Status.DONE | Status.RESULT_OK | Status.ERROR | Status.FAULT
                     | Status.CALIBRATION_WARNING)


@dataclass(frozen=True)
class PlcInputs:
    """Registers 0-3 as the PLC wrote them."""

    control: Control
    job: int
    plc_heartbeat: int
    part_tag: int

    @property
    def trigger(self) -> bool:
        return Control.TRIGGER in self.control

    @property
    def result_ack(self) -> bool:
        return Control.RESULT_ACK in self.control

    @property
    def fault_reset(self) -> bool:
        return Control.FAULT_RESET in self.control


@dataclass(frozen=True)
class CycleResult:
    """What monoguide reports of one finished cycle (registers 11, 13-33).

    ``offset`` is x, y, z (mm) and A, B, C (deg, KUKA Z-Y'-X'': ``R = Rz(A) Ry(B) Rx(C)``) of the base offset
    ``D_b`` in the robot base frame, zeros when nothing was written; ``quality`` the reprojection RMS (px) and
    the predicted sigma of position (mm) and rotation (deg).
    """

    error_code: int
    cycle_counter: int  # the journal's cycle number (any size); register 13 shows it modulo 65536
    job: int
    part_tag: int
    offset: tuple[float, float, float, float, float, float] = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    quality: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class PlcOutputs:
    """Registers 10-33 as monoguide wrote them (what the PLC reads)."""

    status: Status
    heartbeat: int
    result: CycleResult


# --- 16-bit integers ---------------------------------------------------------------------------


def uint16_word(value: int, register: int) -> int:
    """``value`` as one register, refused (:class:`DeviceRequestInvalid` naming the register) outside 0..65535."""
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= UINT16_MAX:
        raise DeviceRequestInvalid(f"register {register} ({register_name(register)}) = {value!r}: not a uint16 "
                                   f"(0..{UINT16_MAX})")
    return value


def int16_word(value: int, register: int) -> int:
    """A signed ``value`` (-32768..32767) as one register in two's complement."""
    if isinstance(value, bool) or not isinstance(value, int) or not -0x8000 <= value <= 0x7FFF:
        raise DeviceRequestInvalid(f"register {register} ({register_name(register)}) = {value!r}: not an int16 "
                                   f"(-32768..32767)")
    return value & UINT16_MAX


def int16_from_word(word: int) -> int:
    """The signed value of one register (two's complement)."""
    return word - 0x10000 if word & 0x8000 else word


def wrap_uint16(value: int) -> int:
    """Counters (heartbeat, cycle counter) wrap 65535 -> 0."""
    return value & UINT16_MAX


def cycle_counter_word(number: int) -> int:
    """Register 13 for the journal's cycle ``number`` (0, 1, 2, ... without end): ``number`` modulo 65536, so
    the register counts 65534, 65535, 0, 1, ... as its contract says. A negative or non-integer number is a bug
    and raises :class:`DeviceRequestInvalid`."""
    if isinstance(number, bool) or not isinstance(number, int) or number < 0:
        raise DeviceRequestInvalid(f"register {CYCLE_COUNTER} ({register_name(CYCLE_COUNTER)}): cycle number "
                                   f"{number!r} is not a whole number >= 0")
    return wrap_uint16(number)


# --- float32 -----------------------------------------------------------------------------------


def float32_words(value: float, register: int, word_order: WordOrder = "big") -> list[int]:
    """One float32 as two registers, high word first (``"little"``: low word first). A value that is not
    finite or does not fit a float32 raises :class:`DeviceRequestInvalid` naming the register."""
    if not isinstance(value, int | float) or not math.isfinite(value):
        raise DeviceRequestInvalid(f"register {register} ({register_name(register)}) = {value!r}: not a finite "
                                   f"number")
    try:
        high, low = struct.unpack(">HH", struct.pack(">f", value))
    except OverflowError as exc:
        raise DeviceRequestInvalid(f"register {register} ({register_name(register)}) = {value!r}: outside the "
                                   f"float32 range") from exc
    return [high, low] if _order(word_order) == "big" else [low, high]


def float32_from_words(words: Sequence[int], register: int, word_order: WordOrder = "big") -> float:
    """Two registers (as :func:`float32_words` wrote them) -> the float; NaN or infinity raises
    :class:`PlcValueInvalid` naming the register and the words."""
    first, second = words
    high, low = (first, second) if _order(word_order) == "big" else (second, first)
    value = struct.unpack(">f", struct.pack(">HH", high, low))[0]
    if not math.isfinite(value):
        raise PlcValueInvalid(f"registers {register}-{register + 1} ({register_name(register)}) = "
                              f"[0x{first:04X}, 0x{second:04X}] ({word_order} word order): {value} is not finite")
    return value


# --- blocks ------------------------------------------------------------------------------------


def decode_inputs(words: Sequence[int]) -> PlcInputs:
    """Registers 0-3 -> :class:`PlcInputs`. A control word with an undefined bit set raises
    :class:`PlcValueInvalid` naming register 0 and the value (nothing of it is used)."""
    _check_words(words, INPUT_COUNT, CONTROL)
    control = words[CONTROL]
    if control & ~CONTROL_DEFINED:
        raise PlcValueInvalid(f"register {CONTROL} (control word) = 0x{control:04X}: bits "
                              f"0x{control & ~CONTROL_DEFINED & UINT16_MAX:04X} are not defined (only bit 0 TRIGGER, "
                              f"bit 1 RESULT_ACK, bit 2 FAULT_RESET)")
    return PlcInputs(Control(control), words[JOB], words[PLC_HEARTBEAT], words[PART_TAG])


def encode_inputs(inputs: PlcInputs) -> list[int]:
    """The PLC's side of :func:`decode_inputs` (the simulated PLC, tests)."""
    return [uint16_word(int(inputs.control), CONTROL), uint16_word(inputs.job, JOB),
            uint16_word(inputs.plc_heartbeat, PLC_HEARTBEAT), uint16_word(inputs.part_tag, PART_TAG)]


CHECK_JOB = 65535  # register 1: the calibration check, not a part (docs/plc-interface.md, "The check job")


def check_job(inputs: PlcInputs, jobs: Collection[int]) -> int:
    """The job number if it selects one of the config's part entries (``jobs``, numbered from 1) or is the check
    job (:data:`CHECK_JOB`); else :class:`PlcValueInvalid` (0) or :class:`PlcUnknownJob` naming register 1, the
    value and the jobs there are."""
    if inputs.job == 0:
        raise PlcValueInvalid(f"register {JOB} (job number) = 0: jobs are numbered from 1")
    if inputs.job == CHECK_JOB:
        return CHECK_JOB
    if inputs.job not in jobs:
        listed = ", ".join(str(j) for j in sorted(jobs))
        raise PlcUnknownJob(f"register {JOB} (job number) = {inputs.job}: the config has {len(jobs)} "
                            f"part entr{'y' if len(jobs) == 1 else 'ies'} (job{'' if len(jobs) == 1 else 's'} "
                            f"{listed})")
    return inputs.job


def encode_status(status: Status | int) -> int:
    """The status word; an undefined bit is refused (:class:`DeviceRequestInvalid`)."""
    value = int(status)
    if value & ~STATUS_DEFINED or value < 0:
        raise DeviceRequestInvalid(f"register {STATUS} (status word) = 0x{value:04X}: undefined bits set")
    return value


def decode_status(word: int) -> Status:
    """The status word as the PLC reads it; an undefined bit raises :class:`PlcValueInvalid`."""
    if word & ~STATUS_DEFINED:
        raise PlcValueInvalid(f"register {STATUS} (status word) = 0x{word:04X}: undefined bits set")
    return Status(word)


def encode_result(result: CycleResult, heartbeat: int, word_order: WordOrder = "big") -> list[int]:
    """Registers 11-33 in one list (12 carries ``heartbeat`` unchanged, so that one write can hold them all)."""
    if len(result.offset) != len(OFFSET_NAMES) or len(result.quality) != len(QUALITY_NAMES):
        raise DeviceRequestInvalid(f"a cycle result needs {len(OFFSET_NAMES)} offset and {len(QUALITY_NAMES)} "
                                   f"quality values, got {len(result.offset)} and {len(result.quality)}")
    words = [uint16_word(result.error_code, ERROR_CODE), uint16_word(heartbeat, HEARTBEAT),
             cycle_counter_word(result.cycle_counter), uint16_word(result.job, ECHO_JOB),
             uint16_word(result.part_tag, ECHO_PART_TAG)]
    for first, values in ((OFFSET, result.offset), (QUALITY, result.quality)):
        for i, value in enumerate(values):
            words += float32_words(value, first + 2 * i, word_order)
    return words


def decode_outputs(words: Sequence[int], word_order: WordOrder = "big") -> PlcOutputs:
    """Registers 10-33 -> :class:`PlcOutputs` (the PLC's view: the simulated PLC, tests, ``status``)."""
    _check_words(words, BLOCK_SIZE - STATUS, STATUS)
    at = {register: words[register - STATUS] for register in range(STATUS, BLOCK_SIZE)}
    offset = tuple(float32_from_words((at[r], at[r + 1]), r, word_order) for r in range(OFFSET, QUALITY, 2))
    quality = tuple(float32_from_words((at[r], at[r + 1]), r, word_order) for r in range(QUALITY, BLOCK_SIZE, 2))
    result = CycleResult(at[ERROR_CODE], at[CYCLE_COUNTER], at[ECHO_JOB], at[ECHO_PART_TAG], offset, quality)
    return PlcOutputs(decode_status(at[STATUS]), at[HEARTBEAT], result)  # type: ignore[arg-type]


def register_name(register: int) -> str:
    """``16`` -> ``"offset x_mm"``; a second word of a float32 is named after its first."""
    if register in REGISTER_NAMES:
        return REGISTER_NAMES[register]
    if register - 1 in REGISTER_NAMES and register - 1 >= OFFSET:
        return REGISTER_NAMES[register - 1] + " (low word)"
    return "not in the contract"


# --- private -----------------------------------------------------------------------------------


def _order(word_order: str) -> WordOrder:
    if word_order not in WORD_ORDERS:
        raise DeviceRequestInvalid(f"word order {word_order!r}: expected 'big' or 'little'")
    return word_order  # type: ignore[return-value]


def _check_words(words: Sequence[int], count: int, first: int) -> None:
    if len(words) != count or any(not isinstance(w, int) or not 0 <= w <= UINT16_MAX for w in words):
        raise DeviceProtocolError(f"registers {first}-{first + count - 1}: expected {count} uint16 words, got "
                                  f"{list(words)!r}")
