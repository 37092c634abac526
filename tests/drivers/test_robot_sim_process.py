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

from monoguide.daemon.assembly import build_sim_cell
from monoguide.daemon.config import load_cell_config
from monoguide.drivers.sim.robot_process import CONTROLLER_MODULES

SIM_CELL = Path(__file__).parents[2] / "config" / "sim-cell.toml"
HOSTS = {"ur": "127.0.0.140", "kuka": "127.0.0.141"}

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
