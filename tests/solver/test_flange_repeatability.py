"""The robot's repeatability at the flange (``PoseProblem.T_f_c``): the robot stops at ``T_b_f N``, N drawn per
axis in the flange's axes, and the camera, mounted ~190 mm out at ``T_f_c``, moves with it. Checked against
seeded draws of that motion (a Monte Carlo through the ML solver) and against finite differences of the
projection, not against the code's own formulas."""

from __future__ import annotations

import math

import numpy as np
import pytest

from monoguide.solver import frames
from monoguide.solver.errors import NotARotation
from monoguide.solver.planning import LayoutRequest, assess_layout, pose_sigmas
from monoguide.solver.planning.errors import LayoutRequestInvalid
from monoguide.solver.planning.request import validate_request
from monoguide.solver.pose import solve_ml
from monoguide.solver.synthetic import paper_roof_cell
from monoguide.solver.uncertainty import observation_covariance, predicted_covariance

REP_MM, REP_DEG, SIGMA_PX = 0.05, 0.01, 0.1
# the simulated cell's mounting: 180 mm out along the tool axis, off-centre and turned (config/sim-cell.toml)
T_F_C = frames.make_T(frames.rotvec_to_matrix(np.radians([0.4, -0.3, 90.0])), np.array([62.0, -35.0, 180.0]))


def _moved_cameras(T_s1_si: np.ndarray, N: list[np.ndarray], T_f_c: np.ndarray | None) -> np.ndarray:
    """Where the cameras truly are when the flange (or, without T_f_c, the camera itself) stops at ``T N``."""
    if T_f_c is None:
        return np.stack([T @ n for T, n in zip(T_s1_si, N, strict=True)])
    T_c_f = frames.invert(T_f_c)
    return np.stack([T @ T_c_f @ n @ T_f_c for T, n in zip(T_s1_si, N, strict=True)])


def _draw_N(rng: np.random.Generator) -> np.ndarray:
    return frames.make_T(frames.rotvec_to_matrix(rng.normal(0.0, math.radians(REP_DEG), 3)),
                         rng.normal(0.0, REP_MM, 3))


def _grasp_errors(T_f_c: np.ndarray | None, draws: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Grasp-point position errors (draws, 3) mm and rotation errors (draws, 3) rad of the ML estimate."""
    cell = paper_roof_cell()
    rng = np.random.default_rng(seed)
    grasp = cell.points_w.mean(axis=0)
    truth = cell.T_s1_w0
    g_true = frames.transform_points(truth, grasp.reshape(1, 3))[0]
    pos, rot = np.empty((draws, 3)), np.empty((draws, 3))
    base = cell.problem(cell.project(truth), SIGMA_PX, REP_MM, REP_DEG).with_flange(T_f_c)
    for k in range(draws):
        cameras = _moved_cameras(cell.T_s1_si, [_draw_N(rng) for _ in cell.T_s1_si], T_f_c)
        pixels = cell.project(truth, cameras) + rng.normal(0.0, SIGMA_PX, (len(cell.observed), 2))
        est = solve_ml(base.with_pixels(pixels), T_init=truth).T_s1_w
        pos[k] = frames.transform_points(est, grasp.reshape(1, 3))[0] - g_true
        rot[k] = frames.matrix_to_rotvec(est[:3, :3] @ truth[:3, :3].T)
    return pos, rot


def _predicted(T_f_c: np.ndarray | None) -> tuple[float, float]:
    cell = paper_roof_cell()
    problem = cell.problem(cell.project(cell.T_s1_w0), SIGMA_PX, REP_MM, REP_DEG).with_flange(T_f_c)
    s = pose_sigmas(predicted_covariance(problem, cell.T_s1_w0), cell.T_s1_w0, cell.points_w.mean(axis=0))
    return s.sigma_trans_mm, math.radians(s.sigma_rot_deg)


def test_the_flange_model_predicts_the_grasp_error_of_a_robot_stopping_off_its_taught_flange_pose() -> None:
    pos, rot = _grasp_errors(T_F_C, draws=300, seed=20260711)
    mc_mm = math.sqrt(np.mean(np.sum(pos**2, axis=1)))
    mc_rad = math.sqrt(np.mean(np.sum(rot**2, axis=1)))
    flange_mm, flange_rad = _predicted(T_F_C)
    camera_mm, camera_rad = _predicted(None)
    assert mc_mm == pytest.approx(flange_mm, rel=0.15)
    assert mc_rad == pytest.approx(flange_rad, rel=0.15)
    # the camera-centred model under-predicts this robot: a flange rotation also swings the camera's centre
    assert flange_mm > 1.1 * camera_mm and mc_mm > 1.1 * camera_mm
    assert flange_rad > 1.1 * camera_rad and mc_rad > 1.1 * camera_rad


def test_without_T_f_c_the_repeatability_still_moves_the_camera_about_its_centre() -> None:
    pos, rot = _grasp_errors(None, draws=200, seed=7)
    camera_mm, camera_rad = _predicted(None)
    assert math.sqrt(np.mean(np.sum(pos**2, axis=1))) == pytest.approx(camera_mm, rel=0.15)
    assert math.sqrt(np.mean(np.sum(rot**2, axis=1))) == pytest.approx(camera_rad, rel=0.15)


@pytest.mark.parametrize("T_f_c", [None, T_F_C], ids=["camera", "flange"])
def test_the_pixel_covariance_is_that_of_the_drawn_motion(T_f_c: np.ndarray | None) -> None:
    """Q_P against finite differences of the projection over each of N's six independent parts."""
    cell = paper_roof_cell()
    truth = cell.T_s1_w0
    problem = cell.problem(cell.project(truth), SIGMA_PX, REP_MM, REP_DEG).with_flange(T_f_c)
    Q_P = observation_covariance(problem, problem.points_in_views(truth))
    h = 1e-4
    sigmas = [math.radians(REP_DEG)] * 3 + [REP_MM] * 3
    expected = np.eye(2 * len(cell.observed)) * SIGMA_PX**2
    for view in range(len(cell.T_s1_si)):
        for axis, sigma in enumerate(sigmas):
            n = np.zeros(6)
            n[axis] = h
            N = frames.make_T(frames.rotvec_to_matrix(n[:3]), n[3:])
            Ns = [N if v == view else np.eye(4) for v in range(len(cell.T_s1_si))]
            g = ((cell.project(truth, _moved_cameras(cell.T_s1_si, Ns, T_f_c)) - cell.project(truth)) / h).ravel()
            expected += np.outer(g, g) * sigma**2
    assert np.allclose(Q_P, expected, rtol=1e-3, atol=1e-4 * SIGMA_PX**2)


def test_a_camera_on_the_flange_itself_is_the_camera_centred_model() -> None:
    cell = paper_roof_cell()
    problem = cell.problem(cell.project(cell.T_s1_w0), SIGMA_PX, REP_MM, REP_DEG)
    Q = problem.points_in_views(cell.T_s1_w0)
    assert np.allclose(observation_covariance(problem.with_flange(np.eye(4)), Q), observation_covariance(problem, Q),
                       rtol=1e-12, atol=0.0)


def test_the_planner_predicts_with_the_flange_model_and_refuses_a_bad_mounting() -> None:
    cell = paper_roof_cell()
    T_w0_si = [frames.invert(cell.T_s1_w0) @ T for T in cell.T_s1_si]
    request = LayoutRequest(cell.camera, cell.points_w, sigma_px=SIGMA_PX, repeatability_mm=REP_MM,
                            repeatability_deg=REP_DEG, interior_samples=0)
    plain = assess_layout(request, T_w0_si).sigmas_with_repeatability
    flange = assess_layout(LayoutRequest(**{**request.__dict__, "T_f_c": T_F_C}), T_w0_si).sigmas_with_repeatability
    assert plain is not None and flange is not None
    assert plain.sigma_trans_mm == pytest.approx(_predicted(None)[0], rel=1e-9)
    assert flange.sigma_trans_mm == pytest.approx(_predicted(T_F_C)[0], rel=1e-9)
    bad = T_F_C.copy()
    bad[:3, :3] *= 1.1
    with pytest.raises(LayoutRequestInvalid, match="T_f_c"):
        validate_request(LayoutRequest(**{**request.__dict__, "T_f_c": bad}))
    with pytest.raises(NotARotation, match="T_f_c"):
        problem = cell.problem(cell.project(cell.T_s1_w0))
        problem.with_flange(bad)
