"""The simulated robot controllers report a flange pose that sees only the configured share of each stop's
deviation from the taught pose (``[sim] reported_repeatability_fraction``), while their truth file keeps the
true stop (the simulated camera stands there). Real controller processes, real adapters, seeded truth."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
from helpers.robots import stopping

from monoguide.daemon.assembly import build_sim_cell
from monoguide.daemon.config import load_cell_config
from monoguide.drivers.kuka_robot import KukaRobot
from monoguide.drivers.sim.cell import SimCell
from monoguide.drivers.sim.robot_process import start_controller
from monoguide.drivers.ur_robot import UrRobot
from monoguide.solver.frames import compose, invert, matrix_to_rotvec

SIM_CELL = Path(__file__).parents[3] / "config" / "sim-cell.toml"
HOSTS = {"ur": "127.0.13.40", "kuka": "127.0.13.41"}
FRACTION = 0.25
REPEATABILITY_MM, REPEATABILITY_DEG = 0.2, 0.04  # large enough that the share shows far above wire precision
OPTIONS = {"connect_timeout_s": 5.0, "move_timeout_s": 5.0, "ack_timeout_s": 1.0, "pose_tolerance_mm": 5.0,
           "pose_tolerance_deg": 1.0}


def _cell() -> SimCell:
    cell = build_sim_cell(load_cell_config(SIM_CELL))
    return SimCell(dataclasses.replace(cell.spec, reported_repeatability_fraction=FRACTION, seed=5,
                                       repeatability_mm=REPEATABILITY_MM, repeatability_deg=REPEATABILITY_DEG))


def _deviation(T_taught: np.ndarray, T: np.ndarray) -> np.ndarray:
    """(rotation vector rad, translation mm) of ``T`` off the taught pose, in the flange frame."""
    D = compose(invert(T_taught), T)
    return np.concatenate([matrix_to_rotvec(D[:3, :3]), D[:3, 3]])


@pytest.mark.parametrize("kind", ["ur", "kuka"])
def test_the_reported_pose_sees_the_configured_share_of_the_true_stop(kind: str, tmp_path: Path) -> None:
    cell = _cell()
    spec = cell.write_robot_spec(tmp_path / "robot.json", part=1)
    assert json.loads(spec.read_text())["reported_repeatability_fraction"] == FRACTION
    taught = tuple(cell.T_b_f_taught(i) for i in range(cell.n_measuring_poses))
    controller = start_controller(kind, spec, tmp_path / "truth.json", HOSTS[kind], move_time_s=0.05)
    with stopping(controller):
        robot = (UrRobot(controller.host, T_b_f_taught=taught, frequency_hz=50.0, **OPTIONS) if kind == "ur"
                 else KukaRobot(controller.host, controller.port, T_b_f_taught=taught, **OPTIONS))
        try:
            robot.open()
            reported = {i: robot.move_to_measuring_pose(i).T_b_f for i in (1, 2, 3)}
        finally:
            robot.close()
        truth = json.loads(controller.truth.read_text())
    for i, T_reported in reported.items():
        true_stop = np.array(truth["stops"][str(i + 1)])
        true_dev, seen_dev = _deviation(taught[i], true_stop), _deviation(taught[i], T_reported)
        # the robot truly stood off the taught pose by its repeatability ...
        assert 0.02 * REPEATABILITY_MM < np.linalg.norm(true_dev[3:]) < 6 * REPEATABILITY_MM
        # ... and its report saw exactly the configured share of that deviation (rotation and translation)
        np.testing.assert_allclose(seen_dev[3:], FRACTION * true_dev[3:], atol=2e-5)
        np.testing.assert_allclose(seen_dev[:3], FRACTION * true_dev[:3], atol=2e-8)
        np.testing.assert_allclose(T_reported, np.array(truth["stops_reported"][str(i + 1)]), atol=2e-5)
