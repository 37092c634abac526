"""The line's PLC played by a test over the real pymodbus server of drivers/sim/plc.py: :class:`Line` beats the
heartbeat, writes the control word and waits on the status word; every status write recorded; async tests run
in an event loop of their own (the PLC server and the service under test share it)."""

from __future__ import annotations

import asyncio
import contextlib
import functools
from collections.abc import AsyncIterator, Callable
from typing import Any

from monoguide.drivers.plc_registers import BLOCK_SIZE, CONTROL, PLC_HEARTBEAT, STATUS, Control, Status, decode_outputs
from monoguide.drivers.sim.plc import PlcServer

WAIT_S = 5.0


def in_own_event_loop(test: Callable[..., Any]) -> Callable[..., Any]:
    """Run an async test in its own event loop (the PLC server and the service share it)."""

    @functools.wraps(test)
    def run(*args: Any, **kwargs: Any) -> Any:
        return asyncio.run(test(*args, **kwargs))

    return run


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
        result = (await self.outputs()).result  # what register 11 says of it (a FAULT's code)
        raise AssertionError(f"PLC: no {what} within {timeout_s} s (status {await self.status()!r}, register 11 = "
                             f"{result.error_code}, register 13 = {result.cycle_counter})")

    async def trigger(self, job: int | None = None, tag: int | None = None, timeout_s: float = 60.0) -> Status:
        """TRIGGER as docs/plc-interface.md tells a PLC to raise it: on READY; when READY falls before BUSY shows (a
        device was lost meanwhile: the trigger is ignored), drop it, wait for READY again and raise it again. Returns
        the first status with BUSY, DONE or FAULT."""
        deadline = asyncio.get_running_loop().time() + timeout_s
        started = Status.BUSY | Status.DONE | Status.FAULT
        while True:
            await self.wait(lambda s: Status.READY in s, "READY", deadline - asyncio.get_running_loop().time())
            await self.control(Control.TRIGGER, job=job, tag=tag)
            status = await self.wait(lambda s: bool(s & started) or Status.READY not in s, "BUSY, its end or READY "
                                     "falling", max(deadline - asyncio.get_running_loop().time(), WAIT_S))
            if status & started:
                return status
            await self.control(0)  # ignored: READY fell first

    async def outputs(self) -> Any:
        return decode_outputs(await self.server.read(STATUS, BLOCK_SIZE - STATUS))

    async def acknowledge(self) -> None:
        await self.control(Control.RESULT_ACK)
        await self.wait(lambda s: not s & (Status.DONE | Status.RESULT_OK | Status.ERROR), "DONE cleared")
        await self.control(0)
        await self.wait(lambda s: Status.READY in s, "READY after the acknowledgement")


@contextlib.asynccontextmanager
async def plc_line(host: str, port: int = 5020) -> AsyncIterator[Line]:
    """The PLC alone at ``host``:``port``, its program beating (the test starts and stops services against it: its
    registers outlive them); stopped at the end."""
    server = PlcServer(host, port)
    await server.start()
    line = Line(server)
    await line.start()
    try:
        yield line
    finally:
        await line.stop()
        await server.stop()


def record_status_writes(server: PlcServer) -> list[int]:
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
