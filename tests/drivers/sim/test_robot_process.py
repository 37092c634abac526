"""A simulated robot controller never outlives the process that started it: its launcher (``sim-cell``, a test)
may die the moment it has read the controller's ``LISTEN`` line, and the controller must still notice."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from helpers.robots import ADAPTER_OPTIONS, assert_within_repeatability, sim_cell, stopping, taught_poses

from monoguide.daemon.assembly import build_sim_cell
from monoguide.daemon.config import load_cell_config
from monoguide.drivers.errors import DeviceTimeout
from monoguide.drivers.kuka_robot import KukaRobot
from monoguide.drivers.sim.robot_process import CONTROLLER_MODULES, start_controller
from monoguide.drivers.ur_robot import UrRobot

SIM_CELL = Path(__file__).parents[3] / "config" / "sim-cell.toml"
HOSTS = {"ur": "127.0.0.140", "kuka": "127.0.0.141"}
RUNTIME_HOSTS = {"ur": "127.0.6.10", "kuka": "127.0.6.11"}

# the launcher: start the controller, read its LISTEN line, print the controller's pid and die at once
LAUNCHER = """
import subprocess, sys, os
controller = subprocess.Popen(sys.argv[1:], stdout=subprocess.PIPE, text=True)
line = controller.stdout.readline()
print(controller.pid, line.strip(), flush=True)
os._exit(0)
"""


@pytest.mark.parametrize("kind", sorted(CONTROLLER_MODULES))
def test_controller_ends_when_its_launcher_dies_right_after_listen(kind: str, tmp_path: Path) -> None:
    spec = build_sim_cell(load_cell_config(SIM_CELL)).write_robot_spec(tmp_path / "robot.json")
    argv = [sys.executable, "-m", CONTROLLER_MODULES[kind], "--spec", str(spec), "--truth",
            str(tmp_path / "truth.json"), "--host", HOSTS[kind]]
    launcher = subprocess.run([sys.executable, "-c", LAUNCHER, *argv], capture_output=True, text=True, timeout=60)
    pid_text, listen, *_ = [*launcher.stdout.split(maxsplit=2), "", ""]
    assert listen == "LISTEN", launcher.stdout + launcher.stderr
    pid = int(pid_text)
    try:
        deadline = time.monotonic() + 5.0
        while time.monotonic() < deadline:
            try:
                os.kill(pid, 0)  # an orphan is reaped by init once it ends
            except ProcessLookupError:
                return
            time.sleep(0.05)
        pytest.fail(f"simulated {kind} controller {pid} outlived its launcher by 5 s")
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)  # the one we started, if it is still there


@pytest.mark.parametrize("kind", sorted(CONTROLLER_MODULES))
def test_a_stall_commanded_at_run_time_ends_with_none(kind: str, tmp_path: Path) -> None:
    """``--commands``: a fault set while the controller runs (sim-cell's ``robot <fault>``) applies from the next
    request, and ``none`` makes the controller answer again, to the real adapter."""
    cell = sim_cell()
    spec = cell.write_robot_spec(tmp_path / "robot.json", part=3)
    controller = start_controller(kind, spec, tmp_path / "truth.json", RUNTIME_HOSTS[kind], move_time_s=0.05,
                                  commands=True)

    def adapter() -> UrRobot | KukaRobot:
        if kind == "ur":
            return UrRobot(controller.host, T_b_f_taught=taught_poses(cell), frequency_hz=50.0, **ADAPTER_OPTIONS)  # type: ignore[arg-type]
        return KukaRobot(controller.host, controller.port, T_b_f_taught=taught_poses(cell), **ADAPTER_OPTIONS)  # type: ignore[arg-type]

    with stopping(controller):
        robot = adapter()
        try:
            robot.open()
            robot.move_to_measuring_pose(0)
            controller.command("stall")
            with pytest.raises(DeviceTimeout):
                robot.move_to_measuring_pose(1)
        finally:
            robot.close()
        controller.command("none")
        robot = adapter()
        try:
            robot.open()
            status = robot.move_to_measuring_pose(1)
        finally:
            robot.close()
    assert status.in_position == 2
    assert_within_repeatability(cell, status.T_b_f, 1)
