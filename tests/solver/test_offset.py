"""The base offset (Eq. 5) moves the taught grasp path with the part; the envelope refuses the rest."""

import numpy as np
import pytest

from monoguide.solver import frames
from monoguide.solver.errors import OffsetOutOfEnvelope
from monoguide.solver.offset import Envelope, base_offset, check_envelope, part_displacement
from monoguide.solver.synthetic import deviated_part, paper_roof_cell

CELL = paper_roof_cell()


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


def test_envelope_accepts_inside_and_refuses_outside():
    points_s1 = frames.transform_points(CELL.T_s1_w0, CELL.points_w)
    shift = frames.make_T(np.eye(3), [30.0, -20.0, 10.0])
    angle, moved = check_envelope(shift, points_s1, Envelope(50.0, 5.0))
    assert angle == pytest.approx(0.0, abs=1e-9) and moved == pytest.approx(np.sqrt(1400.0))
    with pytest.raises(OffsetOutOfEnvelope, match=r"37\.42 mm.*allows 5 deg and 30 mm"):
        check_envelope(shift, points_s1, Envelope(30.0, 5.0))
    centroid = points_s1.mean(axis=0)
    turn = frames.make_T(np.eye(3), centroid) @ frames.make_T(
        frames.rotvec_to_matrix(np.radians([0.0, 0.0, 6.0])), np.zeros(3)) @ frames.make_T(np.eye(3), -centroid)
    with pytest.raises(OffsetOutOfEnvelope, match=r"6\.000 deg"):
        check_envelope(turn, points_s1, Envelope(500.0, 5.0))


def test_nan_offset_is_refused():
    bad = np.eye(4)
    bad[0, 3] = np.nan
    with pytest.raises(OffsetOutOfEnvelope, match="not finite"):
        check_envelope(bad, np.zeros((1, 3)), Envelope())
