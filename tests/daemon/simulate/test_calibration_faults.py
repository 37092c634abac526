"""The simulated cell's calibration faults (issue 20, item 5) on the daemon's side: sim-cell's commands (checked,
written into the state file whole, kept by a later camera failure, over sim-cell's real standard input into the
service's in-process camera), their place in ``simulate --faults`` (injected, kept for their parts, cleared), and
the summary that tells what they cost."""

from __future__ import annotations

import json
import math
import queue
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from helpers.cell_configs import cell_config
from helpers.repository import SIM_CELL
from helpers.sim_processes import START_S, stop

from monoguide.daemon.assembly import build_sim_cell
from monoguide.daemon.config import load_cell_config
from monoguide.daemon.simulate import (
    InjectedFault,
    RunOptions,
    Targets,
    cycles_needed_for_faults,
    fault_plan,
    run_simulation,
    summarize,
)
from monoguide.daemon.simulate._fault_channel import CALIBRATION_COMMANDS, FaultChannel
from monoguide.daemon.simulate._fault_plan import (
    CALIBRATION_CODES,
    CALIBRATION_FAULT_PARTS,
    CALIBRATION_FAULT_PLAN,
    FAULT_PLAN,
    FaultInjector,
    faults_to_inject,
)
from monoguide.drivers.errors import ConfigError
from monoguide.drivers.sim.calibration_faults import CALIBRATION_FAULTS, CalibrationFaults
from monoguide.drivers.sim.camera import SimCamera


def test_the_calibration_commands_are_the_simulators_own() -> None:
    assert CALIBRATION_COMMANDS == CALIBRATION_FAULTS


class _Channel:
    """A fault channel with no devices but a camera that follows (what it writes is kept), 7 measuring poses."""

    def __init__(self) -> None:
        self.written: list[dict[str, Any]] = []
        self.said: list[tuple[str, bool]] = []
        self.channel = FaultChannel({"plc": None, "robot": None}, self.written.append,
                                    lambda line, err=False: self.said.append((line, err)), measuring_poses=7)

    def send(self, text: str) -> str:
        self.channel.handle(text)
        return self.said[-1][0]


def test_each_command_writes_the_whole_set_and_a_camera_failure_keeps_it() -> None:
    c = _Channel()
    assert c.send("camera bump 0.1 0") == "fault: camera bump 0.1 0 x"
    assert c.written[-1]["calibration"]["bump"] == {"deg": 0.1, "mm": 0.0, "axis": "x"}
    assert c.send("camera focal -0.5") == "fault: camera focal -0.5"
    assert c.send("pose drift 3 0.3 0.05") == "fault: pose drift 3 0.3 0.05"
    whole = c.written[-1]["calibration"]
    assert whole["bump"]["deg"] == 0.1 and whole["focal_pct"] == -0.5 and whole["drift"] == {
        "3": {"mm": 0.3, "deg": 0.05}}
    assert "failure" not in c.written[-1]  # no one-grab failure yet
    assert CalibrationFaults.from_state(whole) == CalibrationFaults(0.1, 0.0, "x", -0.5, {3: (0.3, 0.05)})

    assert c.send("camera black 2") == "fault: camera black"
    black = c.written[-1]
    assert (black["failure"], black["count"]) == ("black", 2) and black["calibration"] == whole
    c.send("camera bump 0 0 z")  # clears the bump; the failure's serial is kept (not taken up again)
    assert c.written[-1]["serial"] == black["serial"] and c.written[-1]["calibration"]["bump"] is None
    assert c.written[-1]["calibration"]["serial"] > black["serial"]
    c.send("camera focal 0")
    c.send("pose drift 3 0 0")
    assert not CalibrationFaults.from_state(c.written[-1]["calibration"]).active


@pytest.mark.parametrize(("command", "reason"), [
    ("camera bump x 0", "DEG 'x' is not a number"),
    ("camera bump 0.1 nan", "MM 'nan' is not a finite number"),
    ("camera bump 0.1 0 w", "axis 'w': expected x, y or z"),
    ("camera bump 0.1", "camera bump takes DEG MM [AXIS]"),
    ("camera bump 45 0", "DEG 45 is beyond +-10"),
    ("camera focal ten", "PCT 'ten' is not a number"),
    ("pose drift 8 0.3 0.05", "pose number 8: the cell has measuring poses 1 to 7"),
    ("pose drift 0 0.3 0.05", "pose number '0'"),
    ("pose drift one 0.3 0.05", "pose number 'one'"),
    ("pose drift 1 0.3", "pose drift takes K MM DEG"),
    ("pose wobble 1", "unknown pose fault 'wobble'"),
])
def test_a_bad_calibration_command_says_which_value_and_writes_nothing(command: str, reason: str) -> None:
    c = _Channel()
    said, err = (c.channel.handle(command), c.said[-1])[1]
    assert err and said.startswith("fault error: ") and reason in said, said
    assert c.written == []


def test_without_a_following_camera_a_calibration_fault_is_refused() -> None:
    said: list[str] = []
    FaultChannel({"plc": None, "robot": None}, None, lambda line, err=False: said.append(line)).handle(
        "camera bump 0.1 0")
    assert "no simulated camera follows this cell" in said[-1]


def test_the_plan_names_them_in_normal_form_and_refuses_a_bad_one() -> None:
    assert fault_plan(("camera bump 0.1 0",)) == (("camera", "bump 0.1 0 x", CALIBRATION_CODES),)
    assert fault_plan(("pose drift 1 0.3 0.05", "robot stall"))[0] == ("pose", "drift 1 0.3 0.05", CALIBRATION_CODES)
    for bad, reason in (("camera bump 0.1 0 q", "axis 'q'"), ("camera focal", "camera focal PCT"),
                        ("camera wobble", "or a calibration fault")):
        with pytest.raises(ConfigError, match=reason):
            fault_plan((bad,))
    assert fault_plan() == FAULT_PLAN  # the device faults; --faults adds the calibration group
    assert faults_to_inject() == FAULT_PLAN + CALIBRATION_FAULT_PLAN
    assert cycles_needed_for_faults() == 1 + 2 * len(FAULT_PLAN) + (CALIBRATION_FAULT_PARTS + 1) * len(
        CALIBRATION_FAULT_PLAN)
    assert cycles_needed_for_faults(("camera bump 0.1 0",)) == 1 + CALIBRATION_FAULT_PARTS + 1


def _inject(total: int, names: tuple[str, ...]) -> tuple[list[tuple[int, str]], FaultInjector]:
    """Play ``total`` parts through an injector: (parts done when sent, command) per command sent."""
    sent: list[tuple[int, str]] = []
    done = 0
    injector = FaultInjector(lambda line: sent.append((done, line)), total, fault_plan(names), 2.0, lambda _: None)
    for done in range(total):
        injector.before_part(done, 0.0)
        injector.part_done()
    return sent, injector


def test_a_calibration_fault_stays_for_its_parts_and_spare_parts_lengthen_it() -> None:
    sent, injector = _inject(5, ("camera bump 0.1 0",))
    # before part 2 (1 done), cleared when part 4 is done, part 5 good
    assert sent == [(1, "camera bump 0.1 0 x"), (3, "camera bump 0 0")]
    assert injector.injected == [InjectedFault(2, "camera", "bump 0.1 0 x", CALIBRATION_CODES, 3, True)]
    sent, injector = _inject(10, ("pose drift 2 0.3 0.05",))
    assert sent == [(1, "pose drift 2 0.3 0.05"), (8, "pose drift 2 0 0")]  # parts 2..9 under it
    assert injector.injected[0].parts == 8
    sent, _ = _inject(9, ("camera timeout", "camera focal 0.5", "robot stall"))
    assert sent == [(1, "camera timeout 1"), (3, "camera focal 0.5"), (5, "camera focal 0"),  # parts 4..6
                    (7, "robot stall"), (7, "robot none")]


def _cycle(n: int, ok: bool, mm: float | None = None, code: str | None = None) -> dict[str, Any]:
    return {"cycle": n, "job": 1, "part_tag": n, "journal_cycle": n, "status": "ok" if ok else "error",
            "error_code": code, "plc_code": 0 if ok else 300, "line_outcome": "acknowledged", "fault": None,
            "truth_part": n, "grasp_error_mm": mm, "grasp_error_deg": None if mm is None else mm / 100,
            "offset_written": [float(n)] * 6 if ok else None, "offset_ideal": None, "offset_solved": None,
            "timings_ms": {"overhead": 30.0, "hole_finding": 20.0, "solve": 5.0, "checks": 1.0}}


def test_the_summary_tells_what_a_calibration_fault_cost_and_expects_no_refusal() -> None:
    cycles = [_cycle(1, True, 0.2), _cycle(2, True, 2.3), _cycle(3, False, code="INCONSISTENT_MEASUREMENT"),
              _cycle(4, True, 0.4), _cycle(5, True, 0.3)]
    truth = [{"part": c["cycle"], "offset_written": c["offset_written"]} for c in cycles if c["offset_written"]]
    fault = InjectedFault(2, "camera", "bump 0.1 0 x", CALIBRATION_CODES, 3, True)
    summary = summarize(cycles, truth, faults=[fault], targets=Targets.for_run(False))
    (outcome,) = summary["faults"]
    assert outcome["cycles"] == [2, 3, 4] and outcome["ok"] == 2
    assert outcome["refused"] == {"INCONSISTENT_MEASUREMENT": 1} and outcome["reported"] is True
    assert outcome["grasp_rms_mm"] == pytest.approx(math.sqrt((2.3**2 + 0.4**2) / 2))
    assert outcome["grasp_max_mm"] == 2.3 and outcome["ok_beyond_requirement"] == 1 and outcome["back_ready"]
    assert outcome["got"].startswith("2 of 3 ok (grasp RMS 1.651 / max 2.300 mm, 1 beyond 0.5 mm)")
    # the run's own grasp error is that of the cycles under no calibration fault
    assert summary["grasped"] == 2 and summary["grasp_rms_mm"] == pytest.approx(math.sqrt((0.2**2 + 0.3**2) / 2))
    targets = {t["name"]: t for t in summary["targets"]}
    assert "faults_reported_and_ready" not in targets
    assert targets["calibration_faults_ok_beyond_0.5mm"] == {"name": "calibration_faults_ok_beyond_0.5mm",
                                                             "value": 1, "limit": 0, "met": False}


# --- over sim-cell's real standard input ----------------------------------------------------------


class _Lines:
    def __init__(self, stream: Any) -> None:
        self.lines: queue.Queue[str] = queue.Queue()
        threading.Thread(target=lambda: [self.lines.put(line.strip()) for line in stream], daemon=True).start()

    def expect(self, prefix: str, timeout_s: float = 10.0) -> str:
        deadline = time.monotonic() + timeout_s
        while (left := deadline - time.monotonic()) > 0:
            try:
                line = self.lines.get(timeout=left)
            except queue.Empty:
                break
            if line.startswith(prefix):
                return line
        pytest.fail(f"no line starting {prefix!r} within {timeout_s:g} s")


def test_the_commands_reach_the_services_camera_through_sim_cells_stdin_and_state_file(tmp_path: Path) -> None:
    config, state = cell_config(tmp_path, "127.0.33.41", "127.0.33.42", sharp=True), tmp_path / "s.json"
    process = subprocess.Popen([sys.executable, "-m", "monoguide.daemon.cli", "sim-cell", "--config", str(config),
                                "--state-file", str(state), "--parts", "0"], stdin=subprocess.PIPE,
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    out, err = _Lines(process.stdout), _Lines(process.stderr)

    def command(text: str) -> None:
        assert process.stdin is not None
        process.stdin.write(text + "\n")
        process.stdin.flush()

    try:
        out.expect("state file", START_S)
        command("pose drift 8 0.3 0.05")  # the cell has 7: from the simulated robot's own spec
        assert "pose number 8: the cell has measuring poses 1 to 7" in err.expect("fault error:")
        command("camera bump 0.3 0 y")
        assert out.expect("fault:") == "fault: camera bump 0.3 0 y"
        command("pose drift 2 0.3 0.05")
        assert out.expect("fault:") == "fault: pose drift 2 0.3 0.05"
        command("camera glare")
        assert out.expect("fault:") == "fault: camera glare"
        entry = json.loads(state.read_text())["camera_fault"]
        assert entry["failure"] == "glare"
        expected = CalibrationFaults(bump_deg=0.3, bump_axis="y", drift={2: (0.3, 0.05)})
        assert CalibrationFaults.from_state(entry["calibration"]) == expected

        cfg = load_cell_config(config)
        camera = SimCamera(build_sim_cell(cfg), follow=state)  # as the service builds it
        camera.open()
        camera.grab(1.0)
        assert camera.calibration_faults == expected
        command("camera bump 0 0")
        out.expect("fault:")
        command("pose drift 2 0 0")
        out.expect("fault:")
        camera.grab(1.0)
        assert not camera.calibration_faults.active
        truth = camera.cell.T_c_w_true()
        np.testing.assert_allclose(CalibrationFaults().T_c_w(camera.cell), truth)
        assert process.poll() is None
    finally:
        stop(process)


def test_simulate_refuses_a_pose_drift_of_a_pose_the_cell_lacks_before_it_starts(tmp_path: Path) -> None:
    options = RunOptions(SIM_CELL, tmp_path, cycles=5, faults=True, host="127.0.33.43",
                         fault_names=("pose drift 9 0.3 0.05",))
    with pytest.raises(ConfigError, match=r"pose number 9: the cell .* has measuring poses 1 to 7"):
        run_simulation(options)
    assert not (tmp_path / "sim-cell.log").exists()  # nothing started


def test_fail_every_fails_one_part_in_n_in_turn_but_not_the_last_nor_beside_a_fault() -> None:
    """``simulate --fail-every N``: parts N, 2N, ... meet a one-grab camera failure, black and occluded in turn; never
    the last part (a good one follows each, so READY after it is seen), never a part a scheduled fault has."""
    sent: list[tuple[int, str]] = []
    done = 0
    injector = FaultInjector(lambda line: sent.append((done, line)), 10, (), 2.0, lambda _: None, fail_every=3)
    for done in range(10):
        injector.before_part(done, 0.0)
        injector.part_done()
    assert sent == [(2, "camera black 1"), (5, "camera occluded 1"), (8, "camera black 1")]
    assert [f.cycle for f in injector.injected] == [3, 6, 9]
    sent.clear()
    injector = FaultInjector(lambda line: sent.append((done, line)), 9, (), 2.0, lambda _: None, fail_every=3)
    for done in range(9):
        injector.before_part(done, 0.0)
        injector.part_done()
    assert [line for _, line in sent] == ["camera black 1", "camera occluded 1"]  # part 9, the last, is good
    sent.clear()
    injector = FaultInjector(lambda line: sent.append((done, line)), 6, fault_plan(("robot stall",)), 2.0,
                             lambda _: None, fail_every=2)
    for done in range(6):
        injector.before_part(done, 0.0)
        injector.part_done()
    assert [(f.cycle, f.label) for f in injector.injected] == [(2, "robot stall"), (4, "camera occluded")]
