"""The simulated robot's one-shot faults (``restart``, ``cut-after-offset MS [DOWN_S]``): their names agree between
the simulator and ``monoguide sim-cell`` (runtime code never imports the simulator, so sim-cell keeps a copy), bad
arguments are refused naming them, and sim-cell forwards them to the running controller."""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from monoguide.daemon.cli.simcell import FAULT_COMMANDS, ROBOT_ACTIONS
from monoguide.drivers.sim.robot_motion import CUT_DOWN_S, FAULT_ACTIONS, FAULT_MODES, FaultCommand, parse_fault

SIM_CELL = Path(__file__).parents[3] / "config" / "sim-cell.toml"
ROBOT_HOST = "127.0.23.120"


def test_sim_cell_knows_the_simulators_fault_names() -> None:
    assert ROBOT_ACTIONS == FAULT_ACTIONS and FAULT_COMMANDS["robot"] == FAULT_MODES


@pytest.mark.parametrize(("text", "command"), [
    ("restart", FaultCommand("restart")),
    ("cut-after-offset 0", FaultCommand("cut-after-offset", 0.0, CUT_DOWN_S)),
    ("cut-after-offset 4.5 2", FaultCommand("cut-after-offset", 4.5, 2.0)),
    ("none", FaultCommand("none")),
])
def test_fault_commands_parse(text: str, command: FaultCommand) -> None:
    assert parse_fault(text) == command


@pytest.mark.parametrize(("text", "match"), [
    ("restart now", "takes nothing more"),
    ("cut-after-offset", "MS"),
    ("cut-after-offset soon", "numbers"),
    ("cut-after-offset 5 0", "DOWN_S above 0"),
    ("cut-after-offset -1", "MS 0"),
    ("cut-after-offset 1 2 3", "MS"),
    ("melt", "expected one of"),
])
def test_bad_fault_commands_are_refused_naming_what_is_wrong(text: str, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        parse_fault(text)


def test_sim_cell_forwards_the_one_shot_robot_faults_and_refuses_bad_ones(tmp_path: Path) -> None:
    text = SIM_CELL.read_text().replace('host = "127.0.0.1"  # where', f'host = "{ROBOT_HOST}"  # where')
    config = tmp_path / "cell.toml"
    config.write_text(text)
    state = tmp_path / "state.json"
    process = subprocess.Popen([sys.executable, "-m", "monoguide.daemon.cli", "sim-cell", "--config", str(config),
                                "--state-file", str(state), "--no-plc"], stdin=subprocess.PIPE,
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    watchdog = threading.Timer(60.0, process.kill)  # a silent sim-cell would block readline for good
    watchdog.start()
    try:
        assert process.stdout is not None and process.stdin is not None and process.stderr is not None
        while not process.stdout.readline().startswith("state file"):
            assert process.poll() is None
        truth_file = Path(json.loads(state.read_text())["robot"]["truth"])
        for line in ("robot cut-after-offset soon", "robot restart now"):
            process.stdin.write(line + "\n")
            process.stdin.flush()
            said = process.stderr.readline()
            while not said.startswith("fault error:"):
                said = process.stderr.readline()
            assert "robot cut-after-offset takes MS" in said or "takes nothing more" in said, said
        for line in ("robot cut-after-offset 5 0.5", "robot restart"):
            process.stdin.write(line + "\n")
            process.stdin.flush()
            assert process.stdout.readline().strip() == f"fault: {line.split()[0]} {line.split()[1]}"
        deadline = time.monotonic() + 5.0
        while (truth := json.loads(truth_file.read_text()))["starts"] < 2:  # the program stopped and started again
            assert time.monotonic() < deadline, truth
            time.sleep(0.02)
        assert truth["commands_applied"] == 2 and truth["fault"] == "none"
    finally:
        watchdog.cancel()
        process.terminate()
        process.wait(15)
        for stream in (process.stdin, process.stdout, process.stderr):
            if stream is not None:
                stream.close()


def test_sim_cell_help_shows_its_bracketed_words() -> None:
    """rich reads ``[plc]`` as markup and swallowed it ("listen where  says"): the help escapes it."""
    from typer.testing import CliRunner

    from monoguide.daemon.cli import app

    result = CliRunner().invoke(app, ["sim-cell", "--help"], env={"COLUMNS": "200"})
    assert result.exit_code == 0
    assert "can listen where [plc] says" in result.output and "camera <failure> [count])" in result.output
