"""The paper's planning study (Sec. 4, Fig. 5): straight-down views, holes moved outwards in the image.

Ground truth is independent of the code under test: pixels come from OpenCV's own projection
(``cv2.projectPoints`` with the same Brown-Conrady coefficients), the quarter positions are worked out by
hand from the image size, and the prediction is checked against the scatter of real solves.
"""

import math

import cv2
import numpy as np
import pytest

from monoguide.solver import frames
from monoguide.solver.camera import PAPER_CAMERA
from monoguide.solver.planning import layout_covariance, look_at_poses, quarter_targets, uncertainty_map
from monoguide.solver.pose import solve_ml
from monoguide.solver.synthetic import PAPER_ROOF_POINTS_W, deviated_part, paper_roof_cell


def opencv_pixels(T_c_w: np.ndarray, points_w: np.ndarray) -> np.ndarray:
    """Raw pixels of part points seen from camera ``T_c_w``, by OpenCV (not by CameraModel)."""
    rvec, _ = cv2.Rodrigues(T_c_w[:3, :3])
    cam = PAPER_CAMERA
    px, _ = cv2.projectPoints(points_w.reshape(-1, 1, 3), rvec, T_c_w[:3, 3], cam.K, cam.dist_coeffs)
    return px.reshape(-1, 2)


def test_look_at_poses_image_each_hole_at_its_target_from_straight_above():
    rng = np.random.default_rng(31)
    targets = np.column_stack([rng.uniform(100, 2300, 4), rng.uniform(100, 1900, 4)])
    poses = look_at_poses(PAPER_ROOF_POINTS_W, PAPER_CAMERA, 650.0, targets)
    for i, T_w_si in enumerate(poses):
        T_c_w = frames.invert(T_w_si)
        np.testing.assert_allclose(opencv_pixels(T_c_w, PAPER_ROOF_POINTS_W[i : i + 1])[0], targets[i], atol=1e-6)
        depth = (T_c_w[:3, :3] @ PAPER_ROOF_POINTS_W[i] + T_c_w[:3, 3])[2]
        assert depth == pytest.approx(650.0, abs=1e-9)
        np.testing.assert_allclose(T_w_si[:3, 2], [0.0, 0.0, -1.0], atol=1e-15)  # optical axis down onto the sheet


def test_quarter_targets_are_a_quarter_from_the_edge_away_from_the_part_centre():
    # 2456 x 2058 px: a quarter in from the left edge (-0.5) is u = 613.5, from the right 2455.5 - 614 = 1841.5;
    # v = 514.0 or 1543.0. Camera x is -x_w and camera y is y_w, so "away from the centre" is, for P1 at the
    # part's (0, 0) corner, +u and -v.
    expected = np.array([[1841.5, 514.0], [613.5, 514.0], [613.5, 1543.0], [1841.5, 1543.0]])
    np.testing.assert_allclose(quarter_targets(PAPER_CAMERA, PAPER_ROOF_POINTS_W), expected, atol=1e-9)


def test_fig5_map_falls_as_the_holes_move_outwards_and_flattens():
    fig5 = uncertainty_map(PAPER_CAMERA, PAPER_ROOF_POINTS_W, 650.0, steps=10)
    diagonal = np.diag(fig5.sigma_trans_mm)
    assert np.all(np.diff(diagonal) < 0)
    assert np.all(np.diff(np.diag(fig5.sigma_rot_deg)) < 0)
    drops = -np.diff(diagonal)
    assert drops[-1] < 0.2 * drops[0]  # diminishing returns far from the centre (Fig. 5)
    quarter = fig5.sigma_trans_mm[np.argmin(abs(fig5.offsets_v_px - 514)), np.argmin(abs(fig5.offsets_u_px - 614))]
    assert quarter < 0.25 * fig5.sigma_trans_mm[0, 0]


def test_the_predicted_covariance_is_the_scatter_of_real_solves():
    """What the planner minimises is what the estimator delivers: 400 seeded solves of noisy pixels scatter
    as ``layout_covariance`` predicts (within the sampling error of 400 draws)."""
    cell = paper_roof_cell()
    sigma = 0.1
    predicted = layout_covariance(cell.camera, cell.points_w, [frames.invert(cell.T_s1_w0) @ T for T in cell.T_s1_si],
                                  sigma)
    rng = np.random.default_rng(2024)
    errors = []
    for _ in range(400):
        T_true = deviated_part(cell, rng, 0.0, 0.0)
        pixels = cell.project(T_true) + rng.normal(0.0, sigma, (4, 2))
        T = solve_ml(cell.problem(pixels, sigma)).T_s1_w
        dR = T[:3, :3] @ T_true[:3, :3].T
        errors.append(np.concatenate([frames.matrix_to_rotvec(dR), T[:3, 3] - T_true[:3, 3]]))
    errors = np.array(errors)
    rot_rms = math.sqrt(np.mean(np.sum(errors[:, :3] ** 2, axis=1)))
    trans_rms = math.sqrt(np.mean(np.sum(errors[:, 3:] ** 2, axis=1)))
    assert rot_rms == pytest.approx(math.sqrt(np.trace(predicted[:3, :3])), rel=0.12)
    assert trans_rms == pytest.approx(math.sqrt(np.trace(predicted[3:, 3:])), rel=0.12)
