"""The PLC adapter: Modbus TCP with the pymodbus asynchronous client (``docs/plc-interface.md``).

Three layers: pymodbus moves the requests; :mod:`monoguide.drivers.plc_registers` encodes the registers;
:class:`ModbusPlc` gives them their meaning (the port :class:`monoguide.drivers.plc.Plc`).

Every request has a deadline (``timeout_s``) and a typed failure naming the registers (relative and
absolute) and the unit: no answer -> :class:`DeviceTimeout`, no connection -> :class:`DeviceDisconnected`,
a Modbus exception response (illegal address, ...) -> :class:`DeviceProtocolError`.

Reconnection: pymodbus's client reconnects by itself unless told not to; this adapter tells it not to
(``reconnect_delay=0``, ``retries=0``) and never reconnects behind the cycle's back. A lost connection is
an error on the call that met it; the service decides when to call :meth:`ModbusPlc.connect` again (with
its backoff), and every connect writes a status word of 0 first. :meth:`ModbusPlc.close` closes for good.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Awaitable, Callable
from typing import Any

from pymodbus.client import AsyncModbusTcpClient
from pymodbus.exceptions import ConnectionException, ModbusException, ModbusIOException

from monoguide.drivers.errors import (
    DeviceDisconnected,
    DeviceError,
    DeviceProtocolError,
    DeviceRequestInvalid,
    DeviceTimeout,
)
from monoguide.drivers.plc_registers import (
    BLOCK_SIZE,
    CONTROL,
    HEARTBEAT,
    INPUT_COUNT,
    RESULT_FIRST,
    STATUS,
    CycleResult,
    PlcInputs,
    PlcOutputs,
    Status,
    WordOrder,
    decode_inputs,
    decode_outputs,
    encode_result,
    encode_status,
    wrap_uint16,
)

log = logging.getLogger(__name__)

READ_HOLDING_REGISTERS = "read"
WRITE_REGISTERS = "write"
# pymodbus's own timeout is the same deadline; ours is a backstop a little later, so pymodbus answers first
_BACKSTOP_S = 0.05


class ModbusPlc:
    """The line's PLC over Modbus TCP; satisfies :class:`monoguide.drivers.plc.Plc`."""

    def __init__(self, host: str, port: int = 502, unit: int = 1, base: int = 0, word_order: WordOrder = "big",
                 timeout_s: float = 1.0) -> None:
        if isinstance(base, bool) or not isinstance(base, int) or not 0 <= base <= 0x10000 - BLOCK_SIZE:
            raise DeviceRequestInvalid(f"PLC base {base!r}: the {BLOCK_SIZE} registers must fit in 0..65535")
        self.host, self.port, self.unit, self.base = host, port, unit, base
        self.word_order: WordOrder = word_order
        self.timeout_s = timeout_s
        self._heartbeat = 0
        self._client: AsyncModbusTcpClient | None = None

    @property
    def address(self) -> str:
        return f"{self.host}:{self.port} unit {self.unit}"

    async def connect(self) -> None:
        """Connect within ``timeout_s`` and write a status word of 0 (before anything else)."""
        await self.close()
        client = AsyncModbusTcpClient(self.host, port=self.port, timeout=self.timeout_s, retries=0,
                                      reconnect_delay=0, reconnect_delay_max=0, name=f"plc {self.address}")
        self._client = client
        try:
            connected = await asyncio.wait_for(client.connect(), self.timeout_s + _BACKSTOP_S)
        except (TimeoutError, OSError, ModbusException) as exc:
            connected = False
            log.debug("PLC %s: connect failed: %r", self.address, exc)
        if not connected:
            await self.close()
            raise DeviceDisconnected(f"PLC {self.address}: cannot connect within {self.timeout_s:g} s")
        try:
            await self.write_status(Status(0))
            self._heartbeat = (await self._read(HEARTBEAT, 1))[0]  # continue the count from what the PLC shows
        except DeviceError:
            await self.close()
            raise
        log.info("PLC %s: connected, status word cleared", self.address)

    async def read_inputs(self) -> PlcInputs:
        return decode_inputs(await self._read(CONTROL, INPUT_COUNT))

    async def write_status(self, status: Status) -> None:
        await self._write(STATUS, [encode_status(status)])

    async def write_result(self, result: CycleResult) -> None:
        await self._write(RESULT_FIRST, encode_result(result, self._heartbeat, self.word_order))

    async def beat(self) -> int:
        value = wrap_uint16(self._heartbeat + 1)
        await self._write(HEARTBEAT, [value])
        self._heartbeat = value
        return value

    async def read_outputs(self) -> PlcOutputs:
        return decode_outputs(await self._read(STATUS, BLOCK_SIZE - STATUS), self.word_order)

    async def close(self) -> None:
        client, self._client = self._client, None
        if client is not None:
            client.close()

    # --- private ---------------------------------------------------------------------------------

    async def _read(self, register: int, count: int) -> list[int]:
        response = await self._call(READ_HOLDING_REGISTERS, register, count, lambda c: c.read_holding_registers(
            self.base + register, count=count, device_id=self.unit))
        words = list(response.registers)
        if len(words) != count:
            raise DeviceProtocolError(f"PLC {self.address}: read of {self._span(register, count)} answered "
                                      f"{len(words)} registers")
        return words

    async def _write(self, register: int, words: list[int]) -> None:
        await self._call(WRITE_REGISTERS, register, len(words), lambda c: c.write_registers(
            self.base + register, words, device_id=self.unit))

    async def _call(self, what: str, register: int, count: int,
                    request: Callable[[AsyncModbusTcpClient], Awaitable[Any]]) -> Any:
        span = self._span(register, count)
        client = self._client
        if client is None or not client.connected:
            raise DeviceDisconnected(f"PLC {self.address}: not connected ({what} of {span})")
        try:
            response = await asyncio.wait_for(request(client), self.timeout_s + _BACKSTOP_S)
        except (TimeoutError, ModbusIOException) as exc:
            if not client.connected:
                raise DeviceDisconnected(f"PLC {self.address}: connection lost during {what} of {span}") from exc
            raise DeviceTimeout(f"PLC {self.address}: no answer to {what} of {span} within {self.timeout_s:g} s")\
                from exc
        except (ConnectionException, OSError) as exc:
            raise DeviceDisconnected(f"PLC {self.address}: connection lost during {what} of {span}: {exc}") from exc
        except ModbusException as exc:
            raise DeviceProtocolError(f"PLC {self.address}: {what} of {span} failed: {exc}") from exc
        if response.isError():
            code = getattr(response, "exception_code", "?")
            raise DeviceProtocolError(f"PLC {self.address}: {what} of {span} refused with Modbus exception "
                                      f"{code} ({_EXCEPTION_TEXT.get(code, 'unknown')})")
        return response

    def _span(self, register: int, count: int) -> str:
        last = register + count - 1
        relative = f"register {register}" if count == 1 else f"registers {register}-{last}"
        return f"{relative} (absolute {self.base + register}{'' if count == 1 else f'-{self.base + last}'})"


_EXCEPTION_TEXT = {1: "illegal function", 2: "illegal data address", 3: "illegal data value",
                   4: "server device failure", 6: "server device busy", 10: "gateway path unavailable",
                   11: "gateway target device failed to respond"}
