"""The steps chained as the wizard will run them on the simulated cell: the tracker reads in its own frame,
the cell frame maps its readings into CF, and every later step uses the fitted CF (issue 12, steps 2-5).

The SMR positions come from the simulated cell's own truth (``SimCell.tracker_targets``: benchmarks, the SMR on
the flange at the robot's actual pose, the target nests, the featured holes), with the tracker's 0.025 mm."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from monoguide.daemon.assembly import build_sim_cell
from monoguide.daemon.config import load_cell_config
from monoguide.drivers.sim.cell import SimCell
from monoguide.drivers.sim.target_renderer import base_calibration_poses, place_target, tracker_reading
from monoguide.solver.calibration.base import fit_robot_base
from monoguide.solver.calibration.cell import fit_cell_frame, fit_part_frame
from monoguide.solver.calibration.sfi import calibrate_measuring_pose, fit_target_frame
from monoguide.solver.calibration.target import default_target_marks, target_pose
from monoguide.solver.frames import compose, invert, pose_difference, transform_points


def _read(cell: SimCell, names, rng, T_cf_tracker) -> dict[str, np.ndarray]:
    """The tracker's readings of the named nests (in its frame, with its noise) mapped into the fitted CF."""
    truth = cell.tracker_targets()
    raw = tracker_reading(np.array([truth[n] for n in names]), rng, 0.025)
    return dict(zip(names, transform_points(T_cf_tracker, raw), strict=True))


def test_the_chained_steps_meet_the_issue_targets() -> None:
    rng = np.random.default_rng(99)
    cell = build_sim_cell(load_cell_config("config/sim-cell.toml"))
    spec = cell.spec
    # 2. cell frame from the benchmarks, read in the tracker's frame
    bench = list(spec.benchmarks_cf)
    T_cf_tracker = fit_cell_frame(spec.benchmarks_cf, _read(cell, bench, rng, np.eye(4))).T
    # 3. robot base: the robot stands at each calibration pose, the tracker reads the flange's SMR ("TCP")
    T_b_f = base_calibration_poses(16, rng)
    smr = []
    for T in T_b_f:
        cell.set_actual_flange_pose(0, T)
        smr.append(_read(cell, ["TCP"], rng, T_cf_tracker)["TCP"])
    base = fit_robot_base(T_b_f, np.array(smr))
    deg, mm = pose_difference(base.T_cf_b, spec.T_cf_b)
    assert mm < 0.05 and deg < 0.005, (mm, deg)
    # 4. part frame from the featured holes of the reference part
    names = spec.point_names
    part = fit_part_frame(dict(zip(names, spec.points_w, strict=True)), _read(cell, names, rng, T_cf_tracker))
    deg, mm = pose_difference(part.T, spec.T_cf_w0)
    assert mm < 0.05 and deg < 0.005, (mm, deg)
    # 5. SFi: each target placed 10 times (a cell whose target lies there), 4 visits of the pose per placement
    marks = default_target_marks()
    for i in range(cell.n_measuring_poses):
        visits = []
        for _ in range(10):
            target = replace(spec.targets[i], T_cf_t=place_target(spec.targets[i].T_cf_t, rng))
            placed = SimCell(replace(spec, targets=tuple(target if k == i else t for k, t in enumerate(spec.targets))))
            nests = [f"{target.name}.{k + 1}" for k in range(len(target.points_t))]
            read = _read(placed, nests, rng, T_cf_tracker)
            T_cf_t = fit_target_frame(target.points_t, np.array([read[n] for n in nests])).T
            for _ in range(4):
                placed.move_to_measuring_pose(i, rng)
                T_si_t = compose(invert(placed.actual_camera_pose(i)), target.T_cf_t)
                px = cell.camera.project(transform_points(T_si_t, marks.centers_t))
                px += rng.normal(0.0, 0.1, px.shape)
                visits.append((T_cf_t, target_pose(cell.camera, marks, px, T_si_t).T_c_t))
        sfi = calibrate_measuring_pose(visits, f"S{i + 1}")
        deg, mm = pose_difference(sfi.T_cf_si, spec.T_cf_si[i])
        assert mm < 0.05 and deg < 0.01, (i, mm, deg)
