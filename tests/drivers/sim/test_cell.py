"""The simulated cell's truth, checked against the cell config and the paper's geometry."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from monoguide.daemon.assembly import sim_cell_spec
from monoguide.daemon.config import load_cell_config
from monoguide.drivers.sim.camera import SimCamera
from monoguide.drivers.sim.cell import SimCell
from monoguide.drivers.sim.hole_renderer import RenderSettings
from monoguide.drivers.sim.make_cell_config import paper_cell_poses
from monoguide.drivers.sim.tracker import load_targets
from monoguide.solver.frames import invert, matrix_to_rotvec, pose_difference, transform_points

CONFIG = load_cell_config(Path(__file__).parents[3] / "config" / "sim-cell.toml")
SPEC = sim_cell_spec(CONFIG)
PLAN = paper_cell_poses()["plan"]  # the layout the config was generated from (solver.planning.plan_layout)


def test_same_seed_same_truth() -> None:
    a, b = SimCell(SPEC), SimCell(SPEC)
    np.testing.assert_array_equal(a.new_part(), b.new_part())
    np.testing.assert_array_equal(a.actual_camera_pose(), b.actual_camera_pose())
    assert not np.allclose(SimCell(dataclasses.replace(SPEC, seed=SPEC.seed + 1)).new_part(), a.T_cf_w_true)


def test_new_parts_stay_inside_the_deviation_ranges() -> None:
    cell = SimCell(SPEC)
    rng = np.random.default_rng(3)
    centroid = SPEC.points_w.mean(axis=0)
    for _ in range(50):
        T_w0_w = invert(SPEC.T_cf_w0) @ cell.new_part(rng)
        rot_deg = np.degrees(np.abs(matrix_to_rotvec(T_w0_w[:3, :3])))
        shift = transform_points(T_w0_w, centroid[None])[0] - centroid
        assert np.all(rot_deg <= np.array(SPEC.deviation_rotation_deg) * 1.01)
        assert np.all(np.abs(shift) <= np.array(SPEC.deviation_translation_mm) + 1e-9)
    np.testing.assert_array_equal(cell.reference_part(), SPEC.T_cf_w0)


def test_robot_stops_within_its_repeatability() -> None:
    cell = SimCell(SPEC)
    errors = []
    for i in range(cell.n_measuring_poses):
        cell.move_to_measuring_pose(i)
        T_cf_f = SPEC.T_cf_b @ cell.actual_flange_pose(i)
        T_cf_f_taught = CONFIG.cell_poses[i].T_cf_si @ invert(SPEC.T_f_c)
        errors.append(pose_difference(T_cf_f, T_cf_f_taught))
    deg, mm = np.array(errors).T
    assert np.all(deg < 6 * np.sqrt(3) * SPEC.repeatability_deg) and np.all(deg > 0)
    assert np.all(mm < 6 * np.sqrt(3) * SPEC.repeatability_mm) and np.all(mm > 0)


def test_perfect_robot_sees_each_hole_where_the_plan_puts_it() -> None:
    cell = SimCell(dataclasses.replace(SPEC, repeatability_mm=0.0, repeatability_deg=0.0))
    for i, pose in enumerate(CONFIG.measuring_poses):
        cell.move_to_measuring_pose(i)
        np.testing.assert_allclose(cell.actual_camera_pose(), pose.T_cf_si, atol=1e-9)
        p_c = transform_points(invert(cell.actual_camera_pose()) @ SPEC.T_cf_w0, SPEC.points_w[i][None])
        assert np.linalg.norm(p_c[0]) == pytest.approx(PLAN.standoff_mm[i], abs=1e-6)
        np.testing.assert_allclose(SPEC.camera.project(p_c)[0], PLAN.pixels[i], atol=1e-6)


def test_smr_positions_and_the_tracker_frame(tmp_path: Path) -> None:
    cell = SimCell(SPEC)
    smrs = cell.smr_positions()
    np.testing.assert_array_equal(smrs["B2"], [1500.0, 0.0, 0.0])
    np.testing.assert_allclose(smrs["P3"], transform_points(SPEC.T_cf_w0, SPEC.points_w[2][None])[0])
    tcp = SPEC.T_cf_b @ cell.actual_flange_pose() @ np.array([0.0, 0.0, 250.0, 1.0])
    np.testing.assert_allclose(smrs["TCP"], tcp[:3])
    target = CONFIG.sim.targets[1]
    np.testing.assert_allclose(smrs["T2.3"], transform_points(target.T_cf_t, target.points_t[2][None])[0])
    nests, noise, beam_on = load_targets(cell.write_tracker_targets(tmp_path / "t.json"))
    assert noise == 0.025 and beam_on == "B1" and set(nests) == set(smrs)
    T = CONFIG.sim.T_cf_tracker
    for name, p in nests.items():
        np.testing.assert_allclose(T[:3, :3] @ p + T[:3, 3], smrs[name], atol=1e-9)
    assert json.loads((tmp_path / "t.json").read_text())["format"] == "monoguide.sim-tracker-targets/1"


def test_truth_of_the_reference_part_in_sf1_is_the_planned_view() -> None:
    """Ground truth from the plan the config was generated with: at S1 the camera sees P1 from the planned
    standoff at the planned pixel (the config's comment on S1)."""
    cell = SimCell(SPEC)
    cell.reference_part()
    p1_s1 = transform_points(cell.T_s1_w_true(), SPEC.points_w[:1])[0]
    assert np.linalg.norm(p1_s1) == pytest.approx(PLAN.standoff_mm[0], abs=1e-6)
    np.testing.assert_allclose(SPEC.camera.project(p1_s1[None])[0], PLAN.pixels[0], atol=1e-6)
    np.testing.assert_allclose(cell.T_s1_w_true(), cell.T_s1_w0(), atol=1e-12)


@pytest.mark.parametrize("seed", [11, 12, 13])
def test_truth_of_a_deviated_part_in_sf1_is_where_the_camera_at_s1_sees_its_hole(seed: int) -> None:
    """T_s1_w_true checked against the rendered image: the robot (perfect) stands at S1 through its own
    chain T_cf_b T_b_f T_f_c, the renderer draws the part there, and the hole's centre is measured on the
    pixels (the dark blob's centroid), independently of the formula T_s1_w_true uses."""
    cell = SimCell(dataclasses.replace(SPEC, repeatability_mm=0.0, repeatability_deg=0.0))
    cell.new_part(np.random.default_rng(seed))
    cell.move_to_measuring_pose(0)
    camera = SimCamera(cell, RenderSettings(noise_sigma=1.0, light_gradient=0.0), seed=seed)
    camera.open()
    image = camera.grab(5.0).image.astype(float)
    measured = _dark_blob_centroid(image)
    # the measuring pose looks at the hole obliquely: the dark blob's centroid is the centroid of the rim's
    # image (an ellipse, whose centroid is not the image of the hole's centre), so that is what it is checked on
    predicted = _rim_image_centroid(cell.T_s1_w_true(), SPEC.points_w[0], SPEC.hole_radius_mm)
    np.testing.assert_allclose(measured, predicted, atol=0.05)
    reference = _rim_image_centroid(cell.T_s1_w0(), SPEC.points_w[0], SPEC.hole_radius_mm)
    assert np.linalg.norm(measured - reference) > 20.0, "the part did not move: the check above proves nothing"


def test_a_measuring_pose_that_does_not_exist_is_refused() -> None:
    with pytest.raises(ValueError, match="measuring pose 9"):
        SimCell(SPEC).move_to_measuring_pose(9)


def _dark_blob_centroid(image: np.ndarray) -> np.ndarray:
    """The hole's centre as the centroid of its darkness: the one dark blob in the frame, weighted by how
    much of each pixel is hole (sheet grey 180, hole grey 30 with no light gradient)."""
    mask = (image < 105).astype(np.uint8)
    count, _labels, stats, _ = cv2.connectedComponentsWithStats(mask)
    big = [k for k in range(1, count) if stats[k, cv2.CC_STAT_AREA] > 50]
    assert len(big) == 1, f"expected one hole in view at S1, found {len(big)}"
    x, y, w, h = (int(v) for v in stats[big[0], :4])
    pad = 6
    window = image[y - pad : y + h + pad, x - pad : x + w + pad]
    weight = np.clip((180.0 - window) / 150.0, 0.0, 1.0)
    rows, cols = np.mgrid[y - pad : y + h + pad, x - pad : x + w + pad]
    return np.array([np.sum(weight * cols), np.sum(weight * rows)]) / np.sum(weight)


def _rim_image_centroid(T_c_w: np.ndarray, centre_w: np.ndarray, radius_mm: float) -> np.ndarray:
    """Area centroid (px) of the image of a hole's rim (a circle in the part's x-y plane), from the rim's
    projection at 2000 points (the shoelace formula)."""
    t = np.linspace(0.0, 2.0 * np.pi, 2000, endpoint=False)
    rim_w = centre_w + radius_mm * np.column_stack([np.cos(t), np.sin(t), np.zeros_like(t)])
    x, y = SPEC.camera.project(transform_points(T_c_w, rim_w)).T
    cross = x * np.roll(y, -1) - np.roll(x, -1) * y
    area = cross.sum() / 2.0
    return np.array([((x + np.roll(x, -1)) * cross).sum(), ((y + np.roll(y, -1)) * cross).sum()]) / (6.0 * area)
