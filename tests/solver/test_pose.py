"""Pose estimators against seeded synthetic truth."""

import math

import numpy as np
import pytest

from monoguide.solver import frames
from monoguide.solver.camera import PAPER_CAMERA
from monoguide.solver.errors import DegenerateGeometry, InconsistentMeasurement, TooFewObservations
from monoguide.solver.pose import ESTIMATORS, initial_differential, initial_iterated, solve_ml, solve_pose
from monoguide.solver.problem import PoseProblem
from monoguide.solver.synthetic import SyntheticCell, deviated_part, paper_roof_cell, perturbed_views
from monoguide.solver.uncertainty import predicted_covariance

CELL = paper_roof_cell()


def _draw(cell, rng, max_deg, max_mm, min_depth=200.0):
    while True:
        T = deviated_part(cell, rng, max_deg, max_mm)
        if cell.problem(cell.project(T)).points_in_views(T)[:, 2].min() > min_depth:
            return T


@pytest.mark.parametrize("method", ["ml", "paper"])
@pytest.mark.parametrize(("max_deg", "max_mm"), [(5.0, 50.0), (20.0, 200.0)])
def test_exact_recovery_without_noise(method, max_deg, max_mm):
    rng = np.random.default_rng(int(max_deg))
    for _ in range(10):
        T_true = _draw(CELL, rng, max_deg, max_mm)
        result = solve_pose(CELL.problem(CELL.project(T_true)), method)
        np.testing.assert_allclose(result.T_s1_w, T_true, atol=1e-9)
        assert result.rms_px < 1e-6


def test_paper_initial_value_is_first_order_accurate():
    """Eq. 21 is exact to first order: the error after one step shrinks with the square of the deviation."""
    rng = np.random.default_rng(3)
    for scale in (1.0, 0.1):
        errors = []
        for _ in range(10):
            T_true = deviated_part(CELL, rng, 2.0 * scale, 20.0 * scale)
            problem = CELL.problem(CELL.project(T_true))
            deviation = frames.pose_difference(problem.T_s1_w0, T_true)
            after = frames.pose_difference(initial_differential(problem, problem.T_s1_w0), T_true)
            errors.append(after[1] / deviation[1])
        if scale == 1.0:
            big = np.median(errors)
        else:
            assert np.median(errors) < 0.3 * big  # ten times smaller deviation: relative error falls ~10x
    assert big < 0.2


def test_iterated_initial_value_reaches_large_deviations():
    rng = np.random.default_rng(4)
    for _ in range(20):
        T_true = _draw(CELL, rng, 20.0, 200.0)
        T, steps = initial_iterated(CELL.problem(CELL.project(T_true)))
        d_rot, d_trans = frames.pose_difference(T, T_true)
        assert d_rot < 0.05 and d_trans < 1.0 and steps <= 10


def test_ml_reaches_the_cramer_rao_bound_and_its_covariance_predicts_the_error():
    rng = np.random.default_rng(5)
    sigma = 0.1
    err2, crb2, mahalanobis = [], [], []
    for _ in range(400):
        T_true = _draw(CELL, rng, 5.0, 50.0)
        exact = CELL.project(T_true)
        problem = CELL.problem(exact + rng.normal(0, sigma, exact.shape), sigma_px=sigma)
        result = solve_ml(problem)  # the bare estimator: solve_pose would refuse 1 in 1000 (its false alarms)
        e = np.concatenate(
            [frames.matrix_to_rotvec(T_true[:3, :3] @ result.T_s1_w[:3, :3].T), T_true[:3, 3] - result.T_s1_w[:3, 3]]
        )
        err2.append(e[3:] @ e[3:])
        crb2.append(np.trace(predicted_covariance(problem, T_true)[3:, 3:]))
        mahalanobis.append(e @ np.linalg.solve(result.covariance, e))
    assert 0.9 < math.sqrt(np.mean(err2) / np.mean(crb2)) < 1.1
    assert 0.85 < np.mean(mahalanobis) / 6 < 1.15  # chi-square with 6 degrees of freedom


def _error(T_true, T_est):
    """(6,) error over (rotation vector rad, translation mm), left perturbation in SF1 like the covariance."""
    return np.concatenate(
        [frames.matrix_to_rotvec(T_true[:3, :3] @ T_est[:3, :3].T), T_true[:3, 3] - T_est[:3, 3]]
    )


@pytest.mark.parametrize(("method", "sigma"), [("paper", 0.2), ("ml", 0.1)])
def test_reported_covariance_predicts_the_whole_6x6_error(method, sigma):
    """Eq. 29 (paper) and the Cramer-Rao bound (ml), rotation block and cross terms included: every error,
    whitened by the covariance its own solve reported, must have the identity as its covariance. A rotation
    block off by a factor 1.4 in variance or a wrong sign of the cross terms fails this."""
    rng = np.random.default_rng(6)
    whitened = []
    for _ in range(1000):
        T_true = _draw(CELL, rng, 5.0, 50.0)
        exact = CELL.project(T_true)
        result = ESTIMATORS[method](CELL.problem(exact + rng.normal(0, sigma, exact.shape), sigma_px=sigma))
        L = np.linalg.cholesky(result.covariance)
        whitened.append(np.linalg.solve(L, _error(T_true, result.T_s1_w)))
    w = np.array(whitened)
    empirical = w.T @ w / len(w)
    # standard errors for 1000 draws: 0.045 on the diagonal, 0.032 off it
    np.testing.assert_allclose(np.diag(empirical), np.ones(6), atol=0.15)
    np.testing.assert_allclose(empirical - np.diag(np.diag(empirical)), np.zeros((6, 6)), atol=0.12)
    # and in degrees for the rotation alone: observed RMS angle against the reported rotation block
    assert 0.85 < math.sqrt(np.mean(np.sum(w[:, :3] ** 2, axis=1)) / 3) < 1.15


def test_view_sigma_folds_robot_repeatability_into_the_covariance():
    rng = np.random.default_rng(7)
    folded, ignored = [], []
    for _ in range(200):
        T_true = _draw(CELL, rng, 5.0, 50.0)
        exact = CELL.project(T_true, perturbed_views(CELL, rng, 0.05, 0.01))
        pixels = exact + rng.normal(0, 0.1, exact.shape)
        for view_mm, view_deg, sink in ((0.05, 0.01, folded), (0.0, 0.0, ignored)):
            result = solve_ml(CELL.problem(pixels, 0.1, view_mm, view_deg))
            err = np.sum((result.T_s1_w[:3, 3] - T_true[:3, 3]) ** 2)
            sink.append((err, np.trace(result.covariance[3:, 3:])))
    ratio_folded = math.sqrt(np.mean([e for e, _ in folded]) / np.mean([p for _, p in folded]))
    ratio_ignored = math.sqrt(np.mean([e for e, _ in ignored]) / np.mean([p for _, p in ignored]))
    assert 0.85 < ratio_folded < 1.15
    assert ratio_ignored > 3.0  # pixel noise alone is overconfident by far


def test_several_points_per_view_and_a_single_view():
    rng = np.random.default_rng(8)
    corners = np.array([[0, 0, 0], [300, 0, 0], [300, 200, 0], [0, 200, 5], [150, 100, -3]], dtype=float)
    T_w_c = frames.make_T(np.diag([-1.0, 1.0, -1.0]), [150.0, 100.0, 700.0])
    T_s1_w0 = frames.invert(T_w_c)
    single = SyntheticCell(PAPER_CAMERA, corners, np.eye(4)[None], T_s1_w0, tuple((0, j) for j in range(5)))
    two_views = SyntheticCell(
        PAPER_CAMERA, CELL.points_w,
        np.stack([np.eye(4), frames.invert(CELL.T_s1_w0 @ frames.make_T(np.diag([-1.0, 1.0, -1.0]),
                                                                           [600.0, 2000.0, 1500.0]))]),
        frames.invert(frames.make_T(np.diag([-1.0, 1.0, -1.0]), [600.0, 0.0, 1500.0])),
        ((0, 0), (0, 1), (1, 2), (1, 3)),
    )
    for cell in (single, two_views):
        T_true = deviated_part(cell, rng, 3.0, 30.0)
        for method in ("ml", "paper"):
            result = solve_pose(cell.problem(cell.project(T_true)), method)
            np.testing.assert_allclose(result.T_s1_w, T_true, atol=1e-8)


def _eight_point_view(rng):
    corners = np.array([[0, 0, 0], [300, 0, 0], [300, 200, 0], [0, 200, 5], [150, 100, -3], [80, 40, 0],
                        [220, 160, 0], [40, 170, 2]], dtype=float)
    T_s1_w0 = frames.invert(frames.make_T(np.diag([-1.0, 1.0, -1.0]), [150.0, 100.0, 700.0]))
    cell = SyntheticCell(PAPER_CAMERA, corners, np.eye(4)[None], T_s1_w0, tuple((0, j) for j in range(8)))
    T_true = deviated_part(cell, rng, 2.0, 20.0)
    return cell, T_true, cell.project(T_true) + rng.normal(0, 0.1, (8, 2))


def test_robust_loss_resists_one_outlier_but_the_pose_is_still_refused():
    rng = np.random.default_rng(9)
    cell, T_true, pixels = _eight_point_view(rng)
    pixels[3] += [15.0, -10.0]
    plain = solve_ml(cell.problem(pixels))
    robust = solve_ml(cell.problem(pixels), robust=True)
    assert frames.pose_difference(robust.T_s1_w, T_true)[1] < 0.3 * frames.pose_difference(plain.T_s1_w, T_true)[1]
    assert robust.method == "ml-huber"
    # the estimator resists, the check still refuses: Huber must not make a wrong centre acceptable, and with
    # 10 degrees of freedom the wrong observation is located
    for flag in (False, True):
        with pytest.raises(InconsistentMeasurement, match=r"observations\[3\] \(view 0, point 3\)") as info:
            solve_pose(cell.problem(pixels), "ml", robust=flag)
        assert "cannot tell" not in info.value.message


def test_all_rays_through_one_point_is_degenerate():
    views = CELL.T_s1_si
    problem = PoseProblem(
        PAPER_CAMERA, CELL.points_w, views, np.array([0, 1, 2, 3]), np.array([0, 0, 0, 0]),
        np.zeros((4, 2)), CELL.T_s1_w0,
    )
    T = CELL.T_s1_w0
    pixels = np.stack([
        PAPER_CAMERA.project(frames.transform_points(frames.invert(views[i]) @ T, CELL.points_w[:1]))[0]
        for i in range(4)
    ])
    with pytest.raises(DegenerateGeometry, match="six degrees of freedom"):
        solve_pose(problem.with_pixels(pixels), "ml")


def test_holes_at_the_image_centre_leave_the_distance_unobservable():
    centre = np.tile([(PAPER_CAMERA.width - 1) / 2, (PAPER_CAMERA.height - 1) / 2], (4, 1))
    cell = paper_roof_cell(targets_px=centre)
    with pytest.raises(DegenerateGeometry):
        solve_pose(cell.problem(cell.project(cell.T_s1_w0)), "ml")


def test_three_points_are_refused_by_default_and_nothing_is_checked_when_allowed():
    rng = np.random.default_rng(10)
    T_true = deviated_part(CELL, rng, 3.0, 30.0)
    three = SyntheticCell(CELL.camera, CELL.points_w, CELL.T_s1_si, CELL.T_s1_w0, CELL.observed[:3])
    pixels = three.project(T_true) + rng.normal(0, 0.1, (3, 2))
    pixels[0] += [100.0, 0.0]  # a wrong centre that three points cannot reveal
    with pytest.raises(TooFewObservations, match=r"3 observed point.*at least 4.*nothing can be checked"):
        solve_pose(three.problem(pixels))
    result = solve_pose(three.problem(pixels), min_observations=3)
    assert result.consistency.dof == 0 and result.consistency.threshold is None
    assert result.rms_px < 1e-6  # the residual is zero whatever the pixels: the point of the default


def test_too_few_observations():
    with pytest.raises(TooFewObservations, match="2 observation"):
        PoseProblem(PAPER_CAMERA, CELL.points_w, CELL.T_s1_si, np.array([0, 1]), np.array([0, 1]),
                    np.zeros((2, 2)), CELL.T_s1_w0)
