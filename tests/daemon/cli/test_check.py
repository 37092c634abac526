"""``monoguide check`` on the simulated cell: it asks a running ``monoguide sim-cell`` for the reference part itself
(through the command pipe its state file names; nobody types anything into sim-cell), checks the calibration on
it and passes; where sim-cell cannot be asked it names the command to type and moves nothing; without a sim-cell
it says so in one line. sim-cell and check run as processes; the simulated robot's truth file (the part in the
cell, the robot's stops) is the ground truth. Loopback 127.0.57.20-23."""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from helpers.cell_configs import cell_config
from helpers.sim_processes import keep_reading, start_sim_cell, stop

from monoguide.daemon.config import load_cell_config
from monoguide.daemon.service import Journal
from monoguide.drivers.plc_registers import CHECK_JOB

START_S = 60.0


@pytest.fixture
def sim_cell(tmp_path: Path, request: pytest.FixtureRequest) -> Iterator[dict[str, Any]]:
    """A sim-cell whose state file only ``--state-file`` names (not the config), standard input closed."""
    config = cell_config(tmp_path, request.param, sharp=True)
    state = tmp_path / "sim-state.json"
    process, _ = start_sim_cell(config, "--no-plc", "--state-file", str(state), timeout_s=START_S)
    said = keep_reading(process)
    try:
        yield {"config": config, "state": state, "said": said,
               "truth": Path(json.loads(state.read_text())["robot"]["truth"])}
    finally:
        stop(process, 15.0)


@pytest.mark.parametrize("sim_cell", ["127.0.57.20"], indirect=True)
def test_check_presents_the_reference_part_itself_and_passes(sim_cell: dict[str, Any], tmp_path: Path) -> None:
    done = _check(sim_cell["config"], tmp_path / "state", "--state-file", str(sim_cell["state"]), "--json")
    assert done.returncode == 0, done.stderr[-3000:]
    assert "the simulated cell presents the reference part (robot reference-part" in done.stderr
    found = json.loads(done.stdout.strip().splitlines()[-1])
    assert found["passed"] is True and set(found["check"]["views"]) == {"S1", "S2", "S3", "S4"}
    truth = json.loads(sim_cell["truth"].read_text())  # the part the camera saw: the roof's reference, as taught
    assert (truth["reference_part"], truth["part_type"], truth["part"]) == ("in the cell", 1, 1)
    np.testing.assert_array_equal(np.array(truth["T_cf_w"]), load_cell_config(sim_cell["config"]).reference.T_cf_w0)
    assert "fault: robot reference-part" in sim_cell["said"]  # sim-cell took it as its own command
    with Journal(tmp_path / "state", read_only=True) as journal:
        (row,) = journal.last_cycles(1)
    assert (row.job, row.status) == (CHECK_JOB, "ok")


@pytest.mark.parametrize("sim_cell", ["127.0.57.22"], indirect=True)
def test_where_sim_cell_cannot_be_asked_check_names_the_command_and_moves_nothing(sim_cell: dict[str, Any],
                                                                                  tmp_path: Path) -> None:
    state = json.loads(sim_cell["state"].read_text())
    del state["commands"]  # a state file that names no command pipe
    other = tmp_path / "no-pipe-state.json"
    other.write_text(json.dumps(state))
    done = _check(sim_cell["config"], tmp_path / "state", "--state-file", str(other))
    assert done.returncode == 1, done.stderr[-3000:]
    assert _lines(done.stderr) == [f"SIMULATE_ERROR check failed: the sim-cell of {other} (pid {state['pid']}) names "
                                   "no command pipe in its state file: type `robot reference-part` into its standard "
                                   "input"]
    truth = json.loads(sim_cell["truth"].read_text())
    assert truth["stops"] == {} and truth["part"] == 0 and truth["reference_part"] is None  # nothing moved


def test_check_without_a_running_simulated_cell_says_so_in_one_line(tmp_path: Path) -> None:
    absent = tmp_path / "absent-state.json"
    config = cell_config(tmp_path, "127.0.57.23", sharp=True, state_file=absent)
    done = _check(config, tmp_path / "state")
    assert done.returncode == 1, done.stderr[-3000:]
    assert _lines(done.stderr) == [f"DEVICE_NOT_FOUND check failed: no simulated cell running: {absent} does not "
                                   "exist (start `monoguide sim-cell`)"]


def _check(config: Path, state_dir: Path, *options: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "monoguide.daemon.cli", "check", "--config", str(config),
                           "--state-dir", str(state_dir), *options], capture_output=True, text=True, timeout=180,
                          stdin=subprocess.DEVNULL)


def _lines(stderr: str) -> list[str]:
    """Standard error without the progress line (``check: job 1 ...``) of a check that got as far as its devices."""
    return [line for line in stderr.splitlines() if line.strip() and not line.startswith("check: ")]
