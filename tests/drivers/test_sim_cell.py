"""The simulated cell's truth, checked against the cell config and the paper's geometry."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from monoguide.daemon.assembly import sim_cell_spec
from monoguide.daemon.config import load_cell_config
from monoguide.drivers.sim.cell import SimCell
from monoguide.drivers.sim.tracker import load_targets
from monoguide.solver.frames import invert, matrix_to_rotvec, pose_difference, transform_points
from monoguide.solver.planning import quarter_targets

CONFIG = load_cell_config(Path(__file__).parents[2] / "config" / "sim-cell.toml")
SPEC = sim_cell_spec(CONFIG)


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
        T_cf_f_taught = CONFIG.measuring_poses[i].T_cf_si @ invert(SPEC.T_f_c)
        errors.append(pose_difference(T_cf_f, T_cf_f_taught))
    deg, mm = np.array(errors).T
    assert np.all(deg < 6 * np.sqrt(3) * SPEC.repeatability_deg) and np.all(deg > 0)
    assert np.all(mm < 6 * np.sqrt(3) * SPEC.repeatability_mm) and np.all(mm > 0)


def test_perfect_robot_sees_each_hole_where_the_plan_puts_it() -> None:
    cell = SimCell(dataclasses.replace(SPEC, repeatability_mm=0.0, repeatability_deg=0.0))
    targets = quarter_targets(SPEC.camera, SPEC.points_w)
    for i, pose in enumerate(CONFIG.measuring_poses):
        cell.move_to_measuring_pose(i)
        np.testing.assert_allclose(cell.actual_camera_pose(), pose.T_cf_si, atol=1e-9)
        p_c = transform_points(invert(pose.T_cf_si) @ SPEC.T_cf_w0, SPEC.points_w[i][None])
        assert p_c[0, 2] == pytest.approx(650.0, abs=1e-6)
        np.testing.assert_allclose(SPEC.camera.project(p_c)[0], targets[i], atol=1e-6)


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


def test_truth_of_a_measurement_is_in_the_calibrated_sf1() -> None:
    cell = SimCell(SPEC)
    cell.new_part()
    expected = invert(CONFIG.measuring_poses[0].T_cf_si) @ cell.T_cf_w_true
    np.testing.assert_allclose(cell.T_s1_w_true(), expected)
    with pytest.raises(ValueError, match="measuring pose 9"):
        cell.move_to_measuring_pose(9)
