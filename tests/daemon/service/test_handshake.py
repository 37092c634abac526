"""The service's PLC handshake (issue 10), in-process: the PLC is the real pymodbus server of
drivers/sim/plc.py played by the test, monoguide connects with the real ModbusPlc client. The cycle's work
is a small stand-in with a seeded offset (the camera and robot are covered end to end in
test_run_on_sim_cell.py): what is tested here is what the PLC sees, register by register."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import socket
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from helpers.cell_configs import plc_cell_config
from helpers.plc_line import WAIT_S, Line, in_own_event_loop, record_status_writes
from helpers.service_stand_in import OFFSET, QUALITY, StandIn, service_on_line

from monoguide.daemon.config import load_cell_config
from monoguide.daemon.errors import CycleAborted
from monoguide.daemon.service import CellDevices, DeviceSlot, Journal, liveness, read_status, run_service
from monoguide.drivers.errors import (
    DeviceDisconnected,
    DeviceNotFound,
    PlcAckTimeout,
    PlcHeartbeatLost,
    PlcTriggerDropped,
    PlcUnknownJob,
)
from monoguide.drivers.plc_registers import STATUS, Control, Status
from monoguide.drivers.sim.plc import PlcServer


def _journal(tmp_path: Path) -> Any:
    with Journal(tmp_path / "state") as journal:
        return journal.last_cycles(10)


@in_own_event_loop
async def test_good_cycle_then_trigger_dropped_then_sigterm(tmp_path: Path) -> None:
    stand_in = StandIn()
    async with service_on_line(tmp_path, "127.0.5.1", stand_in) as (line, service, stop):
        # a good cycle: BUSY, then DONE + RESULT_OK with the result registers already in place
        await line.control(Control.TRIGGER, job=1, tag=4711)
        await line.wait(lambda s: Status.BUSY in s and Status.READY not in s, "BUSY")
        stand_in.release.set()
        status = await line.wait(lambda s: Status.DONE in s, "DONE")
        assert status == Status.DONE | Status.RESULT_OK
        out = await line.outputs()
        assert out.result.error_code == 0 and out.result.cycle_counter == 1
        assert (out.result.job, out.result.part_tag) == (1, 4711)
        np.testing.assert_allclose(out.result.offset, OFFSET, rtol=1e-6)
        np.testing.assert_allclose(out.result.quality, QUALITY, rtol=1e-6)
        assert stand_in.written == [OFFSET]
        await line.acknowledge()
        # a trigger while not READY (RESULT_ACK still high) is ignored
        # trigger dropped while BUSY: ERROR with its code, nothing written
        stand_in.release.clear()
        await line.control(Control.TRIGGER, tag=4712)
        await line.wait(lambda s: Status.BUSY in s, "BUSY")
        await line.control(0)
        status = await line.wait(lambda s: Status.DONE in s, "DONE after the drop")
        assert status == Status.DONE | Status.ERROR
        out = await line.outputs()
        assert out.result.error_code == PlcTriggerDropped.plc_code and out.result.cycle_counter == 2
        assert out.result.offset == (0.0,) * 6
        assert stand_in.written == [OFFSET]
        await line.acknowledge()
        # SIGTERM mid-cycle: the cycle is aborted and reported, then status word 0
        await line.control(Control.TRIGGER, tag=4713)
        await line.wait(lambda s: Status.BUSY in s, "BUSY")
        stop.set()
        status = await line.wait(lambda s: Status.DONE in s, "DONE after SIGTERM")
        assert status == Status.DONE | Status.ERROR
        assert (await line.outputs()).result.error_code == CycleAborted.plc_code
        await asyncio.wait_for(service, WAIT_S)
        assert await line.status() == Status(0)
    rows = _journal(tmp_path)
    assert [(r.number, r.status, r.error_code) for r in rows] == [
        (3, "error", "CYCLE_ABORTED"), (2, "error", "PLC_TRIGGER_DROPPED"), (1, "ok", None)]
    assert stand_in.written == [OFFSET]


@in_own_event_loop
async def test_trigger_dropped_during_the_write_reports_what_the_robot_has(tmp_path: Path) -> None:
    stand_in = StandIn(write_gate=threading.Event())
    stand_in.release.set()
    async with service_on_line(tmp_path, "127.0.5.2", stand_in) as (line, _service, _stop):
        await line.control(Control.TRIGGER, tag=7)
        assert await asyncio.to_thread(stand_in.write_started.wait, WAIT_S)
        await line.control(0)
        await asyncio.sleep(0.1)
        assert Status.BUSY in await line.status()  # the write is not interrupted
        stand_in.write_gate.set()  # type: ignore[union-attr]
        status = await line.wait(lambda s: Status.DONE in s, "DONE")
        assert status == Status.DONE | Status.RESULT_OK  # the robot has the offset: the PLC is told so
        np.testing.assert_allclose((await line.outputs()).result.offset, OFFSET, rtol=1e-6)
        await line.acknowledge()


@in_own_event_loop
async def test_unknown_job_and_trigger_while_not_ready(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    stand_in = StandIn()
    stand_in.release.set()
    async with service_on_line(tmp_path, "127.0.5.3", stand_in) as (line, _service, _stop):
        await line.control(Control.TRIGGER, job=7, tag=9)
        status = await line.wait(lambda s: Status.DONE in s, "DONE")
        assert status == Status.DONE | Status.ERROR
        out = await line.outputs()
        assert (out.result.error_code, out.result.job, out.result.part_tag) == (PlcUnknownJob.plc_code, 7, 9)
        # TRIGGER falls and rises again while DONE is shown (not READY): ignored and logged
        await line.control(0)
        await asyncio.sleep(0.1)
        await line.control(Control.TRIGGER)
        await asyncio.sleep(0.1)
        assert "trigger ignored: not READY" in caplog.text
        await line.control(Control.RESULT_ACK)
        await line.wait(lambda s: not s & Status.DONE, "DONE cleared")
        await line.control(0, job=1)
        await line.wait(lambda s: Status.READY in s, "READY")
        assert (await line.outputs()).result.cycle_counter == 1
    assert stand_in.written == []


@in_own_event_loop
async def test_heartbeat_lost_latches_fault_until_fault_reset(tmp_path: Path) -> None:
    stand_in = StandIn()
    async with service_on_line(tmp_path, "127.0.5.4", stand_in, heartbeat_timeout_s=0.5) as (line, _service, _stop):
        await line.control(Control.TRIGGER, tag=11)
        await line.wait(lambda s: Status.BUSY in s, "BUSY")
        line.beating = False
        status = await line.wait(lambda s: Status.FAULT in s, "FAULT")
        assert not status & (Status.READY | Status.BUSY)
        assert (await line.outputs()).result.error_code == PlcHeartbeatLost.plc_code
        stand_in.release.set()  # the aborted cycle ends: journaled and counted, nothing written
        deadline = asyncio.get_running_loop().time() + WAIT_S
        while (await line.outputs()).result.cycle_counter != 1 and asyncio.get_running_loop().time() < deadline:
            await asyncio.sleep(0.01)
        out = await line.outputs()
        assert (out.result.error_code, out.result.cycle_counter) == (PlcHeartbeatLost.plc_code, 1)
        assert Status.DONE not in await line.status()
        await line.control(0)
        await line.control(Control.FAULT_RESET)  # heartbeat still stopped: the latch holds
        await asyncio.sleep(0.2)
        assert Status.FAULT in await line.status()
        await line.control(0)
        line.beating = True
        await asyncio.sleep(0.3)
        assert Status.FAULT in await line.status()  # the heartbeat alone does not clear it
        await line.control(Control.FAULT_RESET)
        await line.wait(lambda s: Status.FAULT not in s, "FAULT cleared")
        await line.control(0)
        await line.wait(lambda s: Status.READY in s, "READY after FAULT_RESET")
    assert stand_in.written == []
    assert _journal(tmp_path)[0].error_code == "PLC_HEARTBEAT_LOST"


@in_own_event_loop
async def test_no_acknowledgement_latches_plc_ack_timeout(tmp_path: Path) -> None:
    stand_in = StandIn()
    stand_in.release.set()
    async with service_on_line(tmp_path, "127.0.5.5", stand_in, ack_timeout_s=0.5) as (line, _service, _stop):
        await line.control(Control.TRIGGER, tag=21)
        await line.wait(lambda s: Status.DONE in s, "DONE")
        status = await line.wait(lambda s: Status.FAULT in s, "FAULT after no acknowledgement")
        assert status == Status.FAULT
        assert (await line.outputs()).result.error_code == PlcAckTimeout.plc_code
        await line.control(Control.FAULT_RESET)
        await line.wait(lambda s: Status.FAULT not in s, "FAULT cleared")
        await line.control(0)
        await line.wait(lambda s: Status.READY in s, "READY")


@in_own_event_loop
async def test_systemd_notifications_and_status_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(str(tmp_path / "notify"))
    sock.setblocking(False)
    monkeypatch.setenv("NOTIFY_SOCKET", str(tmp_path / "notify"))
    monkeypatch.setenv("WATCHDOG_USEC", "400000")  # pings every 0.2 s
    monkeypatch.setenv("WATCHDOG_PID", str(os.getpid()))
    stand_in = StandIn()
    stand_in.release.set()
    messages: list[str] = []

    def drain() -> None:  # as systemd does: the socket's queue holds 10 datagrams, a full one loses messages
        with contextlib.suppress(BlockingIOError):
            while True:
                messages.append(sock.recv(4096).decode())

    async with service_on_line(tmp_path, "127.0.5.6", stand_in) as (line, _service, _stop):
        await asyncio.sleep(0.5)
        status = read_status(tmp_path / "state")
        assert status is not None and status.state == "idle" and liveness(status).running
        assert status.devices["plc"].connected
        assert status.plc is not None and status.plc["status"] == ["READY"] and status.plc["control"] == []
        await line.control(Control.TRIGGER, tag=31)
        await line.wait(lambda s: Status.DONE in s, "DONE")
        for _ in range(13):  # the status file is rewritten at least once a second
            await asyncio.sleep(0.1)
            drain()
        plc = read_status(tmp_path / "state").plc  # type: ignore[union-attr]
        assert plc is not None and (plc["control"], plc["part_tag"], plc["job"]) == (["TRIGGER"], 31, 1)
        assert "DONE" in plc["status"] and "RESULT_OK" in plc["status"] and isinstance(plc["heartbeat"], int)
        assert plc["plc_heartbeat"] > 0  # the line beats every 0.1 s, the file is up to 1 s old: not equal
        assert 0 <= (await line.outputs()).heartbeat - plc["heartbeat"] <= 3  # register 12 beats every 0.5 s
        await line.acknowledge()
    drain()
    sock.close()
    assert messages[0].startswith("READY=1\nSTATUS=idle")
    assert "WATCHDOG=1" in messages and "STOPPING=1" in messages
    assert "STATUS=awaiting_ack; last: cycle 1 ok" in messages
    assert read_status(tmp_path / "state").state == "stopped"  # type: ignore[union-attr]


@in_own_event_loop
async def test_a_device_lost_in_a_cycle_fails_it_and_is_reconnected(tmp_path: Path,
                                                                   caplog: pytest.LogCaptureFixture) -> None:
    opened: list[str] = []
    refusals = iter([DeviceNotFound("camera 'cam-1': not on the network")] * 2)  # two reopenings fail: 1.5 s

    def open_camera() -> str:
        if opened and (refusal := next(refusals, None)) is not None:
            raise refusal
        opened.append("camera")
        return f"camera #{len(opened)}"

    class Unplugged(StandIn):
        def measure(self, job: int, abort: threading.Event, abort_error: Callable[[], Exception],
                    holes: bool = True, seen: Any = None) -> Any:
            if len(opened) == 1:
                raise DeviceDisconnected("camera 'cam-1': device gone")
            return super().measure(job, abort, abort_error)

    stand_in = Unplugged()
    stand_in.release.set()
    devices = CellDevices([DeviceSlot("camera", open_camera, lambda _camera: None)])
    caplog.set_level(logging.INFO)
    async with service_on_line(tmp_path, "127.0.5.7", stand_in, devices=devices) as (line, _service, _stop):
        await line.control(Control.TRIGGER, tag=41)
        assert await line.wait(lambda s: Status.DONE in s, "DONE") == Status.DONE | Status.ERROR
        assert (await line.outputs()).result.error_code == DeviceDisconnected.plc_code
        await line.control(Control.RESULT_ACK)
        await line.wait(lambda s: not s & Status.DONE, "DONE cleared")
        await line.control(0)
        await asyncio.sleep(0.2)
        assert Status.READY not in await line.status()  # the camera is not back yet
        await line.wait(lambda s: Status.READY in s, "READY with the camera back")
        await line.control(Control.TRIGGER, tag=42)
        assert await line.wait(lambda s: Status.DONE in s, "DONE") == Status.DONE | Status.RESULT_OK
        await line.acknowledge()
    assert "camera lost (DEVICE_DISCONNECTED camera 'cam-1': device gone); reconnecting in 0.5 s" in caplog.text
    assert "camera: cannot connect (DEVICE_NOT_FOUND camera 'cam-1': not on the network); reconnecting in" \
        in caplog.text
    assert "camera: connected again after 2 failed attempt(s)" in caplog.text
    assert opened == ["camera", "camera"] and stand_in.written == [OFFSET]


@in_own_event_loop
async def test_the_plc_lost_and_back_is_reconnected_with_status_0_first(tmp_path: Path,
                                                                        caplog: pytest.LogCaptureFixture) -> None:
    stand_in = StandIn()
    stand_in.release.set()
    host, port = "127.0.5.8", 5020
    server = PlcServer(host, port)
    await server.start()
    line = Line(server)
    await line.start()
    stop = asyncio.Event()
    service = asyncio.create_task(run_service(load_cell_config(plc_cell_config(tmp_path, host, port)),
                                              tmp_path / "state", stop=stop, devices=CellDevices([]),
                                              runner_factory=stand_in.factory))
    try:
        await line.wait(lambda s: Status.READY in s, "READY")
        await line.control(Control.TRIGGER, tag=51)
        await line.wait(lambda s: Status.DONE in s, "DONE")
        await line.acknowledge()
        await line.stop()
        await server.stop()  # the PLC goes away (power cycle): its registers start from 0 again
        await asyncio.sleep(0.3)
        server = PlcServer(host, port)
        await server.start()
        await server.write(STATUS, [int(Status.DONE | Status.RESULT_OK)])  # as if left from before
        status_writes = record_status_writes(server)
        line = Line(server)
        await line.start()
        await line.wait(lambda s: Status.READY in s, "READY again", 10.0)
        ready = status_writes.index(int(Status.READY))  # 0 (rewritten each second) until READY: never a stale DONE
        assert ready > 0 and set(status_writes[:ready]) == {0}, status_writes
        assert (await line.outputs()).result.cycle_counter == 1
    finally:
        stop.set()
        await asyncio.wait_for(service, WAIT_S)
        await line.stop()
        await server.stop()
    assert "PLC lost (DEVICE_" in caplog.text and "reconnecting in" in caplog.text
