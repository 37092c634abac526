"""The service's PLC handshake (issue 10), in-process: the PLC is the real pymodbus server of
drivers/sim/plc.py played by the test, monoguide connects with the real ModbusPlc client. The cycle's work
is a small stand-in with a seeded offset (the camera and robot are covered end to end in
test_service_cell.py): what is tested here is what the PLC sees, register by register."""

from __future__ import annotations

import asyncio
import contextlib
import functools
import logging
import os
import re
import socket
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest

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
from monoguide.drivers.plc_registers import (
    BLOCK_SIZE,
    CONTROL,
    PLC_HEARTBEAT,
    STATUS,
    Control,
    Status,
    decode_outputs,
)
from monoguide.drivers.sim.plc import PlcServer

SIM_CELL = Path(__file__).parents[2] / "config" / "sim-cell.toml"
WAIT_S = 5.0
OFFSET = (1.25, -2.5, 0.75, 0.1, -0.2, 0.3)  # the stand-in's solved offset: what registers 16-27 must show
QUALITY = (0.05, 0.02, 0.001)


def _sync(test: Callable[..., Any]) -> Callable[..., Any]:
    """Run an async test in its own event loop (the PLC server and the service share it)."""

    @functools.wraps(test)
    def run(*args: Any, **kwargs: Any) -> Any:
        return asyncio.run(test(*args, **kwargs))

    return run


def _config(tmp_path: Path, host: str, port: int, heartbeat_timeout_s: float = 1.0, ack_timeout_s: float = 2.0,
            extra: str = "") -> Path:
    text = SIM_CELL.read_text()
    text = re.sub(r"\[plc\].*?(?=\n\[sim\])", f"[plc]\nhost = \"{host}\"\nport = {port}\nheartbeat_timeout_s = "
                  f"{heartbeat_timeout_s}\nack_timeout_s = {ack_timeout_s}\ntimeout_s = 0.5\n", text, flags=re.S)
    path = tmp_path / "cell.toml"
    path.write_text(text + extra)
    return path


@dataclass
class StandIn:
    """The cycle's work, scripted: ``measure`` waits for ``release`` (or the abort), the rest is instant;
    ``written`` lists the offsets "written to the robot"."""

    release: threading.Event = field(default_factory=threading.Event)
    written: list[tuple[float, ...]] = field(default_factory=list)
    write_started: threading.Event = field(default_factory=threading.Event)
    write_gate: threading.Event | None = None

    def factory(self, _config: Any, _camera: Any, _robot: Any, _images: Any) -> StandIn:
        return self

    def close(self) -> None:
        return None

    def measure(self, job: int, abort: threading.Event, abort_error: Callable[[], Exception]) -> Any:
        while not self.release.wait(0.01):
            if abort.is_set():
                raise abort_error()
        if abort.is_set():
            raise abort_error()
        return _Measurement(job)

    def solve(self, measurement: Any) -> Any:
        return _Solution()

    def check(self, measurement: Any, solution: Any) -> None:
        return None

    def write(self, solution: Any, before_send: Callable[[int], None] | None = None) -> int:
        sequence = len(self.written) + 1
        if before_send is not None:
            before_send(sequence)  # the journal's intent, committed before anything goes to the robot
        self.write_started.set()
        if self.write_gate is not None:
            assert self.write_gate.wait(WAIT_S)
        self.written.append(solution.offset)
        return sequence


@dataclass
class _Measurement:
    job: int
    captures: list[Any] = field(default_factory=list)
    record: dict[str, Any] = field(default_factory=lambda: {"kind": "stand-in"})
    timings_s: dict[str, float] = field(default_factory=dict)
    last_frame_at: float = 0.0


@dataclass
class _Solution:
    result: dict[str, Any] = field(default_factory=lambda: {"offset": list(OFFSET)})
    D_b: np.ndarray = field(default_factory=lambda: np.eye(4))
    offset: tuple[float, ...] = OFFSET
    quality: tuple[float, ...] = QUALITY


class Line:
    """The test's PLC program over the real server: heartbeat, control word, waits on the status word."""

    def __init__(self, server: PlcServer) -> None:
        self.server = server
        self.beating = True
        self._task: asyncio.Task[None] | None = None

    async def start(self) -> None:
        await self.server.write(1, [1])  # job 1
        self._task = asyncio.create_task(self._beat())

    async def _beat(self) -> None:
        value = 0
        while True:
            await asyncio.sleep(0.1)
            if self.beating:
                value = (value + 1) & 0xFFFF
                await self.server.write(PLC_HEARTBEAT, [value])

    async def stop(self) -> None:
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task

    async def control(self, bits: int, job: int | None = None, tag: int | None = None) -> None:
        await self.server.write(CONTROL, [bits])
        if job is not None:
            await self.server.write(1, [job])
        if tag is not None:
            await self.server.write(3, [tag])

    async def status(self) -> Status:
        return Status((await self.server.read(STATUS))[0])

    async def wait(self, done: Callable[[Status], bool], what: str, timeout_s: float = WAIT_S) -> Status:
        deadline = asyncio.get_running_loop().time() + timeout_s
        while asyncio.get_running_loop().time() < deadline:
            status = await self.status()
            if done(status):
                return status
            await asyncio.sleep(0.005)
        raise AssertionError(f"PLC: no {what} within {timeout_s} s (status {await self.status()!r})")

    async def outputs(self) -> Any:
        return decode_outputs(await self.server.read(STATUS, BLOCK_SIZE - STATUS))

    async def acknowledge(self) -> None:
        await self.control(Control.RESULT_ACK)
        await self.wait(lambda s: not s & (Status.DONE | Status.RESULT_OK | Status.ERROR), "DONE cleared")
        await self.control(0)
        await self.wait(lambda s: Status.READY in s, "READY after the acknowledgement")


@contextlib.asynccontextmanager
async def _cell(tmp_path: Path, host: str, stand_in: StandIn, devices: CellDevices | None = None,  # type: ignore[no-untyped-def]
                **config: Any):
    port = 5020
    server = PlcServer(host, port)
    await server.start()
    line = Line(server)
    await line.start()
    cfg = load_cell_config(_config(tmp_path, host, port, **config))
    stop = asyncio.Event()
    service = asyncio.create_task(run_service(cfg, tmp_path / "state", stop=stop, devices=devices or CellDevices([]),
                                              runner_factory=stand_in.factory))
    try:
        await line.wait(lambda s: Status.READY in s, "READY at start")
        yield line, service, stop
    finally:
        stop.set()
        with contextlib.suppress(Exception):
            await asyncio.wait_for(service, WAIT_S)
        await line.stop()
        await server.stop()


def _record_status_writes(server: PlcServer) -> list[int]:
    """Every value written to the status word from now on, as the PLC's datastore receives it."""
    writes: list[int] = []
    context = server.server.context
    set_values = context.async_setValues

    async def recording(device_id: int, func_code: int, address: int, values: Any) -> Any:
        if server.base + STATUS in range(address, address + len(values)):
            writes.append(int(values[server.base + STATUS - address]))
        return await set_values(device_id, func_code, address, values)

    context.async_setValues = recording  # type: ignore[method-assign]
    return writes


def _journal(tmp_path: Path) -> Any:
    with Journal(tmp_path / "state") as journal:
        return journal.last_cycles(10)


@_sync
async def test_good_cycle_then_trigger_dropped_then_sigterm(tmp_path: Path) -> None:
    stand_in = StandIn()
    async with _cell(tmp_path, "127.0.5.1", stand_in) as (line, service, stop):
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


@_sync
async def test_trigger_dropped_during_the_write_reports_what_the_robot_has(tmp_path: Path) -> None:
    stand_in = StandIn(write_gate=threading.Event())
    stand_in.release.set()
    async with _cell(tmp_path, "127.0.5.2", stand_in) as (line, _service, _stop):
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


@_sync
async def test_unknown_job_and_trigger_while_not_ready(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    stand_in = StandIn()
    stand_in.release.set()
    async with _cell(tmp_path, "127.0.5.3", stand_in) as (line, _service, _stop):
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


@_sync
async def test_heartbeat_lost_latches_fault_until_fault_reset(tmp_path: Path) -> None:
    stand_in = StandIn()
    async with _cell(tmp_path, "127.0.5.4", stand_in, heartbeat_timeout_s=0.5) as (line, _service, _stop):
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


@_sync
async def test_no_acknowledgement_latches_plc_ack_timeout(tmp_path: Path) -> None:
    stand_in = StandIn()
    stand_in.release.set()
    async with _cell(tmp_path, "127.0.5.5", stand_in, ack_timeout_s=0.5) as (line, _service, _stop):
        await line.control(Control.TRIGGER, tag=21)
        await line.wait(lambda s: Status.DONE in s, "DONE")
        status = await line.wait(lambda s: Status.FAULT in s, "FAULT after no acknowledgement")
        assert status == Status.FAULT
        assert (await line.outputs()).result.error_code == PlcAckTimeout.plc_code
        await line.control(Control.FAULT_RESET)
        await line.wait(lambda s: Status.FAULT not in s, "FAULT cleared")
        await line.control(0)
        await line.wait(lambda s: Status.READY in s, "READY")


@_sync
async def test_systemd_notifications_and_status_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(str(tmp_path / "notify"))
    sock.setblocking(False)
    monkeypatch.setenv("NOTIFY_SOCKET", str(tmp_path / "notify"))
    monkeypatch.setenv("WATCHDOG_USEC", "400000")  # pings every 0.2 s
    monkeypatch.setenv("WATCHDOG_PID", str(os.getpid()))
    stand_in = StandIn()
    stand_in.release.set()
    async with _cell(tmp_path, "127.0.5.6", stand_in) as (line, _service, _stop):
        await asyncio.sleep(0.5)
        status = read_status(tmp_path / "state")
        assert status is not None and status.state == "idle" and liveness(status).running
        assert status.devices["plc"].connected
        await line.control(Control.TRIGGER, tag=31)
        await line.wait(lambda s: Status.DONE in s, "DONE")
        await line.acknowledge()
    messages = []
    with contextlib.suppress(BlockingIOError):
        while True:
            messages.append(sock.recv(4096).decode())
    sock.close()
    assert messages[0].startswith("READY=1\nSTATUS=idle")
    assert "WATCHDOG=1" in messages and "STOPPING=1" in messages
    assert "STATUS=awaiting_ack; last: cycle 1 ok" in messages
    assert read_status(tmp_path / "state").state == "stopped"  # type: ignore[union-attr]


@_sync
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
        def measure(self, job: int, abort: threading.Event, abort_error: Callable[[], Exception]) -> Any:
            if len(opened) == 1:
                raise DeviceDisconnected("camera 'cam-1': device gone")
            return super().measure(job, abort, abort_error)

    stand_in = Unplugged()
    stand_in.release.set()
    devices = CellDevices([DeviceSlot("camera", open_camera, lambda _camera: None)])
    caplog.set_level(logging.INFO)
    async with _cell(tmp_path, "127.0.5.7", stand_in, devices=devices) as (line, _service, _stop):
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


@_sync
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
    service = asyncio.create_task(run_service(load_cell_config(_config(tmp_path, host, port)), tmp_path / "state",
                                              stop=stop, devices=CellDevices([]), runner_factory=stand_in.factory))
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
        status_writes = _record_status_writes(server)
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
