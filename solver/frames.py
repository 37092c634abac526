"""Small SE(3) helpers. ``T_a_b`` maps coordinates in frame b to frame a (the pose of b in a).

Lengths are millimetres and angles radians inside monoguide; the UR and KUKA conversions at the end
are for the drivers, which speak the robot's units at the device boundary.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from monoguide.solver.errors import NotARotation

# |R^T R - I| accepted in a given rotation: a matrix printed to 5 decimals is off by about 1e-5
# (0.0006 deg); 1e-4 still means 0.006 deg. Beyond it the matrix is wrong, not rounded.
ORTHONORMAL_TOL = 1e-4


def make_T(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """4x4 transform from a rotation ``R`` (3, 3) and a translation ``t`` (3,)."""
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


def invert(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid transform (4, 4), exact for orthonormal rotations."""
    R = T[:3, :3]
    Ti = np.eye(4)
    Ti[:3, :3] = R.T
    Ti[:3, 3] = -R.T @ T[:3, 3]
    return Ti


def compose(*transforms: np.ndarray) -> np.ndarray:
    """``compose(T_a_b, T_b_c, ...)`` = ``T_a_b @ T_b_c @ ...``."""
    out = np.eye(4)
    for T in transforms:
        out = out @ T
    return out


def transform_points(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Map ``points`` (n, 3) given in frame b to frame a with ``T_a_b``; returns (n, 3)."""
    return points @ T[:3, :3].T + T[:3, 3]


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrix [v]x of a 3-vector."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def cross_rows(v: np.ndarray, A: np.ndarray) -> np.ndarray:
    """``v[i] x A[i, j]`` for v (m, 3) and A (m, k, 3): the rows of ``A[i] @ -[v[i]]x``.

    np.cross spends most of its time moving axes; this is the same sum written out.
    """
    x, y, z = v[:, 0, None], v[:, 1, None], v[:, 2, None]
    a, b, c = A[..., 0], A[..., 1], A[..., 2]
    return np.stack([y * c - z * b, z * a - x * c, x * b - y * a], axis=-1)


def rotvec_to_matrix(r: np.ndarray) -> np.ndarray:
    """Rodrigues: rotation vector (3,) in rad -> rotation matrix (3, 3).

    Written with scalars: the solver calls it once per iteration, where numpy's per-call cost dominates.
    """
    x, y, z = float(r[0]), float(r[1]), float(r[2])
    theta2 = x * x + y * y + z * z
    if theta2 < 1e-16:
        a, b = 1.0 - theta2 / 6.0, 0.5 - theta2 / 24.0
    else:
        theta = math.sqrt(theta2)
        a, b = math.sin(theta) / theta, (1.0 - math.cos(theta)) / theta2
    # R = I + a [r]x + b [r]x^2, with [r]x^2 = r r^T - theta^2 I
    return np.array(
        [
            [1.0 - b * (y * y + z * z), b * x * y - a * z, b * x * z + a * y],
            [b * x * y + a * z, 1.0 - b * (x * x + z * z), b * y * z - a * x],
            [b * x * z - a * y, b * y * z + a * x, 1.0 - b * (x * x + y * y)],
        ]
    )


def matrix_to_rotvec(R: np.ndarray) -> np.ndarray:
    """Rotation matrix (3, 3) -> rotation vector (3,) in rad, |r| in [0, pi]."""
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    sin_theta = 0.5 * math.sqrt(float(w @ w))
    cos_theta = 0.5 * (float(R[0, 0] + R[1, 1] + R[2, 2]) - 1.0)
    theta = math.atan2(sin_theta, cos_theta)  # accurate over the whole range, unlike acos
    if theta < 1e-6:
        return 0.5 * w * (1.0 + theta * theta / 6.0)
    if math.pi - theta > 1e-3:
        return theta / (2.0 * sin_theta) * w
    # Near pi the antisymmetric part vanishes: n n^T = (sym(R) - cos I) / (1 - cos).
    nnT = (0.5 * (R + R.T) - cos_theta * np.eye(3)) / (1.0 - cos_theta)
    i = int(np.argmax(np.diag(nnT)))
    axis = nnT[i] / math.sqrt(nnT[i, i])
    if float(axis @ w) < 0:
        axis = -axis
    return theta * axis


def pose_from_vector(x: np.ndarray) -> np.ndarray:
    """(6,) = (rotation vector rad, translation mm) -> 4x4 transform."""
    return make_T(rotvec_to_matrix(x[:3]), x[3:6])


def pose_to_vector(T: np.ndarray) -> np.ndarray:
    """4x4 transform -> (6,) = (rotation vector rad, translation mm)."""
    return np.concatenate([matrix_to_rotvec(T[:3, :3]), T[:3, 3]])


def rotation_angle_deg(R: np.ndarray) -> float:
    """Angle of a rotation (3, 3), in degrees."""
    return math.degrees(float(np.linalg.norm(matrix_to_rotvec(R))))


def pose_difference(T_a: np.ndarray, T_b: np.ndarray) -> tuple[float, float]:
    """Rotation angle (deg) and translation distance (mm) between two poses of the same frame."""
    dR = T_a[:3, :3].T @ T_b[:3, :3]
    return rotation_angle_deg(dR), float(np.linalg.norm(T_a[:3, 3] - T_b[:3, 3]))


def check_transform(T: np.ndarray, name: str, tol: float = ORTHONORMAL_TOL) -> np.ndarray:
    """Return ``T`` as a float (4, 4) array or raise :class:`NotARotation` naming ``name`` and the defect."""
    T = np.asarray(T, dtype=float)
    if T.shape != (4, 4):
        raise NotARotation(f"{name}: expected a 4x4 matrix, got shape {T.shape}")
    if not np.all(np.isfinite(T)):
        raise NotARotation(f"{name}: not finite: {T.tolist()}")
    if not np.allclose(T[3], [0.0, 0.0, 0.0, 1.0], atol=tol):
        raise NotARotation(f"{name}: last row must be [0, 0, 0, 1], got {T[3].tolist()}")
    R = T[:3, :3]
    defect = float(np.max(np.abs(R.T @ R - np.eye(3))))
    if defect > tol:
        raise NotARotation(f"{name}: rotation part is not orthonormal: |R^T R - I| = {defect:.3g}, more than "
            f"rounding explains (up to {tol:g} is accepted and orthonormalised)")
    if np.linalg.det(R) < 0:
        raise NotARotation(f"{name}: rotation part is a reflection (det = {np.linalg.det(R):.6f})")
    return T


def rigid_transform(T: np.ndarray, name: str, tol: float = ORTHONORMAL_TOL) -> np.ndarray:
    """:func:`check_transform`, then the rotation snapped to the nearest orthonormal one: a rounded
    (printed) matrix is accepted and made exact, a wrong one is refused with its measured defect."""
    T = check_transform(T, name, tol)
    return make_T(orthonormalize(T[:3, :3]), T[:3, 3])


def orthonormalize(R: np.ndarray) -> np.ndarray:
    """Nearest rotation matrix (Frobenius) to ``R`` (3, 3), e.g. for rounded printed matrices."""
    U, _, Vt = np.linalg.svd(R)
    D = np.diag([1.0, 1.0, float(np.sign(np.linalg.det(U @ Vt)))])
    return U @ D @ Vt


# --- robot conventions (device boundary) --------------------------------------------------------


def kuka_abc_to_matrix(a_deg: float, b_deg: float, c_deg: float) -> np.ndarray:
    """KUKA A, B, C in degrees (Z-Y'-X'' intrinsic: R = Rz(A) Ry(B) Rx(C)) -> rotation (3, 3)."""
    a, b, c = (math.radians(v) for v in (a_deg, b_deg, c_deg))
    ca, sa, cb, sb, cc, sc = math.cos(a), math.sin(a), math.cos(b), math.sin(b), math.cos(c), math.sin(c)
    return np.array(
        [
            [ca * cb, ca * sb * sc - sa * cc, ca * sb * cc + sa * sc],
            [sa * cb, sa * sb * sc + ca * cc, sa * sb * cc - ca * sc],
            [-sb, cb * sc, cb * cc],
        ]
    )


def matrix_to_kuka_abc(R: np.ndarray) -> tuple[float, float, float]:
    """Rotation (3, 3) -> KUKA (A, B, C) in degrees; at B = +-90 deg (gimbal lock) C is set to 0."""
    sb = -float(R[2, 0])
    b = math.asin(max(-1.0, min(1.0, sb)))
    if abs(math.cos(b)) > 1e-9:
        a = math.atan2(R[1, 0], R[0, 0])
        c = math.atan2(R[2, 1], R[2, 2])
    else:
        a = math.atan2(-R[0, 1], R[1, 1])
        c = 0.0
    return math.degrees(a), math.degrees(b), math.degrees(c)


def kuka_frame_to_T(x: float, y: float, z: float, a: float, b: float, c: float) -> np.ndarray:
    """KUKA FRAME {X, Y, Z (mm), A, B, C (deg)} -> 4x4 transform in mm."""
    return make_T(kuka_abc_to_matrix(a, b, c), np.array([x, y, z], dtype=float))


def T_to_kuka_frame(T: np.ndarray) -> tuple[float, float, float, float, float, float]:
    """4x4 transform in mm -> KUKA FRAME (X, Y, Z mm, A, B, C deg)."""
    a, b, c = matrix_to_kuka_abc(T[:3, :3])
    return float(T[0, 3]), float(T[1, 3]), float(T[2, 3]), a, b, c


def ur_pose_to_T(pose: np.ndarray) -> np.ndarray:
    """UR pose [x, y, z (m), rx, ry, rz (rotation vector, rad)] -> 4x4 transform in mm."""
    pose = np.asarray(pose, dtype=float)
    return make_T(rotvec_to_matrix(pose[3:6]), pose[:3] * 1000.0)


def T_to_ur_pose(T: np.ndarray) -> np.ndarray:
    """4x4 transform in mm -> UR pose [x, y, z (m), rx, ry, rz (rad)]."""
    return np.concatenate([T[:3, 3] / 1000.0, matrix_to_rotvec(T[:3, :3])])


def taught_flange_poses(T_cf_b: np.ndarray | None, T_f_c: np.ndarray | None,
                        poses: Sequence[tuple[np.ndarray | None, np.ndarray]]) -> tuple[np.ndarray, ...]:
    """``T_b_f`` (4, 4) of each measuring pose, given as (taught ``T_b_f`` or None, calibrated ``T_cf_si``): as
    taught, else from the calibrated camera pose, ``inv(T_cf_b) T_cf_si inv(T_f_c)``. Empty when a pose has
    neither (without ``T_cf_b`` or ``T_f_c``): then nobody can say where the flange should stand."""
    out = []
    for T_b_f, T_cf_si in poses:
        if T_b_f is not None:
            out.append(T_b_f)
        elif T_cf_b is not None and T_f_c is not None:
            out.append(compose(invert(T_cf_b), T_cf_si, invert(T_f_c)))
        else:
            return ()
    return tuple(out)
