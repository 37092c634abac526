"""The simulated camera renders the truth of the simulated cell; every failure mode on command."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from monoguide.daemon.assembly import sim_cell_spec
from monoguide.daemon.config import load_cell_config
from monoguide.drivers.camera import Camera, CameraSettings
from monoguide.drivers.errors import DeviceDisconnected, DeviceSettingRejected, DeviceTimeout
from monoguide.drivers.sim.camera import SimCamera
from monoguide.drivers.sim.cell import SimCell
from monoguide.drivers.sim.robot_motion import TRUTH_FORMAT, write_truth
from monoguide.solver.frames import invert, transform_points

CONFIG = load_cell_config(Path(__file__).parents[3] / "config" / "sim-cell.toml")
SPEC = sim_cell_spec(CONFIG)
ROI_HALF = 60


def truth_px(cell: SimCell, i: int) -> np.ndarray:
    """Hole i projected through the cell's geometry: part pose, robot's actual flange, mounting, lens."""
    T_cf_c = SPEC.T_cf_b @ cell.actual_flange_pose(i) @ SPEC.T_f_c
    p_c = transform_points(invert(T_cf_c) @ cell.T_cf_w_true, SPEC.points_w[i][None])
    return SPEC.camera.project(p_c)[0]


def dark_centroid(image: np.ndarray, near: np.ndarray) -> np.ndarray:
    u0, v0 = (round(c) - ROI_HALF for c in near)
    roi = image[v0 : v0 + 2 * ROI_HALF, u0 : u0 + 2 * ROI_HALF].astype(float)
    inside = roi < 0.5 * (np.percentile(roi, 90) + np.percentile(roi, 1))  # half-way between sheet and hole
    m = cv2.moments(inside.astype(np.uint8), binaryImage=True)
    return np.array([u0 + m["m10"] / m["m00"], v0 + m["m01"] / m["m00"]])


@pytest.fixture
def cell() -> SimCell:
    c = SimCell(SPEC)
    c.new_part()
    return c


@pytest.fixture
def camera(cell: SimCell) -> SimCamera:
    cam = SimCamera(cell)
    cam.open()
    cam.configure(CameraSettings(exposure_us=8000.0))
    return cam


@pytest.mark.parametrize("i", [0, 2])
def test_rendered_hole_is_where_the_truth_projects(cell: SimCell, camera: SimCamera, i: int) -> None:
    assert isinstance(camera, Camera)
    cell.move_to_measuring_pose(i)
    frame = camera.grab(1.0)
    assert frame.image.shape == (2058, 2456) and frame.image.dtype == np.uint8
    expected = truth_px(cell, i)
    assert np.linalg.norm(dark_centroid(frame.image, expected) - expected) < 0.3


def test_region_crops_the_sensor(cell: SimCell, camera: SimCamera) -> None:
    expected = truth_px(cell, 0)
    ox, oy = int(expected[0]) - 300, int(expected[1]) - 200
    camera.configure(CameraSettings(region=(ox, oy, 640, 480)))
    image = camera.grab(1.0).image
    assert image.shape == (480, 640)
    assert np.linalg.norm(dark_centroid(image, expected - [ox, oy]) - (expected - [ox, oy])) < 0.3


def test_exposure_changes_brightness(camera: SimCamera) -> None:
    normal = float(np.median(camera.grab(1.0).image))
    camera.configure(CameraSettings(exposure_us=4000.0))
    half = float(np.median(camera.grab(1.0).image))
    assert half == pytest.approx(normal / 2, rel=0.05)


def test_timeout_and_disconnect_on_command(camera: SimCamera) -> None:
    camera.fail_next("timeout")
    with pytest.raises(DeviceTimeout):
        camera.grab(0.05)
    camera.grab(1.0)
    camera.fail_next("disconnect")
    with pytest.raises(DeviceDisconnected):
        camera.grab(1.0)
    with pytest.raises(DeviceDisconnected):
        camera.grab(1.0)


def test_black_occluded_and_glare_frames(cell: SimCell, camera: SimCamera) -> None:
    expected = truth_px(cell, 0)
    u, v = (round(c) for c in expected)
    camera.fail_next("black")
    assert camera.grab(1.0).image.max() < 16
    camera.fail_next("occluded")
    roi = camera.grab(1.0).image[v - 40 : v + 40, u - 40 : u + 40]
    assert roi.min() > 100  # no dark hole left
    camera.fail_next("glare")
    roi = camera.grab(1.0).image[v - 80 : v + 80, u - 80 : u + 80]
    assert np.count_nonzero(roi == 255) > 1000
    assert camera.grab(1.0).image[v, u] < 100  # the next frame is normal again


def test_unsupported_settings_are_rejected(camera: SimCamera) -> None:
    with pytest.raises(DeviceSettingRejected, match="Mono16"):
        camera.configure(CameraSettings(pixel_format="Mono16"))
    with pytest.raises(DeviceSettingRejected, match="region"):
        camera.configure(CameraSettings(region=(2000, 0, 640, 480)))


def test_hole_out_of_view_when_the_part_is_far_off() -> None:
    cell = SimCell(dataclasses.replace(SPEC, seed=1))
    cell.set_part_pose(SPEC.T_cf_w0 @ np.array([[1, 0, 0, -400.0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]))
    cam = SimCamera(cell)
    cam.open()
    cam.grab(1.0)
    assert cam.last_view is not None and not cam.last_view.in_view[0]


@pytest.mark.parametrize("focus_factor", [1.0, 0.75])
def test_defocus_grows_away_from_the_cell_lens_focus(focus_factor: float) -> None:
    from monoguide.drivers.sim.hole_renderer import blur_sigma_at
    from monoguide.solver.ellipse import Ellipse
    from monoguide.solver.holes import measure_hole
    from monoguide.solver.rim_fit import refine_ellipse_photometric

    probe = SimCell(SPEC)
    probe.reference_part()
    probe.move_to_measuring_pose(0)
    depth = float(transform_points(probe.T_c_w_true(0), SPEC.points_w[:1])[0, 2])
    cell = SimCell(dataclasses.replace(SPEC, focus_distance_mm=focus_factor * depth, aperture_mm=6.0))
    cell.reference_part()
    cell.move_to_measuring_pose(0)
    cam = SimCamera(cell)
    cam.open()
    cam.configure(CameraSettings(exposure_us=8000.0))
    image = cam.grab(1.0).image
    truth = truth_px(cell, 0)
    r_px = SPEC.hole_radius_mm * SPEC.camera.fx / depth
    paper = measure_hole(image, truth, r_px, photometric=False, max_offset_px=10.0)
    start = Ellipse(center=paper.center, axes=paper.axes, angle_deg=paper.angle_deg)
    _, sigma = refine_ellipse_photometric(image.astype(np.float32), start, paper.edge_width_px)
    expected = float(blur_sigma_at(depth, cam.render, SPEC.camera.fx))
    assert cam.render.focus_distance_mm == pytest.approx(focus_factor * depth)
    assert np.sqrt(sigma**2 - 1.0 / 12.0) == pytest.approx(expected, rel=0.12)
    if focus_factor != 1.0:
        assert expected > 2.0 * cam.render.blur_sigma_px  # clearly out of focus


def test_following_a_sim_cell_sees_its_robot_and_part_and_takes_its_faults_once(tmp_path: Path) -> None:
    """The daemon's camera follows the sim-cell through its state file: the controller's truth file says where
    the robot stopped and which part it holds; ``camera_fault`` entries apply once per serial, and one already
    there when the camera opens is history."""
    truth_cell = SimCell(SPEC)  # the controller's side: a part, a stop at S2
    T_cf_w = truth_cell.new_part()
    T_b_f = truth_cell.move_to_measuring_pose(1)
    truth_path, state_path = tmp_path / "robot-truth.json", tmp_path / "state.json"
    write_truth(truth_path, {"format": TRUTH_FORMAT, "part": 1, "in_position": 2, "T_b_f": T_b_f.tolist(),
                             "T_cf_w": T_cf_w.tolist(), "stops": {"2": T_b_f.tolist()}, "offsets": []})

    def state(**extra: object) -> None:
        state_path.write_text(json.dumps({"format": "monoguide.sim-cell-state/1", "robot": {"truth": str(truth_path)},
                                          **extra}))

    state(camera_fault={"failure": "timeout", "count": 1, "serial": 4})  # before the camera opened: not applied
    camera = SimCamera(SimCell(SPEC), follow=state_path)  # its own cell: reference part, at S1
    camera.open()
    frame = camera.grab(1.0)
    np.testing.assert_allclose(camera.cell.T_cf_w_true, T_cf_w)
    assert camera.cell.current_pose == 1
    expected = truth_px(truth_cell, 1)
    assert np.linalg.norm(dark_centroid(frame.image, expected) - expected) < 1.0

    state(camera_fault={"failure": "black", "count": 2, "serial": 5})
    assert camera.grab(1.0).image.max() < 16
    assert camera.grab(1.0).image.max() < 16
    assert camera.grab(1.0).image.max() > 100  # two only, and serial 5 is not taken up again


def test_following_without_a_sim_cell_renders_the_own_cell(tmp_path: Path) -> None:
    camera = SimCamera(SimCell(SPEC), follow=tmp_path / "absent.json")
    camera.open()
    assert camera.grab(1.0).image.shape == (2058, 2456)
    (tmp_path / "absent.json").write_text("{not json")
    with pytest.raises(DeviceDisconnected, match="cannot read the sim-cell state file"):
        camera.grab(1.0)
