"""Measuring-pose planning: the layout it builds, and the Fig. 5 map."""

import numpy as np

from monoguide.solver import frames
from monoguide.solver.camera import PAPER_CAMERA
from monoguide.solver.planning import look_at_poses, quarter_targets, uncertainty_map
from monoguide.solver.synthetic import PAPER_ROOF_POINTS_W


def test_look_at_poses_image_each_hole_at_its_target_from_straight_above():
    rng = np.random.default_rng(31)
    targets = np.column_stack([rng.uniform(100, 2300, 4), rng.uniform(100, 1900, 4)])
    poses = look_at_poses(PAPER_ROOF_POINTS_W, PAPER_CAMERA, 650.0, targets)
    for i, T_w_si in enumerate(poses):
        point_c = frames.transform_points(frames.invert(T_w_si), PAPER_ROOF_POINTS_W[i : i + 1])
        np.testing.assert_allclose(PAPER_CAMERA.project(point_c)[0], targets[i], atol=1e-8)
        assert point_c[0, 2] == np.float64(650.0) or abs(point_c[0, 2] - 650.0) < 1e-9
        np.testing.assert_allclose(T_w_si[:3, 2], [0.0, 0.0, -1.0])  # optical axis down onto the sheet


def test_quarter_targets_are_a_quarter_from_the_edge_away_from_the_part_centre():
    targets = quarter_targets(PAPER_CAMERA, PAPER_ROOF_POINTS_W)
    w, h = PAPER_CAMERA.width, PAPER_CAMERA.height
    for u, v in targets:
        assert min(abs(u + 0.5), abs(w - 0.5 - u)) == np.float64(w / 4) or abs(min(u + 0.5, w - 0.5 - u) - w / 4) < 1
        assert abs(min(v + 0.5, h - 0.5 - v) - h / 4) < 1
    # hole 1 is at the part's (0, 0) corner: outwards is -x_w = +u (camera x = -part x) and -y_w = -v
    assert targets[0][0] > w / 2 and targets[0][1] < h / 2


def test_fig5_map_falls_as_the_holes_move_outwards_and_flattens():
    fig5 = uncertainty_map(PAPER_CAMERA, PAPER_ROOF_POINTS_W, 650.0, steps=10)
    diagonal = np.diag(fig5.sigma_trans_mm)
    assert np.all(np.diff(diagonal) < 0)
    assert np.all(np.diff(np.diag(fig5.sigma_rot_deg)) < 0)
    drops = -np.diff(diagonal)
    assert drops[-1] < 0.2 * drops[0]  # diminishing returns far from the centre (Fig. 5)
    quarter = fig5.sigma_trans_mm[np.argmin(abs(fig5.offsets_v_px - 514)), np.argmin(abs(fig5.offsets_u_px - 614))]
    assert quarter < 0.25 * fig5.sigma_trans_mm[0, 0]
