"""The PLC register encoding against ground truth packed with ``struct`` (no socket)."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from monoguide.drivers.errors import (
    DeviceProtocolError,
    DeviceRequestInvalid,
    PlcHeartbeatLost,
    PlcUnknownJob,
    PlcValueInvalid,
)
from monoguide.drivers.plc import HeartbeatWatch, offset_registers
from monoguide.drivers.plc_registers import (
    BLOCK_SIZE,
    CYCLE_COUNTER,
    ERROR_CODE,
    STATUS,
    Control,
    CycleResult,
    PlcInputs,
    Status,
    check_job,
    cycle_counter_word,
    decode_inputs,
    decode_outputs,
    encode_inputs,
    encode_result,
    encode_status,
    float32_from_words,
    float32_words,
    int16_from_word,
    int16_word,
    register_name,
    uint16_word,
    wrap_uint16,
)
from monoguide.solver.frames import kuka_abc_to_matrix, make_T

RNG = np.random.default_rng(20261123)
FLOATS = [0.0, -0.0, 1.0, -1.5, 123.456, -49.987654, 3.0e-5, 1.0e30, float(np.float32(np.pi))] + \
    [float(v) for v in RNG.uniform(-500, 500, 20)]


def _truth_words(value: float) -> tuple[int, int]:
    """The float32's big-endian bytes split into its high and low 16-bit words."""
    raw = struct.pack(">f", value)
    return int.from_bytes(raw[:2], "big"), int.from_bytes(raw[2:], "big")


@pytest.mark.parametrize("value", FLOATS)
def test_float32_word_order_both_ways(value: float) -> None:
    high, low = _truth_words(value)
    assert float32_words(value, 16, "big") == [high, low]
    assert float32_words(value, 16, "little") == [low, high]
    expected = struct.unpack(">f", struct.pack(">f", value))[0]
    assert float32_from_words([high, low], 16, "big") == expected
    assert float32_from_words([low, high], 16, "little") == expected


def test_float32_known_pattern() -> None:
    # 1.5 is 0x3FC00000: high word 0x3FC0, low word 0x0000 (the worked example of docs/plc-interface.md)
    assert float32_words(1.5, 16) == [0x3FC0, 0x0000]
    assert float32_words(1.5, 16, "little") == [0x0000, 0x3FC0]
    assert float32_words(-12.25, 18) == [0xC144, 0x0000]


@pytest.mark.parametrize("value", [float("nan"), float("inf"), -float("inf"), 1e39, "1.0", None])
def test_float32_refuses_what_cannot_be_written(value: object) -> None:
    with pytest.raises(DeviceRequestInvalid, match=r"register 20 \(offset z_mm\)"):
        float32_words(value, 20)  # type: ignore[arg-type]


def test_float32_read_back_not_finite_names_registers() -> None:
    with pytest.raises(PlcValueInvalid, match=r"registers 28-29 \(quality rms_px\).*0x7FC0"):
        float32_from_words([0x7FC0, 0x0000], 28)


def test_word_order_must_be_known() -> None:
    with pytest.raises(DeviceRequestInvalid, match="'middle'"):
        float32_words(1.0, 16, "middle")  # type: ignore[arg-type]


def test_uint16_and_int16() -> None:
    assert uint16_word(65535, 13) == 65535
    for bad in (-1, 65536, 1.0, True):
        with pytest.raises(DeviceRequestInvalid, match=r"register 13 \(cycle counter\)"):
            uint16_word(bad, 13)  # type: ignore[arg-type]
    for value in (-32768, -1, 0, 1, 32767):
        word = int16_word(value, 11)
        assert word == struct.unpack(">H", struct.pack(">h", value))[0]
        assert int16_from_word(word) == value
    with pytest.raises(DeviceRequestInvalid):
        int16_word(32768, 11)
    assert wrap_uint16(65536) == 0 and wrap_uint16(65535 + 3) == 2


@pytest.mark.parametrize(("number", "register"), [(0, 0), (65_535, 65_535), (65_536, 0), (65_537, 1),
                                                   (300_000, 300_000 - 4 * 65_536), (2**31 + 5, 5), (2**40 + 7, 7)])
def test_register_13_is_the_cycle_number_modulo_65536(number: int, register: int) -> None:
    assert cycle_counter_word(number) == register
    words = encode_result(CycleResult(0, number, 1, 1), heartbeat=0)
    assert words[CYCLE_COUNTER - ERROR_CODE] == register
    assert decode_outputs([0, *words]).result.cycle_counter == register


@pytest.mark.parametrize("bad", [-1, 1.5, True, None])
def test_a_cycle_number_that_is_no_whole_number_is_refused(bad: object) -> None:
    with pytest.raises(DeviceRequestInvalid, match=r"register 13 \(cycle counter\)"):
        cycle_counter_word(bad)  # type: ignore[arg-type]


def test_control_word_bits_and_inputs() -> None:
    inputs = decode_inputs([0b101, 1, 77, 4242])
    assert inputs.trigger and inputs.fault_reset and not inputs.result_ack
    assert (inputs.job, inputs.plc_heartbeat, inputs.part_tag) == (1, 77, 4242)
    assert decode_inputs([0b010, 2, 0, 0]).result_ack
    assert encode_inputs(PlcInputs(Control.TRIGGER | Control.RESULT_ACK, 3, 9, 65535)) == [3, 3, 9, 65535]


@pytest.mark.parametrize("control", [0x0008, 0x8001, 0xFFFF])
def test_undefined_control_bit_is_refused_naming_register_and_value(control: int) -> None:
    with pytest.raises(PlcValueInvalid, match=rf"register 0 \(control word\) = 0x{control:04X}"):
        decode_inputs([control, 1, 0, 0])


def test_inputs_need_four_words() -> None:
    with pytest.raises(DeviceProtocolError, match="registers 0-3"):
        decode_inputs([0, 1, 2])
    with pytest.raises(DeviceProtocolError):
        decode_inputs([0, 1, 2, 70000])


def test_job_numbers() -> None:
    assert check_job(decode_inputs([1, 1, 0, 0]), (1,)) == 1
    with pytest.raises(PlcValueInvalid, match=r"register 1 \(job number\) = 0"):
        check_job(decode_inputs([1, 0, 0, 0]), (1,))
    with pytest.raises(PlcUnknownJob,
                       match=r"register 1 \(job number\) = 3: the config has 2 part entries \(jobs 1, 2\)"):
        check_job(decode_inputs([1, 3, 0, 0]), (1, 2))


def test_status_bits_are_those_of_the_contract() -> None:
    assert [int(s) for s in (Status.READY, Status.BUSY, Status.DONE, Status.RESULT_OK, Status.ERROR,
                             Status.FAULT, Status.CALIBRATION_WARNING)] == [1, 2, 4, 8, 16, 32, 64]
    assert [int(c) for c in (Control.TRIGGER, Control.RESULT_ACK, Control.FAULT_RESET)] == [1, 2, 4]
    assert encode_status(Status.DONE | Status.RESULT_OK) == 12
    assert encode_status(Status.READY | Status.CALIBRATION_WARNING) == 65
    with pytest.raises(DeviceRequestInvalid, match="register 10"):
        encode_status(128)


def test_result_block_layout_against_struct() -> None:
    offset = (12.5, -3.25, 0.75, 1.5, -0.5, 0.125)
    quality = (0.08, 0.031, 0.0042)
    result = CycleResult(error_code=0, cycle_counter=65535, job=2, part_tag=4711, offset=offset, quality=quality)
    for order in ("big", "little"):
        words = encode_result(result, heartbeat=99, word_order=order)
        assert len(words) == BLOCK_SIZE - 11  # registers 11-33
        assert words[:5] == [0, 99, 65535, 2, 4711]  # 11 error, 12 heartbeat as is, 13 counter, 14 job, 15 tag
        packed = struct.pack(">9f", *offset, *quality)
        pairs = [(int.from_bytes(packed[i:i + 2], "big"), int.from_bytes(packed[i + 2:i + 4], "big"))
                 for i in range(0, len(packed), 4)]
        expected = [w for hi, lo in pairs for w in ((hi, lo) if order == "big" else (lo, hi))]
        assert words[5:] == expected
        outputs = decode_outputs([int(Status.DONE | Status.RESULT_OK), *words], order)
        assert outputs.heartbeat == 99 and outputs.status == Status.DONE | Status.RESULT_OK
        assert outputs.result.offset == struct.unpack(">6f", packed[:24])
        assert outputs.result.quality == struct.unpack(">3f", packed[24:])
        assert (outputs.result.cycle_counter, outputs.result.job, outputs.result.part_tag) == (65535, 2, 4711)


def test_result_refuses_bad_values() -> None:
    with pytest.raises(DeviceRequestInvalid, match=r"register 11 \(error code\) = 70000"):
        encode_result(CycleResult(70000, 0, 1, 0), 0)
    with pytest.raises(DeviceRequestInvalid, match=r"register 24 \(offset b_deg\)"):
        encode_result(CycleResult(0, 0, 1, 0, (0, 0, 0, 0, float("nan"), 0)), 0)
    with pytest.raises(DeviceRequestInvalid, match="6 offset"):
        encode_result(CycleResult(0, 0, 1, 0, (0, 0, 0)), 0)  # type: ignore[arg-type]
    with pytest.raises(PlcValueInvalid, match="register 10"):
        decode_outputs([0x0080] + [0] * (BLOCK_SIZE - STATUS - 1))


def test_register_names() -> None:
    assert register_name(16) == "offset x_mm" and register_name(17) == "offset x_mm (low word)"
    assert register_name(32) == "quality sigma_rotation_deg" and register_name(5) == "not in the contract"


def test_offset_registers_are_kuka_abc_of_the_base_offset() -> None:
    a, b, c = 2.0, -1.5, 0.75  # deg, seeded truth
    D_b = make_T(kuka_abc_to_matrix(a, b, c), np.array([10.0, -20.0, 3.5]))
    assert np.allclose(offset_registers(D_b), (10.0, -20.0, 3.5, a, b, c), atol=1e-9)
    # the convention spelt out: R = Rz(A) Ry(B) Rx(C)
    ra, rb, rc = np.radians([a, b, c])
    Rz = np.array([[np.cos(ra), -np.sin(ra), 0], [np.sin(ra), np.cos(ra), 0], [0, 0, 1]])
    Ry = np.array([[np.cos(rb), 0, np.sin(rb)], [0, 1, 0], [-np.sin(rb), 0, np.cos(rb)]])
    Rx = np.array([[1, 0, 0], [0, np.cos(rc), -np.sin(rc)], [0, np.sin(rc), np.cos(rc)]])
    assert np.allclose(offset_registers(make_T(Rz @ Ry @ Rx, np.zeros(3)))[3:], (a, b, c))


def test_heartbeat_watch() -> None:
    watch = HeartbeatWatch(2.0)
    watch.check(100.0)  # nothing seen yet: nothing to judge
    watch.observe(5, 0.0)
    watch.observe(5, 1.9)
    watch.check(1.9)
    watch.observe(6, 2.0)  # changed: the clock restarts
    watch.check(3.9)
    assert watch.alive(3.9)
    with pytest.raises(PlcHeartbeatLost, match=r"register 2 \(PLC heartbeat\) stood at 6"):
        watch.check(4.01)
    assert not watch.alive(4.01)
