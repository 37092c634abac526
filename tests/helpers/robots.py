"""What the UR and KUKA adapter tests share: the simulated cell and its taught poses, the adapters' test
options, the faults a simulated controller plays, and the checks against the controller's ground truth."""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest

from monoguide.daemon.assembly import build_sim_cell
from monoguide.daemon.config import load_cell_config
from monoguide.drivers.errors import (
    DeviceDisconnected,
    DeviceError,
    DeviceTimeout,
    RobotAckTimeout,
    RobotNotReady,
    RobotPositionTimeout,
    RobotProtectiveStop,
)
from monoguide.drivers.kuka_robot import KukaRobot
from monoguide.drivers.sim.cell import SimCell
from monoguide.drivers.sim.robot_process import ControllerProcess
from monoguide.drivers.ur_robot import UrRobot
from monoguide.solver.frames import pose_difference

SIM_CELL = Path(__file__).parents[2] / "config" / "sim-cell.toml"

# short timeouts and a tight pose tolerance, so that the failure modes show within a test's time
ADAPTER_OPTIONS = {"connect_timeout_s": 2.0, "move_timeout_s": 2.0, "ack_timeout_s": 0.5, "stale_timeout_s": 0.4,
                   "pose_tolerance_mm": 0.5, "pose_tolerance_deg": 0.1}

# (fault the simulated controller plays, what the adapter is asked, the error it must raise)
FAILURE_MODES = [
    ("stall", "move", DeviceTimeout),
    ("drop", "move", DeviceDisconnected),
    ("protective-stop", "move", RobotProtectiveStop),
    ("never-reach", "move", RobotPositionTimeout),
    ("no-ack", "offset", RobotAckTimeout),
    ("program-stopped", "offset", RobotNotReady),
]


def sim_cell() -> SimCell:
    cell = build_sim_cell(load_cell_config(SIM_CELL))
    cell.new_part()  # a deviated part: the ideal offset is not the identity
    return cell


def taught_poses(cell: SimCell) -> tuple[np.ndarray, ...]:
    return tuple(cell.T_b_f_taught(i) for i in range(cell.n_measuring_poses))


@contextmanager
def stopping(controller: ControllerProcess) -> Iterator[ControllerProcess]:
    try:
        yield controller
    finally:
        controller.stop()


def truth(controller: ControllerProcess) -> dict:
    return json.loads(controller.truth.read_text())


def wait_for_truth(controller: ControllerProcess, key: str, n: int) -> dict:
    """The controller's ground truth once it holds ``n`` entries under ``key``."""
    deadline = time.monotonic() + 2.0
    while time.monotonic() < deadline:
        t = truth(controller)
        if len(t[key]) >= n:
            return t
        time.sleep(0.02)
    pytest.fail(f"the simulated controller never recorded {n} {key}")


# what the wire keeps of an offset: UR doubles; KUKA fixed-point text with 6 decimals (1 nm, 1e-6 deg), which moves
# the grasp point ~2 m from the base by up to 2000 mm * 5e-7 deg * pi / 180 ~ 2e-5 mm
WIRE_ATOL = {"ur": 1e-9, "kuka": 5e-7}
GRASP_ATOL_MM = {"ur": 1e-9, "kuka": 5e-5}


def offsets_recorded(controller: ControllerProcess, sequences: list[int], part: int, D_ideal: np.ndarray,
                     kind: str = "ur") -> list[dict]:
    """The offsets the controller recorded for ``sequences``, checked: the first is ``D_ideal`` (within what the
    wire keeps) and grasps exactly."""
    offsets = wait_for_truth(controller, "offsets", len(sequences))["offsets"]
    assert [o["sequence"] for o in offsets] == sequences and {o["part"] for o in offsets} == {part}
    np.testing.assert_allclose(np.array(offsets[0]["D_b"]), D_ideal, atol=WIRE_ATOL[kind] * 10)
    assert offsets[0]["grasp_error_mm"] < GRASP_ATOL_MM[kind] and offsets[0]["grasp_error_deg"] < WIRE_ATOL[kind] * 2
    return offsets


def assert_within_repeatability(cell: SimCell, T_b_f: np.ndarray, i: int) -> None:
    """The robot stopped near taught pose ``i``, off by no more than its repeatability allows (never exactly)."""
    angle_deg, distance_mm = pose_difference(T_b_f, cell.T_b_f_taught(i))
    assert 0 < distance_mm < 6 * cell.spec.repeatability_mm * np.sqrt(3)
    assert angle_deg < 6 * cell.spec.repeatability_deg * np.sqrt(3)


def lose_connection(robot: UrRobot | KukaRobot) -> None:
    """Poll the robot until the adapter notices that its controller is gone."""
    with pytest.raises((DeviceDisconnected, DeviceTimeout)):
        for _ in range(100):
            robot.status()
            time.sleep(0.02)


def check_failure_mode(controller: ControllerProcess, robot: UrRobot | KukaRobot, action: str,
                       error: type[DeviceError]) -> None:
    """Open ``robot``, ask it ``action`` ("move" or "offset") and expect ``error``; close and stop both after."""
    try:
        robot.open()
        with pytest.raises(error) as info:
            if action == "move":
                robot.move_to_measuring_pose(1)
            else:
                robot.write_base_offset(np.eye(4))
        assert info.value.code == error.code
    finally:
        robot.close()
        controller.stop()


def make_adapter(kind: str, controller: ControllerProcess, cell: SimCell, **kw: float) -> UrRobot | KukaRobot:
    """The real adapter of ``kind`` for ``controller``, with the test options (``kw`` overrides them)."""
    options = {**ADAPTER_OPTIONS, **kw}
    if kind == "ur":
        return UrRobot(controller.host, T_b_f_taught=taught_poses(cell), frequency_hz=125.0, **options)  # type: ignore[arg-type]
    return KukaRobot(controller.host, controller.port, T_b_f_taught=taught_poses(cell), **options)  # type: ignore[arg-type]


def wait_for(condition: Callable[[], bool], what: str, timeout_s: float = 3.0) -> None:
    """Until ``condition()`` holds; fails the test naming ``what`` after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            pytest.fail(f"not {what} within {timeout_s:g} s")
        time.sleep(0.01)
