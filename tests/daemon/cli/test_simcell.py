"""`monoguide sim-cell`: its one-per-state-file claim (issue 7, item 11), its PLC and its part supply (issue 10),
with real processes."""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import queue
import select
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from helpers.cell_configs import cell_config
from helpers.repository import SIM_CELL
from helpers.sim_processes import START_S, start_sim_cell, stop

from monoguide.daemon.assembly import build_robot, build_sim_cell
from monoguide.daemon.config import CellConfig, load_cell_config
from monoguide.daemon.simulate import FAULT_COMMANDS
from monoguide.drivers.errors import RobotProtectiveStop
from monoguide.drivers.modbus_plc import ModbusPlc
from monoguide.drivers.plc_registers import CycleResult, PlcInputs, PlcOutputs, Status
from monoguide.drivers.sim.robot_motion import follow_truth
from monoguide.solver.frames import T_to_kuka_frame, invert, matrix_to_rotvec, transform_points


def _sim_cell(state: Path) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, "-m", "monoguide.daemon.cli", "sim-cell", "--config", str(SIM_CELL),
                             "--state-file", str(state)], stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


def _first_line(process: subprocess.Popen[str], timeout_s: float = START_S) -> str:
    assert process.stdout is not None
    ready, _, _ = select.select([process.stdout], [], [], timeout_s)
    return process.stdout.readline() if ready else ""


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
        assert message.startswith("DEVICE_BUSY ") and "already running" in message and str(state) in message
        assert "Traceback" not in message
        assert _first_line(winner).startswith("tracker listening on"), "the winner does not run"
        time.sleep(0.3)
        assert winner.poll() is None
        assert json.loads(state.read_text())["pid"] == winner.pid  # survived the loser's exit, and is the winner's
        assert stop(winner) == 0
        assert not state.exists() and not state.with_name("state.json.lock").exists()
    finally:
        for p in both:
            stop(p)


def test_a_state_file_left_by_a_killed_sim_cell_is_taken_over(tmp_path: Path) -> None:
    state = tmp_path / "state.json"
    first = _sim_cell(state)
    try:
        assert _first_line(first).startswith("tracker listening on")
        while "plc" not in (running := json.loads(state.read_text() if state.exists() else "{}")):
            time.sleep(0.05)
        first.send_signal(signal.SIGKILL)  # no clean-up: its state file and lock file stay behind
        first.wait(10)
        assert state.exists()
        deadline = time.monotonic() + 3.0
        while _alive(running["plc"]["pid"]) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not _alive(running["plc"]["pid"]), "the simulated PLC outlived its killed sim-cell"
    finally:
        stop(first)
    second = _sim_cell(state)
    try:
        assert _first_line(second).startswith("tracker listening on")
        assert json.loads(state.read_text())["pid"] == second.pid
    finally:
        assert stop(second) == 0


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
        stop(process)
    assert message.startswith("CONFIG_INVALID ") and "is a directory" in message and str(tmp_path / which) in message
    assert "Traceback" not in message
    assert (tmp_path / which).is_dir() and os.listdir(tmp_path / which) == []  # left as it was


# --- the simulated PLC and the part supply (issue 10) ------------------------------------------


def _run_sim_cell(config: Path, state: Path, *options: str) -> tuple[subprocess.Popen[str], list[str]]:
    """Start sim-cell with its state file at ``state``; its stdout lines up to the state file's (it runs then)."""
    return start_sim_cell(config, "--state-file", str(state), *options)


def _stop_cell(process: subprocess.Popen[str], pids: list[int]) -> None:
    """Stop sim-cell and prove that none of its device processes outlived it (SIGKILL any that did)."""
    assert stop(process) == 0
    deadline = time.monotonic() + 5.0
    alive = pids
    while alive and time.monotonic() < deadline:
        alive = [pid for pid in pids if _alive(pid)]
        time.sleep(0.05)
    for pid in alive:
        os.kill(pid, signal.SIGKILL)
    assert not alive, f"sim-cell left device processes behind: {alive}"


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    with contextlib.suppress(FileNotFoundError):
        return Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[0] != "Z"  # a zombie is gone
    return False


def _within_envelope(T_cf_w: np.ndarray, cfg: CellConfig) -> bool:
    assert cfg.sim is not None
    T_w0_w = invert(cfg.reference.T_cf_w0) @ T_cf_w
    centroid = cfg.part.points_w.mean(axis=0)
    rot_deg = np.degrees(np.abs(matrix_to_rotvec(T_w0_w[:3, :3])))
    shift = transform_points(T_w0_w, centroid[None])[0] - centroid
    return bool(np.all(rot_deg <= np.array(cfg.sim.deviation_rotation_deg) * 1.01)
                and np.all(np.abs(shift) <= np.array(cfg.sim.deviation_translation_mm) + 1e-9)
                and np.linalg.norm(shift) > 1e-3)


def test_sim_cell_runs_the_plc_and_a_part_supply_with_a_truth_log(tmp_path: Path) -> None:
    config, state, truth_log = cell_config(tmp_path, "127.0.3.1", "127.0.3.2"), tmp_path / "s.json", \
        tmp_path / "truth.jsonl"
    cfg = load_cell_config(config)
    process, lines = _run_sim_cell(config, state, "--truth-log", str(truth_log))
    pids: list[int] = []
    try:
        running = json.loads(state.read_text())
        pids = [running["tracker"]["pid"], running["robot"]["pid"], running["plc"]["pid"]]
        assert f"plc listening on 127.0.3.2:5020 unit 1 (pid {running['plc']['pid']})" in lines
        assert running["plc"] == {"host": "127.0.3.2", "port": 5020, "pid": pids[2]}

        async def read_plc() -> tuple[PlcInputs, PlcInputs, PlcOutputs]:
            plc = ModbusPlc("127.0.3.2", 5020, unit=1)
            await plc.connect()
            try:
                first = await plc.read_inputs()
                await asyncio.sleep(1.2)  # the simulated PLC beats every 0.5 s
                return first, await plc.read_inputs(), await plc.read_outputs()
            finally:
                await plc.close()

        first, later, outputs = asyncio.run(read_plc())
        assert later.plc_heartbeat != first.plc_heartbeat
        assert (later.job, later.part_tag) == (1, 1001)  # the line's first part arrived, waiting for READY
        assert outputs.status == 0 and outputs.heartbeat == 0  # nobody has written monoguide's block

        robot = build_robot(cfg, state)
        robot.open()
        camera_cell = build_sim_cell(cfg)  # the simulated camera's truth, in this process
        truth_file = Path(running["robot"]["truth"])
        try:
            robot.move_to_measuring_pose(0)  # cycle 1: part 1 arrives
            follow_truth(camera_cell, truth_file)
            T_cf_w1 = camera_cell.T_cf_w_true
            robot.move_to_measuring_pose(1)  # S2 in the same cycle: the same part
            follow_truth(camera_cell, truth_file)
            np.testing.assert_array_equal(camera_cell.T_cf_w_true, T_cf_w1)
            T_cf_b, T_cf_w0 = cfg.reference.T_cf_b, cfg.reference.T_cf_w0
            assert T_cf_b is not None
            D_ideal = invert(T_cf_b) @ T_cf_w1 @ invert(T_cf_w0) @ T_cf_b  # T_b_w inv(T_b_w0)
            robot.write_base_offset(D_ideal)
            robot.move_to_measuring_pose(0)  # cycle 2: part 2 arrives, no offset written for it
            follow_truth(camera_cell, truth_file)
            T_cf_w2 = camera_cell.T_cf_w_true
        finally:
            robot.close()
    finally:
        _stop_cell(process, pids)

    parts = [json.loads(line) for line in truth_log.read_text().splitlines()]
    assert [p["part"] for p in parts] == [1, 2]
    np.testing.assert_allclose(np.array(parts[0]["T_cf_w"]), T_cf_w1, atol=1e-9)  # the camera saw these parts
    np.testing.assert_allclose(np.array(parts[1]["T_cf_w"]), T_cf_w2, atol=1e-9)
    assert not np.allclose(T_cf_w1, T_cf_w2)
    assert _within_envelope(T_cf_w1, cfg) and _within_envelope(T_cf_w2, cfg)
    ideal = np.array(T_to_kuka_frame(D_ideal))
    np.testing.assert_allclose(parts[0]["offset_ideal"], ideal, atol=1e-6)
    np.testing.assert_allclose(parts[0]["offset_written"], ideal, atol=1e-6)
    assert parts[0]["grasp_error_mm"] < 1e-6 and parts[0]["grasp_error_deg"] < 1e-6
    assert parts[1]["offset_written"] is None and parts[1]["grasp_error_mm"] is None
    assert np.linalg.norm(np.array(parts[1]["offset_ideal"])[:3]) > 1.0  # a deviated part needs an offset


def test_no_plc_leaves_the_plc_address_to_another_server(tmp_path: Path) -> None:
    config, state = cell_config(tmp_path, "127.0.3.3", "127.0.3.4"), tmp_path / "s.json"
    with socket.socket() as other_plc:  # a PLC programmer's own server, there first
        other_plc.bind(("127.0.3.4", 5020))
        other_plc.listen()
        process, lines = _run_sim_cell(config, state, "--no-plc")
        running = json.loads(state.read_text())
        try:
            assert "plc" not in running
            assert "plc left out (--no-plc): 127.0.3.4:5020 is free for another server" in lines
            time.sleep(0.3)
            assert process.poll() is None
        finally:
            _stop_cell(process, [running["tracker"]["pid"], running["robot"]["pid"]])


def test_truth_log_needs_a_simulated_robot(tmp_path: Path) -> None:
    text = SIM_CELL.read_text().replace('backend = "sim-ur"', 'backend = "ur"')
    config = tmp_path / "cell.toml"
    config.write_text(text)
    process = subprocess.Popen([sys.executable, "-m", "monoguide.daemon.cli", "sim-cell", "--config", str(config),
                                "--state-file", str(tmp_path / "s.json"), "--truth-log", str(tmp_path / "t.jsonl")],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert process.wait(START_S) == 2
        assert process.stderr is not None
        message = process.stderr.read()
    finally:
        stop(process)
    assert message.startswith("CONFIG_INVALID ") and "--truth-log" in message and "sim-ur" in message
    assert not (tmp_path / "t.jsonl").exists() and not (tmp_path / "s.json").exists()


def test_the_part_supply_is_seeded_by_the_config(tmp_path: Path) -> None:
    from monoguide.drivers.sim.part_supply import PartSupply  # tests may reach the simulator directly

    cfg = load_cell_config(SIM_CELL)
    spec = build_sim_cell(cfg).write_robot_spec(tmp_path / "robot.json")
    first, again = (PartSupply.from_spec_file(spec, None) for _ in range(2))
    parts = [first.arrive() for _ in range(3)]
    np.testing.assert_array_equal(np.array(parts), np.array([again.arrive() for _ in range(3)]))
    assert all(_within_envelope(first.T_cf_b @ T_b_w, cfg) for T_b_w in parts)
    assert not np.allclose(parts[0], parts[1]) and not np.allclose(parts[1], parts[2])
    data = json.loads(spec.read_text())
    other = PartSupply(data["seed"] + 1, data["part_supply"], np.array(data["T_b_g0"]), None)
    assert not np.allclose(other.arrive(), parts[0])


# --- the fault channel and --parts (issue 10/11) --------------------------------------------------


class _Output:
    """A stream's lines as they come (a reader thread); :meth:`expect` takes the first one not yet taken that
    starts with a prefix, waiting for it with a deadline."""

    def __init__(self, stream: Any) -> None:
        self.lines: queue.Queue[str] = queue.Queue()
        self.pending: list[str] = []
        threading.Thread(target=lambda: [self.lines.put(line.strip()) for line in stream], daemon=True).start()

    def expect(self, prefix: str, timeout_s: float = 5.0) -> str:
        deadline = time.monotonic() + timeout_s
        while True:
            if match := [line for line in self.pending if line.startswith(prefix)]:
                self.pending.remove(match[0])
                return match[0]
            if (left := deadline - time.monotonic()) <= 0:
                pytest.fail(f"no line {prefix!r} within {timeout_s} s; not taken: {self.pending}")
            with contextlib.suppress(queue.Empty):
                self.pending.append(self.lines.get(timeout=left))


def _command(process: subprocess.Popen[str], text: str) -> None:
    assert process.stdin is not None
    process.stdin.write(text + "\n")
    process.stdin.flush()


async def _play_monoguide(plc: ModbusPlc, cycles: int) -> list[int]:
    """monoguide's side of ``cycles`` good cycles (READY, TRIGGER -> BUSY -> DONE|RESULT_OK, ACK -> READY); then
    READY stays while the line should play no more. Returns the part tags the line triggered."""
    tags: list[int] = []

    async def until(condition: Callable[[PlcInputs], bool], timeout_s: float = 5.0) -> PlcInputs | None:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if condition(inputs := await plc.read_inputs()):
                return inputs
            await asyncio.sleep(0.01)
        return None

    for n in range(cycles + 1):
        await plc.write_status(Status.READY)
        triggered = await until(lambda i: i.trigger, 5.0 if n < cycles else 1.0)
        if triggered is None:
            break
        tags.append(triggered.part_tag)
        await plc.write_status(Status.BUSY)
        await plc.write_result(CycleResult(0, n + 1, triggered.job, triggered.part_tag, (1.0, 2.0, 3.0, 0.1, 0.2,
                                                                                          0.3)))
        await plc.write_status(Status.DONE | Status.RESULT_OK)
        assert await until(lambda i: i.result_ack and not i.trigger) is not None
        await plc.write_status(Status(0))
        assert await until(lambda i: not i.result_ack) is not None
    return tags


def test_fault_names_are_the_simulators_own() -> None:
    from monoguide.drivers.sim.camera import FAILURES
    from monoguide.drivers.sim.plc import FAULTS
    from monoguide.drivers.sim.robot_motion import FAULT_MODES

    assert FAULT_COMMANDS == {"plc": FAULTS, "robot": FAULT_MODES, "camera": FAILURES}


def test_fault_commands_reach_each_device_and_parts_stop_after_n(tmp_path: Path) -> None:
    config, state = cell_config(tmp_path, "127.0.6.1", "127.0.6.2"), tmp_path / "s.json"
    cfg = load_cell_config(config)
    process = subprocess.Popen([sys.executable, "-m", "monoguide.daemon.cli", "sim-cell", "--config", str(config),
                                "--state-file", str(state), "--parts", "2"], stdin=subprocess.PIPE,
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    out, err = _Output(process.stdout), _Output(process.stderr)
    pids: list[int] = []
    try:
        out.expect("state file", START_S)
        running = json.loads(state.read_text())
        pids = [running["tracker"]["pid"], running["robot"]["pid"], running["plc"]["pid"]]

        # bad commands: said on stderr, the cell runs on
        for bad, reason in (("laser on", "unknown device 'laser'"), ("plc melt", "unknown plc fault 'melt'"),
                            ("robot", "which fault?"), ("camera black 0", "count must be"),
                            ("camera black two", "count must be"), ("plc no-ack now", "takes nothing more")):
            _command(process, bad)
            assert reason in err.expect("fault error:"), bad
        assert process.poll() is None

        # camera: into the state file, a new serial per command
        _command(process, "camera black 2")
        assert out.expect("fault:") == "fault: camera black"
        first = json.loads(state.read_text())["camera_fault"]
        _command(process, "camera glare")
        assert out.expect("fault:") == "fault: camera glare"
        second = json.loads(state.read_text())["camera_fault"]
        assert (first["failure"], first["count"]) == ("black", 2) and (second["failure"], second["count"]) == \
            ("glare", 1)
        assert second["serial"] > first["serial"]

        # robot: a protective stop seen through the real adapter, then cleared
        robot = build_robot(cfg, state)
        robot.open()
        try:
            _command(process, "robot protective-stop")
            assert out.expect("fault:") == "fault: robot protective-stop"
            with pytest.raises(RobotProtectiveStop):
                robot.move_to_measuring_pose(0)
            _command(process, "robot none")
            assert out.expect("fault:") == "fault: robot none"
            deadline = time.monotonic() + 2.0
            while robot.status().protective_stop and time.monotonic() < deadline:
                time.sleep(0.02)
            assert robot.move_to_measuring_pose(0).in_position == 1
        finally:
            robot.close()

        async def plc_side() -> tuple[list[int], list[int], list[int]]:
            plc = ModbusPlc("127.0.6.2", 5020, unit=1)
            await plc.connect()
            try:
                tags = await _play_monoguide(plc, 2)  # --parts 2: a third trigger never comes
                _command(process, "plc heartbeat-stopped")
                out.expect("fault: plc heartbeat-stopped")
                await asyncio.sleep(0.6)  # a beat under way may still land
                stopped = [(await plc.read_inputs()).plc_heartbeat]
                for _ in range(3):
                    await asyncio.sleep(0.4)  # the simulated PLC beats every 0.5 s
                    stopped.append((await plc.read_inputs()).plc_heartbeat)
                _command(process, "plc none")
                out.expect("fault: plc none")
                await asyncio.sleep(1.2)
                return tags, stopped, [(await plc.read_inputs()).plc_heartbeat]
            finally:
                await plc.close()

        tags, stopped, again = asyncio.run(plc_side())
        assert tags == [1001, 1002]
        records = [json.loads(out.expect("plc: ").removeprefix("plc: ")) for _ in range(2)]
        assert [r["part"] for r in records] == [1, 2] and all(r["outcome"] == "acknowledged" for r in records)
        assert len(set(stopped)) == 1, f"the heartbeat kept changing: {stopped}"
        assert again[0] != stopped[-1], "plc none did not start the heartbeat again"
        assert process.poll() is None
    finally:
        _stop_cell(process, pids)
