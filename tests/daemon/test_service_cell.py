"""`monoguide run` end to end (issue 10): the simulated robot and part supply of `monoguide sim-cell --no-plc`
(its own processes), the daemon's simulated camera following that robot, `monoguide run` as a process, and
the PLC played by this test over the real pymodbus server. The offsets the PLC reads are checked against the
sim-cell's truth log (what the robot really got, what the part really needed)."""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import re
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from simcell_helpers import SIM_CELL, cell_config, start_sim_cell, stop
from test_service_handshake import Line, _record_status_writes, _sync

from monoguide.daemon.journal import Journal
from monoguide.drivers.errors import PlcTriggerDropped
from monoguide.drivers.plc_registers import Control, Status
from monoguide.drivers.sim.plc import PlcServer

ROBOT_HOST, PLC_HOST, PLC_PORT = "127.0.5.20", "127.0.5.21", 5020
START_S = 60.0  # sim-cell and the service's devices on a shared machine
CYCLE_S = 60.0


@pytest.fixture(scope="module")
def cell(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Path]]:
    """One sim-cell (robot with part supply, tracker; no PLC) for the module; its config and truth log."""
    tmp = tmp_path_factory.mktemp("service-cell")
    state, truth = tmp / "sim-state.json", tmp / "truth.jsonl"
    config = cell_config(tmp, ROBOT_HOST, PLC_HOST, sharp=True, state_file=state,  # sharp: 0.2 s a frame, not 3 s
                         more=[("heartbeat_timeout_s = 2.0", "heartbeat_timeout_s = 2.0\nack_timeout_s = 30.0")],
                         extra="\n[service]\nimages_max_mb = 50.0\n")
    process, _ = start_sim_cell(config, "--no-plc", "--truth-log", str(truth), stdin=subprocess.PIPE,
                                timeout_s=START_S)
    try:
        yield {"config": config, "truth": truth, "tmp": tmp}
    finally:
        stop(process, 15.0)


async def _run(config: Path, state_dir: Path, *options: str) -> asyncio.subprocess.Process:
    return await asyncio.create_subprocess_exec(
        sys.executable, "-m", "monoguide.daemon.cli", "run", "--config", str(config), "--state-dir", str(state_dir),
        *options, stdout=asyncio.subprocess.DEVNULL, stderr=asyncio.subprocess.PIPE)


async def _exit(process: asyncio.subprocess.Process, timeout_s: float = 20.0) -> tuple[int, str]:
    _, err = await asyncio.wait_for(process.communicate(), timeout_s)
    return process.returncode or 0, err.decode()


@contextlib.asynccontextmanager
async def _plc() -> Any:
    server = PlcServer(PLC_HOST, PLC_PORT)
    await server.start()
    line = Line(server)
    await line.start()
    try:
        yield line
    finally:
        await line.stop()
        await server.stop()


async def _one_part(line: Line, tag: int) -> Any:
    """Trigger, wait for DONE, read the result; leaves DONE unacknowledged."""
    await line.wait(lambda s: Status.READY in s, "READY", START_S)
    await line.control(Control.TRIGGER, job=1, tag=tag)
    await line.wait(lambda s: Status.BUSY in s, "BUSY")
    status = await line.wait(lambda s: Status.DONE in s, "DONE", CYCLE_S)
    return status, await line.outputs()


def _truth(cell: dict[str, Path]) -> list[dict[str, Any]]:
    return [json.loads(line) for line in cell["truth"].read_text().splitlines() if line.strip()]


@_sync
async def test_good_cycles_give_the_true_offset(cell: dict[str, Path]) -> None:
    state_dir = cell["tmp"] / "state-good"
    async with _plc() as line:
        service = await _run(cell["config"], state_dir, "--cycles", "3")
        # TRIGGER dropped while BUSY: ERROR with its code; the part goes without an offset (truth: null)
        await line.wait(lambda s: Status.READY in s, "READY", START_S)
        await line.control(Control.TRIGGER, job=1, tag=100)
        await line.wait(lambda s: Status.BUSY in s, "BUSY")
        await asyncio.sleep(0.3)  # the robot is on its way to measuring pose 1: the part has arrived
        await line.control(0)
        assert await line.wait(lambda s: Status.DONE in s, "DONE", CYCLE_S) == Status.DONE | Status.ERROR
        dropped = (await line.outputs()).result
        await line.acknowledge()
        results = []
        for tag in (101, 102):
            status, out = await _one_part(line, tag)
            assert status == Status.DONE | Status.RESULT_OK, out
            results.append(out.result)
            await line.acknowledge() if tag == 101 else await line.control(Control.RESULT_ACK)
        await line.wait(lambda s: not s & Status.DONE, "DONE cleared")
        await line.control(0)
        code, err = await _exit(service)
        assert code == 0, err
        assert await line.status() == Status(0)  # stopped: nobody takes it for READY
    assert (dropped.error_code, dropped.cycle_counter, dropped.part_tag) == (PlcTriggerDropped.plc_code, 1, 100)
    assert dropped.offset == (0.0,) * 6
    assert [(r.cycle_counter, r.job, r.part_tag, r.error_code) for r in results] == [(2, 1, 101, 0), (3, 1, 102, 0)]
    truth = _truth(cell)[-3:]  # this test's three parts
    assert truth[0]["offset_written"] is None and truth[0]["grasp_error_mm"] is None
    written = truth[1:]
    for result, truth in zip(results, written, strict=True):
        np.testing.assert_allclose(result.offset, truth["offset_written"], atol=1e-3)  # float32 of what was written
        # the base offset's translation carries the rotation error times the distance from the robot base;
        # at the grasp point (what the robot cares for) the error is what the truth log says
        np.testing.assert_allclose(result.offset[:3], truth["offset_ideal"][:3], atol=1.5)  # mm
        np.testing.assert_allclose(result.offset[3:], truth["offset_ideal"][3:], atol=0.05)  # deg
        assert truth["grasp_error_mm"] < 0.5 and truth["grasp_error_deg"] < 0.05
    with Journal(state_dir) as journal:
        rows = journal.last_cycles(5)
    assert [(r.number, r.status, r.part_tag, r.error_code) for r in rows] == [
        (3, "ok", 102, None), (2, "ok", 101, None), (1, "error", 100, "PLC_TRIGGER_DROPPED")]
    assert {"cycle", "plc_journal", "offset_write"} <= set(rows[0].timings_s)
    assert len(rows[0].poses_at_capture) == 4 and rows[0].image_paths


@_sync
async def test_kill_9_then_restart_clears_the_stale_done_and_keeps_the_journal(cell: dict[str, Path]) -> None:
    state_dir = cell["tmp"] / "state-kill"
    async with _plc() as line:
        service = await _run(cell["config"], state_dir)
        status, out = await _one_part(line, 201)
        assert status == Status.DONE | Status.RESULT_OK and out.result.cycle_counter == 1
        service.kill()  # kill -9 with DONE shown
        await _exit(service)
        assert Status.DONE in await line.status()  # the register keeps the dead service's word
        await line.control(0)
        status_writes = _record_status_writes(line.server)
        service = await _run(cell["config"], state_dir)
        await line.wait(lambda s: Status.READY in s, "READY after the restart", START_S)
        assert status_writes[:2] == [0, int(Status.READY)]  # 0 first, READY once the devices connect
        assert (await line.outputs()).result.cycle_counter == 1  # from the journal
        shown = await asyncio.to_thread(subprocess.run, [sys.executable, "-m", "monoguide.daemon.cli", "status",
                                                         "--state-dir", str(state_dir), "--json"],
                                        capture_output=True, text=True, timeout=30)
        report = json.loads(shown.stdout)
        assert shown.returncode == 0 and report["service"]["status"]["state"] == "idle", shown.stderr
        assert all(d["connected"] for d in report["service"]["status"]["devices"].values())
        assert set(report["service"]["status"]["devices"]) == {"plc", "camera", "robot"}
        # kill -9 mid-cycle: nothing committed for it, the next cycle is number 2
        await line.control(Control.TRIGGER, tag=202)
        await line.wait(lambda s: Status.BUSY in s, "BUSY")
        service.kill()
        await _exit(service)
        await line.control(0)
        service = await _run(cell["config"], state_dir)
        status, out = await _one_part(line, 203)
        assert status == Status.DONE | Status.RESULT_OK and out.result.cycle_counter == 2
        await line.acknowledge()
        service.send_signal(signal.SIGTERM)
        code, err = await _exit(service)
        assert code == 0, err
        assert await line.status() == Status(0)
    with Journal(state_dir) as journal:
        assert journal.integrity_check() == "ok"
        assert [(r.number, r.part_tag) for r in journal.last_cycles(5)] == [(2, 203), (1, 201)]


def test_a_config_error_exits_2_naming_the_key(tmp_path: Path) -> None:
    config = tmp_path / "cell.toml"
    config.write_text(SIM_CELL.read_text() + "\n[service]\nimages_max_mb = -5\n")
    done = subprocess.run([sys.executable, "-m", "monoguide.daemon.cli", "run", "--config", str(config),
                           "--state-dir", str(tmp_path / "state")], capture_output=True, text=True, timeout=60)
    assert done.returncode == 2, done.stderr
    assert "images_max_mb" in done.stderr and "CONFIG_INVALID" in done.stderr
    assert not (tmp_path / "state").exists()  # nothing started
    text = re.sub(r"\[plc\].*?(?=\n\[sim\])", "", SIM_CELL.read_text(), flags=re.S)
    config.write_text(text)
    done = subprocess.run([sys.executable, "-m", "monoguide.daemon.cli", "run", "--config", str(config),
                           "--state-dir", str(tmp_path / "state")], capture_output=True, text=True, timeout=60,
                          env={**os.environ, "STATE_DIRECTORY": str(tmp_path / "s")})
    assert done.returncode == 2 and "[plc]" in done.stderr, done.stderr
