"""The tracker line protocol's encoding and meaning, without a port."""

from __future__ import annotations

import re

import numpy as np
import pytest

from monoguide.drivers.errors import DeviceFault, DeviceProtocolError, DeviceRequestInvalid
from monoguide.drivers.tracker_protocol import (
    Reply,
    decode_reply,
    decode_request,
    encode_error,
    encode_ok,
    encode_request,
    format_measurement,
    parse_identity,
    parse_measurement,
    raise_for_error,
)
from monoguide.solver.errors import MonoguideError


def test_request_round_trip() -> None:
    line = encode_request(17, "MEAS:POINT?", "B1")
    assert line == b"17 MEAS:POINT? B1\n"
    assert decode_request(line.rstrip(b"\n")).args == ("B1",)


@pytest.mark.parametrize(("bad", "named"), [((0, "X"), "tag 0"), ((1, "TWO WORDS"), "'TWO WORDS'"), ((1, ""), "''"),
                                            ((1, "MEAS:POINT?", "B 1"), "'B 1'"), ((1, "X", "Bä"), "'Bä'"),
                                            ((1, "X", "B\x07"), "'B\\x07'"), ((1, "X", "B" * 300), "longer than")])
def test_bad_requests_are_refused_with_a_typed_error_naming_the_value(bad: tuple, named: str) -> None:
    with pytest.raises(DeviceRequestInvalid, match=re.escape(named)) as info:
        encode_request(*bad)
    assert isinstance(info.value, MonoguideError) and info.value.code == "DEVICE_REQUEST_INVALID"


def test_ok_and_error_replies_decode() -> None:
    assert decode_reply(encode_ok(5, "MM")) == Reply(5, True, ("MM",))
    err = decode_reply(encode_error(6, "E200", "beam broken"))
    assert (err.tag, err.ok, err.error_code, err.error_text) == (6, False, "E200", "beam broken")


@pytest.mark.parametrize("line", [b"", b"OK 1 2 3", b"12 MAYBE", b"\x15?#\xfe garbled", b"x" * 300, b"3 OK \x07"])
def test_garbage_is_a_protocol_error(line: bytes) -> None:
    with pytest.raises(DeviceProtocolError):
        decode_reply(line)


def test_error_codes_map_to_their_exception() -> None:
    with pytest.raises(DeviceFault, match="E200"):
        raise_for_error(decode_reply(b"4 ERR E200 beam broken"), "MEAS:POINT?")
    with pytest.raises(DeviceProtocolError, match="E100"):
        raise_for_error(decode_reply(b"4 ERR E100 unknown command"), "FOO")


@pytest.mark.parametrize("unit", ["MM", "M", "IN"])
def test_measurement_round_trips_through_every_unit(unit: str) -> None:
    point = np.array([1234.5678, -987.6543, 12.25])
    fields = format_measurement(point, 0.0123, 42, unit)
    m = parse_measurement(Reply(1, True, fields), unit)
    np.testing.assert_allclose(m.point_mm, point, atol=5e-4)
    assert m.measurement_number == 42 and m.rms_mm == pytest.approx(0.0123, abs=5e-4)


def test_malformed_measurement_and_identity() -> None:
    with pytest.raises(DeviceProtocolError, match="x y z rms"):
        parse_measurement(Reply(1, True, ("1", "2", "3")), "MM")
    with pytest.raises(DeviceProtocolError, match="non-numeric"):
        parse_measurement(Reply(1, True, ("1", "2", "nan?", "0.1", "3")), "MM")
    with pytest.raises(DeviceProtocolError, match="vendor,model"):
        parse_identity(Reply(1, True, ("just-a-name",)))
    identity = parse_identity(decode_reply(b"2 OK ACME Corp,Tracker X,123,2.1"))
    assert (identity.vendor, identity.model, identity.serial, identity.firmware) == ("ACME Corp", "Tracker X",
                                                                                      "123", "2.1")
