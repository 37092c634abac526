"""The PLC port: what the cycle needs of the line's PLC, in the cell's words (``docs/plc-interface.md``).

The PLC is the Modbus server, monoguide the client. The cycle reads the PLC's four registers (control
word, job, PLC heartbeat, part tag), writes its status word, increments its own heartbeat every
:data:`HEARTBEAT_PERIOD_S`, and at the end of a cycle writes the result registers first and the status
word after them, in a separate write, so that a PLC seeing DONE always reads a complete result.
:meth:`Plc.connect` writes a status word of 0 before anything else, so that after a crash the PLC never
sees a DONE from before it. The port is asynchronous: the service runs on asyncio and so does pymodbus.

Meaning shared by every adapter (the heartbeat watch, the base offset as six register values) lives here
too; encoding is in :mod:`monoguide.drivers.plc_registers`.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

from monoguide.drivers.errors import PlcHeartbeatLost
from monoguide.drivers.plc_registers import PLC_HEARTBEAT, CycleResult, PlcInputs, PlcOutputs, Status
from monoguide.solver.frames import T_to_kuka_frame, check_transform

HEARTBEAT_PERIOD_S = 0.5  # monoguide's heartbeat (register 12) while the service is healthy


@runtime_checkable
class Plc(Protocol):
    """What the cycle and the service need from the line's PLC."""

    @property
    def address(self) -> str:
        """Where the PLC is reached (``"192.168.0.10:502 unit 1"``), for messages."""
        ...

    async def connect(self) -> None:
        """Connect, then write a status word of 0 before anything else."""
        ...

    async def read_inputs(self) -> PlcInputs:
        """Registers 0-3 in one read: control word, job number, PLC heartbeat, part tag (validated)."""
        ...

    async def write_status(self, status: Status) -> None:
        """The status word (register 10), alone in its own write."""
        ...

    async def write_result(self, result: CycleResult) -> None:
        """Registers 11, 13-33 (error code, cycle counter, echoes, offset, quality) in one write; the status
        word is written after it by :meth:`write_status`."""
        ...

    async def beat(self) -> int:
        """Increment monoguide's heartbeat (register 12, wrapping 65535 -> 0); returns the value written."""
        ...

    async def read_outputs(self) -> PlcOutputs:
        """Registers 10-33 as the PLC sees them (status display, the cycle counter after a restart)."""
        ...

    async def close(self) -> None:
        """Close the connection for good (no reconnection afterwards)."""
        ...


class HeartbeatWatch:
    """Watches the PLC heartbeat (register 2): it must change at least once per ``timeout_s``.

    Feed it every value read with the monotonic time of the read; :meth:`check` raises
    :class:`PlcHeartbeatLost` once the value has stood still for longer than ``timeout_s``. The clock is
    passed in, so the watch is testable without waiting.
    """

    def __init__(self, timeout_s: float) -> None:
        if not timeout_s > 0:
            raise ValueError(f"heartbeat timeout {timeout_s!r} must be > 0")
        self.timeout_s = timeout_s
        self._value: int | None = None
        self._changed_at = 0.0

    def observe(self, value: int, now_s: float) -> None:
        if value != self._value:
            self._value, self._changed_at = value, now_s

    def check(self, now_s: float) -> None:
        """Raise :class:`PlcHeartbeatLost` when the heartbeat has not changed for ``timeout_s``."""
        if self._value is not None and now_s - self._changed_at > self.timeout_s:
            raise PlcHeartbeatLost(f"register {PLC_HEARTBEAT} (PLC heartbeat) stood at {self._value} for "
                                   f"{now_s - self._changed_at:.2f} s (timeout {self.timeout_s:g} s)")

    def alive(self, now_s: float) -> bool:
        return self._value is not None and now_s - self._changed_at <= self.timeout_s


def offset_registers(D_b: np.ndarray) -> tuple[float, float, float, float, float, float]:
    """The base offset ``D_b`` (4, 4, mm, robot base frame) as registers 16-27: x, y, z mm and A, B, C deg
    (KUKA Z-Y'-X'': ``R = Rz(A) Ry(B) Rx(C)``)."""
    D_b = check_transform(D_b, "base offset D_b")
    return T_to_kuka_frame(D_b)
