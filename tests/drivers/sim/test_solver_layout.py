"""The layout planner (issue 8): planned measuring poses hold the whole deviation envelope.

Every check is made independently of the planner's own bookkeeping: the envelope's parts come from the
simulated cell's ``part_deviation``, pixels from OpenCV's ``projectPoints`` with the same Brown-Conrady
coefficients, angles and distances from the poses by hand.
"""

from __future__ import annotations

import itertools
import math

import cv2
import numpy as np
import pytest

from monoguide.drivers.sim.cell import part_deviation
from monoguide.solver import frames
from monoguide.solver.camera import PAPER_CAMERA, CameraModel
from monoguide.solver.planning import (
    DeviationEnvelope,
    LayoutConstraints,
    LayoutRequest,
    LayoutTooFewPoints,
    layout_covariance,
    look_at_poses,
    plan_layout,
    pose_sigmas,
)
from monoguide.solver.synthetic import PAPER_ROOF_POINTS_W

SIM_CELL_CONSTRAINTS = LayoutConstraints((400.0, 1000.0), 30.0, 100.0, (450.0, 900.0))


def corner_deviations(translation_mm, rotation_deg, centre_w) -> list[np.ndarray]:
    """``T_w0_w`` of the 64 corners of the envelope, built with the simulated cell's own deviation."""
    limits = np.concatenate([np.radians(rotation_deg), translation_mm])
    return [part_deviation(s[:3] * limits[:3], s[3:] * limits[3:], centre_w)
            for s in (np.array(signs) for signs in itertools.product((-1.0, 1.0), repeat=6))]


def seen(camera: CameraModel, T_w0_c: np.ndarray, T_w0_w: np.ndarray, point_w: np.ndarray) -> tuple[float, float]:
    """(margin px to the nearest image border, depth mm) of a part point, projected by OpenCV."""
    T_c_w = frames.invert(T_w0_c) @ T_w0_w
    rvec, _ = cv2.Rodrigues(T_c_w[:3, :3])
    px, _ = cv2.projectPoints(point_w.reshape(1, 1, 3), rvec, T_c_w[:3, 3], camera.K, camera.dist_coeffs)
    u, v = px.reshape(2)
    depth = float((T_c_w[:3, :3] @ point_w + T_c_w[:3, 3])[2])
    return min(u + 0.5, camera.width - 0.5 - u, v + 0.5, camera.height - 0.5 - v), depth


def check_envelope(request: LayoutRequest, poses, constraints: LayoutConstraints, draws: int, seed: int) -> float:
    """Assert every hole of every view in the image with the margin and inside the depth of field at every
    corner of the envelope and at ``draws`` fresh random parts; returns the worst margin seen."""
    points = np.asarray(request.points_w, dtype=float)
    env = request.envelope
    centre = points.mean(axis=0) if env.centre_w is None else np.asarray(env.centre_w)
    parts = corner_deviations(np.asarray(env.translation_mm), np.asarray(env.rotation_deg), centre)
    rng = np.random.default_rng(seed)
    for _ in range(draws):
        rotvec = np.radians(rng.uniform(-1, 1, 3) * env.rotation_deg)
        parts.append(part_deviation(rotvec, rng.uniform(-1, 1, 3) * env.translation_mm, centre))
    worst = math.inf
    near, far = constraints.depth_of_field_mm
    for i, T_w0_c in enumerate(poses):
        for T_w0_w in parts:
            margin, depth = seen(request.camera, T_w0_c, T_w0_w, points[i])
            assert depth > 0.0
            assert margin >= constraints.margin_px - 1e-6, f"hole {i} only {margin:.1f} px inside the image"
            assert near - 1e-6 <= depth <= far + 1e-6, f"hole {i} at depth {depth:.1f} mm"
            worst = min(worst, margin)
    return worst


def test_planned_roof_layout_holds_the_envelope_and_beats_today():
    """The issue's roof cell: every hole at least 100 px inside the image and inside 450-900 mm at the 64
    corners of +-50 mm / +-5 deg and at 300 fresh parts; predicted sigma below the issue's targets."""
    request = LayoutRequest(PAPER_CAMERA, PAPER_ROOF_POINTS_W, DeviationEnvelope(), SIM_CELL_CONSTRAINTS,
                            sigma_px=0.1, repeatability_mm=0.05, repeatability_deg=0.01)
    plan = plan_layout(request)
    worst = check_envelope(request, plan.T_w0_si, SIM_CELL_CONSTRAINTS, draws=300, seed=8)
    assert worst == pytest.approx(plan.margin_px_min, abs=1e-6)  # the corners are where the margin is least
    assert plan.sigmas.sigma_rot_deg <= 0.0045 and plan.sigmas.sigma_origin_mm <= 0.075
    today = look_at_poses(PAPER_ROOF_POINTS_W, PAPER_CAMERA, 650.0)
    today_rep = layout_covariance(PAPER_CAMERA, PAPER_ROOF_POINTS_W, today, 0.1, 0.05, 0.01)
    today_sigmas = pose_sigmas(today_rep, frames.invert(today[0]), PAPER_ROOF_POINTS_W.mean(axis=0))
    assert plan.sigmas_with_repeatability.sigma_rot_deg < today_sigmas.sigma_rot_deg
    assert plan.sigmas_with_repeatability.sigma_trans_mm < today_sigmas.sigma_trans_mm
    for i, T in enumerate(plan.T_w0_si):  # standoff and line of sight by hand
        to_camera = T[:3, 3] - PAPER_ROOF_POINTS_W[i]
        assert 400.0 <= np.linalg.norm(to_camera) <= 1000.0
        assert math.degrees(math.acos(to_camera[2] / np.linalg.norm(to_camera))) <= 30.0 + 1e-9


def test_todays_layout_loses_the_corner_holes_and_its_sigma_is_the_issues():
    """The straight-down layout of the old config: a hole leaves the image at a corner of the envelope, and
    layout_covariance gives the issue's table (0.0066 deg / 0.099 mm; tilted 30 deg, 0.0039 / 0.071)."""
    today = look_at_poses(PAPER_ROOF_POINTS_W, PAPER_CAMERA, 650.0)
    centre = PAPER_ROOF_POINTS_W.mean(axis=0)
    corners = corner_deviations(np.full(3, 50.0), np.full(3, 5.0), centre)
    worst = min(seen(PAPER_CAMERA, T, D, PAPER_ROOF_POINTS_W[i])[0] for i, T in enumerate(today) for D in corners)
    assert worst < -300.0
    cov = layout_covariance(PAPER_CAMERA, PAPER_ROOF_POINTS_W, today, 0.1)
    assert math.degrees(math.sqrt(np.trace(cov[:3, :3]))) == pytest.approx(0.0066, abs=5e-5)
    assert math.sqrt(np.trace(cov[3:, 3:])) == pytest.approx(0.099, abs=5e-4)
    tilted = [_tilted_look_at(p, centre, 30.0, 650.0) for p in PAPER_ROOF_POINTS_W]
    cov = layout_covariance(PAPER_CAMERA, PAPER_ROOF_POINTS_W, tilted, 0.1)
    assert math.degrees(math.sqrt(np.trace(cov[:3, :3]))) == pytest.approx(0.0039, abs=5e-5)
    assert math.sqrt(np.trace(cov[3:, 3:])) == pytest.approx(0.071, abs=5e-4)


@pytest.mark.parametrize(
    "points_w",
    [
        PAPER_ROOF_POINTS_W[:3],  # three holes: exactly determined, still planned
        PAPER_ROOF_POINTS_W,
        np.array([[0.0, 0.0, 0.0], [800.0, 0.0, 0.0], [800.0, 500.0, 12.0], [0.0, 500.0, 0.0]]),  # a small bracket
    ],
    ids=["3 holes", "4 holes roof", "4 holes bracket"],
)
def test_parts_with_three_and_four_holes_are_planned_for_the_whole_envelope(points_w):
    constraints = LayoutConstraints((300.0, 1000.0), 30.0, 80.0, (300.0, 1100.0))
    request = LayoutRequest(PAPER_CAMERA, points_w, DeviationEnvelope((30.0, 30.0, 30.0), (3.0, 3.0, 3.0)),
                            constraints, seed=3)
    plan = plan_layout(request)
    assert len(plan.T_w0_si) == len(points_w)
    check_envelope(request, plan.T_w0_si, constraints, draws=100, seed=5)
    assert plan.sigmas is not None and plan.sigmas.sigma_rot_deg < 0.05 and plan.sigmas.sigma_trans_mm < 0.5


def test_two_holes_are_refused_naming_why():
    request = LayoutRequest(PAPER_CAMERA, PAPER_ROOF_POINTS_W[:2])
    with pytest.raises(LayoutTooFewPoints, match="turn about the line through them") as caught:
        plan_layout(request)
    assert caught.value.code == "LAYOUT_TOO_FEW_POINTS" and caught.value.plc_code == 512


def test_lines_of_sight_are_measured_from_each_holes_own_surface_normal():
    """Holes on a face tilted 20 deg about x: the 25 deg limit applies to the angle from that face's normal
    (by hand), not from the part's z axis."""
    normal = np.array([0.0, -math.sin(math.radians(20.0)), math.cos(math.radians(20.0))])
    points = np.array([[0.0, 0.0, 0.0], [900.0, 0.0, 0.0], [900.0, 600.0, 218.4], [0.0, 600.0, 218.4]])
    constraints = LayoutConstraints((400.0, 1000.0), 25.0, 60.0, (300.0, 1200.0))
    request = LayoutRequest(PAPER_CAMERA, points, DeviationEnvelope((20.0, 20.0, 20.0), (2.0, 2.0, 2.0)),
                            constraints, normals_w=np.tile(normal, (4, 1)))
    plan = plan_layout(request)
    angles = []
    for i, T in enumerate(plan.T_w0_si):
        to_camera = (T[:3, 3] - points[i]) / np.linalg.norm(T[:3, 3] - points[i])
        angles.append(math.degrees(math.acos(to_camera @ normal)))
    assert max(angles) <= 25.0 + 1e-9
    assert max(angles) > 20.0  # it does tilt; measured from z the same views would be up to 45 deg off
    check_envelope(request, plan.T_w0_si, constraints, draws=0, seed=0)


def test_the_grasp_point_sigma_adds_the_rotation_times_its_lever():
    """A covariance with only a rotation about z (sigma 1e-4 rad) seen at a grasp point 500 mm off the
    axis: the grasp point moves by 0.05 mm, the part origin not at all."""
    cov = np.zeros((6, 6))
    cov[2, 2] = 1e-8
    sigmas = pose_sigmas(cov, np.eye(4), np.array([300.0, 400.0, 70.0]))
    assert sigmas.sigma_trans_mm == pytest.approx(0.05, rel=1e-12)
    assert sigmas.sigma_origin_mm == 0.0
    assert sigmas.sigma_rot_deg == pytest.approx(math.degrees(1e-4), rel=1e-12)


def test_the_plan_is_reproducible():
    request = LayoutRequest(PAPER_CAMERA, PAPER_ROOF_POINTS_W, constraints=SIM_CELL_CONSTRAINTS, seed=4)
    a, b = plan_layout(request), plan_layout(request)
    np.testing.assert_array_equal(np.array(a.T_w0_si), np.array(b.T_w0_si))


def _tilted_look_at(point: np.ndarray, centre: np.ndarray, tilt_deg: float, standoff: float) -> np.ndarray:
    """A camera ``standoff`` from ``point``, its optical axis through the point and tilted ``tilt_deg`` from
    the vertical towards ``centre`` (standing on the far side of the point): the hole at the principal point."""
    inward = (centre - point) * np.array([1.0, 1.0, 0.0])
    inward /= np.linalg.norm(inward)
    t = math.radians(tilt_deg)
    z = -np.array([0.0, 0.0, 1.0]) * math.cos(t) + inward * math.sin(t)  # optical axis, camera -> hole
    x = np.cross([0.0, 0.0, 1.0], z)
    x /= np.linalg.norm(x)
    R = np.column_stack([x, np.cross(z, x), z])
    # the principal point's ray is (0, 0, 1) undistorted: the hole is imaged at (cx, cy)
    return frames.make_T(R, point - standoff * z)
