"""The planner's check of the fixed marks (``solver.planning.marks``): a mark the part can hide anywhere in its
envelope, a mark out of the image, behind the camera or on another mark's image is reported, naming the view and the
mark; the simulated cell's marks (config/sim-cell-marks.toml) pass.

Every expected number is computed here by hand geometry (a line cut with a plane, a distance to a line), never read
back from the check's own sampling."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from monoguide.daemon.config import load_cell_config
from monoguide.daemon.plan import cell_marks_check
from monoguide.drivers.sim import make_cell_config as gen
from monoguide.solver.camera import PAPER_CAMERA
from monoguide.solver.envelope import DeviationEnvelope
from monoguide.solver.frames import make_T
from monoguide.solver.planning.errors import LayoutOutOfView, LayoutRequestInvalid
from monoguide.solver.planning.marks import (
    BEHIND_CAMERA,
    HIDDEN,
    OUT_OF_IMAGE,
    OVERLAPS,
    VISIBLE,
    Mark,
    MarkedView,
    PartSheet,
    check_marks,
)

SIM_CELL_MARKS = Path(__file__).parents[3] / "config" / "sim-cell-marks.toml"
SQUARE_W = np.array([[0.0, 0.0, 0.0], [1000.0, 0.0, 0.0], [1000.0, 1000.0, 0.0], [0.0, 1000.0, 0.0]])
HOLES_W = np.array([[100.0, 100.0, 0.0], [900.0, 100.0, 0.0], [900.0, 900.0, 0.0], [100.0, 900.0, 0.0]])
SHIFT_X = DeviationEnvelope(translation_mm=(50.0, 0.0, 0.0), rotation_deg=(0.0, 0.0, 0.0))
CAMERA_CF = np.array([1200.0, 500.0, 800.0])  # beyond the sheet's edge x = 1000, 800 mm above its plane
RADIUS = 10.0
BELOW = 10.0


def looking_at(eye: np.ndarray, target: np.ndarray) -> np.ndarray:
    """``T_cf_si`` of a camera at ``eye`` whose z axis (line of sight) points at ``target``."""
    z = (target - eye) / np.linalg.norm(target - eye)
    x = np.cross([0.0, 1.0, 0.0], z)
    x /= np.linalg.norm(x)
    return make_T(np.column_stack([x, np.cross(z, x), z]), eye)


def mark_cutting_plane_at(x_cut: float) -> np.ndarray:
    """The mark BELOW mm under the plane z = 0 whose line of sight from CAMERA_CF cuts that plane at x = ``x_cut``
    (y = 500): the line from the camera through (x_cut, 500, 0) continued to z = -BELOW."""
    cut = np.array([x_cut, 500.0, 0.0])
    s = (CAMERA_CF[2] + BELOW) / CAMERA_CF[2]
    return CAMERA_CF + s * (cut - CAMERA_CF)


def one_mark(position: np.ndarray, envelope: DeviationEnvelope = SHIFT_X, camera_at: np.ndarray = CAMERA_CF,
             outline: np.ndarray | None = SQUARE_W):
    view = MarkedView("V1", looking_at(camera_at, position), (0,), (0,), 100.0)
    part = PartSheet("plate", np.eye(4), HOLES_W, envelope.at(HOLES_W), outline)
    return check_marks(PAPER_CAMERA, [view], [Mark("M1", position, RADIUS)], [part])


def test_a_mark_under_the_edge_of_the_part_shifted_to_the_envelopes_edge_is_hidden() -> None:
    """The sheet's edge x = 1000 mm moves to x = 1050 mm with the part shifted +50 mm (the envelope's edge); the
    mark's line of sight cuts the plane exactly there: hidden, at that shift, 0 mm from the outline."""
    check = one_mark(mark_cutting_plane_at(1050.0))
    (r,) = check.results
    assert r.status == HIDDEN and not r.ok and not check.ok
    assert r.clearance_mm == pytest.approx(0.0, abs=0.05) and r.required_mm == RADIUS + 5.0
    assert r.part == "plate" and r.deviation_mm[0] == pytest.approx(50.0, abs=0.1)
    error = check.error()
    assert isinstance(error, LayoutOutOfView)
    assert "view V1, mark M1" in error.message and "part plate hides it" in error.message
    with pytest.raises(LayoutOutOfView, match="view V1, mark M1: part plate hides it"):
        check.raise_if_not_seen()


def test_the_same_mark_20_mm_farther_out_is_visible_with_its_clearance() -> None:
    """Moved 20 mm farther from the part (x + 20, still BELOW mm under the plane): its line of sight from the camera
    800 mm above the plane now cuts it 20 * 800 / 810 = 19.75 mm farther out (similar triangles), so the part shifted
    +50 mm keeps exactly that from it: visible (>= 15 mm)."""
    moved = mark_cutting_plane_at(1050.0) + np.array([20.0, 0.0, 0.0])
    expected = 20.0 * CAMERA_CF[2] / (CAMERA_CF[2] + BELOW)
    (r,) = one_mark(moved).results
    assert r.status == VISIBLE and r.ok and r.reasons == ()
    assert r.clearance_mm == pytest.approx(expected, abs=0.01) and expected == pytest.approx(19.753, abs=1e-3)
    assert r.deviation_mm[0] == pytest.approx(50.0, abs=0.1)  # still the part at the envelope's edge
    assert r.margin_px is not None and r.margin_px > 900  # near the image's centre


def test_a_corner_of_the_outline_swept_by_a_turn_is_found_between_the_envelopes_corners() -> None:
    """A square turned about its centre (the envelope's point) by up to 10 deg: the mark lies 10 mm beyond the
    corner's arc where the corner passes at +3.7 deg, a turn no corner of the envelope's box holds. The check finds
    those 10 mm (hidden: under 15); the box's corners alone would see > 15 mm and call it visible."""
    square = np.array([[-500.0, -500.0, 0.0], [500.0, -500.0, 0.0], [500.0, 500.0, 0.0], [-500.0, 500.0, 0.0]])
    holes = 0.8 * square
    turn = DeviationEnvelope(translation_mm=(0.0, 0.0, 0.0), rotation_deg=(0.0, 0.0, 10.0))
    angle = math.radians(45.0 + 3.7)
    radius = math.hypot(500.0, 500.0) + 10.0
    mark = np.array([radius * math.cos(angle), radius * math.sin(angle), 0.0])
    view = MarkedView("V1", looking_at(mark + np.array([0.0, 0.0, 700.0]), mark), (0,), (0,), 100.0)
    part = PartSheet("plate", np.eye(4), holes, turn.at(holes), square)
    (r,) = check_marks(PAPER_CAMERA, [view], [Mark("M1", mark, RADIUS)], [part]).results
    assert r.status == HIDDEN and r.clearance_mm == pytest.approx(10.0, abs=0.1)
    assert r.deviation_deg[2] == pytest.approx(3.7, abs=0.05)
    (corners_only,) = check_marks(PAPER_CAMERA, [view], [Mark("M1", mark, RADIUS)], [part], levels=2,
                                  refine=False).results
    assert corners_only.ok and corners_only.clearance_mm > 15.0


def test_a_mark_off_the_image_and_one_behind_the_camera_are_reported() -> None:
    T = looking_at(np.array([500.0, 500.0, 800.0]), np.array([500.0, 500.0, 0.0]))
    marks = [Mark("FAR", np.array([1500.0, 500.0, -10.0]), RADIUS),  # 1000 mm aside at 810 mm: 51 deg off the axis
             Mark("BACK", np.array([500.0, 500.0, 900.0]), RADIUS, np.array([0.0, 0.0, -1.0])),
             Mark("EDGE", np.array([500.0 + 810.0 * 1150.0 / PAPER_CAMERA.fx, 500.0, -10.0]), RADIUS)]
    view = MarkedView("S9", T, (0, 1, 2), (), 100.0)
    check = check_marks(PAPER_CAMERA, [view], marks)
    far, back, edge = check.results
    assert far.status == OUT_OF_IMAGE and far.margin_px < 0.0 and far.clearance_mm is None
    assert back.status == BEHIND_CAMERA and back.margin_px is None
    # its centre ~1150 px from the principal point along -u (the camera's x is the cell's -x), whose left border is
    # 1238 px away: with its radius (10 mm at 810 mm: ~30 px) about 60 px from the border, under the 100 px
    assert edge.status == OUT_OF_IMAGE and 0.0 < edge.margin_px < 100.0
    message = check.error().message
    assert "view S9, mark FAR: it is imaged" in message and "view S9, mark BACK: it lies behind the camera" in message


def test_two_marks_whose_images_overlap_are_reported() -> None:
    T = looking_at(np.array([500.0, 500.0, 800.0]), np.array([500.0, 500.0, 0.0]))
    marks = [Mark("A", np.array([500.0, 500.0, -10.0]), RADIUS), Mark("B", np.array([515.0, 500.0, -10.0]), RADIUS),
             Mark("C", np.array([560.0, 500.0, -10.0]), RADIUS)]
    a, b, c = check_marks(PAPER_CAMERA, [MarkedView("S1", T, (0, 1, 2), (), 100.0)], marks).results
    assert a.status == OVERLAPS and a.nearest == "B" and a.gap_px < 0
    assert b.status == OVERLAPS and c.ok and c.gap_px > 0
    # by hand: 25 mm between B's and C's edges at 810 mm is about 25 * f / 810 px
    assert c.gap_px == pytest.approx(25.0 * PAPER_CAMERA.fx / 810.0, rel=0.05)


def test_without_an_outline_the_holes_hull_grown_by_50_mm_is_the_part_and_the_report_says_so() -> None:
    """The holes' hull ends at x = 900 mm; grown by 50 mm, at x = 950, shifted +50 mm at x = 1000: a mark whose line
    of sight cuts the plane at x = 1020 keeps 20 mm."""
    check = one_mark(mark_cutting_plane_at(1020.0), outline=None)
    (r,) = check.results
    assert r.ok and r.clearance_mm == pytest.approx(20.0, abs=0.01)
    assert check.notes == ("part plate: no outline_w; taken as the convex hull of its holes grown by 50 mm",)
    (r,) = one_mark(mark_cutting_plane_at(1005.0), outline=None).results
    assert r.status == HIDDEN and r.clearance_mm == pytest.approx(5.0, abs=0.01)


def test_a_mark_above_the_parts_plane_is_never_hidden() -> None:
    (r,) = one_mark(np.array([1030.0, 500.0, 60.0])).results  # the part's plane never rises: z shift 0
    assert r.ok and r.clearance_mm is None


def test_bad_indices_are_refused_naming_the_view() -> None:
    view = MarkedView("S3", np.eye(4), (0, 4), (), 100.0)
    with pytest.raises(LayoutRequestInvalid, match=r"view S3: marks \[4\]"):
        check_marks(PAPER_CAMERA, [view], [Mark("M1", np.zeros(3), RADIUS)])


def test_the_simulated_cells_marks_pass() -> None:
    """config/sim-cell-marks.toml: every mark of every roof pose seen, >= 15 mm clear of the roof over the envelope
    (its generator asserts the same on the numbers it writes)."""
    config = load_cell_config(SIM_CELL_MARKS)
    check = cell_marks_check(config)
    assert check is not None and check.ok, check.error()
    assert len(check.results) == len(config.reference_marks) == 12
    assert min(r.clearance_mm for r in check.results) >= RADIUS + 5.0
    assert min(r.margin_px for r in check.results) >= config.layout.constraints.margin_px
    assert {r.view for r in check.results} == {"S1", "S2", "S3", "S4"} and check.notes == ()
    assert cell_marks_check(load_cell_config(SIM_CELL_MARKS.with_name("sim-cell.toml"))) is None
    assert gen.MARK_DISTANCE_MM == 280.0 and gen.MARK_BELOW_MM == 100.0
