"""The line's PLC as the service holds it: what it is shown in each state, its control word read with latched
edges, the connection kept with backoff (docs/plc-interface.md).

The contract — which status bits belong to which state — is one short function (:func:`status_word`) that
docs/plc-interface.md can be checked against. :class:`PlcLink` owns the connection: every (re)connect writes a
status word of 0 first, then the shown result; each read of registers 0-3 also beats monoguide's heartbeat
every :data:`HEARTBEAT_PERIOD_S` and rewrites the status word every :data:`STATUS_REFRESH_S` even unchanged.
:class:`ControlLatch` keeps what was seen of the control word between reads, so that a TRIGGER low shorter than
a poll is not lost once seen and an acknowledgement completes however the PLC orders its writes.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from monoguide.daemon.cycle import CYCLE_STATES, State
from monoguide.daemon.service._devices import BACKOFF_S
from monoguide.daemon.service._journal import Journal
from monoguide.drivers.errors import DeviceError
from monoguide.drivers.plc import HEARTBEAT_PERIOD_S, HeartbeatWatch, Plc
from monoguide.drivers.plc_registers import Control, CycleResult, PlcInputs, Status
from monoguide.solver.errors import MonoguideError

log = logging.getLogger(__name__)

POLL_S = 0.02  # the PLC's registers 0-3 are read this often
STATUS_REFRESH_S = 1.0  # the status word is rewritten this often even unchanged (nobody else may hold it wrong)
ZERO_OFFSET = (0.0,) * 6
ZERO_QUALITY = (0.0,) * 3


def status_word(state: State, outcome_ok: bool | None, acknowledged: bool,
                calibration_warning: bool = False, stopping: bool = False) -> Status:
    """The status word (register 10) shown in ``state``, with CALIBRATION_WARNING while ``calibration_warning``
    (in every state but STARTING and STOPPED).

    ``outcome_ok``: in AWAITING_ACK, whether the cycle's offset was written (RESULT_OK) or not (ERROR);
    ``acknowledged``: RESULT_ACK was seen, DONE/RESULT_OK/ERROR are cleared while TRIGGER and RESULT_ACK
    fall (READY follows once both are low). ``stopping``: the service is stopping (SIGTERM): never READY.
    """
    word = _state_word(state, outcome_ok, acknowledged)
    if stopping:
        word &= ~Status.READY
    if calibration_warning and state not in (State.STARTING, State.STOPPED):
        word |= Status.CALIBRATION_WARNING
    return word


def _state_word(state: State, outcome_ok: bool | None, acknowledged: bool) -> Status:
    if state is State.IDLE:
        return Status.READY
    if state in CYCLE_STATES or state is State.REPORTING:
        return Status.BUSY
    if state is State.AWAITING_ACK:
        if acknowledged:
            return Status(0)
        return Status.DONE | (Status.RESULT_OK if outcome_ok else Status.ERROR)
    if state is State.FAULT:
        return Status.FAULT
    return Status(0)  # STARTING, STOPPED: neither READY nor BUSY


def failed_result(plc_code: int, counter: int, job: int, part_tag: int,
                  quality: tuple[float, float, float] = ZERO_QUALITY) -> CycleResult:
    """The result registers of a cycle that wrote nothing to the robot: offset 0, the error's code."""
    return CycleResult(plc_code, counter, job, part_tag, ZERO_OFFSET, quality)


@dataclass
class Shown:
    """What the cell shows of its last cycle: the result registers (11, 13-33) and the outcome bits of DONE, and
    the summary the status file and ``STATUS=`` give. Written by the cycle's report, read by the loop."""

    result: CycleResult
    last_result: dict[str, Any] | None = None
    outcome_ok: bool | None = None  # DONE with RESULT_OK (True) or ERROR (False)
    acknowledged: bool = False  # RESULT_ACK seen: DONE and its bits are cleared
    calibration_warning: bool = False  # the status word's CALIBRATION_WARNING (CalibrationHealth.warning)
    done_at: float = 0.0  # time.monotonic() of DONE
    finished: int = 0  # cycles journaled by this run

    @classmethod
    def from_journal(cls, journal: Journal) -> Shown:
        """At start: the journal's last cycle, with no error code (the PLC learns no stale error)."""
        last = journal.last_cycles(1)
        job, tag = (last[0].job or 0, last[0].part_tag or 0) if last else (0, 0)
        return cls(failed_result(0, journal.cycle_counter(), job, tag), summary(last[0]) if last else None)

    def new_cycle(self) -> None:
        self.outcome_ok, self.acknowledged = None, False


def summary(row: Any) -> dict[str, Any]:
    """A journal row as the status file's ``last_result``."""
    part = row.record.get("part") if isinstance(row.record, dict) else None
    return {"cycle": row.number, "status": row.status, "job": row.job, "part": part, "part_tag": row.part_tag,
            "error_code": row.error_code, "finished_at": row.finished_at}


@dataclass
class ControlLatch:
    """The control word (register 0) as the cycle needs it, over many reads.

    TRIGGER starts a cycle when it is high and has been seen low since the last start (a rising edge, or a short
    low seen in between: latched); one held across a (re)connection is not a new one. After DONE, the
    acknowledgement is complete once RESULT_ACK was seen and then TRIGGER and RESULT_ACK were each seen low.
    """

    previous: Control = field(default_factory=lambda: Control(0))
    trigger_armed: bool = False
    trigger_low_since_ack: bool = False
    ack_low_since_ack: bool = False

    def connected(self, control: Control) -> None:
        self.previous = control
        self.trigger_armed = Control.TRIGGER not in control

    def read(self, control: Control) -> Control:
        """A new read; returns the bits that rose since the last one."""
        rising = Control(control & ~self.previous)
        self.previous = control
        return rising

    def take_trigger(self, control: Control) -> bool:
        """Whether TRIGGER is a new one (consumed: the next high TRIGGER needs a low first)."""
        new = Control.TRIGGER in control and self.trigger_armed
        if new:
            self.trigger_armed = False
        return new

    def saw(self, control: Control) -> None:
        """After the read was acted on: a low TRIGGER arms the next one."""
        if Control.TRIGGER not in control:
            self.trigger_armed = True

    def acknowledging(self, control: Control) -> None:
        """RESULT_ACK was first seen (DONE shown): start watching both bits fall."""
        self.trigger_low_since_ack = Control.TRIGGER not in control
        self.ack_low_since_ack = Control.RESULT_ACK not in control

    def acknowledged(self, control: Control) -> bool:
        self.trigger_low_since_ack |= Control.TRIGGER not in control
        self.ack_low_since_ack |= Control.RESULT_ACK not in control
        if self.trigger_low_since_ack and self.ack_low_since_ack:
            self.trigger_armed = True  # seen low since DONE
            return True
        return False


class PlcLink:
    """The PLC's connection: connect with backoff (status word 0 first), read, beat, show, lose it."""

    def __init__(self, plc: Plc, journal: Journal, heartbeat_timeout_s: float) -> None:
        self.plc, self.journal = plc, journal
        self.watch = HeartbeatWatch(heartbeat_timeout_s)
        self.latch = ControlLatch()
        self.connected, self.attempts, self.next_try = False, 0, 0.0
        self.error: MonoguideError | None = None
        self.word: Status | None = None  # the status word last written (None: unknown, rewrite it)
        self.fault_shown: MonoguideError | None = None  # the fault whose code register 11 shows
        self.numbering_checked = False  # a new journal continues after the PLC's register 13 (first connect)
        self._next_beat = self._next_refresh = 0.0
        self.inputs: PlcInputs | None = None  # registers 0-3 as last read
        self.heartbeat: int | None = None  # register 12 as last written

    @property
    def address(self) -> str:
        return self.plc.address

    async def connect(self, now: float, shown: Shown, result: Callable[[], CycleResult]) -> bool:
        """One attempt when its time has come: status word 0, the result registers (``result()``: as they must
        show now, the journal's numbering continued first), the control word."""
        if now < self.next_try:
            return False
        try:
            await self.plc.connect()  # writes status word 0 before anything else
            if not self.numbering_checked:
                await self._continue_numbering(shown)
            await self.plc.write_result(result())
            inputs = await self.plc.read_inputs()  # a trigger held across a (re)connection is not a new one
        except DeviceError as exc:
            self.attempts += 1
            delay = BACKOFF_S[min(self.attempts, len(BACKOFF_S)) - 1]
            self.error, self.next_try = exc, now + delay
            log.warning("PLC: cannot connect (%s %s); reconnecting in %g s", exc.code, exc.message, delay)
            with contextlib.suppress(DeviceError):
                await self.plc.close()
            return False
        self.connected, self.attempts, self.error = True, 0, None
        self.word, self._next_beat, self.inputs = Status(0), now, inputs
        self.latch.connected(inputs.control)
        return True

    def registers(self) -> dict[str, Any] | None:
        """What the PLC and monoguide show each other now (the status file's ``plc``): the control word's bits,
        job, PLC heartbeat and part tag as last read (registers 0-3), the status word's bits and monoguide's
        heartbeat as last written (10, 12); None while not connected."""
        if not self.connected or self.inputs is None:
            return None
        i = self.inputs
        return {"control": _bits(Control, int(i.control)), "job": i.job, "plc_heartbeat": i.plc_heartbeat,
                "part_tag": i.part_tag, "status": _bits(Status, int(self.word or 0)), "heartbeat": self.heartbeat}

    async def read(self, now: float) -> PlcInputs:
        """Registers 0-3; the heartbeat and the status word's refresh when due. A :class:`DeviceError` when the
        connection is gone (the caller calls :meth:`lost`)."""
        inputs = self.inputs = await self.plc.read_inputs()
        if now >= self._next_beat:
            self.heartbeat = await self.plc.beat()
            self._next_beat = now + HEARTBEAT_PERIOD_S
        if now >= self._next_refresh and self.word is not None:
            await self.plc.write_status(self.word)  # unchanged: what the PLC reads is always ours
            self._next_refresh = now + STATUS_REFRESH_S
        self.watch.observe(inputs.plc_heartbeat, now)
        return inputs

    async def show(self, word: Status, result: CycleResult, fault: MonoguideError | None) -> None:
        """The status word; first, when a new fault latched, the result registers with its code (register 11)."""
        if fault is not None and fault is not self.fault_shown:
            self.fault_shown = fault  # before the write: the cycle may clear it meanwhile (a newer counter)
            await self.plc.write_result(result)
        if word != self.word:
            await self.plc.write_status(word)
            self.word = word

    async def write_result(self, result: CycleResult) -> None:
        await self.plc.write_result(result)

    async def lost(self, error: DeviceError) -> None:
        """The connection is gone: close it, reconnect after the first backoff."""
        delay = BACKOFF_S[0]
        error.device = "plc"  # type: ignore[attr-defined]  # not the camera's or the robot's: they stay open
        log.warning("PLC lost (%s %s); reconnecting in %g s", error.code, error.message, delay)
        self.connected, self.error, self.next_try, self.word = False, error, time.monotonic() + delay, None
        with contextlib.suppress(DeviceError):
            await self.plc.close()

    async def close(self) -> None:
        """At exit: a status word of 0 (nobody may take a stopped service for READY), then the connection."""
        if self.connected:
            try:
                await self.plc.write_status(Status(0))
            except DeviceError as exc:
                log.warning("PLC: status word 0 not written at exit: %s", exc.message)
        with contextlib.suppress(DeviceError):
            await self.plc.close()
        self.connected = False

    async def _continue_numbering(self, shown: Shown) -> None:
        """A journal without cycles (new, or recreated after it was lost) continues after the number the PLC's
        register 13 shows, so the PLC's counter never runs 1, 2, ... again."""
        if self.journal.cycle_counter() == 0:
            counter = (await self.plc.read_outputs()).result.cycle_counter
            if await asyncio.to_thread(self.journal.continue_numbering, counter):
                log.warning("journal: no cycle in %s; numbering continues after cycle %d, which PLC register 13 "
                            "showed", self.journal.path, counter)
                shown.result = dataclasses.replace(shown.result, cycle_counter=counter)
        self.numbering_checked = True


def _bits(flags: type[Control] | type[Status], word: int) -> list[str]:
    """The names of the bits set in ``word``, in register order (an undefined bit as ``bit N``)."""
    names = [flag.name or "" for flag in flags if word & flag.value]
    return names + [f"bit {n}" for n in range(16) if word & (1 << n) and not any(f.value == 1 << n for f in flags)]
