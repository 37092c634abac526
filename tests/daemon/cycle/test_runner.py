"""The blocking cycle (daemon/cycle/_runner.py) end to end: a real ``monoguide sim-cell`` (its simulated
UR controller in its own process, with the part supply and the truth log), the robot adapter over RTDE, the
simulated camera in this process following that robot. Offsets are judged against the truth log the controller
writes."""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import threading
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from helpers.cell_configs import cell_config
from helpers.sim_processes import start_sim_cell, stop

from monoguide.daemon.assembly import build_camera, build_robot
from monoguide.daemon.config import CellConfig, ChecksConfig, load_cell_config
from monoguide.daemon.cycle import CycleRunner
from monoguide.daemon.errors import CycleAborted
from monoguide.drivers.camera import Camera
from monoguide.drivers.robot import Robot
from monoguide.drivers.sim.robot_motion import read_truth
from monoguide.solver.errors import FeatureNotFound, OffsetOutOfEnvelope


@dataclasses.dataclass
class Cell:
    config: CellConfig
    state: Path
    truth_log: Path
    camera: Camera
    robot: Robot
    process: subprocess.Popen[str]

    def parts(self) -> list[dict]:
        """The truth log, after sim-cell has stopped (a part's line is written when it leaves the cell)."""
        stop(self.process)
        return [json.loads(line) for line in self.truth_log.read_text().splitlines()]


def _start(tmp_path: Path, robot_host: str) -> Iterator[Cell]:
    config_path = cell_config(tmp_path, robot_host, sharp=True, state_file=tmp_path / "state.json")
    truth_log = tmp_path / "truth.jsonl"
    process, _ = start_sim_cell(config_path, "--no-plc", "--truth-log", str(truth_log))
    config = load_cell_config(config_path)
    camera, robot = build_camera(config), build_robot(config)
    camera.open()
    robot.open()
    try:
        yield Cell(config, tmp_path / "state.json", truth_log, camera, robot, process)
    finally:
        robot.close()
        camera.close()
        stop(process)


@pytest.fixture
def cell(tmp_path: Path) -> Iterator[Cell]:
    yield from _start(tmp_path, "127.0.4.1")


@pytest.fixture
def failing_cell(tmp_path: Path) -> Iterator[Cell]:
    yield from _start(tmp_path, "127.0.4.3")


def _never() -> threading.Event:
    return threading.Event()


def test_good_cycles_write_offsets_that_grasp_the_true_part(cell: Cell, tmp_path: Path) -> None:
    runner = CycleRunner(cell.config, cell.camera, cell.robot, images_dir=tmp_path / "images")
    solutions = []
    for _ in range(2):
        measurement = runner.measure(1, _never(), lambda: CycleAborted("stop"))
        solution = runner.solve(measurement)
        runner.check(measurement, solution)
        assert runner.write(solution) > 0
        solutions.append(solution)
        assert set(measurement.timings_s) == {"robot_motion", "exposure", "hole_finding", "solve", "checks",
                                              "offset_write", "overhead"}
        assert all(v >= 0 for v in measurement.timings_s.values())
    # the robot's actual pose at each capture is the controller's stop (its truth file)
    truth = read_truth(Path(json.loads(cell.state.read_text())["robot"]["truth"]))
    for capture in measurement.captures:
        np.testing.assert_allclose(capture.T_b_f, np.array(truth["stops"][str(capture.pose_index + 1)]), atol=1e-3)
        assert capture.image_path is not None and Path(capture.image_path).is_file()
    assert measurement.record["format"] == "monoguide.measurement/1" and len(measurement.record["observations"]) == 4

    parts = cell.parts()
    assert [p["part"] for p in parts] == [1, 2]
    for part, solution in zip(parts, solutions, strict=True):
        assert part["grasp_error_mm"] < 0.1 and part["grasp_error_deg"] < 0.01, part
        ideal, written = np.array(part["offset_ideal"]), np.array(part["offset_written"])
        np.testing.assert_allclose(written, solution.offset, atol=1e-3)  # what the PLC is shown is what was written
        assert np.linalg.norm(written[:3] - ideal[:3]) < 3.0 and np.max(np.abs(written[3:] - ideal[3:])) < 0.05
        rms, sigma_mm, sigma_deg = solution.quality
        assert 0 < rms < 1.0 and 0 < sigma_mm < 0.5 and 0 < sigma_deg < 0.1


class _AbortAtCheck(threading.Event):
    """An abort flag that the service sets while the cycle runs: set from the ``n``-th look on."""

    def __init__(self, n: int) -> None:
        super().__init__()
        self.looks, self.n = 0, n

    def is_set(self) -> bool:
        self.looks += 1
        return self.looks >= self.n or super().is_set()


def test_failing_cycles_write_nothing(failing_cell: Cell) -> None:
    cell, cfg = failing_cell, failing_cell.config
    runner = CycleRunner(cfg, cell.camera, cell.robot)  # the job rule is the service's (test_service_handshake)

    # part 1: aborted after S1 (the 3rd look: before requesting S2)
    with pytest.raises(CycleAborted, match="SIGTERM"):
        runner.measure(1, _AbortAtCheck(3), lambda: CycleAborted("SIGTERM"))

    # part 2: the offset lies outside a tiny envelope
    tiny = CycleRunner(dataclasses.replace(cfg, checks=ChecksConfig(envelope_mm=0.5)), cell.camera, cell.robot)
    measurement = tiny.measure(1, _never(), lambda: CycleAborted("stop"))
    solution = tiny.solve(measurement)
    with pytest.raises(OffsetOutOfEnvelope):
        tiny.check(measurement, solution)

    # (a stop off the taught pose is the robot adapter's refusal, ROBOT_POSE_MISMATCH: tests/drivers)

    # part 3: the camera delivers black frames (a `camera black 8` command to sim-cell, through its state file)
    state = json.loads(cell.state.read_text())
    state["camera_fault"] = {"failure": "black", "count": 8, "serial": 1}
    tmp = cell.state.with_name("state.json.tmp")
    tmp.write_text(json.dumps(state))
    os.replace(tmp, cell.state)
    with pytest.raises(FeatureNotFound):
        runner.measure(1, _never(), lambda: CycleAborted("stop"))

    parts = cell.parts()
    assert [p["part"] for p in parts] == [1, 2, 3]
    assert all(p["offset_written"] is None and p["grasp_error_mm"] is None for p in parts)
