"""``config/sim-cell.toml``: generated, on the planned layout, and holding the paper's deviation range.

The checks go through the simulated cell's own chain (robot base, taught flange pose, true camera mounting,
part pose) and OpenCV's projection, not through the planner that produced the poses.
"""

from __future__ import annotations

import dataclasses
import itertools
import tomllib
from pathlib import Path

import cv2
import numpy as np
import pytest

from monoguide.daemon.assembly import sim_cell_spec
from monoguide.daemon.config import load_cell_config
from monoguide.drivers.sim.camera import SimCamera
from monoguide.drivers.sim.cell import SimCell, part_deviation
from monoguide.drivers.sim.hole_renderer import RenderSettings
from monoguide.drivers.sim.make_cell_config import cell_config_toml, main
from monoguide.solver.frames import compose
from monoguide.solver.planning import look_at_poses

CONFIG_PATH = Path(__file__).parents[3] / "config" / "sim-cell.toml"
CONFIG = load_cell_config(CONFIG_PATH)
SPEC = sim_cell_spec(CONFIG)


def test_the_committed_config_is_what_the_generator_writes(tmp_path: Path) -> None:
    """Same keys, same texts, numbers within 1e-9: the matrices are printed to 12 decimals, whose last digit
    depends on the numpy/BLAS build that computed them — never compare the last bit of a float."""
    _assert_same_toml(tomllib.loads(CONFIG_PATH.read_text()), tomllib.loads(cell_config_toml()),
                      "config/sim-cell.toml is stale: run python -m monoguide.drivers.sim.make_cell_config "
                      "config/sim-cell.toml")
    out = tmp_path / "cell.toml"
    assert main([str(out)]) == 0
    _assert_same_toml(tomllib.loads(out.read_text()), tomllib.loads(CONFIG_PATH.read_text()), "written file")


def test_the_config_comparison_sees_a_changed_digit() -> None:
    text = tomllib.loads(CONFIG_PATH.read_text())
    moved = tomllib.loads(CONFIG_PATH.read_text())
    moved["reference"]["T_cf_b"][0][3] += 1e-6  # a micrometre: a different cell
    with pytest.raises(AssertionError, match=r"reference.T_cf_b\[0\]\[3\]"):
        _assert_same_toml(text, moved, "")
    nudged = tomllib.loads(CONFIG_PATH.read_text())
    nudged["reference"]["T_cf_b"][0][3] += 1e-12  # below the printed precision: the same config
    _assert_same_toml(text, nudged, "")


def _assert_same_toml(a: object, b: object, why: str, where: str = "") -> None:
    if isinstance(a, dict) and isinstance(b, dict):
        assert a.keys() == b.keys(), f"{why}: keys differ at {where or 'top'}: {sorted(a.keys() ^ b.keys())}"
        for key in a:
            _assert_same_toml(a[key], b[key], why, f"{where}.{key}" if where else key)
    elif isinstance(a, list) and isinstance(b, list):
        assert len(a) == len(b), f"{why}: {where} has {len(a)} against {len(b)} entries"
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            _assert_same_toml(x, y, why, f"{where}[{i}]")
    elif isinstance(a, float) or isinstance(b, float):
        assert isinstance(a, int | float) and isinstance(b, int | float), f"{why}: {where}: {a!r} against {b!r}"
        assert a == pytest.approx(b, abs=1e-9, rel=0), f"{why}: {where}: {a!r} against {b!r}"
    else:
        assert a == b, f"{why}: {where}: {a!r} against {b!r}"


def test_the_simulated_parts_deviate_over_the_papers_range() -> None:
    """Drawn within 99 % of the paper's +-50 mm / +-5 deg (the envelope the line is planned and checked for)."""
    assert SPEC.deviation_translation_mm == pytest.approx((49.5, 49.5, 49.5), abs=1e-12)
    assert SPEC.deviation_rotation_deg == pytest.approx((4.95, 4.95, 4.95), abs=1e-12)
    layout = CONFIG.layout
    assert layout is not None
    assert layout.envelope.translation_mm == (50.0, 50.0, 50.0) and layout.envelope.rotation_deg == (5.0, 5.0, 5.0)
    near, far = layout.constraints.depth_of_field_mm
    assert SPEC.focus_distance_mm is not None and near < SPEC.focus_distance_mm < far


def test_the_robots_taught_poses_put_the_camera_on_the_measuring_poses() -> None:
    """The sim robot's kinematics agree with T_cf_si: base, taught flange pose and the true mounting."""
    cell = SimCell(dataclasses.replace(SPEC, repeatability_mm=0.0, repeatability_deg=0.0))
    for i, pose in enumerate(CONFIG.measuring_poses):
        cell.move_to_measuring_pose(i)
        np.testing.assert_allclose(compose(SPEC.T_cf_b, cell.actual_flange_pose(i), SPEC.T_f_c), pose.T_cf_si,
                                   atol=1e-9)
        flange_to_camera = pose.T_cf_si[:3, 3] - compose(SPEC.T_cf_b, cell.T_b_f_taught(i))[:3, 3]
        assert np.linalg.norm(flange_to_camera) == pytest.approx(np.linalg.norm(SPEC.T_f_c[:3, 3]), abs=1e-9)


def _corner_parts() -> list[np.ndarray]:
    centre = SPEC.points_w.mean(axis=0)
    limits = np.concatenate([np.radians(SPEC.deviation_rotation_deg), SPEC.deviation_translation_mm])
    return [compose(SPEC.T_cf_w0, part_deviation(s[:3] * limits[:3], s[3:] * limits[3:], centre))
            for s in (np.array(c) * 1.0 for c in itertools.product((-1, 1), repeat=6))]


def _margin_and_depth(cell: SimCell, i: int) -> tuple[float, float]:
    T_c_w = cell.T_c_w_true(i)
    rvec, _ = cv2.Rodrigues(T_c_w[:3, :3])
    cam = SPEC.camera
    px, _ = cv2.projectPoints(SPEC.points_w[i].reshape(1, 1, 3), rvec, T_c_w[:3, 3], cam.K, cam.dist_coeffs)
    u, v = px.reshape(2)
    depth = float((T_c_w[:3, :3] @ SPEC.points_w[i] + T_c_w[:3, 3])[2])
    return min(u + 0.5, cam.width - 0.5 - u, v + 0.5, cam.height - 0.5 - v), depth


def test_every_hole_stays_in_view_at_every_corner_of_the_deviation_range() -> None:
    """At the 64 corners of +-50 mm / +-5 deg, with the robot's repeatability drawn, every view sees its hole
    at least 100 px inside the image (the config's [layout] margin_px) and inside its depth of field; the
    worst corner of each view, rendered by the simulated camera, shows the hole whole."""
    cell = SimCell(SPEC)
    near, far = CONFIG.layout.constraints.depth_of_field_mm
    worst: dict[int, tuple[float, np.ndarray]] = {}
    for T_cf_w in _corner_parts():
        cell.set_part_pose(T_cf_w)
        for i in range(len(CONFIG.measuring_poses)):  # the roof's (job 1); the hood's: test_hood_views
            cell.move_to_measuring_pose(i)
            margin, depth = _margin_and_depth(cell, i)
            assert margin >= 99.0, f"S{i + 1}: hole {margin:.1f} px from the border"  # repeatability: < 1 px
            assert near - 1.0 <= depth <= far + 1.0, f"S{i + 1}: hole at depth {depth:.1f} mm"
            if margin < worst.get(i, (np.inf, None))[0]:
                worst[i] = (margin, T_cf_w)
    camera = SimCamera(cell, RenderSettings(noise_sigma=0.5), seed=3)
    camera.open()
    for i, (_, T_cf_w) in worst.items():
        cell.set_part_pose(T_cf_w)
        cell.move_to_measuring_pose(i)
        camera.grab(5.0)
        assert camera.last_view is not None and camera.last_view.in_view[i]


def test_the_old_straight_down_layout_would_have_lost_holes() -> None:
    """The check above can fail: the layout the config had before issue 8 (straight down from 650 mm, holes
    a quarter from the edge) leaves the image at corners of the same range."""
    old = tuple(compose(SPEC.T_cf_w0, T) for T in look_at_poses(SPEC.points_w, SPEC.camera, 650.0))
    cell = SimCell(dataclasses.replace(SPEC, T_cf_si=old, repeatability_mm=0.0, repeatability_deg=0.0))
    margins = []
    for T_cf_w in _corner_parts():
        cell.set_part_pose(T_cf_w)
        for i in range(len(CONFIG.measuring_poses)):  # the roof's (job 1); the hood's: test_hood_views
            cell.move_to_measuring_pose(i)
            margins.append(_margin_and_depth(cell, i)[0])
    assert min(margins) < -300.0


def test_the_simulated_camera_has_the_cells_lens() -> None:
    """[sim] focus_distance_mm and aperture_mm reach the renderer: the thin lens's blur circle
    (aperture * f * |1/depth - 1/focus|, by hand) is 2 px at both ends of the planned depth of field."""
    camera = SimCamera(SimCell(SPEC))
    assert camera.render.focus_distance_mm == SPEC.focus_distance_mm == 600.0
    assert camera.render.aperture_mm == SPEC.aperture_mm > 0.0
    for depth in CONFIG.layout.constraints.depth_of_field_mm:
        circle = SPEC.aperture_mm * SPEC.camera.fx * abs(1.0 / depth - 1.0 / SPEC.focus_distance_mm)
        assert circle == pytest.approx(2.0, abs=1e-3)
    own = SimCamera(SimCell(SPEC), RenderSettings(focus_distance_mm=450.0, aperture_mm=3.0))
    assert own.render.focus_distance_mm == 450.0 and own.render.aperture_mm == 3.0  # a given lens is kept


def test_the_hood_views_see_both_their_holes_at_every_corner_of_the_deviation_range() -> None:
    """Job 2: each of its three poses keeps both of its holes inside the image with the layout's margin and inside
    the depth of field, at every corner of the envelope (rendered truth: the SimCell's projection of the hood)."""
    from monoguide.drivers.sim.make_cell_config import HOOD_POINTS_W, HOOD_VIEWS, LAYOUT

    hood = CONFIG.for_job(2)
    assert [p.points for p in hood.measuring_poses] == [tuple(v) for v in HOOD_VIEWS]
    cell = SimCell(SPEC)
    cell.set_part_type(2)
    assert np.allclose(cell.spec.points_w, HOOD_POINTS_W)
    centre = HOOD_POINTS_W.mean(axis=0)
    limits = np.concatenate([np.radians(SPEC.deviation_rotation_deg), SPEC.deviation_translation_mm])
    cam = SPEC.camera
    worst_margin, depths = np.inf, []
    for corner in itertools.product((-1.0, 1.0), repeat=6):
        s = np.array(corner)
        cell.set_part_pose(compose(hood.reference.T_cf_w0, part_deviation(s[:3] * limits[:3], s[3:] * limits[3:],
                                                                            centre)))
        for pose in hood.measuring_poses:
            cell.move_to_measuring_pose(pose.number - 1)
            T_c_w = cell.T_c_w_true(pose.number - 1)
            rvec, _ = cv2.Rodrigues(T_c_w[:3, :3])
            for j in pose.points:
                px, _ = cv2.projectPoints(HOOD_POINTS_W[j].reshape(1, 1, 3), rvec, T_c_w[:3, 3], cam.K,
                                          cam.dist_coeffs)
                u, v = px.reshape(2)
                worst_margin = min(worst_margin, u + 0.5, cam.width - 0.5 - u, v + 0.5, cam.height - 0.5 - v)
                depths.append(float((T_c_w[:3, :3] @ HOOD_POINTS_W[j] + T_c_w[:3, 3])[2]))
    assert worst_margin >= LAYOUT.margin_px * 0.9  # the robot's repeatability moves the image a little
    assert LAYOUT.depth_of_field_mm[0] <= min(depths) and max(depths) <= LAYOUT.depth_of_field_mm[1]
