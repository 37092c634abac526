"""`monoguide sim-cell` starts the simulated controller the config names; `monoguide probe robot` drives it
(identity, --goto K, --write-zero) the same way for UR and KUKA; config errors of the [robot] section."""

from __future__ import annotations

import json
import os
import select
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from monoguide.daemon.assembly import build_sim_cell
from monoguide.daemon.cli import app
from monoguide.daemon.config import load_cell_config
from monoguide.daemon.errors import ConfigError
from monoguide.solver.frames import pose_difference

SIM_CELL = Path(__file__).parents[3] / "config" / "sim-cell.toml"
ROBOT_SECTION = {
    "sim-ur": 'backend = "sim-ur"\nhost = "127.0.0.80"\nport = 30004\nsim_move_time_s = 0.1\n',
    "sim-kuka": 'backend = "sim-kuka"\nhost = "127.0.0.81"\nport = 54600\nsim_move_time_s = 0.1\n',
}
runner = CliRunner()


def cell_with_robot(tmp_path: Path, robot_section: str) -> Path:
    text = SIM_CELL.read_text()
    start = text.index("[robot]")
    end = text.index("\n[", start + 1)
    path = tmp_path / "cell.toml"
    path.write_text(text[:start] + "[robot]\n" + robot_section + text[end:])
    return path


@pytest.fixture(params=sorted(ROBOT_SECTION))
def sim_cell(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[tuple[Path, Path, str]]:
    config = cell_with_robot(tmp_path, ROBOT_SECTION[request.param])
    state = tmp_path / "state.json"
    process = subprocess.Popen([sys.executable, "-m", "monoguide.daemon.cli", "sim-cell", "--config", str(config),
                                "--state-file", str(state)], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
    assert process.stdout is not None
    try:
        said = b""
        while b"state file" not in said:  # raw reads: a buffered readline would hide lines from select
            ready, _, _ = select.select([process.stdout], [], [], 40.0)
            assert ready, f"sim-cell said only {said!r}"
            chunk = os.read(process.stdout.fileno(), 4096)
            assert chunk, f"sim-cell ended after {said!r}"
            said += chunk
        assert f"robot ({request.param}) listening on 127.0.0.8".encode() in said, said
        yield config, state, request.param
    finally:
        robot_pid = json.loads(state.read_text())["robot"]["pid"] if state.exists() else None
        process.send_signal(signal.SIGTERM)
        process.wait(10)
        process.stdout.close()
        if robot_pid is not None:
            with pytest.raises(ProcessLookupError):  # sim-cell left no controller behind
                os.kill(robot_pid, 0)


def test_probe_robot_goto_and_write_zero(sim_cell: tuple[Path, Path, str]) -> None:
    config, state, backend = sim_cell
    result = runner.invoke(app, ["probe", "robot", "--config", str(config), "--state-file", str(state),
                                 "--goto", "2", "--write-zero"])
    assert result.exit_code == 0, result.output
    vendor = "Universal Robots" if backend == "sim-ur" else "KUKA"
    assert f"robot: {vendor}" in result.output and "ready, at no measuring pose" in result.output
    assert "in position at S2" in result.output and "zero offset written" in result.output
    truth_file = Path(json.loads(state.read_text())["robot"]["truth"])
    deadline = time.monotonic() + 2.0
    while not (truth := json.loads(truth_file.read_text()))["offsets"] and time.monotonic() < deadline:
        time.sleep(0.02)  # the controller writes its truth file every 20 ms
    cell = build_sim_cell(load_cell_config(config))
    angle_deg, distance_mm = pose_difference(np.array(truth["stops"]["2"]), cell.T_b_f_taught(1))
    assert distance_mm < 1.0 and angle_deg < 0.1
    (offset,) = truth["offsets"]
    assert offset["received"] == [0.0] * 6
    assert offset["grasp_error_mm"] < 1e-9  # the reference part is in place: zero is the ideal offset


def test_probe_robot_without_a_running_sim_cell(tmp_path: Path) -> None:
    config = cell_with_robot(tmp_path, ROBOT_SECTION["sim-kuka"])
    result = runner.invoke(app, ["probe", "robot", "--config", str(config), "--state-file",
                                 str(tmp_path / "none.json")])
    assert result.exit_code == 1 and "DEVICE_NOT_FOUND" in result.output


def test_probe_robot_on_an_absent_real_controller(tmp_path: Path) -> None:
    config = cell_with_robot(tmp_path, 'backend = "kuka"\nhost = "127.0.0.82"\nconnect_timeout_s = 0.5\n')
    result = runner.invoke(app, ["probe", "robot", "--config", str(config)])
    assert result.exit_code == 1 and "DEVICE_NOT_FOUND" in result.output and "127.0.0.82:54600" in result.output


@pytest.mark.parametrize(("section", "match"), [
    ('backend = "abb"\n', "backend"),
    ('backend = "ur"\nport = 30005\n', "30004 only"),
    ('backend = "sim-kuka"\nmove_timeout_s = 0\n', "move_timeout_s"),
    ('backend = "ur"\nrtde_frequency_hz = 1000.0\n', "500 Hz"),
    ('backend = "kuka"\nhots = "10.0.0.2"\n', "hots"),
])
def test_bad_robot_sections_name_the_key(tmp_path: Path, section: str, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        load_cell_config(cell_with_robot(tmp_path, section))
