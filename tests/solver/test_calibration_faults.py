"""Solver-level calibration faults (``solver.calibration_faults``): each moves the observations as the physics of
the fault says, checked on a lens without distortion against what a camera that moved or refocused must see."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from monoguide.solver import frames
from monoguide.solver.calibration_faults import (
    CalibrationFault,
    axis_motion,
    camera_bump,
    faulty_pixels,
    focal_change,
    pose_drift,
    true_cameras,
)
from monoguide.solver.synthetic import paper_roof_cell

ROOF = paper_roof_cell()
PINHOLE = dataclasses.replace(ROOF.camera, k1=0.0, k2=0.0, p1=0.0, p2=0.0)
CELL = dataclasses.replace(ROOF, camera=PINHOLE)


def _exact(fault: CalibrationFault, cell=CELL) -> np.ndarray:
    truth = dataclasses.replace(cell, camera=fault.true_camera(cell.camera))
    return truth.project(cell.T_s1_w0, true_cameras(cell, fault))


def _depths() -> np.ndarray:
    return np.array([frames.transform_points(frames.invert(CELL.T_s1_si[v]) @ CELL.T_s1_w0,
                                             CELL.points_w[p : p + 1])[0, 2] for v, p in CELL.observed])


def test_a_bump_is_the_calibration_right_multiplied_by_its_inverse() -> None:
    """Issue 20: the calibration states ``T_cf_si`` of the true camera right-multiplied by the inverse of the bump."""
    bump = frames.make_T(frames.rotvec_to_matrix(np.radians([0.1, -0.2, 0.3])), np.array([0.5, -1.0, 2.0]))
    truth = true_cameras(CELL, CalibrationFault(bump=bump))
    for true_pose, calibrated in zip(truth, CELL.T_s1_si, strict=True):
        assert np.allclose(true_pose @ frames.invert(bump), calibrated, atol=1e-12)


def test_a_camera_shifted_along_its_x_sees_the_part_move_the_other_way_by_f_over_depth() -> None:
    moved = _exact(camera_bump("x", mm=1.0)) - CELL.project(CELL.T_s1_w0)
    assert np.allclose(moved[:, 0], -PINHOLE.fx / _depths(), rtol=1e-9)
    assert np.allclose(moved[:, 1], 0.0, atol=1e-9)


def test_a_camera_turned_about_its_y_moves_its_image_by_f_tan_theta() -> None:
    """A point on the optical axis: the camera turned by +theta about y sees it at u = cx - fx tan(theta)."""
    theta = 0.1
    Q = np.array([[0.0, 0.0, 650.0]])
    before = PINHOLE.project(Q)
    after = PINHOLE.project(frames.transform_points(frames.invert(axis_motion("y", deg=theta)), Q))
    assert after[0, 0] - before[0, 0] == pytest.approx(-PINHOLE.fx * math.tan(math.radians(theta)), rel=1e-9)
    # the roof's holes (off axis) move by nearly as much, all views alike
    moved = _exact(camera_bump("y", deg=theta)) - CELL.project(CELL.T_s1_w0)
    assert np.allclose(moved[:, 0], -PINHOLE.fx * math.radians(theta), rtol=0.2)


@pytest.mark.parametrize("pct", [0.1, 0.5, -2.0])
def test_a_focal_change_scales_every_image_offset_from_the_principal_point(pct: float) -> None:
    for camera in (PINHOLE, ROOF.camera):  # with distortion too: it acts before the focal length
        cell = dataclasses.replace(CELL, camera=camera)
        centre = np.array([camera.cx, camera.cy])
        scaled = (cell.project(cell.T_s1_w0) - centre) * (1.0 + pct / 100.0) + centre
        assert np.allclose(_exact(focal_change(pct), cell), scaled, atol=1e-9)


def test_a_pose_drift_moves_only_its_own_view() -> None:
    before = CELL.project(CELL.T_s1_w0)
    after = _exact(pose_drift(2, "x", mm=0.3, deg=0.05))
    moved = np.linalg.norm(after - before, axis=1)
    assert moved[2] > 1.0 and np.all(moved[[0, 1, 3]] == 0.0)


def test_no_fault_is_the_good_cell_and_the_noise_is_seeded() -> None:
    none = CalibrationFault()
    assert np.array_equal(_exact(none), CELL.project(CELL.T_s1_w0))
    a = faulty_pixels(CELL, camera_bump("z", deg=0.3), CELL.T_s1_w0, np.random.default_rng(1))
    b = faulty_pixels(CELL, camera_bump("z", deg=0.3), CELL.T_s1_w0, np.random.default_rng(1))
    assert np.array_equal(a, b)
    # repeatability and centre noise on top: about sqrt(0.1^2 + repeatability) px, not zero
    spread = np.std([faulty_pixels(CELL, none, CELL.T_s1_w0, np.random.default_rng(s)) - _exact(none)
                     for s in range(200)])
    assert 0.1 < spread < 0.5


@pytest.mark.parametrize(
    ("call", "named"),
    [
        (lambda: axis_motion("w", 1.0), "'w'"),
        (lambda: focal_change(-100.0).true_camera(PINHOLE), "-100"),
        (lambda: pose_drift(7, "x", mm=1.0).taught_stops(CELL.T_s1_si), "drift_view 7"),
    ],
)
def test_a_fault_that_cannot_be_is_refused(call, named: str) -> None:
    with pytest.raises(ValueError, match=named):
        call()
