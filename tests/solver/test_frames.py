import math

import numpy as np
import pytest

from monoguide.solver import frames
from monoguide.solver.errors import NotARotation


def _random_T(rng: np.random.Generator) -> np.ndarray:
    r = rng.normal(size=3)
    r *= rng.uniform(0, math.pi) / np.linalg.norm(r)
    return frames.make_T(frames.rotvec_to_matrix(r), rng.uniform(-2000, 2000, size=3))


def test_invert_and_compose_round_trip():
    rng = np.random.default_rng(1)
    for _ in range(50):
        T_a_b, T_b_c = _random_T(rng), _random_T(rng)
        T_a_c = frames.compose(T_a_b, T_b_c)
        np.testing.assert_allclose(frames.compose(frames.invert(T_a_b), T_a_c), T_b_c, atol=1e-9)
        np.testing.assert_allclose(frames.invert(T_a_b) @ T_a_b, np.eye(4), atol=1e-12)


@pytest.mark.parametrize("angle", [0.0, 1e-9, 1e-5, 0.3, 2.0, math.pi - 1e-6, math.pi])
def test_rotvec_round_trip_including_near_pi(angle):
    rng = np.random.default_rng(2)
    for _ in range(20):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        R = frames.rotvec_to_matrix(axis * angle)
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
        back = frames.rotvec_to_matrix(frames.matrix_to_rotvec(R))
        np.testing.assert_allclose(back, R, atol=1e-9)


def test_rotvec_matches_known_rotation_about_z():
    R = frames.rotvec_to_matrix(np.array([0.0, 0.0, math.pi / 2]))
    np.testing.assert_allclose(R @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], atol=1e-15)


def test_kuka_abc_is_z_y_x_intrinsic_and_round_trips():
    def rz(a):
        return frames.rotvec_to_matrix(np.array([0, 0, math.radians(a)]))

    def ry(a):
        return frames.rotvec_to_matrix(np.array([0, math.radians(a), 0]))

    def rx(a):
        return frames.rotvec_to_matrix(np.array([math.radians(a), 0, 0]))

    rng = np.random.default_rng(3)
    for _ in range(100):
        a, b, c = rng.uniform(-179, 179), rng.uniform(-89, 89), rng.uniform(-179, 179)
        R = frames.kuka_abc_to_matrix(a, b, c)
        np.testing.assert_allclose(R, rz(a) @ ry(b) @ rx(c), atol=1e-12)
        np.testing.assert_allclose(frames.matrix_to_kuka_abc(R), (a, b, c), atol=1e-9)


def test_kuka_gimbal_lock_still_reproduces_the_rotation():
    R = frames.kuka_abc_to_matrix(30.0, 90.0, 10.0)
    np.testing.assert_allclose(frames.kuka_abc_to_matrix(*frames.matrix_to_kuka_abc(R)), R, atol=1e-9)


def test_ur_pose_is_metres_and_rotation_vector():
    T = frames.ur_pose_to_T(np.array([0.1, -0.2, 0.3, 0.0, 0.0, math.pi / 2]))
    np.testing.assert_allclose(T[:3, 3], [100.0, -200.0, 300.0])
    np.testing.assert_allclose(T[:3, :3] @ [1, 0, 0], [0, 1, 0], atol=1e-15)
    np.testing.assert_allclose(frames.T_to_ur_pose(T), [0.1, -0.2, 0.3, 0.0, 0.0, math.pi / 2], atol=1e-12)


@pytest.mark.parametrize(
    ("matrix", "fragment"),
    [
        (np.eye(3), "4x4"),
        (np.diag([1.0, 1.0, 1.0, 2.0]), "last row"),
        (np.diag([1.0, 1.01, 1.0, 1.0]), "not orthonormal"),
        (np.diag([1.0, 1.0, -1.0, 1.0]), "reflection"),
    ],
)
def test_check_transform_names_the_defect(matrix, fragment):
    with pytest.raises(NotARotation, match=fragment) as info:
        frames.check_transform(matrix, "T_s1_w0")
    assert "T_s1_w0" in str(info.value)


def test_rigid_transform_accepts_rounding_and_refuses_more():
    T = frames.make_T(frames.rotvec_to_matrix(np.radians([10.0, -20.0, 130.0])), [1.0, 2.0, 3.0])
    rounded = np.round(T, 5)
    assert np.max(np.abs(rounded[:3, :3].T @ rounded[:3, :3] - np.eye(3))) > 1e-6  # refused before issue 7
    exact = frames.rigid_transform(rounded, "T")
    np.testing.assert_allclose(exact[:3, :3].T @ exact[:3, :3], np.eye(3), atol=1e-14)
    np.testing.assert_allclose(exact, T, atol=2e-5)
    skewed = T.copy()
    skewed[0, 0] += 5e-4
    with pytest.raises(NotARotation, match=r"\|R\^T R - I\| = 0\.00\d+, more than rounding"):
        frames.rigid_transform(skewed, "T")
    with pytest.raises(NotARotation, match="not finite"):
        frames.rigid_transform(np.full((4, 4), np.nan), "T")
