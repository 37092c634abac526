"""The simulated camera shows the cell's fixed reference marks (config/sim-cell-marks.toml) where the truth has them:
found by the cycle's hole finder to 0.1 px of their true projection, hidden where the part's sheet (its outline)
lies on the line of sight, moved by a camera bump as the geometry says; the holes are measured as without the
marks; the tracker offers each mark's hidden-point nest under its name.

Every expectation is computed here from the config's numbers (mark positions, robot base, camera mounting, lens,
the part's outline), never read back from the simulator's own bookkeeping."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from monoguide.daemon.assembly import build_sim_cell, sim_cell_spec
from monoguide.daemon.config import load_cell_config
from monoguide.daemon.config._marks import ReferenceMarkConfig
from monoguide.drivers.camera import CameraSettings
from monoguide.drivers.sim.calibration_faults import CalibrationFaults
from monoguide.drivers.sim.camera import SimCamera
from monoguide.drivers.sim.cell import SimCell, SimMark, SimScene
from monoguide.solver.camera import CameraModel
from monoguide.solver.errors import FeatureNotFound
from monoguide.solver.frames import invert, make_T, rotvec_to_matrix, transform_points
from monoguide.solver.holes import measure_hole, perspective_correction

CONFIG = load_cell_config(Path(__file__).parents[3] / "config" / "sim-cell-marks.toml")
LENS = CONFIG.camera.intrinsics
T_CF_B = CONFIG.reference.T_cf_b
T_F_C = CONFIG.sim.T_f_c  # type: ignore[union-attr]
MARKS = {m.name: m for m in CONFIG.reference_marks}
JOB_OF_POSE = {mp.number: p.job for p in CONFIG.parts for mp in p.measuring_poses}
PART = {p.job: p for p in CONFIG.parts}
MARKED_POSES = [i for i, p in enumerate(CONFIG.cell_poses) if p.marks]  # the roof's (the hood's poses have none)
MARK_TOL_PX = 0.1
HOLE_TOL_PX = 0.1


# --- the truth, from the config's numbers ------------------------------------------------------------------------


def camera_pose(cell: SimCell, i: int, B: np.ndarray | None = None) -> np.ndarray:
    """``T_cf_c`` of the true camera at the robot's last stop at pose i: base, flange, mounting (bumped by B)."""
    T = T_CF_B @ cell.actual_flange_pose(i) @ T_F_C
    return T if B is None else T @ B


def projected(T_cf_c: np.ndarray, p_cf: np.ndarray, lens: CameraModel = LENS) -> tuple[np.ndarray, float]:
    """The exact image (2,) px of a cell-frame point and its depth (camera z, mm)."""
    p_c = transform_points(invert(T_cf_c), np.asarray(p_cf, dtype=float)[None])[0]
    return lens.project(p_c[None])[0], float(p_c[2])


def ellipse_offset(T_cf_c: np.ndarray, mark: ReferenceMarkConfig, lens: CameraModel = LENS) -> np.ndarray:
    """The imaged ellipse's centre minus the image of the mark's 3-D centre (the finder measures the former)."""
    return perspective_correction(lens, invert(T_cf_c), mark.position_cf, mark.normal_cf, mark.radius_mm)


def sheet_hides(T_cf_c: np.ndarray, T_cf_w: np.ndarray, outline_w: np.ndarray | None, p_cf: np.ndarray) -> bool:
    """The segment camera centre -> ``p_cf`` crosses the part's plane (z = 0 of W, the outline's) inside the outline."""
    if outline_w is None:
        return False
    assert np.allclose(outline_w[:, 2], 0.0)  # these outlines lie in z = 0 of their part frame
    T_w_cf = invert(T_cf_w)
    eye, p = transform_points(T_w_cf, np.vstack([T_cf_c[:3, 3], p_cf]))
    if eye[2] * p[2] >= 0.0:
        return False
    x = eye + eye[2] / (eye[2] - p[2]) * (p - eye)
    contour = outline_w[:, :2].astype(np.float32).reshape(-1, 1, 2)
    return cv2.pointPolygonTest(contour, (float(x[0]), float(x[1])), False) > 0


def covering(T_cf_c: np.ndarray, job: int, name: str, margin_mm: float = 30.0) -> np.ndarray:
    """``T_cf_w`` of part ``job`` shifted in its own plane so that its outline covers the line of sight from the
    camera ``T_cf_c`` to mark ``name`` with ``margin_mm`` to spare (its rectangle's nearest edge moved past the
    point where that line crosses the part's plane)."""
    part = PART[job]
    eye, p = transform_points(invert(part.T_cf_w0), np.vstack([T_cf_c[:3, 3], MARKS[name].position_cf]))
    q = eye + eye[2] / (eye[2] - p[2]) * (p - eye)  # where the line of sight crosses z = 0 of the reference part
    lo, hi = part.part.outline_w[:, :2].min(axis=0), part.part.outline_w[:, :2].max(axis=0)
    shift = np.zeros(3)
    for axis in (0, 1):
        if q[axis] < lo[axis]:
            shift[axis] = q[axis] - lo[axis] - margin_mm
        elif q[axis] > hi[axis]:
            shift[axis] = q[axis] - hi[axis] + margin_mm
    assert np.any(shift), f"{name} is behind the reference part already"
    return part.T_cf_w0 @ make_T(np.eye(3), shift)


def bump(deg: float, mm: float) -> np.ndarray:
    """``B``: ``deg`` about and ``mm`` along the camera's own x axis (the simulated bump's convention)."""
    return make_T(rotvec_to_matrix(np.array([math.radians(deg), 0.0, 0.0])), np.array([mm, 0.0, 0.0]))


def measure_mark(image: np.ndarray, T_cf_c: np.ndarray, mark: ReferenceMarkConfig,
                 lens: CameraModel = LENS) -> np.ndarray:
    """Where the hole finder puts the image of the mark's 3-D centre (its ellipse centre, perspective-corrected),
    searching about the true projection with the radius its depth gives."""
    truth, depth = projected(T_cf_c, mark.position_cf, lens)
    offset = ellipse_offset(T_cf_c, mark, lens)
    found = measure_hole(image, truth + offset, mark.radius_mm * lens.fx / depth, max_offset_px=8.0)
    return found.center - offset


# --- fixtures ----------------------------------------------------------------------------------------------------


@pytest.fixture
def cell() -> SimCell:
    return build_sim_cell(CONFIG)


@pytest.fixture
def camera(cell: SimCell) -> SimCamera:
    cam = SimCamera(cell, seed=11)
    cam.open()
    cam.configure(CameraSettings(exposure_us=8000.0))
    return cam


def at_pose(cell: SimCell, i: int, T_cf_w: np.ndarray | None = None) -> None:
    """The part type of pose i in the cell (at its reference, or at ``T_cf_w``), the robot at pose i (seeded)."""
    cell.set_part_type(JOB_OF_POSE[CONFIG.cell_poses[i].number])
    cell.set_part_pose(PART[cell.part_job].T_cf_w0 if T_cf_w is None else T_cf_w)
    cell.move_to_measuring_pose(i, np.random.default_rng(300 + i))


# --- (a) every pose's marks in its frame -------------------------------------------------------------------------


def test_the_cell_has_marks_to_show() -> None:
    assert len(MARKED_POSES) >= 4 and all(len(CONFIG.cell_poses[i].marks) == 3 for i in MARKED_POSES)


@pytest.mark.parametrize("i", MARKED_POSES)
def test_each_pose_shows_its_marks_where_the_truth_projects_them(cell: SimCell, camera: SimCamera, i: int) -> None:
    at_pose(cell, i)
    image = camera.grab(1.0).image
    pose = CONFIG.cell_poses[i]
    T_cf_c = camera_pose(cell, i)
    outline = PART[cell.part_job].part.outline_w
    seen = 0
    for k in pose.marks:
        mark = CONFIG.reference_marks[k]
        truth, _ = projected(T_cf_c, mark.position_cf)
        np.testing.assert_allclose(camera.last_marks[mark.name].center_px, truth, atol=1e-6)
        assert LENS.in_image(truth[None], margin=60.0)[0]  # the layout put it well inside the frame
        if sheet_hides(T_cf_c, PART[cell.part_job].T_cf_w0, outline, mark.position_cf):
            assert camera.last_marks[mark.name].hidden and not camera.last_marks[mark.name].rendered
            with pytest.raises(FeatureNotFound):
                measure_mark(image, T_cf_c, mark)
            continue
        seen += 1
        assert camera.last_marks[mark.name].rendered and camera.last_marks[mark.name].in_view
        assert np.linalg.norm(measure_mark(image, T_cf_c, mark) - truth) < MARK_TOL_PX
    assert seen == 3  # the marks lie outside the part at its reference: every one is seen


def test_without_an_outline_the_part_hides_no_mark(cell: SimCell) -> None:
    """The roof moved over S1-M1's line of sight, but a part of no given outline: all three marks of S1 are drawn
    (the sheet is not modelled without an outline)."""
    spec = dataclasses.replace(cell.spec, outline_w=None, part_types=tuple(
        dataclasses.replace(p, outline_w=None) for p in cell.spec.part_types))
    bare = SimCell(spec)
    camera = SimCamera(bare, seed=4)
    camera.open()
    at_pose(bare, 0)
    at_pose(bare, 0, covering(camera_pose(bare, 0), 1, "S1-M1"))
    image = camera.grab(1.0).image
    T_cf_c = camera_pose(bare, 0)
    for k in CONFIG.cell_poses[0].marks:
        mark = CONFIG.reference_marks[k]
        truth, _ = projected(T_cf_c, mark.position_cf)
        assert np.linalg.norm(measure_mark(image, T_cf_c, mark) - truth) < MARK_TOL_PX


# --- (b) the holes as before -------------------------------------------------------------------------------------


@pytest.mark.parametrize("i", [0, 2, 4])
def test_the_holes_are_measured_as_without_the_marks(cell: SimCell, i: int) -> None:
    """The same seeded frame with and without the marks: each hole of the view within 0.1 px of its true projection
    in both, and the two measurements within 0.01 px of each other (the marks do not disturb the holes)."""
    no_marks = SimCell(dataclasses.replace(cell.spec, marks=()))
    measured = []
    for c in (cell, no_marks):
        cam = SimCamera(c, seed=21)
        cam.open()
        at_pose(c, i)
        image = cam.grab(1.0).image
        T_cf_c = camera_pose(c, i)
        part = PART[c.part_job]
        T_c_w = invert(T_cf_c) @ part.T_cf_w0
        out = []
        for p_w in part.part.points_w:  # the view's holes: those in its frame
            p_c = transform_points(T_c_w, p_w[None])[0]
            truth = LENS.project(p_c[None])[0]
            if not LENS.in_image(truth[None], margin=100.0)[0]:
                continue
            offset = perspective_correction(LENS, T_c_w, p_w, np.array([0.0, 0.0, 1.0]), part.part.hole_radius_mm)
            found = measure_hole(image, truth + offset, part.part.hole_radius_mm * LENS.fx / p_c[2], max_offset_px=5.0)
            assert np.linalg.norm(found.center - offset - truth) < HOLE_TOL_PX
            out.append(found.center)
        assert out  # the view has its hole(s)
        measured.append(np.array(out))
    np.testing.assert_allclose(measured[0], measured[1], atol=0.01)


# --- (c) the part's sheet hides a mark ---------------------------------------------------------------------------


@pytest.mark.parametrize("i", MARKED_POSES)
def test_a_part_over_a_marks_line_of_sight_hides_it_and_only_it(cell: SimCell, camera: SimCamera, i: int) -> None:
    """The roof shifted in its plane so that its edge lies 30 mm beyond where one mark's line of sight crosses it
    (a mark whose covering hides no other): that mark is hidden, the others of the view are seen; the roof back at
    its reference, it is seen again."""
    names = [CONFIG.reference_marks[k].name for k in CONFIG.cell_poses[i].marks]
    roof = PART[1]
    at_pose(cell, i)  # the stop is seeded: the same at every at_pose(cell, i)
    T_cf_c = camera_pose(cell, i)
    for target in names:  # the geometry of this test, computed here
        moved = covering(T_cf_c, 1, target)
        hidden = [n for n in names if sheet_hides(T_cf_c, moved, roof.part.outline_w, MARKS[n].position_cf)]
        if hidden == [target]:
            break
    else:
        pytest.fail(f"no mark of {CONFIG.cell_poses[i].name} can be covered alone")
    at_pose(cell, i, moved)
    image = camera.grab(1.0).image
    np.testing.assert_array_equal(camera_pose(cell, i), T_cf_c)
    for name in names:
        mark = MARKS[name]
        truth, _ = projected(T_cf_c, mark.position_cf)
        if name in hidden:
            assert not camera.last_marks[name].rendered and camera.last_marks[name].hidden
            with pytest.raises(FeatureNotFound):
                measure_mark(image, T_cf_c, mark)
        else:
            assert np.linalg.norm(measure_mark(image, T_cf_c, mark) - truth) < MARK_TOL_PX
    at_pose(cell, i)  # the roof back at its reference: the mark is seen again
    image = camera.grab(1.0).image
    truth, _ = projected(T_cf_c, MARKS[target].position_cf)
    assert np.linalg.norm(measure_mark(image, T_cf_c, MARKS[target]) - truth) < MARK_TOL_PX


def test_a_mark_behind_the_camera_or_out_of_the_frame_is_not_drawn(cell: SimCell, camera: SimCamera) -> None:
    """From S1 the marks of S3 (the roof's far corner, ~2 m away) are outside the image: not drawn, with their
    truth kept; a mark behind the camera is not drawn and has no projection."""
    behind = SimMark("BEHIND", camera_pose(cell, 0)[:3, 3] - 200.0 * camera_pose(cell, 0)[:3, 2], 10.0,
                     np.array([0.0, 0.0, 1.0]))
    cell.spec = dataclasses.replace(cell.spec, marks=(*cell.spec.marks, behind))
    at_pose(cell, 0)
    camera.grab(1.0)
    T_cf_c = camera_pose(cell, 0)
    for name in ("S3-M1", "S3-M2", "S3-M3"):
        truth, depth = projected(T_cf_c, MARKS[name].position_cf)
        assert depth > 0 and not LENS.in_image(truth[None], margin=-100.0)[0]
        assert not camera.last_marks[name].rendered and not camera.last_marks[name].in_view
    behind_now = camera_pose(cell, 0)  # the stop moved a little since the mark was placed: still behind
    assert transform_points(invert(behind_now), behind.position_cf[None])[0, 2] < 0
    assert not camera.last_marks["BEHIND"].rendered and np.all(np.isnan(camera.last_marks["BEHIND"].center_px))


# --- (d) calibration faults move the marks as the truth says -----------------------------------------------------


@pytest.mark.parametrize("deg, mm", [(0.2, 0.0), (0.0, 1.5)])
def test_a_camera_bump_moves_the_marks_images_as_the_geometry_says(cell: SimCell, camera: SimCamera,
                                                                   deg: float, mm: float) -> None:
    at_pose(cell, 1)
    camera.set_calibration_faults(CalibrationFaults(bump_deg=deg, bump_mm=mm, bump_axis="x"))
    image = camera.grab(1.0).image
    calibrated, bumped = camera_pose(cell, 1), camera_pose(cell, 1, bump(deg, mm))
    for k in CONFIG.cell_poses[1].marks:
        mark = CONFIG.reference_marks[k]
        before, _ = projected(calibrated, mark.position_cf)
        after, _ = projected(bumped, mark.position_cf)
        assert np.linalg.norm(after - before) > 2.0  # the bump moves the image well beyond the tolerance
        assert np.linalg.norm(measure_mark(image, bumped, mark) - after) < MARK_TOL_PX


def test_a_focal_change_scales_the_marks_images_about_the_principal_point(cell: SimCell, camera: SimCamera) -> None:
    at_pose(cell, 0)
    camera.set_calibration_faults(CalibrationFaults(focal_pct=0.5))
    image = camera.grab(1.0).image
    lens = dataclasses.replace(LENS, fx=LENS.fx * 1.005, fy=LENS.fy * 1.005)
    T_cf_c = camera_pose(cell, 0)
    for k in CONFIG.cell_poses[0].marks:
        mark = CONFIG.reference_marks[k]
        truth, _ = projected(T_cf_c, mark.position_cf, lens)
        assert np.linalg.norm(truth - projected(T_cf_c, mark.position_cf)[0]) > 1.0
        assert np.linalg.norm(measure_mark(image, T_cf_c, mark, lens) - truth) < MARK_TOL_PX


# --- (e) the tracker's nests, the spec -----------------------------------------------------------------------------


def test_the_tracker_offers_each_marks_hidden_point_nest_under_its_name(cell: SimCell) -> None:
    T_tracker_cf = invert(CONFIG.sim.T_cf_tracker)  # type: ignore[union-attr]
    for scene in (None, SimScene()):  # the marks are fixed in the cell: whatever the operator has placed
        cell.scene = scene
        targets = cell.tracker_targets()
        for mark in CONFIG.reference_marks:
            expected = T_tracker_cf[:3, :3] @ mark.position_cf + T_tracker_cf[:3, 3]
            np.testing.assert_allclose(targets[mark.name], expected, atol=1e-9)
        assert {"B1", "B2", "B3", "P1"} <= set(targets)  # the other nests as before
    cell.scene = None
    for job in (2, 1):  # the marks do not follow the part type
        cell.set_part_type(job)
        np.testing.assert_allclose(cell.smr_positions()["S3-M2"], MARKS["S3-M2"].position_cf, atol=1e-12)


def test_a_mark_named_as_another_nest_is_refused(cell: SimCell) -> None:
    cell.spec = dataclasses.replace(cell.spec, marks=(SimMark("B1", np.zeros(3), 10.0),))
    with pytest.raises(ValueError, match="B1"):
        cell.tracker_targets()


def test_the_spec_has_the_configs_marks_and_each_part_types_outline(cell: SimCell) -> None:
    spec = sim_cell_spec(CONFIG)
    assert [m.name for m in spec.marks] == [m.name for m in CONFIG.reference_marks]
    for mark, config in zip(spec.marks, CONFIG.reference_marks, strict=True):
        np.testing.assert_array_equal(mark.position_cf, config.position_cf)
        np.testing.assert_array_equal(mark.normal_cf, config.normal_cf)
        assert mark.radius_mm == config.diameter_mm / 2 == 10.0
    np.testing.assert_array_equal(spec.outline_w, PART[1].part.outline_w)
    for part in spec.part_types:
        np.testing.assert_array_equal(part.outline_w, PART[part.job].part.outline_w)
    cell.set_part_type(2)
    np.testing.assert_array_equal(cell.spec.outline_w, PART[2].part.outline_w)
    cell.set_part_type(1)
    np.testing.assert_array_equal(cell.spec.outline_w, PART[1].part.outline_w)
    plain = sim_cell_spec(load_cell_config(Path(__file__).parents[3] / "config" / "sim-cell.toml"))
    assert plain.marks == () and plain.outline_w is not None


def test_a_calibration_scene_shows_no_marks(cell: SimCell, camera: SimCamera) -> None:
    """``monoguide calibrate --sim`` with a target under the camera: the target is rendered, not the marks."""
    at_pose(cell, 0)
    cell.scene = SimScene(targets={0: cell.spec.targets[0].T_cf_t})
    camera.grab(1.0)
    assert camera.last_marks == {}
