"""The simulated robot's one-shot faults (``restart``, ``cut-after-offset MS [DOWN_S]``): their names agree between
the simulator and ``monoguide sim-cell`` (runtime code never imports the simulator, so sim-cell keeps a copy), bad
arguments are refused naming them, sim-cell forwards them to the running controller, and ``none`` clears an armed
cut (and ends one under way) as it clears a mode: the controller process against the genuine ur-rtde client and the
KUKA XML client. Loopback 127.0.23.120-124."""

from __future__ import annotations

import contextlib
import json
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from helpers.robots import make_adapter, sim_cell, stopping, truth, wait_for

from monoguide.daemon.cli.simcell import FAULT_COMMANDS, ROBOT_ACTIONS
from monoguide.drivers.errors import DeviceDisconnected, DeviceNotFound, DeviceTimeout, RobotAckTimeout
from monoguide.drivers.kuka_robot import KukaRobot
from monoguide.drivers.sim.cell import SimCell
from monoguide.drivers.sim.robot_motion import CUT_DOWN_S, FAULT_ACTIONS, FAULT_MODES, FaultCommand, parse_fault
from monoguide.drivers.sim.robot_process import ControllerProcess, start_controller
from monoguide.drivers.ur_robot import UrRobot
from monoguide.solver.frames import compose, invert

SIM_CELL = Path(__file__).parents[3] / "config" / "sim-cell.toml"
ROBOT_HOST = "127.0.23.120"


def test_sim_cell_knows_the_simulators_fault_names() -> None:
    assert ROBOT_ACTIONS == FAULT_ACTIONS and FAULT_COMMANDS["robot"] == FAULT_MODES


@pytest.mark.parametrize(("text", "command"), [
    ("restart", FaultCommand("restart")),
    ("cut-after-offset 0", FaultCommand("cut-after-offset", 0.0, CUT_DOWN_S)),
    ("cut-after-offset 4.5 2", FaultCommand("cut-after-offset", 4.5, 2.0)),
    ("cut", FaultCommand("cut", 0.0, CUT_DOWN_S)),
    ("cut 2.5", FaultCommand("cut", 0.0, 2.5)),
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
    ("cut 0", "DOWN_S above 0"),
    ("cut later", "a number"),
    ("cut 1 2", "takes \\[DOWN_S\\]"),
    ("melt", "expected one of"),
])
def test_bad_fault_commands_are_refused_naming_what_is_wrong(text: str, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        parse_fault(text)


@pytest.mark.parametrize(("kind", "host"), [("ur", "127.0.23.121"), ("kuka", "127.0.23.122")])
def test_none_disarms_a_cut_after_offset_before_its_offset_comes(kind: str, host: str, tmp_path: Path) -> None:
    with _at_pose_1(kind, host, tmp_path) as (cell, controller, robot):
        controller.command("cut-after-offset 0 5")  # armed: at once when the next offset arrives, for 5 s
        controller.command("none")
        sent = robot.write_base_offset(compose(cell.T_b_w_true(), invert(cell.T_b_w0())))
        began = time.monotonic()
        while time.monotonic() - began < 0.3:  # the connection stays: no cut came
            robot.status()
            time.sleep(0.02)
        held = truth(controller)
        assert (held["held_sequence"], held["offset_valid"], held["fault"]) == (sent, True, "none")
        assert robot.held_offset().sequence == sent  # asked over the same connection


@pytest.mark.parametrize(("kind", "host"), [("ur", "127.0.23.123"), ("kuka", "127.0.23.124")])
def test_none_ends_a_cut_under_way(kind: str, host: str, tmp_path: Path) -> None:
    with _at_pose_1(kind, host, tmp_path) as (cell, controller, robot):
        controller.command("cut-after-offset 0 30")  # every connection closed for 30 s once the offset arrives
        with pytest.raises((DeviceDisconnected, DeviceTimeout, RobotAckTimeout)):
            robot.write_base_offset(compose(cell.T_b_w_true(), invert(cell.T_b_w0())))
        wait_for(lambda: truth(controller)["held_sequence"] != 0, "the program holds the offset")
        with pytest.raises((DeviceNotFound, DeviceDisconnected, DeviceTimeout)):  # the cable is out
            robot.held_offset()
        controller.command("none")  # the cable is back in
        began = time.monotonic()
        while True:
            try:
                held = robot.held_offset()  # the adapter reconnects on each call
                break
            except (DeviceNotFound, DeviceDisconnected, DeviceTimeout):
                assert time.monotonic() - began < 5.0, "still cut 5 s after none (the cut was for 30 s)"
                time.sleep(0.1)
        assert held.sequence == truth(controller)["held_sequence"]


@contextlib.contextmanager
def _at_pose_1(kind: str, host: str, tmp_path: Path
               ) -> Iterator[tuple[SimCell, ControllerProcess, UrRobot | KukaRobot]]:
    """The simulated controller of ``kind`` (its commands on standard input) and the genuine client's adapter,
    the robot at measuring pose 1; both stopped after."""
    cell = sim_cell()
    spec = cell.write_robot_spec(tmp_path / "robot.json", part=3)
    controller = start_controller(kind, spec, tmp_path / "truth.json", host, move_time_s=0.05, commands=True)
    with stopping(controller), make_adapter(kind, controller, cell, connect_timeout_s=0.3) as robot:
        robot.move_to_measuring_pose(0)
        yield cell, controller, robot


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
