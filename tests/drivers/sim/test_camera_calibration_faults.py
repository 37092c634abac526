"""The simulated camera renders the calibration faults of issue 20 (item 5) against the simulated truth: a bump of
the camera on its bracket, a changed focal length, a measuring pose that stops elsewhere; a cleared fault renders
as before, and the faults come through the sim-cell state file and persist."""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from monoguide.daemon.assembly import sim_cell_spec
from monoguide.daemon.config import load_cell_config
from monoguide.drivers.camera import CameraSettings
from monoguide.drivers.sim.calibration_faults import CalibrationFaults
from monoguide.drivers.sim.camera import SimCamera
from monoguide.drivers.sim.cell import SimCell
from monoguide.drivers.sim.robot_motion import TRUTH_FORMAT, write_truth
from monoguide.solver.frames import invert, transform_points

CONFIG = load_cell_config(Path(__file__).parents[3] / "config" / "sim-cell.toml")
SPEC = sim_cell_spec(CONFIG)
ROI_HALF = 60


@pytest.fixture
def cell() -> SimCell:
    c = SimCell(SPEC)
    c.new_part(np.random.default_rng(20))
    return c


@pytest.fixture
def camera(cell: SimCell) -> SimCamera:
    cam = SimCamera(cell, seed=5)
    cam.open()
    cam.configure(CameraSettings(exposure_us=8000.0))
    return cam


def _camera_point(cell: SimCell, i: int) -> np.ndarray:
    """Hole i in the calibrated camera frame at the robot's stop at pose i (no fault)."""
    T_cf_c = SPEC.T_cf_b @ cell.actual_flange_pose(i) @ SPEC.T_f_c
    return transform_points(invert(T_cf_c) @ cell.T_cf_w_true, SPEC.points_w[i][None])[0]


def _centroid(image: np.ndarray, near: np.ndarray) -> np.ndarray:
    u0, v0 = (round(c) - ROI_HALF for c in near)
    roi = image[v0 : v0 + 2 * ROI_HALF, u0 : u0 + 2 * ROI_HALF].astype(float)
    inside = roi < 0.5 * (np.percentile(roi, 90) + np.percentile(roi, 1))
    m = cv2.moments(inside.astype(np.uint8), binaryImage=True)
    return np.array([u0 + m["m10"] / m["m00"], v0 + m["m01"] / m["m00"]])


def _seen(camera: SimCamera, i: int) -> tuple[np.ndarray, np.ndarray]:
    """Grab at pose i: (the hole's centroid in the image, where the renderer put it)."""
    camera.cell.move_to_measuring_pose(i, np.random.default_rng(100 + i))
    frame = camera.grab(1.0)
    drawn = camera.last_view.centers_px[i]  # type: ignore[union-attr]
    return _centroid(frame.image, drawn), drawn


def test_a_bump_of_a_tenth_of_a_degree_about_x_moves_the_image_as_the_geometry_says(camera: SimCamera) -> None:
    """T_f_c_true = T_f_c · B: the camera turned +0.1 deg about its own x, so a point's camera coordinates turn by
    -0.1 deg (y grows by about z · theta): the hole moves down the image by about fy · theta (~ fy / 573)."""
    cell = camera.cell
    before, _ = _seen(camera, 1)
    camera.set_calibration_faults(CalibrationFaults(bump_deg=0.1, bump_axis="x"))
    after, drawn = _seen(camera, 1)
    theta = math.radians(0.1)
    p = _camera_point(cell, 1)
    turned = np.array([p[0], p[1] * math.cos(theta) + p[2] * math.sin(theta),
                       -p[1] * math.sin(theta) + p[2] * math.cos(theta)])
    expected = SPEC.camera.project(turned[None])[0]
    np.testing.assert_allclose(drawn, expected, atol=1e-6)
    np.testing.assert_allclose(after, expected, atol=0.15)  # the image shows it
    shift = after - before
    assert shift[1] == pytest.approx(SPEC.camera.fy * theta, rel=0.05) and abs(shift[0]) < 0.3


def test_a_bump_along_the_camera_axis_moves_the_camera_that_way(camera: SimCamera) -> None:
    cell = camera.cell
    camera.set_calibration_faults(CalibrationFaults(bump_mm=1.0, bump_axis="x"))
    _, drawn = _seen(camera, 2)
    p = _camera_point(cell, 2) - np.array([1.0, 0.0, 0.0])  # the camera 1 mm further along its x
    np.testing.assert_allclose(drawn, SPEC.camera.project(p[None])[0], atol=1e-6)
    camera.set_calibration_faults(CalibrationFaults(bump_deg=0.3, bump_axis="y"))
    _, drawn = _seen(camera, 2)
    theta = math.radians(0.3)
    p = _camera_point(cell, 2)
    turned = np.array([p[0] * math.cos(theta) - p[2] * math.sin(theta), p[1],
                       p[0] * math.sin(theta) + p[2] * math.cos(theta)])
    np.testing.assert_allclose(drawn, SPEC.camera.project(turned[None])[0], atol=1e-6)


def test_a_focal_change_scales_the_image_about_the_principal_point(camera: SimCamera) -> None:
    _, before = _seen(camera, 0)
    camera.set_calibration_faults(CalibrationFaults(focal_pct=0.5))
    seen, after = _seen(camera, 0)
    centre = np.array([SPEC.camera.cx, SPEC.camera.cy])
    np.testing.assert_allclose(after - centre, 1.005 * (before - centre), atol=1e-6)
    assert np.linalg.norm(after - before) > 0.5  # visible: the hole is well off the principal point
    np.testing.assert_allclose(seen, after, atol=0.15)


def test_a_pose_drift_moves_only_its_own_pose_and_a_cleared_fault_renders_as_before(camera: SimCamera) -> None:
    plain = [_seen(camera, i)[1] for i in range(4)]
    camera.set_calibration_faults(CalibrationFaults(drift={2: (0.3, 0.05)}))  # robot pose 2: index 1
    drifted = [_seen(camera, i)[1] for i in range(4)]
    for i in (0, 2, 3):
        np.testing.assert_allclose(drifted[i], plain[i], atol=1e-9)
    u = np.ones(3) / math.sqrt(3.0)
    D = np.eye(4)
    D[:3, :3] = cv2.Rodrigues(math.radians(0.05) * u)[0]
    D[:3, 3] = 0.3 * u
    cell = camera.cell
    T_cf_c = SPEC.T_cf_b @ cell.actual_flange_pose(1) @ D @ SPEC.T_f_c
    p = transform_points(invert(T_cf_c) @ cell.T_cf_w_true, SPEC.points_w[1][None])
    np.testing.assert_allclose(drifted[1], SPEC.camera.project(p)[0], atol=1e-6)
    assert np.linalg.norm(drifted[1] - plain[1]) > 1.0  # 0.05 deg over ~830 mm and 0.3 mm: pixels
    camera.set_calibration_faults(CalibrationFaults())
    for i in range(4):
        np.testing.assert_allclose(_seen(camera, i)[1], plain[i], atol=1e-9)


def test_the_faults_come_through_the_state_file_persist_and_clear(tmp_path: Path) -> None:
    """Read before every grab; one in the file when the camera opens applies (the cell's state, not an event);
    a later one-grab failure entry that carries them keeps them; a malformed entry is ignored."""
    truth_cell = SimCell(SPEC)
    T_cf_w = truth_cell.new_part(np.random.default_rng(3))
    T_b_f = truth_cell.move_to_measuring_pose(0, np.random.default_rng(4))
    truth_path, state_path = tmp_path / "robot-truth.json", tmp_path / "state.json"
    write_truth(truth_path, {"format": TRUTH_FORMAT, "part": 1, "in_position": 1, "T_b_f": T_b_f.tolist(),
                             "T_cf_w": T_cf_w.tolist(), "stops": {"1": T_b_f.tolist()}, "offsets": []})

    def state(camera_fault: object) -> None:
        state_path.write_text(json.dumps({"format": "monoguide.sim-cell-state/1",
                                          "robot": {"truth": str(truth_path)}, "camera_fault": camera_fault}))

    bumped = {"bump": {"deg": 0.1, "mm": 0.0, "axis": "x"}, "focal_pct": 0.0, "drift": {}, "serial": 1}
    state({"calibration": bumped})
    camera = SimCamera(SimCell(SPEC), follow=state_path)
    camera.open()
    camera.grab(1.0)
    assert camera.calibration_faults == CalibrationFaults(bump_deg=0.1)
    faulted = camera.last_view.centers_px[0].copy()  # type: ignore[union-attr]
    state({"failure": "black", "count": 1, "serial": 2, "calibration": bumped})
    assert camera.grab(1.0).image.max() < 16  # the failure once ...
    camera.grab(1.0)
    np.testing.assert_allclose(camera.last_view.centers_px[0], faulted)  # type: ignore[union-attr]
    state({"failure": "black", "count": 1, "serial": 2, "calibration": {"bump": {"deg": "a lot"}}})
    camera.grab(1.0)
    assert camera.calibration_faults == CalibrationFaults(bump_deg=0.1)  # ignored: the last kept
    state({"failure": "black", "count": 1, "serial": 2, "calibration": {**bumped, "bump": None, "serial": 3}})
    camera.grab(1.0)
    assert not camera.calibration_faults.active
    clear = camera.last_view.centers_px[0]  # type: ignore[union-attr]
    T_cf_c = SPEC.T_cf_b @ T_b_f @ SPEC.T_f_c
    p = transform_points(invert(T_cf_c) @ T_cf_w, SPEC.points_w[0][None])
    np.testing.assert_allclose(clear, SPEC.camera.project(p)[0], atol=1e-6)
    assert np.linalg.norm(faulted - clear) > 4.0  # fy · 0.1 deg: 4.3 px
