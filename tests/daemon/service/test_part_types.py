"""The cycle by job over the real transports: `monoguide sim-cell --no-plc --part-types 1,2,1` brings a roof, a hood
and a roof (its own processes: the simulated robot's part supply, the camera following it), `monoguide run` as a
process, and the PLC played by this test over the real pymodbus server asks for each part's job. The offsets the
PLC reads are checked against the truth log (what each part really needed, of which type); job 3, which the cell
does not have, is refused with PLC_UNKNOWN_JOB before anything moves."""

from __future__ import annotations

import json
import subprocess
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from helpers.cell_configs import cell_config
from helpers.plc_line import Line, in_own_event_loop, plc_line
from helpers.sim_processes import keep_reading, start_sim_cell, stop

from monoguide.daemon.errors import PartNotCalibrated
from monoguide.daemon.service import Journal
from monoguide.drivers.errors import PlcUnknownJob
from monoguide.drivers.plc_registers import Control, Status

ROBOT_HOST, PLC_HOST, PLC_PORT = "127.0.5.60", "127.0.5.61", 5020
START_S, CYCLE_S = 60.0, 60.0


@pytest.fixture(scope="module")
def cell(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Any]]:
    tmp = tmp_path_factory.mktemp("part-types")
    state, truth = tmp / "sim-state.json", tmp / "truth.jsonl"
    config = cell_config(tmp, ROBOT_HOST, PLC_HOST, sharp=True, state_file=state,
                         more=[("heartbeat_timeout_s = 2.0", "heartbeat_timeout_s = 2.0\nack_timeout_s = 30.0")])
    process, _ = start_sim_cell(config, "--no-plc", "--truth-log", str(truth), "--part-types", "1,2,1",
                                stdin=subprocess.PIPE, timeout_s=START_S)
    keep_reading(process)
    try:
        yield {"config": config, "truth": truth, "tmp": tmp}
    finally:
        stop(process, 15.0)


async def _part(line: Line, job: int, tag: int) -> Any:
    await line.wait(lambda s: Status.READY in s and not s & Status.DONE, "READY", START_S)
    await line.control(Control.TRIGGER, job=job, tag=tag)
    status = await line.wait(lambda s: Status.DONE in s, "DONE", CYCLE_S)
    result = (await line.outputs()).result
    await line.acknowledge()
    return status, result


def _run(config: Path, state_dir: Path, cycles: int) -> subprocess.Popen[bytes]:
    import sys

    return subprocess.Popen([sys.executable, "-m", "monoguide.daemon.cli", "run", "--config", str(config),
                             "--state-dir", str(state_dir), "--cycles", str(cycles)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)


@in_own_event_loop
async def test_each_job_measures_its_own_part_and_an_unknown_job_moves_nothing(cell: dict[str, Any]) -> None:
    state_dir = cell["tmp"] / "state"
    service = _run(cell["config"], state_dir, 4)
    try:
        async with plc_line(PLC_HOST, PLC_PORT) as line:
            outcomes = [await _part(line, job, tag) for job, tag in ((1, 11), (2, 12), (3, 13), (1, 14))]
        _, err = service.communicate(timeout=60)
        assert service.returncode == 0, err.decode()[-2000:]
    finally:
        if service.poll() is None:
            service.kill()
    statuses = [status for status, _ in outcomes]
    assert statuses == [Status.DONE | Status.RESULT_OK, Status.DONE | Status.RESULT_OK, Status.DONE | Status.ERROR,
                        Status.DONE | Status.RESULT_OK], [r for _, r in outcomes]
    results = [result for _, result in outcomes]
    assert [(r.job, r.part_tag) for r in results] == [(1, 11), (2, 12), (3, 13), (1, 14)]
    assert results[2].error_code == PlcUnknownJob.plc_code and results[2].offset == (0.0,) * 6
    truth = [json.loads(text) for text in cell["truth"].read_text().splitlines() if text.strip()]
    # three parts came (roof, hood, roof); the refused job asked for no pose, so no part was used up by it
    assert [t["part_type"] for t in truth] == [1, 2, 1]
    for result, part in zip((results[0], results[1], results[3]), truth, strict=True):
        np.testing.assert_allclose(result.offset, part["offset_written"], atol=1e-3)
        assert part["grasp_error_mm"] < 0.5 and part["grasp_error_deg"] < 0.05, part
    with Journal(state_dir, read_only=True) as journal:
        rows = journal.last_cycles(4)[::-1]
    assert [(r.job, r.status, r.error_code) for r in rows] == [
        (1, "ok", None), (2, "ok", None), (3, "error", "PLC_UNKNOWN_JOB"), (1, "ok", None)]
    assert [r.record["part"] for r in (rows[0], rows[1], rows[3])] == ["roof", "hood", "roof"]
    assert len(rows[1].record["points_w"]) == 6 and len(rows[1].record["views"]) == 3
    assert len(rows[1].record["observations"]) == 6 and len(rows[0].record["observations"]) == 4
    status = json.loads((state_dir / "status.json").read_text())
    assert {k: status["last_result"][k] for k in ("cycle", "job", "part", "part_tag")} == {
        "cycle": 4, "job": 1, "part": "roof", "part_tag": 14}


PARTLY_CALIBRATED = """
[calibration]  # the wizard calibrated the cell and its first part type (roof); the hood (job 2) never
date = "2026-12-01T06:00:00+00:00"
[calibration.steps]
intrinsics = { done = "2026-12-01T05:00:00+00:00" }
cell = { done = "2026-12-01T05:01:00+00:00" }
base = { done = "2026-12-01T05:02:00+00:00" }
part = { done = "2026-12-01T05:03:00+00:00" }
sfi = { done = "2026-12-01T05:04:00+00:00" }
"""


@in_own_event_loop
async def test_a_part_type_the_wizard_has_not_calibrated_refuses_its_jobs_and_nothing_moves(
        cell: dict[str, Any]) -> None:
    config = cell["tmp"] / "partly-calibrated.toml"
    config.write_text(cell["config"].read_text() + PARTLY_CALIBRATED)
    state_dir = cell["tmp"] / "state-partly"
    parts_before = len([t for t in cell["truth"].read_text().splitlines() if t.strip()])
    service = _run(config, state_dir, 1)
    try:
        async with plc_line(PLC_HOST, PLC_PORT) as line:
            status, result = await _part(line, 2, 21)
        _, err = service.communicate(timeout=60)
        assert service.returncode == 0, err.decode()[-2000:]
    finally:
        if service.poll() is None:
            service.kill()
    assert status == Status.DONE | Status.ERROR
    assert result.error_code == PartNotCalibrated.plc_code == 604 and result.offset == (0.0,) * 6
    with Journal(state_dir, read_only=True) as journal:
        (row,) = journal.last_cycles(1)
    assert (row.job, row.status, row.error_code) == (2, "error", "PART_NOT_CALIBRATED")
    assert "job 2 (hood)" in row.error_message and "part, sfi" in row.error_message, row.error_message
    # the robot asked for no measuring pose: the line's part supply brought no part for it
    assert len([t for t in cell["truth"].read_text().splitlines() if t.strip()]) == parts_before
