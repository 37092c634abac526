"""Units at the robot boundary, checked against an independent implementation (scipy's ``Rotation``) on the
bytes as they travel: UR metres and rotation vectors (radians) in the RTDE data package, KUKA millimetres and
A, B, C degrees (intrinsic Z-Y'-X'', scipy's ``"ZYX"``) in the XML. Seeded rotations, including ones near
180 degrees (where a rotation vector is hardest to extract) and KUKA B near +-90 degrees."""

from __future__ import annotations

import struct
import xml.etree.ElementTree as ET

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from monoguide.drivers import kuka_protocol as kuka
from monoguide.drivers import rtde_protocol as rtde
from monoguide.drivers.kuka_robot import report_to_status
from monoguide.drivers.robot import COMMAND_OFFSET
from monoguide.solver.frames import T_to_kuka_frame, ur_pose_to_T

RNG = np.random.default_rng(20261123)
ROTATIONS = [
    *Rotation.random(20, random_state=7),  # anywhere
    Rotation.from_rotvec(np.radians([0.3, -0.2, 4.9])),  # the cell's envelope
    Rotation.from_rotvec(np.radians(179.9) * np.array([0.6, 0.0, 0.8])),  # near pi
    Rotation.from_rotvec(np.radians(180.0) * np.array([0.0, 1.0, 0.0])),  # exactly pi
    Rotation.from_euler("ZYX", [30.0, 89.5, 10.0], degrees=True),  # KUKA B near +90
    Rotation.from_euler("ZYX", [-120.0, -89.9, 45.0], degrees=True),  # KUKA B near -90
]
IDS = [f"random{k}" for k in range(20)] + ["envelope", "near pi", "pi", "B near +90", "B near -90"]


def transform(rotation: Rotation, translation_mm: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = rotation.as_matrix(), translation_mm
    return T


@pytest.mark.parametrize("rotation", ROTATIONS, ids=IDS)
def test_ur_offset_package_is_metres_and_a_rotation_vector(rotation: Rotation) -> None:
    D = transform(rotation, RNG.uniform(-500.0, 500.0, 3))
    values = rtde.encode_request(rtde.RobotRequest(7, COMMAND_OFFSET, 0, rtde.offset_to_ur(D)))
    payload = rtde.encode_data_package(3, rtde.INPUT_RECIPE_TYPES, values)
    # the package by hand: recipe id, three big-endian int32 registers, six big-endian doubles
    recipe_id, seq, command, pose, *offset = struct.unpack(">B3i6d", payload)
    assert (recipe_id, seq, command, pose) == (3, 7, COMMAND_OFFSET, 0)
    np.testing.assert_allclose(np.array(offset[:3]) * 1000.0, D[:3, 3], rtol=0, atol=1e-9)  # metres
    assert np.linalg.norm(offset[3:]) <= np.pi + 1e-12  # a rotation vector, angle in radians
    np.testing.assert_allclose(Rotation.from_rotvec(offset[3:]).as_matrix(), D[:3, :3], rtol=0, atol=1e-9)


@pytest.mark.parametrize("rotation", ROTATIONS, ids=IDS)
def test_ur_actual_tcp_pose_is_read_as_metres_and_a_rotation_vector(rotation: Rotation) -> None:
    position_m = RNG.uniform(-1.5, 1.5, 3)
    T = ur_pose_to_T(np.concatenate([position_m, rotation.as_rotvec()]))
    np.testing.assert_allclose(T[:3, 3], position_m * 1000.0, rtol=0, atol=1e-9)
    np.testing.assert_allclose(T[:3, :3], rotation.as_matrix(), rtol=0, atol=1e-12)


@pytest.mark.parametrize("rotation", ROTATIONS, ids=IDS)
def test_kuka_offset_message_is_millimetres_and_abc_degrees_z_y_x(rotation: Rotation) -> None:
    D = transform(rotation, RNG.uniform(-500.0, 500.0, 3))
    message = kuka.encode_request(kuka.KukaRequest(9, COMMAND_OFFSET, 0, T_to_kuka_frame(D)))
    offset = ET.fromstring(message).find("Offset")  # the XML by hand (stdlib parser, not the adapter's)
    assert offset is not None
    x, y, z, a, b, c = (float(offset.get(k)) for k in "XYZABC")  # type: ignore[arg-type]
    # six decimals of fixed-point text: 5e-7 mm, 5e-7 deg (a rotation matrix then within ~1e-8)
    np.testing.assert_allclose([x, y, z], D[:3, 3], rtol=0, atol=5e-7)  # millimetres
    assert max(abs(a), abs(b), abs(c)) <= 180.0  # degrees
    R = Rotation.from_euler("ZYX", [a, b, c], degrees=True).as_matrix()  # R = Rz(A) Ry(B) Rx(C)
    np.testing.assert_allclose(R, D[:3, :3], rtol=0, atol=3e-8)


@pytest.mark.parametrize("rotation", ROTATIONS, ids=IDS)
def test_kuka_reported_flange_pose_is_millimetres_and_abc_degrees_z_y_x(rotation: Rotation) -> None:
    a, b, c = rotation.as_euler("ZYX", degrees=True)
    position_mm = RNG.uniform(-2500.0, 2500.0, 3)
    report = kuka.KukaReport("AUT", "NORMAL", True, (*position_mm, a, b, c), 1, 1, 0, 1000)
    status = report_to_status(kuka.decode_report(kuka.encode_report(report)))
    np.testing.assert_allclose(status.T_b_f[:3, 3], position_mm, rtol=0, atol=1e-9)  # nine decimals
    np.testing.assert_allclose(status.T_b_f[:3, :3], rotation.as_matrix(), rtol=0, atol=3e-11)
