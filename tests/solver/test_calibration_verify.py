"""Verification statistics and the Table-3 comparison (issue 12, steps 6 and 7)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from monoguide.solver.calibration.errors import CalibrationTooFewViews
from monoguide.solver.calibration.verify import (
    displacement_vector,
    euler_xyz_deg,
    euler_xyz_to_matrix,
    repeatability,
    table3,
)
from monoguide.solver.frames import make_T, rotvec_to_matrix

# Table 3, first pose of the paper: LT and Mono (psi theta phi deg, x y z mm), and its dR, dT
LT = (-2.31544, 3.407908, -3.50354, -31.260, -12.268, 33.642)
MONO = (-2.30752, 3.405357, -3.47866, -31.246, -12.335, 34.239)


def _T(v) -> np.ndarray:
    return make_T(euler_xyz_to_matrix(*v[:3]), np.array(v[3:], dtype=float))


def test_euler_angles_round_trip_about_x_y_z() -> None:
    R = euler_xyz_to_matrix(4.28209, 2.254749, -2.33946)
    assert np.allclose(euler_xyz_deg(R), [4.28209, 2.254749, -2.33946], atol=1e-10)
    # psi alone is a rotation about x
    assert np.allclose(euler_xyz_to_matrix(5.0, 0.0, 0.0), rotvec_to_matrix(np.radians([5.0, 0.0, 0.0])))


def test_table3_reproduces_the_papers_first_row() -> None:
    t = table3([_T(LT)], [_T(MONO)], tolerance_deg=0.05, tolerance_mm=0.5)
    row = t.rows[0]
    assert np.allclose(row.lt, LT, atol=1e-9) and np.allclose(row.mono, MONO, atol=1e-9)
    assert math.isclose(row.dR_deg, 0.026234, abs_tol=2e-6)  # Eq. 32 as printed
    assert math.isclose(row.dT_mm, 0.600911, abs_tol=2e-6)
    assert t.passed is False  # dT 0.60 mm > 0.5 mm
    assert math.isclose(t.rms_dT_mm, row.dT_mm)
    md = t.markdown()
    assert "| LT | -2.31544 |" in md and "| RMS |" in md
    assert table3([_T(LT)], [_T(LT)]).passed is None


def test_table3_rms_over_poses() -> None:
    lt = [_T(LT), _T((1, 2, 3, 4, 5, 6))]
    mono = [_T(MONO), _T((1, 2, 3, 4, 5, 6.3))]
    t = table3(lt, mono, tolerance_deg=0.05, tolerance_mm=0.7)
    assert math.isclose(t.rms_dT_mm, math.sqrt((0.600911**2 + 0.3**2) / 2), abs_tol=1e-5)
    assert t.passed is True
    assert np.allclose(displacement_vector(lt[1]), (1, 2, 3, 4, 5, 6))
    with pytest.raises(CalibrationTooFewViews):
        table3(lt, mono[:1])


def test_repeatability_statistics_against_seeded_noise() -> None:
    rng = np.random.default_rng(8)
    T0 = _T((1.0, -2.0, 30.0, 100.0, 200.0, 300.0))
    sig_mm, sig_deg = np.array([0.02, 0.05, 0.1]), np.array([0.002, 0.004, 0.008])
    poses = [T0 @ make_T(rotvec_to_matrix(np.radians(rng.normal(0, sig_deg))), rng.normal(0, sig_mm))
             for _ in range(400)]
    rep = repeatability(poses)
    # translation noise was drawn in the pose's own frame; the statistics are per axis of the cell frame
    sigma_cf = np.sqrt(np.diag(T0[:3, :3] @ np.diag(sig_mm**2) @ T0[:3, :3].T))
    assert np.allclose(rep.sigma_mm, sigma_cf, rtol=0.12)
    assert np.allclose(rep.sigma_deg, sig_deg, rtol=0.12)
    assert rep.n == 400 and rep.max_dev_mm > 2 * np.linalg.norm(sig_mm) / math.sqrt(3)
    with pytest.raises(CalibrationTooFewViews):
        repeatability(poses[:1])
