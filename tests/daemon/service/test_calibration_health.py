"""The calibration's health in the service: every solve's residual feeds its part type's trend monitor; past the
warning level the status word's CALIBRATION_WARNING bit is set, past the alarm level the cycle is refused with
CALIBRATION_SUSPECT and every later cycle too, before the robot moves, until a new calibration.

The unit part draws the residual's chi-square (seeded) as the noise model says, and scaled as a fault makes it.
The end-to-end part runs `monoguide sim-cell --no-plc` (the simulated truth) and `monoguide run` with a config
whose calibration believes the camera turned 0.3 deg about its y axis on its bracket while it did not (its
`[camera] T_f_c` and every `T_cf_si` right-multiplied by the inverse of the bump, `[sim] truth_config` the truth),
the PLC played by this test over the real pymodbus server. Loopback 127.0.35.x.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
import tomllib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from helpers.cell_configs import cell_config
from helpers.plc_line import Line, in_own_event_loop, plc_line
from helpers.sim_processes import keep_reading, start_sim_cell, stop

from monoguide.daemon.config import load_cell_config
from monoguide.daemon.cycle import Residual
from monoguide.daemon.service import Journal
from monoguide.daemon.service._health import HEALTH_FILE, CalibrationHealth, request_clear
from monoguide.daemon.simulate import dumps_toml
from monoguide.drivers.plc_registers import CHECK_JOB, Control, Status
from monoguide.solver.errors import CalibrationSuspect
from monoguide.solver.frames import invert, make_T, rotvec_to_matrix

SIM_CELL = Path(__file__).parents[3] / "config" / "sim-cell.toml"
ROBOT_HOST, PLC_HOST, PLC_PORT = "127.0.35.10", "127.0.35.11", 5020
START_S, CYCLE_S = 60.0, 60.0


# --- the monitor in the service's keeping ------------------------------------------------------------------


def _draws(rng: np.random.Generator, n: int, scale: float = 1.0) -> list[Residual]:
    return [Residual(float(scale * rng.chisquare(2)), 2) for _ in range(n)]


def test_good_cycles_never_alarm_and_a_fault_latches_across_a_restart(tmp_path: Path) -> None:
    config = load_cell_config(SIM_CELL)
    health = CalibrationHealth(tmp_path, config)
    rng = np.random.default_rng(20)
    for k, residual in enumerate(_draws(rng, 500), start=1):  # good cycles: one false alarm per 10,000 expected
        health.observe(1, k, "2026-12-01T08:00:00+00:00", residual)
    assert health.latched is None
    health.check_latch()
    with pytest.raises(CalibrationSuspect, match=r"job 1: the residual's trend passed its alarm level") as raised:
        for k, residual in enumerate(_draws(rng, 200, scale=6.0), start=501):  # a fault: the residual 6x larger
            health.observe(1, k, "2026-12-01T09:00:00+00:00", residual)
    alarm_cycle = health.latched["cycle"]
    assert 501 <= alarm_cycle <= 520, alarm_cycle  # a few cycles into the fault, not at once, not never
    assert raised.value.plc_code == 208 and health.warning
    # a restart with the same calibration keeps the latch: every cycle refused before anything moves
    again = CalibrationHealth(tmp_path, config)
    with pytest.raises(CalibrationSuspect, match=rf"latched since cycle {alarm_cycle}"):
        again.check_latch()
    assert again.summary()["latched"]["job"] == 1 and again.warning
    # a new calibration (any calibration value differs) starts afresh
    moved = tmp_path / "recalibrated.toml"
    moved.write_text(SIM_CELL.read_text().replace("fx = 2421.402", "fx = 2421.403", 1))
    fresh = CalibrationHealth(tmp_path, load_cell_config(moved))
    fresh.check_latch()
    assert fresh.latched is None and not fresh.warning


def test_a_corrupt_health_file_starts_afresh_and_names_itself(tmp_path: Path, caplog: pytest.LogCaptureFixture
                                                             ) -> None:
    (tmp_path / HEALTH_FILE).write_text("{not json")
    health = CalibrationHealth(tmp_path, load_cell_config(SIM_CELL))
    assert health.latched is None and str(tmp_path / HEALTH_FILE) in caplog.text
    health.observe(2, 1, "2026-12-01T08:00:00+00:00", Residual(6.0, 6))
    saved = json.loads((tmp_path / HEALTH_FILE).read_text())
    assert saved["monitors"]["2"]["cycles"] == 1 and saved["monitors"]["2"]["dof"] == 6


# --- end to end: a bumped camera, the real transports ---------------------------------------------------------


def _bumped(truth: Path, out: Path, deg: float, axis: int) -> Path:
    """The truth config as a service that believes the camera turned ``deg`` about its ``axis`` would have it."""
    data = tomllib.loads(truth.read_text())
    rotvec = np.zeros(3)
    rotvec[axis] = math.radians(deg)
    undo = invert(make_T(rotvec_to_matrix(rotvec), np.zeros(3)))
    data["camera"]["T_f_c"] = (np.array(data["camera"]["T_f_c"]) @ undo).tolist()
    for pose in data["measuring_poses"]:
        pose["T_cf_si"] = (np.array(pose["T_cf_si"]) @ undo).tolist()
    data["sim"]["truth_config"] = str(truth)
    out.write_text(dumps_toml(data, "the simulated cell as a service with a bumped camera believes it"))
    return out


@pytest.fixture(scope="module")
def cell(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Any]]:
    tmp = tmp_path_factory.mktemp("health")
    state = tmp / "sim-state.json"
    truth = cell_config(tmp, ROBOT_HOST, PLC_HOST, sharp=True, state_file=state,
                        more=[("heartbeat_timeout_s = 2.0", "heartbeat_timeout_s = 2.0\nack_timeout_s = 30.0")])
    process, _ = start_sim_cell(truth, "--no-plc", "--part-types", "1", stdin=subprocess.PIPE, timeout_s=START_S)
    keep_reading(process)
    try:
        yield {"truth": truth, "tmp": tmp, "bumped": _bumped(truth, tmp / "bumped.toml", 0.3, 1), "sim": process}
    finally:
        stop(process, 15.0)


async def _part(line: Line, tag: int, job: int = 1) -> tuple[Status, Any, Status]:
    ready = await line.wait(lambda s: Status.READY in s and not s & Status.DONE, "READY", START_S)
    await line.control(Control.TRIGGER, job=job, tag=tag)
    status = await line.wait(lambda s: Status.DONE in s, "DONE", CYCLE_S)
    result = (await line.outputs()).result
    await line.acknowledge()
    return status, result, ready


def _run(config: Path, state_dir: Path, cycles: int) -> subprocess.Popen[bytes]:
    return subprocess.Popen([sys.executable, "-m", "monoguide.daemon.cli", "run", "--config", str(config),
                             "--state-dir", str(state_dir), "--cycles", str(cycles)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)


async def _parts(config: Path, state_dir: Path, tags: list[int], jobs: list[int] | None = None,
                 sim: subprocess.Popen[str] | None = None) -> list[tuple[Status, Any, Status]]:
    """``tags`` parts (job 1, or ``jobs``); before a check job (65535) sim-cell is told to present the reference
    part next."""
    service = _run(config, state_dir, len(tags))
    try:
        async with plc_line(PLC_HOST, PLC_PORT) as line:
            outcomes = []
            for tag, job in zip(tags, jobs or [1] * len(tags), strict=True):
                if job == CHECK_JOB:
                    assert sim is not None and sim.stdin is not None
                    sim.stdin.write("robot reference-part\n")
                    sim.stdin.flush()
                outcomes.append(await _part(line, tag, job))
            after = await line.wait(lambda s: not s & Status.BUSY, "the last cycle's end", CYCLE_S)
        _, err = service.communicate(timeout=60)
        assert service.returncode == 0, err.decode()[-2000:]
    finally:
        if service.poll() is None:
            service.kill()
    return [*outcomes, (after, None, after)]


@in_own_event_loop
async def test_a_bumped_camera_is_refused_with_calibration_suspect_latched_until_a_new_calibration(
        cell: dict[str, Any]) -> None:
    state_dir = cell["tmp"] / "state"
    *outcomes, _ = await _parts(cell["bumped"], state_dir, [1, 2, 3, 4])
    codes = [result.error_code for _, result, _ in outcomes]
    # each cycle's residual is far off (the consistency test refuses it, 207) and the trend adds them up: its alarm
    # (208) comes within three cycles, and from then on every cycle is refused with it
    assert 208 in codes[:3], codes
    first = codes.index(208)
    assert set(codes[:first]) <= {207} and codes[first:] == [208] * (4 - first), codes
    assert all(status & ~Status.CALIBRATION_WARNING == Status.DONE | Status.ERROR for status, _, _ in outcomes)
    assert all(Status.CALIBRATION_WARNING in status for status, _, _ in outcomes[first:])
    assert all(result.offset == (0.0,) * 6 for _, result, _ in outcomes)
    # after the alarm the PLC sees READY with the warning bit (it may run a check); every part job is refused
    assert all(Status.CALIBRATION_WARNING in ready for _, _, ready in outcomes[first + 1:])
    with Journal(state_dir, read_only=True) as journal:
        rows = journal.last_cycles(4)[::-1]
    assert [r.error_code for r in rows[first:]] == ["CALIBRATION_SUSPECT"] * (4 - first)
    assert "passed its alarm level" in rows[first].error_message
    assert all("latched since cycle" in r.error_message and "nothing moved" in r.error_message
               for r in rows[first + 1:])
    assert all(r.record is None or not r.record.get("observations") for r in rows[first + 1:])  # no image taken
    status = json.loads((state_dir / "status.json").read_text())
    assert status["calibration_health"]["latched"]["code"] == "CALIBRATION_SUSPECT"
    shown = subprocess.run([sys.executable, "-m", "monoguide.daemon.cli", "status", "--state-dir", str(state_dir)],
                           capture_output=True, text=True, timeout=60)
    assert f"calibration: CALIBRATION_SUSPECT latched since cycle {first + 1}: job 1: the residual's trend" in \
        shown.stdout.replace("\n", " "), shown.stdout

    # the cell recalibrated (here: the truth's own values): the latch is gone, the part is measured and grasped
    *again, _ = await _parts(cell["truth"], state_dir, [5])
    (status_word, result, ready), = again
    assert status_word == Status.DONE | Status.RESULT_OK and result.error_code == 0
    assert Status.CALIBRATION_WARNING not in ready


def test_an_operators_clear_resets_the_latch_with_its_reason(tmp_path: Path) -> None:
    config = load_cell_config(SIM_CELL)
    health = CalibrationHealth(tmp_path, config)
    with pytest.raises(CalibrationSuspect):
        for k in range(1, 50):
            health.observe(1, k, "2026-12-01T10:00:00+00:00", Residual(40.0, 2))
    with pytest.raises(ValueError, match="a reason is needed"):
        request_clear(tmp_path, "  ")
    request_clear(tmp_path, "camera bracket re-tightened, calibrate verify passed")
    assert health.take_clear_request() and not health.take_clear_request()  # taken once, its file gone
    health.check_latch()
    assert health.latched is None and health.monitors[1].reading().cycles == 0
    saved = json.loads((tmp_path / HEALTH_FILE).read_text())
    assert saved["latched"] is None and saved["cleared"].startswith("camera bracket re-tightened")
    # a request left while no service ran is taken at the next start
    with pytest.raises(CalibrationSuspect):
        for k in range(1, 50):
            health.observe(1, k, "2026-12-01T11:00:00+00:00", Residual(40.0, 2))
    request_clear(tmp_path, "inspected")
    assert CalibrationHealth(tmp_path, config).latched is None


@in_own_event_loop
async def test_the_check_job_fails_on_a_bumped_camera_and_a_passing_one_clears_the_latch(
        cell: dict[str, Any]) -> None:
    # the bumped calibration: the reference part, lying as taught, is measured away from it: 208, latched
    state_dir = cell["tmp"] / "state-check"
    *outcomes, _ = await _parts(cell["bumped"], state_dir, [31, 32], [CHECK_JOB, 1], cell["sim"])
    (check, check_result, _), (_, part_result, _) = outcomes
    assert check & ~Status.CALIBRATION_WARNING == Status.DONE | Status.ERROR and check_result.error_code == 208
    assert Status.CALIBRATION_WARNING in check and part_result.error_code == 208  # the part job after: latched
    with Journal(state_dir, read_only=True) as journal:
        failed, latched = journal.last_cycles(2)[::-1]
    assert failed.job == CHECK_JOB and failed.error_code == "CALIBRATION_SUSPECT"
    assert failed.error_message.startswith("check job: the reference part ")  # measured off it, or not fitting it
    assert "px from where the calibration puts it" in failed.error_message and "views: S1 " in failed.error_message
    assert "latched since cycle 1" in latched.error_message

    # the truth's calibration, latched (as after an alarm): a check of the reference part passes and clears it
    state_dir = cell["tmp"] / "state-check-pass"
    state_dir.mkdir()
    health = CalibrationHealth(state_dir, load_cell_config(cell["truth"]))
    with pytest.raises(CalibrationSuspect):
        for k in range(1, 50):
            health.observe(1, k, "2026-12-01T10:00:00+00:00", Residual(40.0, 2))
    *outcomes, _ = await _parts(cell["truth"], state_dir, [41, 42, 43], [1, CHECK_JOB, 1], cell["sim"])
    codes = [result.error_code for _, result, _ in outcomes]
    assert codes == [208, 0, 0], codes
    statuses = [status for status, _, _ in outcomes]
    assert statuses[1:] == [Status.DONE | Status.RESULT_OK] * 2, statuses
    assert outcomes[1][1].offset == (0.0,) * 6  # a check writes nothing
    with Journal(state_dir, read_only=True) as journal:
        rows = journal.last_cycles(3)[::-1]
    check_row = rows[1]
    assert check_row.job == CHECK_JOB and check_row.status == "ok" and check_row.result["check"]["passed"] is True
    assert check_row.result["check"]["shift_mm"] <= check_row.result["check"]["limit_mm"]
    saved = json.loads((state_dir / HEALTH_FILE).read_text())
    assert saved["latched"] is None and saved["cleared"].startswith("a passing check job")


def _check_command(config: Path, state_dir: Path, sim: subprocess.Popen[str]) -> subprocess.CompletedProcess[str]:
    assert sim.stdin is not None
    sim.stdin.write("robot reference-part\n")
    sim.stdin.flush()
    return subprocess.run([sys.executable, "-m", "monoguide.daemon.cli", "check", "--config", str(config),
                           "--state-dir", str(state_dir), "--json"], capture_output=True, text=True, timeout=120)


def test_monoguide_check_from_the_command_line_journals_and_latches_as_the_check_job(cell: dict[str, Any]) -> None:
    failed_dir, passed_dir = cell["tmp"] / "state-cli-bumped", cell["tmp"] / "state-cli-truth"
    failed = _check_command(cell["bumped"], failed_dir, cell["sim"])
    assert failed.returncode == 1, failed.stderr[-2000:]
    assert "CALIBRATION_SUSPECT check failed: check job: the reference part " in failed.stderr
    assert json.loads(failed.stdout.strip().splitlines()[-1])["passed"] is False
    with Journal(failed_dir, read_only=True) as journal:
        (row,) = journal.last_cycles(1)
    assert (row.job, row.status, row.error_code) == (CHECK_JOB, "error", "CALIBRATION_SUSPECT")
    assert json.loads((failed_dir / HEALTH_FILE).read_text())["latched"]["job"] == CHECK_JOB

    passed = _check_command(cell["truth"], passed_dir, cell["sim"])
    assert passed.returncode == 0, passed.stderr[-2000:]
    found = json.loads(passed.stdout.strip().splitlines()[-1])["check"]
    assert found["passed"] is True and found["shift_mm"] <= found["limit_mm"] and set(found["views"]) == {
        "S1", "S2", "S3", "S4"}
    with Journal(passed_dir, read_only=True) as journal:
        (row,) = journal.last_cycles(1)
    assert (row.job, row.status) == (CHECK_JOB, "ok") and row.result["check"]["passed"] is True
