"""The grasp in the simulated cell goes only through the robot program's interlock: `monoguide sim-cell` with its
simulated PLC and robot; this test plays monoguide's side (the PLC handshake over Modbus TCP, the offset over the
real robot adapter). The PLC gives the grasp go after it read DONE + RESULT_OK; sim-cell relays it to the robot
and the robot's answer back; the truth log records each grasp, run or refused."""

from __future__ import annotations

import asyncio
import json
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

from monoguide.daemon.assembly import build_robot
from monoguide.daemon.config import load_cell_config
from monoguide.daemon.simulate import read_truth_log, summarize
from monoguide.drivers.modbus_plc import ModbusPlc
from monoguide.drivers.plc_registers import CycleResult, PlcInputs, Status
from monoguide.drivers.sim.robot_motion import read_truth
from monoguide.solver.frames import invert

SIM_CELL = Path(__file__).parents[3] / "config" / "sim-cell.toml"
ROBOT_HOST, PLC_HOST = "127.0.23.101", "127.0.23.102"
START_S = 40.0


def test_the_line_grasps_with_a_fresh_offset_and_the_interlock_refuses_a_stale_one(tmp_path: Path) -> None:
    config = _config(tmp_path)
    cfg = load_cell_config(config)
    state, truth_log = tmp_path / "state.json", tmp_path / "truth.jsonl"
    process = subprocess.Popen([sys.executable, "-m", "monoguide.daemon.cli", "sim-cell", "--config", str(config),
                                "--state-file", str(state), "--truth-log", str(truth_log), "--parts", "2"],
                               stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        lines = _until(process, "state file")
        robot = build_robot(cfg, state)
        robot.open()
        try:
            asyncio.run(_play(cfg, robot, state))
        finally:
            robot.close()
        lines += _until(process, "plc: ", count=2)  # the line's records, each after its grasp's answer
    finally:
        process.terminate()
        process.wait(15)
    grasped = [json.loads(line.removeprefix("grasp: ")) for line in lines if line.startswith("grasp: ")]
    assert [(g["outcome"], g["reason"]) for g in grasped] == [("ran", None), ("refused", "stale offset")]
    assert grasped[0]["grasp_error_mm"] < 1e-6 and grasped[1]["held_sequence"] == grasped[0]["held_sequence"]
    assert grasped[1]["grasp_error_mm"] > 1.0  # part 1's offset on part 2: it would have missed
    log = [json.loads(line) for line in truth_log.read_text().splitlines()]
    assert [g["grasp"]["outcome"] for g in log if "grasp" in g] == ["ran", "refused"]
    # simulate counts them from the truth log; its readers of part lines see the parts only
    assert [p["part"] for p in read_truth_log(truth_log)] == [1, 2]
    counts = summarize([], read_truth_log(truth_log, grasps=True))
    assert (counts["grasps_ran"], counts["grasps_refused"], counts["grasps_refused_stale"]) == (1, 1, 1)
    records = [json.loads(line.removeprefix("plc: ")) for line in lines if line.startswith("plc: ")]
    assert [(r["part"], r["result_ok"], r["grasp"]["outcome"]) for r in records] == [(1, True, "ran"),
                                                                                    (2, True, "refused")]


async def _play(cfg: object, robot: object, state: Path) -> None:
    """Two parts as monoguide's side: part 1 measured and its offset written, part 2 reported RESULT_OK though no
    offset was written for it (a service gone wrong): only the robot program's interlock stands in the way."""
    plc = ModbusPlc(PLC_HOST, 5020, unit=1)
    await plc.connect()
    try:
        for part in (1, 2):
            await plc.write_status(Status.READY)
            triggered = await _until_plc(plc, lambda i: i.trigger)
            await plc.write_status(Status.BUSY)
            await asyncio.to_thread(robot.move_to_measuring_pose, 0)  # type: ignore[attr-defined]
            if part == 1:
                truth = read_truth(Path(json.loads(state.read_text())["robot"]["truth"]))
                T_cf_b, T_cf_w0 = cfg.reference.T_cf_b, cfg.reference.T_cf_w0  # type: ignore[attr-defined]
                D_ideal = invert(T_cf_b) @ np.array(truth["T_cf_w"]) @ invert(T_cf_w0) @ T_cf_b
                await asyncio.to_thread(robot.write_base_offset, D_ideal)  # type: ignore[attr-defined]
            await plc.write_result(CycleResult(0, part, triggered.job, triggered.part_tag, (0.0,) * 6))
            await plc.write_status(Status.DONE | Status.RESULT_OK)
            await _until_plc(plc, lambda i: i.result_ack and not i.trigger)
            await plc.write_status(Status(0))
            await _until_plc(plc, lambda i: not i.result_ack)
    finally:
        await plc.close()


async def _until_plc(plc: ModbusPlc, condition: object, timeout_s: float = 20.0) -> PlcInputs:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if condition(inputs := await plc.read_inputs()):  # type: ignore[operator]
            return inputs
        await asyncio.sleep(0.01)
    raise TimeoutError("the simulated PLC did not get there")


def _until(process: subprocess.Popen[str], prefix: str, count: int = 1, timeout_s: float = START_S) -> list[str]:
    """sim-cell's output lines until ``count`` of them start with ``prefix``."""
    assert process.stdout is not None
    lines: list[str] = []
    watchdog = threading.Timer(timeout_s, process.kill)  # a silent sim-cell would block readline for good
    watchdog.start()
    try:
        while sum(line.startswith(prefix) for line in lines) < count:
            line = process.stdout.readline()
            assert line, f"sim-cell ended (or was killed after {timeout_s:g} s) after {lines}"
            lines.append(line.strip())
    finally:
        watchdog.cancel()
    return lines


def _config(tmp_path: Path) -> Path:
    text = SIM_CELL.read_text()
    for old, new in (('host = "127.0.0.1"  # where', f'host = "{ROBOT_HOST}"  # where'),
                     ('host = "127.0.0.1"  # the simulated PLC', f'host = "{PLC_HOST}"  # the simulated PLC'),
                     ("sim_move_time_s = 0.5", "sim_move_time_s = 0.05")):
        assert text.count(old) == 1, old
        text = text.replace(old, new)
    path = tmp_path / "cell.toml"
    path.write_text(text)
    return path
