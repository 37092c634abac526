"""`monoguide probe` and `monoguide sim-cell`, end to end: real processes, real pty, real GenTL producer."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np
import pytest
from helpers.sim_processes import alive, start_sim_cell, stop
from typer.testing import CliRunner

from monoguide.daemon.assembly import build_sim_cell
from monoguide.daemon.cli import app
from monoguide.daemon.cli.probe import PROBES, Device
from monoguide.daemon.config import load_cell_config

CONFIG_DIR = Path(__file__).parents[3] / "config"
SIM_CELL = CONFIG_DIR / "sim-cell.toml"
runner = CliRunner()


@pytest.fixture
def sim_cell(tmp_path: Path) -> Iterator[tuple[subprocess.Popen[str], Path, str]]:
    """A running ``monoguide sim-cell`` with its state file in ``tmp_path``; stopped (SIGTERM) at teardown."""
    state = tmp_path / "state.json"
    config = _own_addresses(tmp_path)
    process, lines = start_sim_cell(config, "--state-file", str(state), until="tracker listening")
    try:
        match = re.match(r"tracker listening on (\S+)", lines[-1])
        assert match, f"sim-cell said {lines!r}"
        yield process, state, match.group(1)
    finally:
        stop(process)


def _own_addresses(tmp_path: Path) -> Path:
    """A copy of the simulated cell whose robot and PLC listen on this module's own loopback address, so a
    simulator left over from another test (or another run) cannot answer in its place."""
    text = SIM_CELL.read_text().replace('host = "127.0.0.1"', 'host = "127.0.0.61"')
    assert text.count('host = "127.0.0.61"') >= 1
    config = tmp_path / "sim-cell.toml"
    config.write_text(text)
    return config


def test_probe_sim_camera_saves_the_rendered_frame(tmp_path: Path) -> None:
    out = tmp_path / "frame.png"
    result = runner.invoke(app, ["probe", "camera", "--config", str(SIM_CELL), "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert "SimCamera" in result.output and "2456 x 2058" in result.output
    assert cv2.imread(str(out), cv2.IMREAD_UNCHANGED).shape == (2058, 2456)


def test_probe_viky_saves_a_real_gentl_frame(tmp_path: Path) -> None:
    out = tmp_path / "viky.png"
    result = runner.invoke(app, ["probe", "camera", "--config", str(CONFIG_DIR / "viky-camera.toml"),
                                 "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert "Viky, serial 0" in result.output
    assert cv2.imread(str(out), cv2.IMREAD_UNCHANGED).shape == (480, 640)


def test_probe_absent_camera_fails_clearly(tmp_path: Path) -> None:
    text = _viky_config().replace('serial = "0"', 'serial = "77"')
    (tmp_path / "cell.toml").write_text(text)
    result = runner.invoke(app, ["probe", "camera", "--config", str(tmp_path / "cell.toml")])
    assert result.exit_code == 1
    assert "DEVICE_NOT_FOUND" in result.output and "'77'" in result.output


def test_probe_bad_config_is_exit_2_on_standard_error(tmp_path: Path) -> None:
    (tmp_path / "cell.toml").write_text("[cell]\n")
    result = runner.invoke(app, ["probe", "camera", "--config", str(tmp_path / "cell.toml")])
    assert result.exit_code == 2 and result.stdout == ""
    assert result.stderr.startswith("CONFIG_MISSING_KEY ") and "[cell].name: missing" in result.stderr


def test_probe_names_a_misspelt_key_with_its_correction(tmp_path: Path) -> None:
    text = _viky_config().replace("grab_timeout_s = 3.0", "grab_timout_s = 3.0")
    (tmp_path / "cell.toml").write_text(text)
    result = runner.invoke(app, ["probe", "camera", "--config", str(tmp_path / "cell.toml")])
    assert result.exit_code == 2 and result.stdout == ""
    assert result.stderr.startswith("CONFIG_UNKNOWN_KEY ")
    assert "[camera].grab_timout_s: unknown key; did you mean 'grab_timeout_s'?" in result.stderr


def test_probe_piped_prints_whole_plain_lines_and_errors_apart(tmp_path: Path) -> None:
    """Through a real pipe (no terminal): one result a line, however long, no colour codes; errors on stderr."""
    out = tmp_path / ("a-folder-name-long-enough-to-pass-any-terminal-width-" * 3) / "frame.png"
    out.parent.mkdir()
    cmd = [sys.executable, "-m", "monoguide.daemon.cli", "probe", "camera", "--config", str(SIM_CELL), "--out"]
    env = {**os.environ, "COLUMNS": "40"}
    result = subprocess.run([*cmd, str(out)], capture_output=True, text=True, timeout=120, env=env)
    assert result.returncode == 0 and result.stderr == "", result.stderr
    assert result.stdout.splitlines()[-1] == f"saved {out}"
    assert "\x1b[" not in result.stdout
    bad = subprocess.run([*cmd, str(tmp_path / "frame.xyz")], capture_output=True, text=True, timeout=120, env=env)
    assert bad.returncode == 2 and bad.stdout == ""
    assert len(bad.stderr.splitlines()) == 1 and "\x1b[" not in bad.stderr and "CONFIG_INVALID" in bad.stderr


def test_every_device_kind_has_a_probe() -> None:
    assert set(PROBES) == set(Device)


def test_probe_tracker_without_a_running_sim_cell(tmp_path: Path) -> None:
    result = runner.invoke(app, ["probe", "tracker", "--config", str(SIM_CELL),
                                 "--state-file", str(tmp_path / "none.json")])
    assert result.exit_code == 1 and "DEVICE_NOT_FOUND" in result.output and "sim-cell" in result.output


def test_sim_cell_serves_the_tracker_to_probe_and_stops_clean(sim_cell: tuple, tmp_path: Path) -> None:
    process, state, port = sim_cell
    assert state.is_file() and Path(port).exists()
    result = runner.invoke(app, ["probe", "tracker", "--config", str(SIM_CELL), "--state-file", str(state),
                                 "--nest", "B3"])
    assert result.exit_code == 0, result.output
    assert "SimTracker" in result.output
    assert re.search(r"^point B3: x .* mm, rms \S+ mm, measurement \d+$", result.output, re.M), "one line a result"
    xyz = np.array([float(v) for v in re.search(r"x (\S+) y (\S+) z (\S+) mm", result.output).groups()])
    truth = build_sim_cell(load_cell_config(SIM_CELL)).tracker_targets()["B3"]  # the seeded cell's truth
    assert np.linalg.norm(xyz - truth) < 0.15

    tracker_pid = json.loads(state.read_text())["tracker"]["pid"]
    process.send_signal(signal.SIGTERM)
    assert process.wait(10) == 0
    assert not state.exists()
    deadline = time.monotonic() + 5
    while time.monotonic() < deadline and alive(tracker_pid):
        time.sleep(0.05)
    assert not alive(tracker_pid), "sim-cell left its tracker process behind"


def test_probe_tracker_on_a_dead_device_fails_clearly(sim_cell: tuple) -> None:
    _, state, _ = sim_cell
    tracker_pid = json.loads(state.read_text())["tracker"]["pid"]
    os.kill(tracker_pid, signal.SIGSTOP)  # the tracker hangs: no reply
    try:
        result = runner.invoke(app, ["probe", "tracker", "--config", str(SIM_CELL), "--state-file", str(state)])
    finally:
        os.kill(tracker_pid, signal.SIGCONT)
    assert result.exit_code == 1 and "DEVICE_TIMEOUT" in result.output


def test_config_errors_name_the_section_key_and_value(tmp_path: Path) -> None:
    text = _viky_config().replace("grab_timeout_s = 3.0", 'grab_timeout_s = "3"')
    (tmp_path / "cell.toml").write_text(text)
    result = runner.invoke(app, ["probe", "camera", "--config", str(tmp_path / "cell.toml")])
    assert result.exit_code == 2 and isinstance(result.exception, SystemExit)
    assert "CONFIG_INVALID" in result.output
    assert "[camera].grab_timeout_s = '3': expected a finite number" in result.output  # not eaten as markup


def test_probe_tracker_section_missing_or_port_absent(tmp_path: Path) -> None:
    result = runner.invoke(app, ["probe", "tracker", "--config", str(CONFIG_DIR / "viky-camera.toml")])
    assert result.exit_code == 2 and "[tracker]: missing section" in result.output
    port = tmp_path / "ttyNOPE"
    (tmp_path / "cell.toml").write_text(_viky_config() + f'\n[tracker]\nbackend = "serial"\nport = "{port}"\n')
    result = runner.invoke(app, ["probe", "tracker", "--config", str(tmp_path / "cell.toml")])
    assert result.exit_code == 1 and isinstance(result.exception, SystemExit)
    assert "DEVICE_NOT_FOUND" in result.output and str(port) in result.output


@pytest.mark.parametrize(("name", "message"), [("frame.xyz", "suffix"), ("absent/frame.png", "does not exist")])
def test_probe_refuses_an_unwritable_out_before_grabbing(tmp_path: Path, name: str, message: str) -> None:
    result = runner.invoke(app, ["probe", "camera", "--config", str(SIM_CELL), "--out", str(tmp_path / name)])
    assert result.exit_code == 2 and isinstance(result.exception, SystemExit), result.output
    assert "CONFIG_INVALID" in result.output and message in result.output and "SimCamera" not in result.output


def test_sim_cell_refuses_a_config_without_a_simulated_tracker() -> None:
    result = runner.invoke(app, ["sim-cell", "--config", str(CONFIG_DIR / "viky-camera.toml")])
    assert result.exit_code == 2 and "CONFIG_INVALID" in result.output and "[tracker]" in result.output


def test_a_second_sim_cell_leaves_the_running_one_alone(sim_cell: tuple) -> None:
    _, state, _ = sim_cell
    before = state.read_text()
    result = runner.invoke(app, ["sim-cell", "--config", str(SIM_CELL), "--state-file", str(state)])
    assert result.exit_code == 1 and "already running" in result.output and str(state) in result.output
    assert state.read_text() == before  # neither overwritten nor deleted on the way out
    result = runner.invoke(app, ["probe", "tracker", "--config", str(SIM_CELL), "--state-file", str(state)])
    assert result.exit_code == 0, result.output


def test_probe_says_when_the_sim_cell_of_a_state_file_died(tmp_path: Path) -> None:
    state = tmp_path / "state.json"
    state.write_text(json.dumps({"format": "monoguide.sim-cell-state/1", "pid": _dead_pid(), "tracker": {}}))
    result = runner.invoke(app, ["probe", "tracker", "--config", str(SIM_CELL), "--state-file", str(state)])
    assert result.exit_code == 1 and "no longer running" in result.output


def _viky_config() -> str:
    return (CONFIG_DIR / "viky-camera.toml").read_text().replace("../.venv", str(CONFIG_DIR.parent / ".venv"))


def _dead_pid() -> int:
    process = subprocess.Popen([sys.executable, "-c", "pass"])
    process.wait(10)
    return process.pid
