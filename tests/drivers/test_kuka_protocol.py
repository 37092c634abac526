"""The KUKA XML channel without a socket: framing, round trips, and malformed, truncated, oversized and hostile
messages (each a RobotMessageInvalid with its code, quickly, never a crash or a hang)."""

from __future__ import annotations

import dataclasses
import re
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from monoguide.drivers import kuka_protocol as kuka
from monoguide.drivers.errors import RobotMessageInvalid
from monoguide.drivers.kuka_robot import report_to_status
from monoguide.solver.frames import T_to_kuka_frame, kuka_frame_to_T, make_T, rotvec_to_matrix

REPORT = kuka.KukaReport("AUT", "NORMAL", True, (1856.25, 580.125, 1241.5, -92.5, 0.25, 179.75), 17, 3, 0, 123456,
                         ("KUKA", "KR 210", "S-1", "KSS 8.6"), held_sequence=16, offset_valid=True)
GOOD = kuka.encode_report(REPORT)


def test_report_round_trip_and_meaning() -> None:
    assert kuka.decode_report(GOOD) == REPORT
    status = report_to_status(REPORT)
    np.testing.assert_allclose(status.T_b_f, kuka_frame_to_T(*REPORT.pos))
    assert status.ready and status.in_position == 3 and status.ack_sequence == 17 and status.timestamp_s == 123.456
    assert (status.held_sequence, status.offset_valid) == (16, True)


def test_request_round_trip_in_mm_and_degrees_as_fixed_point_text() -> None:
    D = make_T(rotvec_to_matrix(np.radians([0.3, -0.2, 2.5])), np.array([12.5, -40.0, 3.25]))
    frame = T_to_kuka_frame(D)
    message = kuka.encode_request(kuka.KukaRequest(18, 2, 0, frame))
    back = kuka.decode_request(message)
    assert back.sequence == 18 and back.command == 2
    assert back.offset[:3] == (12.5, -40.0, 3.25)  # these are exact in six decimals
    np.testing.assert_allclose(back.offset, frame, rtol=0, atol=5e-7)  # half the last decimal
    np.testing.assert_allclose(kuka_frame_to_T(*back.offset), D, atol=1e-8)


@pytest.mark.parametrize("value", [3e-05, -4.2e-7, 1e-12, 59.9999996, -0.0, 1e5 - 1e-7, 123456.0])
def test_request_numbers_are_fixed_point_never_exponents(value: float) -> None:
    """A tiny offset component (issue 23, case 8: ``repr`` gave ``3e-05``) goes out as plain decimals."""
    if abs(value) > kuka.MAX_ABS_MM:
        with pytest.raises(ValueError, match="outside"):
            kuka.encode_request(kuka.KukaRequest(1, 2, 0, (value, 0.0, 0.0, 0.0, 0.0, 0.0)))
        return
    message = kuka.encode_request(kuka.KukaRequest(1, 2, 0, (value, 0.0, 0.0, 0.0, 0.0, 0.0)))
    text = ET.fromstring(message).find("Offset").get("X")  # type: ignore[union-attr]
    assert re.fullmatch(r"-?\d+\.\d{6}", text), text  # digits, a point, six decimals: no e, no inf, no nan
    assert float(text) == pytest.approx(value, abs=5e-7)
    assert text != "-0.000000"


def test_framing_splits_back_to_back_messages_and_keeps_the_rest() -> None:
    buffer = bytearray(GOOD + b"\r\n" + GOOD + GOOD[:30])
    assert kuka.split_messages(buffer, "Robot") == [GOOD, GOOD]
    assert bytes(buffer) == GOOD[:30]
    buffer.extend(GOOD[30:])
    assert kuka.split_messages(buffer, "Robot") == [GOOD] and not buffer


def test_oversized_stream_and_message_are_refused() -> None:
    buffer = bytearray(b"<Robot>" + b" " * (kuka.MAX_MESSAGE_BYTES + 10))
    with pytest.raises(RobotMessageInvalid, match="no </Robot>"):
        kuka.split_messages(buffer, "Robot")
    assert not buffer
    huge = bytearray(b"<Robot>" + b"x" * kuka.MAX_MESSAGE_BYTES + b"</Robot>")
    with pytest.raises(RobotMessageInvalid, match="exceeds") as info:
        kuka.split_messages(huge, "Robot")
    assert info.value.code == "ROBOT_MESSAGE_INVALID" and info.value.plc_code == 428


BOMB = (b'<?xml version="1.0"?><!DOCTYPE r [<!ENTITY a "aaaaaaaaaa">'
        + b"".join(f'<!ENTITY {c} "{("&" + p + ";") * 10}">'.encode()
                   for p, c in zip("abcdefgh", "bcdefghi", strict=True))
        + b"]><Robot>&i;</Robot>")


@pytest.mark.parametrize(("message", "match"), [
    (GOOD[:-3], "malformed"),  # truncated
    (b"<Robot><State Mode='AUT'", "malformed"),
    (b"\xff\xfe<Robot/>", "malformed"),
    (GOOD.replace(b"Robot", b"Sensor"), "expected a <Robot>"),
    (GOOD.replace(b'Ack="17"', b'Ack="seventeen"'), "not an integer"),
    (GOOD.replace(b'Ack="17"', b'Ack="99999999999"'), "32 bits"),
    (re.sub(rb'X="[^"]*"', b'X="nan"', GOOD), "finite"),
    (re.sub(rb'X="[^"]*"', b'X="1e9"', GOOD), "outside"),
    (GOOD.replace(b'Valid="1"', b'Valid="yes"'), "0 or 1"),
    (GOOD.replace(b' Held="16"', b""), "no attribute Held"),
    (GOOD.replace(b'Program="1"', b'Program="yes"'), "0 or 1"),
    (GOOD.replace(b"<Handshake", b"<Handshak"), "no <Handshake>"),
    (GOOD.replace(b'InPosition="3" ', b""), "no attribute InPosition"),
    (b'<!DOCTYPE r SYSTEM "file:///etc/passwd"><Robot/>', "DTD"),
    (BOMB, "DTD"),  # billion laughs: 10^9 characters if expanded
])
def test_bad_reports_are_typed_errors(message: bytes, match: str) -> None:
    start = time.monotonic()
    with pytest.raises(RobotMessageInvalid, match=match):
        kuka.decode_report(message)
    assert time.monotonic() - start < 0.5  # refused before anything expands


def test_requests_the_channel_cannot_carry_are_refused_before_sending() -> None:
    with pytest.raises(ValueError):
        kuka.encode_request(kuka.KukaRequest(-1, 1, 1))
    with pytest.raises(ValueError):
        kuka.encode_request(kuka.KukaRequest(1, 2, 0, (0.0, 0.0, float("inf"), 0.0, 0.0, 0.0)))


def test_the_eki_configuration_names_exactly_what_the_daemon_sends_and_reads() -> None:
    eki = ET.parse(Path(__file__).parents[2] / "config" / "kuka" / "monoguide.xml").getroot()
    received = {e.get("Tag") for e in eki.iter("ELEMENT") if e.get("Type")}
    sent = {e.get("Tag") for e in eki.find("SEND").iter("ELEMENT")}  # type: ignore[union-attr]

    def paths(element: ET.Element, prefix: str = "") -> set[str]:
        here = f"{prefix}{element.tag}"
        out = {f"{here}/@{k}" for k in element.attrib} | ({here} if (element.text or "").strip() else set())
        for child in element:
            out |= paths(child, here + "/")
        return out

    request = ET.fromstring(kuka.encode_request(kuka.KukaRequest(1, 2, 0, (1.0, 2.0, 3.0, 4.0, 5.0, 6.0))))
    assert paths(request) == received
    report = ET.fromstring(kuka.encode_report(dataclasses.replace(REPORT, identity=None)))
    assert paths(report) == sent
