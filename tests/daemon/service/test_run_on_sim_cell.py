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
from helpers.cell_configs import cell_config
from helpers.plc_line import Line, in_own_event_loop, plc_line, record_status_writes
from helpers.repository import SIM_CELL
from helpers.sim_processes import keep_reading, start_sim_cell, stop

from monoguide.daemon.service import Journal
from monoguide.drivers.errors import DeviceDisconnected, PlcTriggerDropped, RobotOffsetUnconfirmed
from monoguide.drivers.plc_registers import Control, Status
from monoguide.drivers.sim.robot_truth import read_truth
from monoguide.solver import frames

ROBOT_HOST, PLC_HOST, PLC_PORT = "127.0.5.20", "127.0.5.21", 5020
START_S = 60.0  # sim-cell and the service's devices on a shared machine
CYCLE_S = 60.0


@pytest.fixture(scope="module")
def cell(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Any]]:
    """One sim-cell (robot with part supply, tracker; no PLC) for the module; its config and truth log."""
    tmp = tmp_path_factory.mktemp("service-cell")
    state, truth = tmp / "sim-state.json", tmp / "truth.jsonl"
    config = cell_config(tmp, ROBOT_HOST, PLC_HOST, sharp=True, state_file=state,  # sharp: 0.2 s a frame, not 3 s
                         more=[("heartbeat_timeout_s = 2.0", "heartbeat_timeout_s = 2.0\nack_timeout_s = 30.0")],
                         extra="\n[service]\nimages_max_mb = 50.0\n")
    process, _ = start_sim_cell(config, "--no-plc", "--truth-log", str(truth), stdin=subprocess.PIPE,
                                timeout_s=START_S)
    keep_reading(process)
    try:
        yield {"config": config, "truth": truth, "tmp": tmp, "process": process,  # type: ignore[dict-item]
               "robot_truth": state.with_name(state.stem + "-robot-truth.json")}
    finally:
        stop(process, 15.0)


STARTED: list[int] = []  # the services this module started: none may outlive its test, pass or fail


@pytest.fixture(autouse=True)
def _no_service_left() -> Iterator[None]:
    yield
    while STARTED:
        with contextlib.suppress(ProcessLookupError):
            os.kill(STARTED.pop(), signal.SIGKILL)


async def _run(config: Path, state_dir: Path, *options: str) -> asyncio.subprocess.Process:
    process = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "monoguide.daemon.cli", "run", "--config", str(config), "--state-dir", str(state_dir),
        *options, stdout=asyncio.subprocess.DEVNULL, stderr=asyncio.subprocess.PIPE)
    STARTED.append(process.pid)
    return process


async def _exit(process: asyncio.subprocess.Process, timeout_s: float = 20.0) -> tuple[int, str]:
    _, err = await asyncio.wait_for(process.communicate(), timeout_s)
    return process.returncode or 0, err.decode()


async def _one_part(line: Line, tag: int) -> Any:
    """Trigger, wait for DONE, read the result; leaves DONE unacknowledged."""
    await line.wait(lambda s: Status.READY in s, "READY", START_S)
    await line.control(Control.TRIGGER, job=1, tag=tag)
    await line.wait(lambda s: Status.BUSY in s, "BUSY")
    status = await line.wait(lambda s: Status.DONE in s, "DONE", CYCLE_S)
    return status, await line.outputs()


def _truth(cell: dict[str, Path]) -> list[dict[str, Any]]:
    return [json.loads(line) for line in cell["truth"].read_text().splitlines() if line.strip()]


@in_own_event_loop
async def test_good_cycles_give_the_true_offset(cell: dict[str, Path]) -> None:
    state_dir = cell["tmp"] / "state-good"
    async with plc_line(PLC_HOST, PLC_PORT) as line:
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


@in_own_event_loop
async def test_kill_9_then_restart_clears_the_stale_done_and_keeps_the_journal(cell: dict[str, Path]) -> None:
    state_dir = cell["tmp"] / "state-kill"
    async with plc_line(PLC_HOST, PLC_PORT) as line:
        service = await _run(cell["config"], state_dir)
        status, out = await _one_part(line, 201)
        assert status == Status.DONE | Status.RESULT_OK and out.result.cycle_counter == 1
        service.kill()  # kill -9 with DONE shown
        await _exit(service)
        assert Status.DONE in await line.status()  # the register keeps the dead service's word
        await line.control(0)
        status_writes = record_status_writes(line.server)
        service = await _run(cell["config"], state_dir)
        await line.wait(lambda s: Status.READY in s, "READY after the restart", START_S)
        ready = status_writes.index(int(Status.READY))  # 0 (rewritten each second) until READY: never a stale DONE
        assert ready > 0 and set(status_writes[:ready]) == {0}, status_writes
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


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT, signal.SIGHUP], ids=lambda s: s.name)
@in_own_event_loop
async def test_every_stop_signal_ends_the_service_cleanly(cell: dict[str, Path], signum: signal.Signals) -> None:
    state_dir = cell["tmp"] / f"state-{signum.name}"
    async with plc_line(PLC_HOST, PLC_PORT) as line:
        service = await _run(cell["config"], state_dir)
        await line.wait(lambda s: Status.READY in s, "READY", START_S)
        service.send_signal(signum)
        code, err = await _exit(service)
        assert code == 0, err
        assert "service: stopping (signal)" in err and "service: stopped" in err
        assert await line.status() == Status(0)  # not READY from a stopped service
    assert not (state_dir / "service.lock").read_text()  # released: the next service may start


@in_own_event_loop
async def test_a_killed_service_leaves_ready_with_a_still_heartbeat_until_clear_status(cell: dict[str, Path]) -> None:
    """SIGKILL: no clean-up runs. The PLC must judge the service by its heartbeat (register 12 stands still);
    the unit's ExecStopPost= (`run --clear-status`) or the next start writes 0."""
    state_dir = cell["tmp"] / "state-sigkill"
    async with plc_line(PLC_HOST, PLC_PORT) as line:
        service = await _run(cell["config"], state_dir)
        await line.wait(lambda s: Status.READY in s, "READY", START_S)
        service.kill()
        await _exit(service)
        beat = (await line.outputs()).heartbeat
        await asyncio.sleep(2.0)  # the documented window: 4 heartbeat periods
        assert (await line.outputs()).heartbeat == beat  # a dead service's heartbeat stands still
        assert Status.READY in await line.status()  # what register 10 alone would wrongly say
        cleared = await _run(cell["config"], state_dir, "--clear-status")
        code, err = await _exit(cleared)
        assert code == 0, err
        assert await line.status() == Status(0)


@in_own_event_loop
async def test_a_second_service_on_the_same_state_dir_is_refused(cell: dict[str, Path]) -> None:
    state_dir = cell["tmp"] / "state-two"
    async with plc_line(PLC_HOST, PLC_PORT) as line:
        first = await _run(cell["config"], state_dir)
        await line.wait(lambda s: Status.READY in s, "READY", START_S)
        writes = record_status_writes(line.server)
        for options in ((), ("--clear-status",)):
            second = await _run(cell["config"], state_dir, *options)
            code, err = await _exit(second)
            assert code == 1, err
            assert "STATE_DIR_IN_USE" in err and f"PID {first.pid}" in err
        await asyncio.sleep(1.5)
        assert Status.READY in await line.status() and 0 not in writes  # the first one's READY stands
        first.send_signal(signal.SIGTERM)
        code, err = await _exit(first)
        assert code == 0, err


@in_own_event_loop
async def test_a_lost_robot_is_named_and_only_it_is_reconnected(cell: dict[str, Any]) -> None:
    state_dir = cell["tmp"] / "state-lost-robot"
    async with plc_line(PLC_HOST, PLC_PORT) as line:
        service = await _run(cell["config"], state_dir)
        await line.wait(lambda s: Status.READY in s, "READY", START_S)
        await _robot_fault(cell, "drop")  # the controller closes every connection at each request
        await line.trigger(job=1, tag=600, timeout_s=START_S)  # READY may fall first: the link is gone
        assert await line.wait(lambda s: Status.DONE in s, "DONE", CYCLE_S) == Status.DONE | Status.ERROR
        assert (await line.outputs()).result.error_code == DeviceDisconnected.plc_code
        await _robot_fault(cell, "none")
        await line.acknowledge()
        await line.wait(lambda s: Status.READY in s, "READY again", START_S)
        service.send_signal(signal.SIGTERM)
        code, err = await _exit(service)
    assert code == 0, err
    assert "robot lost (DEVICE_DISCONNECTED" in err and "camera lost" not in err, err[-3000:]
    assert "camera: connected again" not in err  # the camera was never closed


@in_own_event_loop
async def test_a_robot_lost_while_idle_takes_ready_away_within_a_poll(cell: dict[str, Any]) -> None:
    """READY means every device answers: the controller closing its connections while the cell waits for a trigger
    takes READY away at once (not at the next trigger, which would fail 403), and READY comes back only when the
    robot answers again; the next part is measured as usual."""
    state_dir = cell["tmp"] / "state-idle-loss"
    async with plc_line(PLC_HOST, PLC_PORT) as line:
        service = await _run(cell["config"], state_dir)
        await line.wait(lambda s: Status.READY in s, "READY", START_S)
        await asyncio.sleep(0.5)  # settled: nothing else under way
        start = asyncio.get_running_loop().time()
        await _robot_fault(cell, "cut 2")  # the cable pulled now, for 2 s
        await line.wait(lambda s: Status.READY not in s, "READY gone", 1.0)
        lost_after = asyncio.get_running_loop().time() - start
        await asyncio.sleep(1.0)
        assert Status.READY not in await line.status()  # reconnecting to a controller that refuses it
        status = await line.trigger(job=1, tag=650, timeout_s=START_S)  # once READY is back
        assert Status.BUSY in status or Status.DONE in status
        assert await line.wait(lambda s: Status.DONE in s, "DONE", CYCLE_S) == Status.DONE | Status.RESULT_OK
        await line.acknowledge()
        service.send_signal(signal.SIGTERM)
        code, err = await _exit(service)
    assert code == 0, err
    assert lost_after < 1.0, lost_after
    assert "robot lost (DEVICE_DISCONNECTED" in err, err[-3000:]


def test_an_empty_state_dir_is_a_usage_error(tmp_path: Path) -> None:
    done = subprocess.run([sys.executable, "-m", "monoguide.daemon.cli", "run", "--config", str(SIM_CELL),
                           "--state-dir", ""], capture_output=True, text=True, timeout=60, cwd=tmp_path)
    assert done.returncode == 2, done.stderr
    assert "STATE_DIR_INVALID" in done.stderr and list(tmp_path.iterdir()) == []


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
    assert "CONFIG_MISSING_KEY" in done.stderr and "monoguide run" in done.stderr
    text = re.sub(r"\[robot\].*?(?=\n\[)", "", SIM_CELL.read_text(), count=1, flags=re.S)
    assert "[robot]" not in text
    config.write_text(text)
    done = subprocess.run([sys.executable, "-m", "monoguide.daemon.cli", "run", "--config", str(config),
                           "--state-dir", str(tmp_path / "state")], capture_output=True, text=True, timeout=60)
    assert done.returncode == 2, done.stderr
    assert "CONFIG_MISSING_KEY" in done.stderr and "[robot]" in done.stderr and "monoguide run" in done.stderr
    assert not (tmp_path / "state").exists()


def _robot_truth(cell: dict[str, Any]) -> dict[str, Any]:
    for _ in range(100):
        with contextlib.suppress(OSError, ValueError):
            return read_truth(cell["robot_truth"])
    raise AssertionError("no robot truth file")


async def _robot_fault(cell: dict[str, Any], command: str) -> None:
    """A fault on sim-cell's standard input, waited for until the controller says it took it up."""
    applied = int(_robot_truth(cell).get("commands_applied", 0))
    cell["process"].stdin.write(f"robot {command}\n")
    cell["process"].stdin.flush()
    deadline = asyncio.get_running_loop().time() + 10.0
    while int(_robot_truth(cell).get("commands_applied", 0)) <= applied:
        assert asyncio.get_running_loop().time() < deadline, f"robot {command} not taken up"
        await asyncio.sleep(0.01)


@pytest.mark.slow
@in_own_event_loop
async def test_a_controller_cut_at_every_millisecond_of_the_write_leaves_no_offset_unreported(
        cell: dict[str, Any]) -> None:
    """The cable pulled 0, 1, 2, ... 9 ms after the offset reached the controller (which takes it on its own
    schedule), back at once or after a second: whatever the PLC is told, the robot's truth agrees — RESULT_OK only
    with the offset the robot holds, ERROR only when it holds nothing from the cycle, FAULT 429 until monoguide has
    settled it, and afterwards the robot holds no offset the PLC was not told RESULT_OK about."""
    state_dir = cell["tmp"] / "state-cut"
    seen: dict[str, int] = {}
    reported_ok: set[int] = set()  # the sequence numbers of offsets the PLC was told RESULT_OK about

    def holds_only_what_the_plc_was_told(when: str) -> None:
        truth = _robot_truth(cell)
        assert not truth["offset_valid"] or truth["held_sequence"] in reported_ok, (when, truth["held_sequence"],
                                                                                     sorted(reported_ok))

    async with plc_line(PLC_HOST, PLC_PORT) as line:
        service = await _run(cell["config"], state_dir)
        for ms in range(10):
            down_s = 0.05 if ms % 2 == 0 else 1.0  # back at once (as a cable blip), or after a second
            await line.wait(lambda s: Status.READY in s, "READY", START_S)
            await _robot_fault(cell, f"cut-after-offset {ms} {down_s}")
            # the controller still down from the last cut takes READY away (within a poll): the trigger is raised
            # again once READY is back, as a PLC does
            await line.trigger(job=1, tag=500 + ms, timeout_s=START_S)
            status = await line.wait(lambda s: bool(s & (Status.DONE | Status.FAULT)), "DONE or FAULT", CYCLE_S)
            out = (await line.outputs()).result
            with Journal(state_dir) as journal:
                intent = journal.intent(journal.cycle_counter())
            if status == Status.DONE | Status.RESULT_OK:
                seen["RESULT_OK"] = seen.get("RESULT_OK", 0) + 1
                assert intent is not None and intent.outcome == "acknowledged"
                held = [o for o in _robot_truth(cell)["offsets"] if o["sequence"] == intent.sequence]
                assert held, (ms, intent.sequence)  # the robot received exactly the offset the PLC reads
                np.testing.assert_allclose(out.offset, frames.T_to_kuka_frame(np.array(held[0]["D_b"])), atol=1e-3)
                reported_ok.add(intent.sequence)
                await line.acknowledge()
            elif status == Status.DONE | Status.ERROR:
                seen[str(out.error_code)] = seen.get(str(out.error_code), 0) + 1
                assert out.offset == (0.0,) * 6
                if intent is not None:  # sent, then settled at once: this cycle's offset is not held
                    assert intent.outcome in ("held", "not_held") and intent.cleared, (ms, intent)
                await line.acknowledge()
            else:
                assert Status.FAULT in status and out.error_code == RobotOffsetUnconfirmed.plc_code, (ms, out)
                seen["429"] = seen.get("429", 0) + 1
                assert out.offset == (0.0,) * 6 and out.part_tag == 500 + ms
                await line.control(0)
                deadline = asyncio.get_running_loop().time() + 30.0
                while Status.READY not in await line.status():  # FAULT_RESET is ignored until it is settled
                    assert asyncio.get_running_loop().time() < deadline, "the unconfirmed offset was never settled"
                    await line.control(Control.FAULT_RESET)
                    await asyncio.sleep(0.1)
                    await line.control(0)
                    await asyncio.sleep(0.3)
            holds_only_what_the_plc_was_told(f"after the cycle cut at {ms} ms: {status!r}")
        service.send_signal(signal.SIGTERM)
        code, err = await _exit(service)
        assert code == 0, err
    with Journal(state_dir) as journal:
        intents = [journal.intent(n) for n in range(1, journal.cycle_counter() + 1)]
    sent = [i for i in intents if i is not None]
    assert sent and all(i.outcome is not None for i in sent), sent  # every offset sent is settled
    assert "RESULT_OK" in seen and len(seen) >= 2, seen  # the sweep reached more than one outcome
    print("outcomes of the sweep:", seen)
