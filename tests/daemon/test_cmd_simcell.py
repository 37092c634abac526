"""`monoguide sim-cell`'s one-per-state-file claim (issue 7, item 11): real processes started together."""

from __future__ import annotations

import json
import os
import select
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

SIM_CELL = Path(__file__).parents[2] / "config" / "sim-cell.toml"
START_S = 40.0  # two cells built at once on a shared machine


def _sim_cell(state: Path) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, "-m", "monoguide.daemon.cli", "sim-cell", "--config", str(SIM_CELL),
                             "--state-file", str(state)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _first_line(process: subprocess.Popen[str], timeout_s: float = START_S) -> str:
    assert process.stdout is not None
    ready, _, _ = select.select([process.stdout], [], [], timeout_s)
    return process.stdout.readline() if ready else ""


def _stop(process: subprocess.Popen[str]) -> int:
    if process.poll() is None:
        process.send_signal(signal.SIGTERM)
        try:
            process.wait(10)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait(5)
    for stream in (process.stdout, process.stderr):
        if stream is not None:
            stream.close()
    return process.returncode


def test_two_sim_cells_started_together_exactly_one_runs(tmp_path: Path) -> None:
    state = tmp_path / "state.json"
    both = [_sim_cell(state), _sim_cell(state)]
    try:
        deadline = time.monotonic() + START_S
        while time.monotonic() < deadline and all(p.poll() is None for p in both):
            time.sleep(0.05)
        ended = [p for p in both if p.poll() is not None]
        assert len(ended) == 1, "both ran (or neither ended): the claim is not exclusive"
        loser = ended[0]
        winner = both[1] if loser is both[0] else both[0]
        assert loser.stderr is not None
        message = loser.stderr.read()
        assert loser.returncode == 1, message
        assert "DEVICE_BUSY" in message and "already running" in message and str(state) in message
        assert "Traceback" not in message
        assert _first_line(winner).startswith("tracker listening on"), "the winner does not run"
        time.sleep(0.3)
        assert winner.poll() is None
        assert json.loads(state.read_text())["pid"] == winner.pid  # survived the loser's exit, and is the winner's
        assert _stop(winner) == 0
        assert not state.exists() and not state.with_name("state.json.lock").exists()
    finally:
        for p in both:
            _stop(p)


def test_a_state_file_left_by_a_killed_sim_cell_is_taken_over(tmp_path: Path) -> None:
    state = tmp_path / "state.json"
    first = _sim_cell(state)
    try:
        assert _first_line(first).startswith("tracker listening on")
        first.send_signal(signal.SIGKILL)  # no clean-up: its state file and lock file stay behind
        first.wait(10)
        assert state.exists()
    finally:
        _stop(first)
    second = _sim_cell(state)
    try:
        assert _first_line(second).startswith("tracker listening on")
        assert json.loads(state.read_text())["pid"] == second.pid
    finally:
        assert _stop(second) == 0


@pytest.mark.parametrize("which", ["state.json", "state.json.lock"])
def test_a_directory_where_the_state_file_goes_is_a_clear_config_error(tmp_path: Path, which: str) -> None:
    state = tmp_path / "state.json"
    (tmp_path / which).mkdir()
    process = _sim_cell(state)
    try:
        assert process.wait(START_S) == 2
        assert process.stderr is not None
        message = process.stderr.read()
    finally:
        _stop(process)
    assert "CONFIG_INVALID" in message and "is a directory" in message and str(tmp_path / which) in message
    assert "Traceback" not in message
    assert (tmp_path / which).is_dir() and os.listdir(tmp_path / which) == []  # left as it was
