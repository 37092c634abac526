"""A simulated line PLC: a pymodbus server holding the register block of ``docs/plc-interface.md``, plus a
small program that plays the line.

The server is the genuine pymodbus TCP server over the ``SimDevice``/``SimData`` datastore that pymodbus
3.16 recommends (the older ``ModbusDeviceContext`` / ``ModbusSequentialDataBlock`` log deprecation
warnings). :class:`LinePlc` plays one part after another: a part arrives (job, part tag), it waits for
READY, sets TRIGGER, waits for DONE, reads the result, sets RESULT_ACK and drops TRIGGER, waits for DONE to
clear and drops RESULT_ACK; meanwhile it toggles its heartbeat. Faults on command (:data:`FAULTS`; ``none``
clears the fault, each applies from the moment it is given): ``trigger-dropped-early`` (TRIGGER dropped as
soon as BUSY is seen), ``heartbeat-stopped`` (the heartbeat register stops changing; ``none`` starts it
again), ``no-ack`` (DONE is never acknowledged; TRIGGER drops when the next part arrives; the service's
acknowledgement timeout then sets FAULT, which the line resets as below). A FAULT status is answered with a
FAULT_RESET pulse (half a heartbeat period long, repeated every period while FAULT stands) once the
heartbeat runs. What the service reports for each (``drivers/errors.py``, ``docs/plc-interface.md``):
trigger-dropped-early ``PLC_TRIGGER_DROPPED`` (453, ERROR), heartbeat-stopped ``PLC_HEARTBEAT_LOST`` (452,
FAULT), no-ack ``PLC_ACK_TIMEOUT`` (454, FAULT after ``[plc] ack_timeout_s``).

With ``grasp_wait_s`` (``--grasp-wait S``: a simulated robot is in the cell) the line gives the robot
the grasp go after each result it read with RESULT_OK and acknowledged: it prints ``GRASP {"part", "part_tag"}``
(``monoguide sim-cell`` passes it to the robot controller) and waits up to S s for the robot's answer on standard
input, ``grasped {json}``, before the next part; the part's record gets it as ``grasp`` (null: no go given).

Run in its own process: ``python -m monoguide.drivers.sim.plc --host 127.0.0.x --port N``. It prints
``LISTEN plc HOST:PORT`` when it serves, then one JSON line per finished part; each line read from
standard input is a fault command (one of :data:`FAULTS`). It serves until SIGTERM (exit status 0), also
after ``--parts N`` parts were played, or until its parent process is gone (``monoguide sim-cell`` killed).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import logging
import os
import signal
import sys
import threading
from collections.abc import Callable
from dataclasses import dataclass, field

from pymodbus.server import ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

from monoguide.drivers.plc_registers import (
    BLOCK_SIZE,
    CONTROL,
    INPUT_COUNT,
    PLC_HEARTBEAT,
    STATUS,
    Control,
    PlcInputs,
    PlcOutputs,
    Status,
    WordOrder,
    decode_outputs,
    encode_inputs,
    wrap_uint16,
)

log = logging.getLogger(__name__)

FAULTS = ("none", "trigger-dropped-early", "heartbeat-stopped", "no-ack")
GRASP_GO = "GRASP"  # printed: the grasp go
GRASP_ANSWER = "grasped"  # read: the robot's outcome
READ_FC, WRITE_FC = 3, 16
POLL_S = 0.01


class PlcServer:
    """A pymodbus Modbus TCP server holding registers ``base .. base + 33`` for ``unit`` (others: absent)."""

    def __init__(self, host: str, port: int, unit: int = 1, base: int = 0) -> None:
        self.host, self.port, self.unit, self.base = host, port, unit, base
        device = SimDevice(id=unit, simdata=[SimData(address=base, count=BLOCK_SIZE, datatype=DataType.REGISTERS)])
        self.server = ModbusTcpServer(device, address=(host, port))
        self._task: asyncio.Task[None] | None = None

    async def start(self) -> None:
        self._task = asyncio.create_task(self.server.serve_forever())
        for _ in range(500):  # serve_forever binds in the background; wait until it listens
            if self.server.transport is not None:
                return
            await asyncio.sleep(POLL_S)
        raise RuntimeError(f"simulated PLC did not listen on {self.host}:{self.port}")

    async def stop(self) -> None:
        await self.server.shutdown()
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task

    async def read(self, register: int, count: int = 1) -> list[int]:
        """Registers as the PLC program sees them (``register`` relative to ``base``)."""
        words = await self.server.context.async_getValues(self.unit, READ_FC, self.base + register, count)
        return list(words)  # type: ignore[arg-type]

    async def write(self, register: int, words: list[int]) -> None:
        await self.server.context.async_setValues(self.unit, WRITE_FC, self.base + register, words)


@dataclass
class LineTiming:
    part_interval_s: float = 0.2  # a part arrives this long after the last one left
    heartbeat_period_s: float = 0.5  # the PLC heartbeat changes this often
    wait_timeout_s: float = 30.0  # how long the line waits for READY / DONE before it gives up on the part


@dataclass
class LinePlc:
    """The line program over a :class:`PlcServer`; every finished part is passed to ``report``."""

    server: PlcServer
    timing: LineTiming = field(default_factory=LineTiming)
    word_order: WordOrder = "big"
    jobs: tuple[int, ...] = (1,)  # the job of each part, in turn (the part types the line brings)
    fault: str = "none"
    report: Callable[[dict[str, object]], None] = lambda record: None
    parts: int = 0
    grasp_wait_s: float | None = None  # give the grasp go after a good result and wait this long for the answer
    go: Callable[[dict[str, object]], None] = lambda part: None
    _grasp_answers: asyncio.Queue[dict[str, object]] = field(default_factory=asyncio.Queue)

    def grasped(self, outcome: dict[str, object]) -> None:
        """The robot's answer to the go (what it printed, passed back by sim-cell)."""
        self._grasp_answers.put_nowait(outcome)

    def command(self, fault: str) -> None:
        """Inject a fault (or ``none`` to clear it)."""
        if fault not in FAULTS:
            raise ValueError(f"fault {fault!r}: expected one of {', '.join(FAULTS)}")
        log.info("simulated PLC: fault %s", fault)
        self.fault = fault

    async def run(self, part_count: int | None = None, linger: bool = False) -> None:
        """Play parts (``part_count``: that many); ``linger``: then keep beating until cancelled."""
        heartbeat = asyncio.create_task(self.heartbeat())
        try:
            while part_count is None or self.parts < part_count:
                await asyncio.sleep(self.timing.part_interval_s)
                await self.play_part()
            if linger:
                await heartbeat
        finally:
            heartbeat.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await heartbeat

    async def play_part(self) -> dict[str, object]:
        """One part through the handshake; returns (and reports) what the line saw."""
        self.parts += 1
        tag = wrap_uint16(1000 + self.parts)
        job = self.jobs[(self.parts - 1) % len(self.jobs)]
        record: dict[str, object] = {"part": self.parts, "job": job, "part_tag": tag}
        await self._set(0, job=job, part_tag=tag)
        if not await self._wait_status(lambda s: Status.READY in s and not s & (Status.DONE | Status.FAULT)):
            return self._finish(record, "no READY")
        await self._set(Control.TRIGGER)
        if self.fault == "trigger-dropped-early":
            await self._wait_status(lambda s: Status.BUSY in s or Status.DONE in s)
            await self._set(0)
        if not await self._wait_status(lambda s: Status.DONE in s):
            await self._set(0)
            return self._finish(record, "no DONE")
        outputs = decode_outputs(await self.server.read(STATUS, BLOCK_SIZE - STATUS), self.word_order)
        record.update(_result_record(outputs))
        if self.fault == "no-ack":
            return self._finish(record, "not acknowledged")
        acknowledged = await self._acknowledge()
        record["grasp"] = await self._grasp(record) if acknowledged and record.get("result_ok") else None
        return self._finish(record, "acknowledged" if acknowledged else "DONE not cleared")

    async def heartbeat(self) -> None:
        """Change the PLC heartbeat every period (unless stopped by command); answer FAULT with FAULT_RESET."""
        while True:
            await asyncio.sleep(self.timing.heartbeat_period_s)
            if self.fault != "heartbeat-stopped":
                value = (await self.server.read(PLC_HEARTBEAT))[0]
                await self.server.write(PLC_HEARTBEAT, [wrap_uint16(value + 1)])
                status = Status((await self.server.read(STATUS))[0] & 0x3F)
                if Status.FAULT in status:  # the heartbeat runs again: pulse FAULT_RESET
                    control = (await self.server.read(CONTROL))[0]
                    await self.server.write(CONTROL, [control | Control.FAULT_RESET])
                    await asyncio.sleep(self.timing.heartbeat_period_s / 2)
                    await self.server.write(CONTROL, [(await self.server.read(CONTROL))[0] & ~Control.FAULT_RESET])

    # --- private ---------------------------------------------------------------------------------

    async def _set(self, control: int, job: int | None = None, part_tag: int | None = None) -> None:
        now = await self.server.read(CONTROL, INPUT_COUNT)
        words = encode_inputs(PlcInputs(Control(control), now[1] if job is None else job, now[PLC_HEARTBEAT],
                                        now[3] if part_tag is None else part_tag))
        await self.server.write(CONTROL, [words[0], words[1]])  # the heartbeat is the heartbeat task's
        await self.server.write(3, [words[3]])

    async def _acknowledge(self) -> bool:
        """RESULT_ACK with TRIGGER low until DONE, RESULT_OK and ERROR clear, then both low."""
        await self._set(Control.RESULT_ACK)
        cleared = await self._wait_status(lambda s: not s & (Status.DONE | Status.RESULT_OK | Status.ERROR))
        await self._set(0)
        return cleared

    async def _grasp(self, record: dict[str, object]) -> dict[str, object] | None:
        """The grasp go for the part just done, and the robot's answer (its program runs the grasp only with a valid
        offset); None when the line gives no go (no simulated robot)."""
        if self.grasp_wait_s is None:
            return None
        while not self._grasp_answers.empty():  # an answer from a go that timed out earlier
            self._grasp_answers.get_nowait()
        self.go({"part": record["part"], "part_tag": record["part_tag"]})
        try:
            return await asyncio.wait_for(self._grasp_answers.get(), self.grasp_wait_s)
        except TimeoutError:
            log.warning("simulated PLC: no answer to the grasp go of part %s within %g s", record["part"],
                        self.grasp_wait_s)
            return {"outcome": "no answer"}

    async def _wait_status(self, done: Callable[[Status], bool]) -> bool:
        deadline = asyncio.get_running_loop().time() + self.timing.wait_timeout_s
        while asyncio.get_running_loop().time() < deadline:
            if done(Status((await self.server.read(STATUS))[0] & 0x3F)):
                return True
            await asyncio.sleep(POLL_S)
        return False

    def _finish(self, record: dict[str, object], outcome: str) -> dict[str, object]:
        record["outcome"] = outcome
        record["fault"] = self.fault
        self.report(record)
        return record


def _result_record(outputs: PlcOutputs) -> dict[str, object]:
    r = outputs.result
    return {"status": int(outputs.status), "result_ok": Status.RESULT_OK in outputs.status,
            "error_code": r.error_code, "cycle_counter": r.cycle_counter, "echo_job": r.job,
            "echo_part_tag": r.part_tag, "offset_written": list(r.offset) if Status.RESULT_OK in outputs.status
            else None, "quality": list(r.quality)}


async def _serve(args: argparse.Namespace) -> None:
    server = PlcServer(args.host, args.port, args.unit, args.base)
    await server.start()
    loop = asyncio.get_running_loop()
    line = LinePlc(server, LineTiming(args.part_interval, args.heartbeat_period), args.word_order, args.jobs,
                   args.fault, lambda record: print(json.dumps(record), flush=True), grasp_wait_s=args.grasp_wait,
                   go=lambda part: print(f"{GRASP_GO} {json.dumps(part)}", flush=True))

    def read_commands() -> None:  # stdin in a thread: one fault command per line; end of input is fine
        for text in sys.stdin:
            if text.strip():
                loop.call_soon_threadsafe(_command, line, text.strip())

    threading.Thread(target=read_commands, daemon=True).start()
    stop = asyncio.Event()
    loop.add_signal_handler(signal.SIGTERM, stop.set)
    parent = os.getppid()  # noted before LISTEN: a parent that dies right after reading it is still noticed
    print(f"LISTEN plc {args.host}:{args.port}", flush=True)
    line_task = asyncio.create_task(line.run(args.parts, linger=True) if args.play else line.heartbeat())
    try:
        while not stop.is_set() and os.getppid() == parent:  # after --parts: served (and beating) until SIGTERM
            with contextlib.suppress(asyncio.TimeoutError):
                await asyncio.wait_for(stop.wait(), 0.2)
    finally:
        line_task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await line_task
        await server.stop()


def _command(line: LinePlc, text: str) -> None:
    if text.startswith(GRASP_ANSWER + " "):
        try:
            line.grasped(json.loads(text[len(GRASP_ANSWER) + 1:]))
        except ValueError as exc:
            print(f"error: {GRASP_ANSWER}: not JSON: {exc}", file=sys.stderr, flush=True)
        return
    try:
        line.command(text)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr, flush=True)


def _jobs(text: str) -> tuple[int, ...]:
    try:
        jobs = tuple(int(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected job numbers separated by commas, e.g. 1,2,2") from None
    if not jobs or not all(1 <= j <= 65535 for j in jobs):
        raise argparse.ArgumentTypeError(f"{text!r}: job numbers run from 1 to 65535")
    return jobs


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m monoguide.drivers.sim.plc", description=__doc__.split("\n")[0])
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--port", type=int, default=502)
    parser.add_argument("--unit", type=int, default=1)
    parser.add_argument("--base", type=int, default=0)
    parser.add_argument("--word-order", choices=("big", "little"), default="big")
    parser.add_argument("--jobs", type=_jobs, default=(1,), help="the job of each part, in turn (e.g. 1,2,2)")
    parser.add_argument("--fault", choices=FAULTS, default="none")
    parser.add_argument("--part-interval", type=float, default=0.2)
    parser.add_argument("--heartbeat-period", type=float, default=0.5)
    parser.add_argument("--parts", type=int, default=None, help="stop after this many parts (default: run on)")
    parser.add_argument("--grasp-wait", type=float, default=None,
                        help="give the grasp go after each good result, wait this long for the robot's answer")
    parser.add_argument("--no-play", dest="play", action="store_false",
                        help="serve the registers and beat the heartbeat, play no parts")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, stream=sys.stderr)
    with contextlib.suppress(KeyboardInterrupt):
        asyncio.run(_serve(args))


if __name__ == "__main__":
    main()
