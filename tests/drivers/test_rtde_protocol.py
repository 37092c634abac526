"""RTDE encoding without a socket: headers, setup answers, data packages, our request recipe."""

from __future__ import annotations

import re
import struct
from pathlib import Path

import numpy as np
import pytest

from monoguide.drivers import rtde_protocol as rtde
from monoguide.drivers.errors import RobotMessageInvalid
from monoguide.solver.frames import make_T, rotvec_to_matrix, ur_pose_to_T


def test_header_is_big_endian_size_including_itself_and_type() -> None:
    message = rtde.encode_message(rtde.REQUEST_PROTOCOL_VERSION, rtde.encode_protocol_version(2))
    assert message == b"\x00\x05V\x00\x02"
    assert rtde.decode_header(message[:3]) == (2, ord("V"))


@pytest.mark.parametrize("header", [b"\x00\x02V", b"\xff\xffU", b"\x00\x05X", b"\x00\x05"])
def test_impossible_headers_are_refused(header: bytes) -> None:
    with pytest.raises(RobotMessageInvalid):
        rtde.decode_header(header)


def test_setup_round_trips_accept_urrtde_trailing_comma() -> None:
    freq, names = rtde.decode_setup_outputs(struct.pack(">d", 125.0) + b"timestamp,actual_TCP_pose,")
    assert freq == 125.0 and names == ["timestamp", "actual_TCP_pose"]
    assert rtde.decode_recipe(rtde.encode_recipe(3, ["INT32", "NOT_FOUND"])) == (3, ["INT32", "NOT_FOUND"])
    assert rtde.decode_setup_inputs(rtde.encode_setup_inputs(rtde.INPUT_RECIPE)) == list(rtde.INPUT_RECIPE)


def test_data_package_round_trip_with_vectors() -> None:
    types = ["DOUBLE", "VECTOR6D", "INT32", "UINT32"]
    values = [1.5, (1.0, 2.0, 3.0, 4.0, 5.0, 6.0), -7, 8]
    payload = rtde.encode_data_package(9, types, values)
    assert len(payload) == 1 + 8 + 48 + 4 + 4
    assert rtde.decode_data_package(payload, types) == (9, values)
    with pytest.raises(RobotMessageInvalid, match="recipe needs"):
        rtde.decode_data_package(payload[:-1], types)


def test_request_is_one_package_with_every_field() -> None:
    D = make_T(rotvec_to_matrix(np.radians([0.3, -0.2, 2.5])), np.array([12.5, -40.0, 3.25]))
    request = rtde.RobotRequest(17, 2, 0, rtde.offset_to_ur(D))
    payload = rtde.encode_data_package(4, rtde.INPUT_RECIPE_TYPES, rtde.encode_request(request))
    recipe_id, values = rtde.decode_data_package(payload, rtde.INPUT_RECIPE_TYPES)
    back = rtde.decode_request(values)
    assert recipe_id == 4 and back.sequence == 17 and back.command == 2
    assert back.offset_ur[:3] == pytest.approx((0.0125, -0.040, 0.00325), abs=1e-15)  # metres
    np.testing.assert_allclose(ur_pose_to_T(np.array(back.offset_ur)), D, atol=1e-12)


@pytest.mark.parametrize("request_", [
    rtde.RobotRequest(2**31, 1, 1, (0.0,) * 6),
    rtde.RobotRequest(1, 2, 0, (0.0, float("nan"), 0.0, 0.0, 0.0, 0.0)),
])
def test_requests_the_registers_cannot_carry_are_refused(request_: rtde.RobotRequest) -> None:
    with pytest.raises(ValueError):
        rtde.encode_request(request_)


def test_text_message_and_bad_names() -> None:
    assert rtde.decode_text_message(rtde.encode_text_message("hello")) == "hello"
    with pytest.raises(RobotMessageInvalid):
        rtde.decode_setup_inputs(b"input_int_register_24,\xff")


def test_the_urscript_template_uses_exactly_the_registers_of_the_recipes() -> None:
    script = (Path(__file__).parents[2] / "config" / "ur" / "monoguide.script").read_text()
    code = "\n".join(line.split("#")[0] for line in script.splitlines())  # comments aside
    ints_read = {int(n) for n in re.findall(r"read_input_integer_register\((\d+)\)", code)}
    doubles_read = {int(n) for n in re.findall(r"read_input_float_register\((\d+)\)", code)}
    written = {int(n) for n in re.findall(r"write_output_integer_register\((\d+),", code)}
    assert {f"input_int_register_{n}" for n in ints_read} == {rtde.REQUEST_SEQUENCE, rtde.REQUEST_COMMAND,
                                                              rtde.REQUEST_POSE_NUMBER}
    assert tuple(f"input_double_register_{n}" for n in sorted(doubles_read)) == rtde.REQUEST_OFFSET
    assert written == set(rtde.ANSWER_REGISTERS)
