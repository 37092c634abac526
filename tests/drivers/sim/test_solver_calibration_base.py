"""Robot base BF and the SMR offset on the flange from simulated tracker readings (issue 12, step 3)."""

from __future__ import annotations

import numpy as np
import pytest

from monoguide.daemon.assembly import build_sim_cell
from monoguide.daemon.config import load_cell_config
from monoguide.drivers.sim.target_renderer import base_calibration_poses, tracker_reading
from monoguide.solver.calibration.base import fit_robot_base
from monoguide.solver.calibration.errors import (
    CalibrationDegenerate,
    CalibrationResidualTooLarge,
    CalibrationTooFewViews,
)
from monoguide.solver.frames import compose, make_T, pose_difference, rotvec_to_matrix, transform_points

N_POSES = 16


@pytest.fixture(scope="module")
def spec():
    return build_sim_cell(load_cell_config("config/sim-cell.toml")).spec


def _smr_cf(spec, T_b_f):
    return np.array([transform_points(compose(spec.T_cf_b, T), np.reshape(spec.tool_smr_f, (1, 3)))[0]
                     for T in T_b_f])


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_base_and_smr_offset_meet_the_issue_target(spec, seed: int) -> None:
    rng = np.random.default_rng(seed)
    T_b_f = base_calibration_poses(N_POSES, rng)
    fit = fit_robot_base(T_b_f, tracker_reading(_smr_cf(spec, T_b_f), rng, 0.025))
    deg, mm = pose_difference(fit.T_cf_b, spec.T_cf_b)
    assert mm < 0.05 and deg < 0.005  # issue 12: base within 0.05 mm / 0.005 deg
    assert np.linalg.norm(fit.smr_f - spec.tool_smr_f) < 0.05
    assert fit.residuals_mm.shape == (N_POSES,)
    assert 0.005 < fit.rms_mm < 0.04  # 0.025 mm 3-D RMS noise, less the fit's 9 parameters
    assert fit.sigma_mm < 0.05 and fit.sigma_deg < 0.005


def test_too_few_poses_are_refused(spec) -> None:
    rng = np.random.default_rng(4)
    T_b_f = base_calibration_poses(5, rng)
    with pytest.raises(CalibrationTooFewViews, match="5 pose\\(s\\)") as info:
        fit_robot_base(T_b_f, _smr_cf(spec, T_b_f))
    assert info.value.plc_code == 702


def test_poses_without_rotation_are_degenerate(spec) -> None:
    rng = np.random.default_rng(5)
    R = np.diag([1.0, -1.0, -1.0])
    T_b_f = [make_T(R, p[:3, 3]) for p in base_calibration_poses(12, rng)]  # only translations
    with pytest.raises(CalibrationDegenerate, match="SMR offset on the flange is not determined"):
        fit_robot_base(T_b_f, _smr_cf(spec, T_b_f))


def test_poses_turning_about_one_axis_only_are_degenerate(spec) -> None:
    rng = np.random.default_rng(7)
    down = np.diag([1.0, -1.0, -1.0])
    T_b_f = [make_T(down @ rotvec_to_matrix(np.array([0.0, 0.0, rng.uniform(-1.5, 1.5)])), p[:3, 3])
             for p in base_calibration_poses(12, rng)]  # the flange only turns about its own axis
    with pytest.raises(CalibrationDegenerate, match="fewer than two axes") as info:
        fit_robot_base(T_b_f, _smr_cf(spec, T_b_f))
    assert info.value.plc_code == 701


def test_a_bad_reading_is_refused_naming_the_pose(spec) -> None:
    rng = np.random.default_rng(6)
    T_b_f = base_calibration_poses(N_POSES, rng)
    p = tracker_reading(_smr_cf(spec, T_b_f), rng, 0.025)
    p[7] += np.array([0.0, 1.0, 0.0])  # the SMR slipped in its nest at pose 8
    with pytest.raises(CalibrationResidualTooLarge, match="pose 8 of 16") as info:
        fit_robot_base(T_b_f, p)
    assert info.value.code == "CALIBRATION_RESIDUAL_TOO_LARGE"
