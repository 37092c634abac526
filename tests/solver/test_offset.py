"""The base offset (Eq. 5) moves the taught grasp path with the part; the envelope refuses the rest."""

import math

import numpy as np
import pytest

from monoguide.solver import frames
from monoguide.solver.envelope import DeviationEnvelope
from monoguide.solver.errors import OffsetOutOfEnvelope
from monoguide.solver.offset import (
    base_offset,
    check_envelope,
    describe_displacement,
    part_displacement,
)
from monoguide.solver.pose import solve_pose
from monoguide.solver.record import parse_record, result_to_dict
from monoguide.solver.synthetic import deviated_part, measurement_record, paper_roof_cell

CELL = paper_roof_cell()
CENTROID_W = CELL.points_w.mean(axis=0)


def test_corrected_grasp_keeps_the_taught_relation_to_the_part():
    rng = np.random.default_rng(21)
    T_b_s1 = frames.make_T(frames.rotvec_to_matrix(rng.normal(size=3)), rng.uniform(-1500, 1500, 3))
    T_b_grasp = frames.make_T(frames.rotvec_to_matrix(rng.normal(size=3)), rng.uniform(-1500, 1500, 3))
    for _ in range(20):
        T_s1_w = deviated_part(CELL, rng, 5.0, 50.0)
        D_b = base_offset(part_displacement(T_s1_w, CELL.T_s1_w0), T_b_s1)
        taught = frames.invert(T_b_s1 @ CELL.T_s1_w0) @ T_b_grasp  # grasp in the reference part's frame
        corrected = frames.invert(T_b_s1 @ T_s1_w) @ (D_b @ T_b_grasp)  # corrected grasp in the new part's frame
        np.testing.assert_allclose(corrected, taught, atol=1e-9)


def _seeded_robot_cell(rng):
    """SF1 seen from a robot base about 2 m away and turned (like config/sim-cell.toml), and a grasp pose
    taught on the reference part: the gripper 300 mm above a point of the roof, pointing down onto it."""
    T_b_s1 = frames.make_T(frames.rotvec_to_matrix(np.radians([178.0, 1.5, -3.0])), [1885.0, 518.0, 1060.0])
    T_b_w0 = T_b_s1 @ CELL.T_s1_w0
    grasp_w = CENTROID_W + rng.uniform(-300.0, 300.0, 3) * [1, 1, 0]
    T_w0_g0 = frames.make_T(np.diag([1.0, -1.0, -1.0]), grasp_w + np.array([0.0, 0.0, 300.0]))
    return T_b_s1, T_b_w0, T_b_w0 @ T_w0_g0


@pytest.mark.parametrize("seed", [31, 32, 33])
def test_base_offset_brings_the_taught_grasp_onto_the_true_part(seed):
    """Ground truth: the ideal corrected grasp is T_b_w_true inv(T_b_w0) T_b_g0. Through the record, the
    solve and the result: the reported base offset must reach it to the noise level, and the bare SF1
    displacement (sent unconjugated) must not."""
    rng = np.random.default_rng(seed)
    T_b_s1, T_b_w0, T_b_g0 = _seeded_robot_cell(rng)
    T_s1_w_true = deviated_part(CELL, rng, 4.0, 40.0)
    T_b_w_true = T_b_s1 @ T_s1_w_true
    ideal = T_b_w_true @ frames.invert(T_b_w0) @ T_b_g0
    pixels = CELL.project(T_s1_w_true) + rng.normal(0, 0.1, (4, 2))
    record = parse_record(measurement_record(CELL, pixels, 0.1, "grasp", T_b_s1=T_b_s1))
    result = solve_pose(record.problem)
    out = result_to_dict(record, result, 1.0)
    D_b = np.array(out["base_offset"])
    d_rot, d_mm = frames.pose_difference(D_b @ T_b_g0, ideal)
    assert d_rot < 0.05 and d_mm < 0.5  # the line's 0.5 mm; sigma here is about 0.1 mm
    unconjugated = np.array(out["displacement_s1"]) @ T_b_g0
    assert frames.pose_difference(unconjugated, ideal)[1] > 20.0
    # the six numbers a KUKA takes are the same matrix (X, Y, Z mm, A, B, C deg, Z-Y'-X'')
    np.testing.assert_allclose(frames.kuka_frame_to_T(*out["base_offset_xyzabc"]), D_b, atol=1e-6)


def _turned(deg_xyz, shift_w=(0.0, 0.0, 0.0), about_w=CENTROID_W):
    """A part pose T_s1_w: the reference turned about ``about_w`` and shifted, both in the part frame."""
    move = frames.make_T(np.eye(3), about_w + np.asarray(shift_w)) @ frames.make_T(
        frames.rotvec_to_matrix(np.radians(deg_xyz)), np.zeros(3)) @ frames.make_T(np.eye(3), -about_w)
    return CELL.T_s1_w0 @ move


def _about_centroid(T_s1_w, grasp_w=CENTROID_W):
    """The displacement of ``T_s1_w`` judged at ``grasp_w``, described about the holes' centroid."""
    return describe_displacement(T_s1_w, CELL.T_s1_w0, grasp_w, CENTROID_W)


def test_a_roof_turned_3_deg_in_place_passes_though_its_corners_move_60_mm():
    d = _about_centroid(_turned([0.0, 0.0, 3.0]))
    corner_shift = 2 * math.sin(math.radians(1.5)) * np.linalg.norm(CELL.points_w[0] - CENTROID_W)
    assert corner_shift > 60.0
    check_envelope(d, DeviationEnvelope())
    assert d.rotation_deg == pytest.approx(3.0) and d.grasp_shift_mm == pytest.approx(0.0, abs=1e-9)
    np.testing.assert_allclose(d.rotation_w0_deg, [0.0, 0.0, 3.0], atol=1e-9)


def test_six_degrees_are_refused_naming_the_axis():
    d = _about_centroid(_turned([0.0, 0.0, 6.0]))
    with pytest.raises(OffsetOutOfEnvelope, match=r"turned \+6\.000 deg about z .* ±5 deg"):
        check_envelope(d, DeviationEnvelope())


@pytest.mark.parametrize(("axis", "index"), [("x", 0), ("y", 1), ("z", 2)])
def test_sixty_mm_along_one_axis_is_refused_naming_the_axis(axis, index):
    shift = np.zeros(3)
    shift[index] = -60.0
    d = _about_centroid(_turned([0.5, -0.5, 1.0], shift))
    np.testing.assert_allclose(d.about_shift_w0, shift, atol=1e-9)  # the centroid is the turning centre
    with pytest.raises(OffsetOutOfEnvelope, match=rf"-60\.00 mm off along {axis} of the reference part .*±50 mm"):
        check_envelope(d, DeviationEnvelope())


def test_per_axis_limits_and_the_totals():
    d = _about_centroid(_turned([0.0, 0.0, 0.0], [0.0, 0.0, 8.0]))
    check_envelope(d, DeviationEnvelope())
    with pytest.raises(OffsetOutOfEnvelope, match=r"\+8\.00 mm off along z.*±5 mm"):
        check_envelope(d, DeviationEnvelope(translation_mm=(50.0, 50.0, 5.0)))
    diagonal = _about_centroid(_turned([0.0, 0.0, 0.0], [40.0, 40.0, 0.0]))
    check_envelope(diagonal, DeviationEnvelope())  # the default total is the per-axis norm, 86.6 mm
    with pytest.raises(OffsetOutOfEnvelope, match=r"56\.57 mm off in total"):
        check_envelope(diagonal, DeviationEnvelope(total_mm=50.0))  # inside per axis, outside in total
    tilted = _about_centroid(_turned([4.0, 0.0, 3.5]))
    with pytest.raises(OffsetOutOfEnvelope, match=r"turned 5\.3\d\d deg in total"):
        check_envelope(tilted, DeviationEnvelope(total_deg=5.0))


def test_the_envelope_is_about_its_point_and_the_grasp_point_only_reports():
    """The same 3 deg turn about the centroid, gripped at a corner hole: the grasp point moves 60 mm, the
    envelope's point (the centroid) not at all, and the part passes. About the corner hole it is refused."""
    turned = _turned([0.0, 0.0, 3.0])
    d = _about_centroid(turned, grasp_w=CELL.points_w[0])
    assert d.grasp_shift_mm > 60.0
    check_envelope(d, DeviationEnvelope())
    corner = tuple(CELL.points_w[0])
    about_corner = describe_displacement(turned, CELL.T_s1_w0, CENTROID_W, CELL.points_w[0])
    with pytest.raises(OffsetOutOfEnvelope, match=r"mm off along [xy] of the reference part frame at \(0\.00, 0\.00"):
        check_envelope(about_corner, DeviationEnvelope(about_w=corner))
    with pytest.raises(ValueError, match="described about"):  # a displacement about another point: a bug
        check_envelope(d, DeviationEnvelope(about_w=corner))


def test_nan_displacement_is_refused():
    bad = CELL.T_s1_w0.copy()
    bad[0, 3] = np.nan
    with pytest.raises(OffsetOutOfEnvelope, match="not finite"):
        check_envelope(_about_centroid(bad), DeviationEnvelope())


@pytest.mark.parametrize("kwargs", [{"total_mm": 0.0}, {"total_deg": float("nan")}, {"translation_mm": (1.0, 2.0)},
                                    {"rotation_deg": (1.0, -1.0, 1.0)}, {"about_w": (0.0, float("inf"), 0.0)}])
def test_envelope_limits_must_be_finite_and_not_negative(kwargs):
    with pytest.raises(ValueError, match="envelope"):
        DeviationEnvelope(**kwargs)
