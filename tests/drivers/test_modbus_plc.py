"""The pymodbus async client adapter against the simulated PLC's pymodbus server over TCP, each test on its own
127.0.0.x address; the PLC program and a PLC process that disappears or freezes."""

from __future__ import annotations

import asyncio
import itertools
import json
import os
import re
import select
import signal
import struct
import subprocess
import sys
import time
from collections.abc import Awaitable, Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from monoguide.daemon.config import load_cell_config
from monoguide.daemon.errors import ConfigError, ConfigMissingKey
from monoguide.drivers.errors import (
    DeviceDisconnected,
    DeviceProtocolError,
    DeviceRequestInvalid,
    DeviceTimeout,
    PlcHeartbeatLost,
    PlcValueInvalid,
)
from monoguide.drivers.modbus_plc import ModbusPlc
from monoguide.drivers.plc import HeartbeatWatch, Plc
from monoguide.drivers.plc_registers import (
    BLOCK_SIZE,
    ERROR_CODE,
    HEARTBEAT,
    OFFSET,
    STATUS,
    CycleResult,
    Status,
)
from monoguide.drivers.sim.plc import LinePlc, LineTiming, PlcServer

SIM_CELL = Path(__file__).parents[2] / "config" / "sim-cell.toml"
PORT = 15020
TIMEOUT_S = 0.5
_addresses = itertools.count(150)


def next_host() -> str:
    return f"127.0.27.{next(_addresses)}"


def run(coro_fn: Callable[..., Awaitable[Any]], *args: Any, limit_s: float = 10.0) -> Any:
    return asyncio.run(asyncio.wait_for(coro_fn(*args), limit_s))


async def served(test: Callable[[PlcServer, ModbusPlc], Awaitable[None]], unit: int = 1, base: int = 0,
                 word_order: str = "big", client_base: int | None = None, client_unit: int | None = None) -> None:
    host = next_host()
    server = PlcServer(host, PORT, unit, base)
    await server.start()
    plc = ModbusPlc(host, PORT, unit if client_unit is None else client_unit,
                    base if client_base is None else client_base, word_order, TIMEOUT_S)  # type: ignore[arg-type]
    try:
        await test(server, plc)
    finally:
        await plc.close()
        await server.stop()


def _float_words(value: float, word_order: str) -> list[int]:
    high, low = struct.unpack(">HH", struct.pack(">f", value))
    return [high, low] if word_order == "big" else [low, high]


# --- the adapter -------------------------------------------------------------------------------


def test_satisfies_the_port() -> None:
    assert isinstance(ModbusPlc("127.0.0.1"), Plc)


def test_connect_clears_a_stale_done_first() -> None:
    async def test(server: PlcServer, plc: ModbusPlc) -> None:
        await server.write(STATUS, [int(Status.DONE | Status.RESULT_OK), 0, 41])  # from before a crash
        await plc.connect()
        assert await server.read(STATUS) == [0]
        assert await plc.beat() == 42  # the heartbeat continues from what the PLC shows
        assert await server.read(HEARTBEAT) == [42]

    run(served, test)


@pytest.mark.parametrize("word_order", ["big", "little"])
def test_round_trip_of_every_register(word_order: str) -> None:
    base, unit = 1000, 3
    offset = (12.5, -48.123, 3.0625, 1.25, -4.9, 0.001)
    quality = (0.085, 0.04, 0.0031)

    async def test(server: PlcServer, plc: ModbusPlc) -> None:
        await server.write(4, [0xAAAA] * 6)  # registers 4-9 belong to nobody: must stay untouched
        await plc.connect()
        await server.write(0, [0b011, 2, 65535, 4711])  # what the PLC writes
        inputs = await plc.read_inputs()
        assert (inputs.trigger, inputs.result_ack, inputs.fault_reset) == (True, True, False)
        assert (inputs.job, inputs.plc_heartbeat, inputs.part_tag) == (2, 65535, 4711)
        assert await plc.beat() == 1
        await plc.write_status(Status.BUSY)
        await plc.write_result(CycleResult(0, 65535, 2, 4711, offset, quality))
        # the result arrives before the status word changes: BUSY still stands
        assert await server.read(STATUS) == [int(Status.BUSY)]
        await plc.write_status(Status.DONE | Status.RESULT_OK)
        block = await server.read(0, BLOCK_SIZE)
        expected = [w for v in (*offset, *quality) for w in _float_words(v, word_order)]
        assert block[STATUS:OFFSET] == [12, 0, 1, 65535, 2, 4711]
        assert block[OFFSET:] == expected
        assert block[4:10] == [0xAAAA] * 6
        outputs = await plc.read_outputs()
        assert outputs.result.offset == struct.unpack(">6f", struct.pack(">6f", *offset))
        assert outputs.result.quality == struct.unpack(">3f", struct.pack(">3f", *quality))
        await server.write(0, [0, 0, 0, 0])
        assert not (await plc.read_inputs()).trigger

    run(served, test, unit, base, word_order)


def test_a_float_the_plc_packed_is_read_in_the_configured_word_order() -> None:
    async def test(server: PlcServer, plc: ModbusPlc) -> None:
        await plc.connect()
        await server.write(OFFSET, _float_words(-1.75, "little"))  # 0xBFE00000 as low word, high word
        assert (await plc.read_outputs()).result.offset[0] == -1.75

    run(served, test, 1, 0, "little")


def test_heartbeat_wraps_and_is_kept_by_the_result_write() -> None:
    async def test(server: PlcServer, plc: ModbusPlc) -> None:
        await server.write(HEARTBEAT, [65535])
        await plc.connect()
        assert await plc.beat() == 0
        await plc.write_result(CycleResult(451, 7, 1, 9))
        assert await server.read(ERROR_CODE, 3) == [451, 0, 7]

    run(served, test)


def test_bad_control_word_from_the_plc_is_a_typed_error() -> None:
    async def test(server: PlcServer, plc: ModbusPlc) -> None:
        await plc.connect()
        await server.write(0, [0x0011, 1, 0, 0])
        with pytest.raises(PlcValueInvalid, match=r"register 0 \(control word\) = 0x0011"):
            await plc.read_inputs()
        await server.write(OFFSET + 4, [0x7F80, 0x0000])  # +inf
        with pytest.raises(PlcValueInvalid, match=r"registers 20-21 \(offset z_mm\)"):
            await plc.read_outputs()

    run(served, test)


def test_registers_missing_at_the_base_is_a_protocol_error_naming_them() -> None:
    async def test(server: PlcServer, plc: ModbusPlc) -> None:
        with pytest.raises(DeviceProtocolError, match=r"unit 1: write of register 10 \(absolute 50\).*illegal data "
                                                      r"address"):
            await plc.connect()

    run(served, test, 1, 0, "big", 40)


def test_wrong_unit_is_a_protocol_error_naming_the_unit() -> None:
    async def test(server: PlcServer, plc: ModbusPlc) -> None:
        with pytest.raises(DeviceProtocolError, match="unit 9"):
            await plc.connect()
        with pytest.raises(DeviceDisconnected, match="not connected"):  # a failed connect leaves nothing open
            await plc.read_inputs()

    run(served, test, 1, 0, "big", None, 9)


@pytest.mark.parametrize("base", [-1, 65503, 1.5])
def test_a_block_that_cannot_fit_is_refused(base: object) -> None:
    with pytest.raises(DeviceRequestInvalid, match=f"PLC base {base!r}"):
        ModbusPlc("127.0.0.1", base=base)  # type: ignore[arg-type]


def test_no_plc_there() -> None:
    async def test() -> None:
        plc = ModbusPlc(next_host(), PORT, timeout_s=TIMEOUT_S)
        start = time.monotonic()
        with pytest.raises(DeviceDisconnected, match=r"cannot connect within 0.5 s"):
            await plc.connect()
        assert time.monotonic() - start < TIMEOUT_S + 0.5
        with pytest.raises(DeviceDisconnected, match="not connected"):
            await plc.read_inputs()

    run(test)


# --- a PLC in its own process that disappears or freezes -------------------------------------


@pytest.fixture
def plc_process() -> Iterator[tuple[subprocess.Popen[str], str]]:
    host = next_host()
    process = subprocess.Popen([sys.executable, "-m", "monoguide.drivers.sim.plc", "--host", host, "--port",
                                str(PORT), "--heartbeat-period", "0.1", "--no-play"],
                               stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert process.stdout is not None
        ready, _, _ = select.select([process.stdout], [], [], 15.0)
        assert ready and process.stdout.readline().split() == ["LISTEN", "plc", f"{host}:{PORT}"]
        yield process, host
    finally:
        if process.poll() is None:
            os.kill(process.pid, signal.SIGCONT)
            process.kill()
        process.wait(5)
        for pipe in (process.stdin, process.stdout):
            if pipe is not None:
                pipe.close()


@pytest.mark.parametrize("how", ["killed", "frozen"])
def test_a_plc_that_disappears_gives_a_typed_error_within_the_timeout(
        plc_process: tuple[subprocess.Popen[str], str], how: str) -> None:
    process, host = plc_process

    async def test() -> None:
        plc = ModbusPlc(host, PORT, timeout_s=TIMEOUT_S)
        await plc.connect()
        await plc.read_inputs()
        os.kill(process.pid, signal.SIGKILL if how == "killed" else signal.SIGSTOP)
        if how == "killed":
            process.wait(5)
        start = time.monotonic()
        expected = DeviceTimeout if how == "frozen" else (DeviceDisconnected, DeviceTimeout)
        with pytest.raises(expected, match=rf"PLC {host}:{PORT} unit 1: .*registers 0-3"):  # type: ignore[arg-type]
            await plc.read_inputs()
        assert time.monotonic() - start < TIMEOUT_S + 0.3
        await plc.close()

    run(test)


def test_the_process_takes_fault_commands_on_stdin(plc_process: tuple[subprocess.Popen[str], str]) -> None:
    """--no-play still beats the heartbeat; ``heartbeat-stopped`` on stdin stops it."""
    process, host = plc_process

    async def test() -> None:
        plc = ModbusPlc(host, PORT, timeout_s=TIMEOUT_S)
        await plc.connect()
        watch = HeartbeatWatch(0.4)
        for _ in range(8):
            watch.observe((await plc.read_inputs()).plc_heartbeat, time.monotonic())
            await asyncio.sleep(0.05)
        watch.check(time.monotonic())  # beating
        assert process.stdin is not None
        process.stdin.write("heartbeat-stopped\n")
        process.stdin.flush()
        with pytest.raises(PlcHeartbeatLost):
            for _ in range(40):
                watch.observe((await plc.read_inputs()).plc_heartbeat, time.monotonic())
                watch.check(time.monotonic())
                await asyncio.sleep(0.05)
        await plc.close()

    run(test)


# --- the line program --------------------------------------------------------------------------


async def _monoguide_side(plc: ModbusPlc, result: CycleResult, limit_s: float = 5.0) -> list[str]:
    """A minimal stand-in for the cycle (issue 10's state machine comes later): READY, wait TRIGGER, BUSY,
    result then DONE, wait RESULT_ACK with TRIGGER low, clear, wait both low, READY. Returns what it saw."""
    seen: list[str] = []

    async def until(condition: Callable[[Any], bool], what: str) -> bool:
        deadline = time.monotonic() + limit_s
        while time.monotonic() < deadline:
            inputs = await plc.read_inputs()
            if condition(inputs):
                seen.append(what)
                return True
            await asyncio.sleep(0.01)
        seen.append(f"no {what}")
        return False

    await plc.write_status(Status.READY)
    await until(lambda i: i.trigger, "trigger")
    await plc.write_status(Status.BUSY)
    await asyncio.sleep(0.1)  # measuring
    if not (await plc.read_inputs()).trigger:
        seen.append("trigger dropped while busy")
        result = CycleResult(453, result.cycle_counter, result.job, result.part_tag)
        await plc.write_result(result)
        await plc.write_status(Status.DONE | Status.ERROR)
    else:
        await plc.write_result(result)
        await plc.write_status(Status.DONE | Status.RESULT_OK)
    if await until(lambda i: i.result_ack and not i.trigger, "ack"):
        await plc.write_status(Status(0))
        await until(lambda i: not i.trigger and not i.result_ack, "both low")
        await plc.write_status(Status.READY)
    return seen


@pytest.mark.parametrize("fault", ["none", "trigger-dropped-early", "no-ack"])
def test_the_line_plays_a_cycle(fault: str) -> None:
    result = CycleResult(0, 1, 1, 1001, (1.0, 2.0, 3.0, 0.5, -0.25, 0.125), (0.1, 0.02, 0.003))
    records: list[dict[str, object]] = []

    async def test(server: PlcServer, plc: ModbusPlc) -> None:
        line = LinePlc(server, LineTiming(0.01, 0.1, 1.0), fault=fault, report=records.append)
        await plc.connect()
        line_task = asyncio.create_task(line.run(1))
        seen = await _monoguide_side(plc, result, limit_s=1.5)
        await line_task
        if fault == "none":
            assert seen == ["trigger", "ack", "both low"]
            assert records[0]["outcome"] == "acknowledged" and records[0]["result_ok"]
            assert records[0]["offset_written"] == list(result.offset)  # exact in float32
            assert (records[0]["echo_job"], records[0]["echo_part_tag"]) == (1, 1001)
            assert await server.read(STATUS) == [int(Status.READY)]
        elif fault == "trigger-dropped-early":
            assert seen[:2] == ["trigger", "trigger dropped while busy"]
            assert records[0]["error_code"] == 453 and records[0]["offset_written"] is None
        else:
            assert seen == ["trigger", "no ack"]
            assert records[0]["outcome"] == "not acknowledged"
            assert Status.DONE in Status((await server.read(STATUS))[0])
        json.dumps(records)  # what the process prints, one line per part

    run(served, test)


def test_the_line_answers_fault_with_a_fault_reset_pulse_once_its_heartbeat_runs() -> None:
    async def test(server: PlcServer, plc: ModbusPlc) -> None:
        line = LinePlc(server, LineTiming(0.01, 0.05, 1.0), fault="heartbeat-stopped")
        beating = asyncio.create_task(line.heartbeat())
        await plc.connect()
        await plc.write_status(Status.FAULT)
        await asyncio.sleep(0.2)
        assert not (await plc.read_inputs()).fault_reset and (await plc.read_inputs()).plc_heartbeat == 0
        line.command("none")
        pulses = []
        for _ in range(60):
            pulses.append((await plc.read_inputs()).fault_reset)
            await asyncio.sleep(0.01)
        assert True in pulses and False in pulses[pulses.index(True):]  # a pulse: set, then cleared
        assert (await plc.read_inputs()).plc_heartbeat > 0
        beating.cancel()
        with pytest.raises(ValueError, match="'smoke'"):
            line.command("smoke")

    run(served, test)


def test_the_process_plays_a_part_and_prints_it() -> None:
    host = next_host()
    process = subprocess.Popen([sys.executable, "-m", "monoguide.drivers.sim.plc", "--host", host, "--port",
                                str(PORT), "--part-interval", "0.01", "--parts", "1", "--job", "1"],
                               stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    result = CycleResult(0, 5, 1, 1001, (-7.5, 0.25, 1.0, 0.0, 0.5, -2.0), (0.1, 0.02, 0.003))
    try:
        assert process.stdout is not None
        assert process.stdout.readline().split() == ["LISTEN", "plc", f"{host}:{PORT}"]

        async def test() -> list[str]:
            plc = ModbusPlc(host, PORT, timeout_s=TIMEOUT_S)
            await plc.connect()
            try:
                return await _monoguide_side(plc, result, limit_s=3.0)
            finally:
                await plc.close()

        assert run(test) == ["trigger", "ack", "both low"]
        record = json.loads(process.stdout.readline())
        assert record["outcome"] == "acknowledged" and record["offset_written"] == list(result.offset)
        assert (record["part"], record["echo_part_tag"], record["cycle_counter"]) == (1, 1001, 5)
        process.terminate()
        assert process.wait(5) == 0
        assert "deprecated" not in (process.stderr.read() if process.stderr else "")
    finally:
        if process.poll() is None:
            process.kill()
            process.wait(5)
        for pipe in (process.stdout, process.stderr):
            if pipe is not None:
                pipe.close()


# --- the [plc] table ---------------------------------------------------------------------------


def _cell_with_plc(tmp_path: Path, table: str) -> Path:
    """The simulated cell with its ``[plc]`` table replaced by ``table``."""
    path = tmp_path / "cell.toml"
    without = re.sub(r"^\[plc\].*?(?=^\[)", "", SIM_CELL.read_text(), count=1, flags=re.S | re.M)
    assert "[plc]" not in without
    path.write_text(without + f"\n[plc]\n{table}")
    return path


def test_the_simulated_cell_names_its_plc() -> None:
    plc = load_cell_config(SIM_CELL).plc
    assert plc is not None and (plc.host, plc.port, plc.unit, plc.base, plc.word_order) == \
        ("127.0.0.1", 5020, 1, 0, "big")


def test_plc_table_defaults(tmp_path: Path) -> None:
    plc = load_cell_config(_cell_with_plc(tmp_path, 'host = "10.0.0.5"\n')).plc
    assert plc is not None
    assert (plc.host, plc.port, plc.unit, plc.base, plc.word_order, plc.heartbeat_timeout_s, plc.timeout_s,
            plc.ack_timeout_s) == \
        ("10.0.0.5", 502, 1, 0, "big", 2.0, 1.0, 10.0)
    plc = load_cell_config(_cell_with_plc(tmp_path, 'host = "h"\nport = 1502\nunit = 3\nbase = 400\n'
                                                    'word_order = "little"\nheartbeat_timeout_s = 1.5\n')).plc
    assert plc is not None and (plc.port, plc.unit, plc.base, plc.word_order, plc.heartbeat_timeout_s) == \
        (1502, 3, 400, "little", 1.5)


@pytest.mark.parametrize(("table", "error", "says"), [
    ("port = 502\n", ConfigMissingKey, "plc.*host"),
    ('host = "h"\nword_order = "middle"\n', ConfigError, r"word_order = 'middle'"),
    ('host = "h"\nunit = 300\n', ConfigError, r"unit = 300"),
    ('host = "h"\nbase = 65530\n', ConfigError, r"base = 65530"),
    ('host = "h"\nheartbeat_timeout_s = 0\n', ConfigError, r"heartbeat_timeout_s"),
    ('host = "h"\nheartbeat_timeout = 2\n', ConfigError, r"heartbeat_timeout"),
])
def test_plc_table_errors_name_the_key(tmp_path: Path, table: str, error: type[Exception], says: str) -> None:
    with pytest.raises(error, match=says):
        load_cell_config(_cell_with_plc(tmp_path, table))
