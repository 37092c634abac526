"""The service: the PLC handshake over Modbus TCP driving the measuring cycle (docs/service.md).

One asyncio loop reads the PLC's registers 0-3 every :data:`POLL_S`, increments monoguide's heartbeat every
:data:`HEARTBEAT_PERIOD_S`, and runs the cycle's blocking stages (measure, solve, check, write of
:class:`monoguide.daemon.cycle._runner.CycleRunner`) in worker threads, so that the PLC is watched while a stage
runs: TRIGGER dropped while BUSY aborts the cycle (:class:`PlcTriggerDropped`), a PLC heartbeat that stands
still latches FAULT (:class:`PlcHeartbeatLost`), SIGTERM aborts it (``CycleAborted``). An abort is seen by
the stage at its next check and never leads to a write to the robot; an abort that comes while the offset
is being written waits for the robot's answer and then reports truthfully (docs/plc-interface.md).

Every state change goes through :class:`CycleStateMachine`; the PLC's status word follows the state
(:func:`monoguide.daemon.service._plc_link.status_word`). A finished cycle is committed to the journal before
the PLC sees DONE: result registers first, the status word after them, in a separate write.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import logging
import os
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from monoguide.daemon.config import CellConfig, ServiceConfig, require_sections
from monoguide.daemon.cycle import CYCLE_STATES, Cause, CycleStateMachine, State
from monoguide.daemon.errors import CycleError
from monoguide.daemon.service._devices import BACKOFF_S, CellDevices, cell_devices
from monoguide.daemon.service._journal import Journal
from monoguide.daemon.service._offsets import OffsetLedger
from monoguide.daemon.service._plc_link import POLL_S, Edges, failed_result, status_word
from monoguide.daemon.service._sd_notify import Notifier, watchdog_interval_s
from monoguide.daemon.service._status import ServiceStatus, write_status
from monoguide.drivers.errors import DeviceError, PlcAckTimeout, PlcHeartbeatLost, PlcTriggerDropped
from monoguide.drivers.plc import HEARTBEAT_PERIOD_S, HeartbeatWatch, Plc
from monoguide.drivers.plc_registers import Control, CycleResult, PlcInputs, Status
from monoguide.solver.errors import MonoguideError

log = logging.getLogger(__name__)

STATUS_FILE_PERIOD_S = 1.0  # status.json rewritten at least this often
LOOP_STALE_S = 2.0  # no poll for this long: the loop is not healthy (no heartbeat, no WATCHDOG=1)
STOP_GRACE_S = 2.0  # on SIGTERM, how long a reported result waits for the PLC's acknowledgement
SETTLE_RETRY_S = 2.0  # an unconfirmed offset: how often the robot is asked again while it cannot say
STATUS_REFRESH_S = 1.0  # the status word is rewritten this often even unchanged (nobody else may hold it wrong)
RunnerFactory = Callable[[CellConfig, Any, Any, "Path | None"], Any]


async def run_service(config: CellConfig, state_dir: Path, *, stop: asyncio.Event | None = None,
                      max_cycles: int | None = None, notifier: Notifier | None = None,
                      devices: CellDevices | None = None, runner_factory: RunnerFactory | None = None,
                      plc: Plc | None = None) -> None:
    """Run the cell until ``stop`` is set or ``max_cycles`` cycles were reported and acknowledged.

    ``devices``, ``runner_factory`` and ``plc`` default to the config's (daemon/assembly.py and
    :class:`monoguide.daemon.cycle._runner.CycleRunner`); tests of the handshake alone pass their own.
    """
    require_sections(config, ("plc",), command="run")
    from monoguide.daemon.cycle import tune_malloc

    tune_malloc()  # frame-sized buffers back to the system when freed: resident memory stays flat (docs/cycle.md)
    if plc is None:
        from monoguide.daemon.assembly import build_plc

        plc = build_plc(config)
    service = _Service(config, Path(state_dir), plc, devices or cell_devices(config),
                       runner_factory or _cycle_runner, stop or asyncio.Event(), max_cycles,
                       notifier or Notifier())
    await service.run()


def _cycle_runner(config: CellConfig, camera: Any, robot: Any, images_dir: Path | None) -> Any:
    from monoguide.daemon.cycle import CycleRunner

    return CycleRunner(config, camera, robot, images_dir)


def _cycle_aborted(why: str) -> MonoguideError:
    from monoguide.daemon.errors import CycleAborted

    return CycleAborted(why)


class _Service:
    def __init__(self, config: CellConfig, state_dir: Path, plc: Plc, devices: CellDevices,
                 runner_factory: RunnerFactory, stop: asyncio.Event, max_cycles: int | None,
                 notifier: Notifier) -> None:
        assert config.plc is not None
        self.config, self.state_dir, self.plc, self.devices = config, state_dir, plc, devices
        self.settings = config.service or ServiceConfig()
        self.runner_factory, self.stop, self.max_cycles, self.notifier = runner_factory, stop, max_cycles, notifier
        self.ack_timeout_s = config.plc.ack_timeout_s
        state_dir.mkdir(parents=True, exist_ok=True)
        self.journal = Journal(state_dir)
        self.ledger = OffsetLedger(self.journal)
        self.ledger.recover()  # intents of a killed service get their cycle's row (429) before anything else
        self.settle_task: asyncio.Task[None] | None = None
        self.settle_next_try = 0.0
        self.numbering_checked = False  # a new journal continues after the PLC's register 13 (first connect)
        self.trigger_armed = False  # TRIGGER seen low since the last cycle started: a high TRIGGER is then a new one
        self.trigger_low_since_done = self.ack_low_since_done = False
        self.next_refresh = 0.0
        self.machine = CycleStateMachine()
        self.watch = HeartbeatWatch(config.plc.heartbeat_timeout_s)
        self.edges: Edges | None = None  # None: the next read only learns the control word
        self.plc_connected, self.plc_attempts, self.plc_next_try = False, 0, 0.0
        self.plc_error: MonoguideError | None = None
        self.cycle_task: asyncio.Task[None] | None = None
        self.runner: Any = None  # the CycleRunner, kept while the camera and robot stay the same objects
        self.runner_devices: tuple[Any, Any] | None = None
        self.housekeeping: asyncio.Task[None] | None = None  # after DONE: timings, image pruning
        self.abort, self.abort_error = threading.Event(), None
        self.outcome_ok: bool | None = None
        self.acknowledged, self.done_at = False, 0.0
        last = self.journal.last_cycles(1)
        self.result = failed_result(0, self.journal.cycle_counter(), last[0].job or 0 if last else 0,
                                    last[0].part_tag or 0 if last else 0)
        self.last_result: dict[str, Any] | None = _summary(last[0]) if last else None
        self.finished = 0
        self.shown: Status | None = None  # the status word last written
        self.fault_shown: MonoguideError | None = None
        self.stop_deadline: float | None = None
        self.last_poll = time.monotonic()
        self.next_beat = 0.0
        self.reported_state: State | None = None
        self.since = time.time()
        self.ready_sent = False

    # --- the loop -----------------------------------------------------------------------------------

    async def run(self) -> None:
        log.info("service: state directory %s, cycle counter %d, PLC %s", self.state_dir,
                 self.result.cycle_counter, self.plc.address)
        if (unconfirmed := self.ledger.unconfirmed_error()) is not None:
            self.machine.fire(Cause.OFFSET_UNCONFIRMED, "at start", error=unconfirmed)
        self._write_status_file()
        helpers = [asyncio.create_task(self.devices.keep_connected()), asyncio.create_task(self._status_loop())]
        try:
            while not await self._step():
                await asyncio.sleep(POLL_S)
        finally:
            for task in helpers:
                task.cancel()
            for task in helpers:
                with contextlib.suppress(asyncio.CancelledError):
                    await task
            await self._shutdown()

    async def _step(self) -> bool:
        """One poll; True when the service should end."""
        now = time.monotonic()
        self.last_poll = now
        if (self.stop.is_set() or self._enough_cycles()) and await self._stopping(now):
            return True
        if not self.plc_connected:
            await self._connect_plc(now)
        else:
            await self._poll(now)
        self._settle_offsets(now)
        await self._settle()
        return False

    def _enough_cycles(self) -> bool:
        return (self.max_cycles is not None and self.finished >= self.max_cycles
                and self.machine.state in (State.IDLE, State.FAULT, State.STARTING))

    async def _stopping(self, now: float) -> bool:
        if self.stop_deadline is None:
            log.info("service: stopping (%s)", "signal" if self.stop.is_set() else f"{self.finished} cycles done")
            self.notifier.stopping()
            self.stop_deadline = now + STOP_GRACE_S
        state = self.machine.state
        if self.settle_task is not None:
            return False  # asking the robot which offset it holds: let it answer (its waits have timeouts)
        if self.cycle_task is not None:
            if state in (State.MEASURING, State.SOLVING, State.CHECKING):
                self._abort(_cycle_aborted(f"the service is stopping (in state {state.value})"))
            return False  # a write in progress finishes; the result is reported
        if state is State.AWAITING_ACK and self.plc_connected and now < max(self.stop_deadline,
                                                                           self.done_at + STOP_GRACE_S):
            return False  # give the PLC a moment to read and acknowledge the last result
        self.machine.fire(Cause.STOP, "SIGTERM" if self.stop.is_set() else f"--cycles {self.max_cycles} reached")
        return True

    async def _connect_plc(self, now: float) -> None:
        if now < self.plc_next_try:
            return
        try:
            await self.plc.connect()  # writes status word 0 before anything else
            if not self.numbering_checked:
                await self._continue_numbering()
            await self.plc.write_result(self._shown_result())
            inputs = await self.plc.read_inputs()  # a trigger held across a (re)connection is not a new one
        except DeviceError as exc:
            self.plc_attempts += 1
            delay = BACKOFF_S[min(self.plc_attempts, len(BACKOFF_S)) - 1]
            self.plc_error, self.plc_next_try = exc, now + delay
            log.warning("PLC: cannot connect (%s %s); reconnecting in %g s", exc.code, exc.message, delay)
            with contextlib.suppress(DeviceError):
                await self.plc.close()
            return
        self.plc_connected, self.plc_attempts, self.plc_error = True, 0, None
        self.shown, self.edges, self.next_beat = Status(0), Edges(inputs.control), now
        self.trigger_armed = Control.TRIGGER not in inputs.control

    async def _continue_numbering(self) -> None:
        """A journal without cycles (new, or recreated after it was lost) continues after the number the PLC's
        register 13 shows, so the PLC's counter never runs 1, 2, ... again."""
        if self.journal.cycle_counter() == 0:
            shown = (await self.plc.read_outputs()).result.cycle_counter
            if await asyncio.to_thread(self.journal.continue_numbering, shown):
                log.warning("journal: no cycle in %s; numbering continues after cycle %d, which PLC register 13 "
                            "showed", self.journal.path, shown)
                self.result = dataclasses.replace(self.result, cycle_counter=shown)
        self.numbering_checked = True

    async def _poll(self, now: float) -> None:
        try:
            inputs = await self.plc.read_inputs()
            if now >= self.next_beat:
                await self.plc.beat()
                self.next_beat = now + HEARTBEAT_PERIOD_S
            if now >= self.next_refresh and self.shown is not None:
                await self.plc.write_status(self.shown)  # unchanged: what the PLC reads is always ours
                self.next_refresh = now + STATUS_REFRESH_S
        except DeviceError as exc:
            await self._plc_lost(exc)
            return
        self.watch.observe(inputs.plc_heartbeat, now)
        assert self.edges is not None  # set by _connect_plc
        rising = self.edges.update(inputs.control)
        log.debug("poll: %r rising %r state %s", inputs, rising, self.machine.state)
        state = self.machine.state
        try:
            self.watch.check(now)
        except PlcHeartbeatLost as exc:
            self._fail_hard(exc)
            return
        if state in CYCLE_STATES and self.cycle_task is not None and Control.TRIGGER not in inputs.control:
            self._abort(PlcTriggerDropped(f"register 0 (control word): TRIGGER dropped while BUSY (in state "
                                          f"{state.value})"))
        trigger = Control.TRIGGER in inputs.control
        if state is State.AWAITING_ACK:
            self._await_ack(inputs, now)
        elif trigger and self.trigger_armed:  # a rising edge, or a low seen since the last start (latched)
            if state is State.IDLE and self.cycle_task is None and self.stop_deadline is None:
                self._start_cycle(inputs, now)
            else:
                log.warning("trigger ignored: not READY (state %s, job %d, part tag %d)", state.value, inputs.job,
                            inputs.part_tag)
            self.trigger_armed = False
        if not trigger:
            self.trigger_armed = True
        if state is State.FAULT and Control.FAULT_RESET in rising:
            self._fault_reset(now)

    def _fail_hard(self, error: MonoguideError) -> None:
        """PLC heartbeat lost: FAULT now, or through the running cycle (which must end first)."""
        if self.cycle_task is not None:
            self._abort(error)
        elif self.machine.can(Cause.HEARTBEAT_LOST):
            self.machine.fire(Cause.HEARTBEAT_LOST, error=error)

    def _abort(self, error: MonoguideError) -> None:
        if not self.abort.is_set():
            self.abort_error = error
            self.abort.set()
            log.warning("cycle abort requested: %s %s", error.code, error.message)

    def _await_ack(self, inputs: PlcInputs, now: float) -> None:
        """DONE shown: RESULT_ACK seen -> DONE, RESULT_OK, ERROR cleared (by _settle); then, once TRIGGER and
        RESULT_ACK have each been seen low (not necessarily in one read: each low is latched), READY. A TRIGGER
        seen low and already high again by then is the next part's: its cycle starts at once."""
        control = inputs.control
        if not self.acknowledged and Control.TRIGGER in control and self.trigger_armed:
            log.warning("trigger ignored: not READY (DONE shown, no RESULT_ACK yet; job %d, part tag %d)", inputs.job,
                        inputs.part_tag)
            self.trigger_armed = False
        if not self.acknowledged and Control.RESULT_ACK in control:
            self.acknowledged = True
            self.trigger_low_since_done = self.ack_low_since_done = False
        if self.acknowledged:
            self.trigger_low_since_done |= Control.TRIGGER not in control
            self.ack_low_since_done |= Control.RESULT_ACK not in control
        if self.acknowledged and self.trigger_low_since_done and self.ack_low_since_done:
            self.machine.fire(Cause.RESULT_ACKNOWLEDGED, f"cycle {self.result.cycle_counter}")
            self.trigger_armed = True  # seen low since DONE
            if Control.TRIGGER in control and self.stop_deadline is None:
                log.info("TRIGGER already high again for the next part (job %d, part tag %d): starting it",
                         inputs.job, inputs.part_tag)
                self.trigger_armed = False
                self._start_cycle(inputs, now)
        elif now - self.done_at > self.ack_timeout_s:
            self.machine.fire(Cause.ACK_TIMEOUT, error=PlcAckTimeout(
                f"register 0 (control word) = 0x{int(inputs.control):04X}: no RESULT_ACK with TRIGGER low within "
                f"{self.ack_timeout_s:g} s of DONE (cycle {self.result.cycle_counter})"))

    def _fault_reset(self, now: float) -> None:
        """FAULT_RESET's rising edge: FAULT clears when the heartbeat runs, no cycle is ending, every offset the
        robot may hold is settled, and the journal is still the file the service opened."""
        why = None
        if self.cycle_task is not None:
            why = "the aborted cycle is still ending"
        elif not self.watch.alive(now):
            why = "the PLC heartbeat is not back"
        elif (unconfirmed := self.ledger.unconfirmed_error()) is not None:
            why = f"{unconfirmed.code}: {unconfirmed.message}"
        else:
            try:
                self.journal.check_identity()
            except MonoguideError as exc:
                why = f"{exc.code}: {exc.message}"
        if why is None:
            self.machine.fire(Cause.FAULT_RESET, "FAULT_RESET pulsed, PLC heartbeat running")
        else:
            log.warning("FAULT_RESET ignored: %s", why)

    def _settle_offsets(self, now: float) -> None:
        """An offset the robot may hold (429): ask the robot, once it is connected, no cycle runs, and not more
        often than every SETTLE_RETRY_S."""
        if not self.ledger.unsettled or self.settle_task is not None or self.cycle_task is not None:
            return
        robot = self.devices.handle("robot")
        if robot is None or now < self.settle_next_try:
            return
        self.settle_next_try = now + SETTLE_RETRY_S
        self.settle_task = asyncio.create_task(self._settle_pending(robot))

    async def _settle_pending(self, robot: Any) -> None:
        try:
            settled = await asyncio.to_thread(self.ledger.settle_pending, robot)
        except MonoguideError as exc:
            log.warning("robot: cannot settle the unconfirmed offset yet (%s %s); asking again in %g s", exc.code,
                        exc.message, SETTLE_RETRY_S)
            exc.device = "robot"  # type: ignore[attr-defined]
            self.devices.lost(exc)
        else:
            for done in settled:
                log.warning("cycle %d: unconfirmed offset settled (%s); FAULT clears on FAULT_RESET", done.cycle,
                            "the robot had taken it" if done.held else "the robot had not taken it")
        finally:
            self.settle_task = None

    async def _report_lost(self, error: DeviceError, outcome: Any, number: int) -> None:
        """The result registers could not be written: FAULT says why the cycle ended (its own error, else the
        PLC's); a good cycle's offset is cleared from the robot, since the PLC was not told RESULT_OK."""
        if outcome.error is None and outcome.number is not None:
            robot = self.devices.handle("robot")
            why = f"the PLC could not be told ({error.code})"
            if robot is not None and await asyncio.to_thread(self.ledger.clear_unreported, robot, number, why):
                self.result = failed_result(error.plc_code, number, self.result.job, self.result.part_tag,
                                            self.result.quality)
        self.machine.fire(Cause.REPORT_FAILED, error=outcome.error or error)
        await self._plc_lost(error)

    async def _plc_lost(self, error: DeviceError) -> None:
        delay = BACKOFF_S[0]
        error.device = "plc"  # type: ignore[attr-defined]  # not the camera's or the robot's: they stay open
        log.warning("PLC lost (%s %s); reconnecting in %g s", error.code, error.message, delay)
        self.plc_connected, self.plc_error, self.plc_next_try = False, error, time.monotonic() + delay
        self.shown = None
        with contextlib.suppress(DeviceError):
            await self.plc.close()
        if self.cycle_task is not None:
            self._abort(error)
        elif self.machine.state in (State.IDLE, State.AWAITING_ACK):
            self.machine.fire(Cause.DEVICE_LOST, f"PLC {self.plc.address}")

    async def _settle(self) -> None:
        """Follow the devices (STARTING <-> IDLE), then show the state: status word, status file, STATUS=."""
        state, ready = self.machine.state, self.devices.connected and self.plc_connected
        if state is State.STARTING and ready and self.cycle_task is None and self.stop_deadline is None:
            self.machine.fire(Cause.DEVICES_CONNECTED, ", ".join(["plc", *self.devices.slots]))
            if not self.ready_sent:
                self.ready_sent = self.notifier.ready(self._status_line()) or True
        elif state is State.IDLE and not ready:
            self.machine.fire(Cause.DEVICE_LOST, ", ".join(n for n, s in self.devices.slots.items() if not s.connected)
                              or "plc")
        if self.machine.state is not self.reported_state:
            self.reported_state, self.since = self.machine.state, time.time()
            self._write_status_file()
            self.notifier.status(self._status_line())
        if self.plc_connected:
            try:
                await self._show()
            except DeviceError as exc:
                await self._plc_lost(exc)

    async def _show(self) -> None:
        fault = self.machine.fault
        if self.machine.state is State.FAULT and fault is not None and fault is not self.fault_shown:
            self.fault_shown = fault  # before the write: the cycle may clear it meanwhile (a newer counter)
            await self.plc.write_result(self._shown_result())  # register 11 tells the PLC why
        word = status_word(self.machine.state, self.outcome_ok, self.acknowledged)
        if word != self.shown:
            await self.plc.write_status(word)
            self.shown = word

    def _shown_result(self) -> CycleResult:
        fault = self.machine.fault if self.machine.state is State.FAULT else None
        return self.result if fault is None else dataclasses.replace(self.result, error_code=fault.plc_code)

    # --- one cycle ----------------------------------------------------------------------------------

    def _start_cycle(self, inputs: PlcInputs, now: float) -> None:
        self.abort.clear()
        self.abort_error, self.outcome_ok, self.acknowledged = None, None, False
        self.machine.fire(Cause.TRIGGER, f"job {inputs.job}, part tag {inputs.part_tag}")
        self.cycle_task = asyncio.create_task(self._cycle(inputs, now))

    async def _cycle(self, inputs: PlcInputs, triggered_at: float) -> None:
        from monoguide.daemon.service._cycle_task import report, run_stages

        try:
            outcome = await run_stages(self, inputs)
            await report(self, inputs, triggered_at, outcome)
        except Exception:  # a bug: say so loudly, and latch FAULT rather than hang BUSY
            log.exception("cycle: unexpected failure")
            error = CycleError("the cycle failed unexpectedly (see the service log)")
            if self.machine.can(Cause.FAILED):
                self.machine.fire(Cause.FAILED, error=error)
            if self.machine.can(Cause.REPORT_FAILED):
                self.machine.fire(Cause.REPORT_FAILED, error=error)
        finally:
            self.cycle_task = None

    # --- status file, sd_notify, exit ---------------------------------------------------------------

    async def _status_loop(self) -> None:
        watchdog_s = watchdog_interval_s()
        period = min(STATUS_FILE_PERIOD_S, watchdog_s or STATUS_FILE_PERIOD_S)
        while True:
            await asyncio.sleep(period)
            if time.monotonic() - self.last_poll < LOOP_STALE_S:  # the loop is healthy
                self._write_status_file()
                if watchdog_s is not None:
                    self.notifier.watchdog()

    def _status_line(self) -> str:
        last = self.last_result
        result = "no cycle yet" if last is None else (
            f"cycle {last['cycle']} {last['status']}" + (f" {last['error_code']}" if last["error_code"] else ""))
        fault = self.machine.fault
        return f"{self.machine.state.value}" + (f" ({fault.code})" if fault else "") + f"; last: {result}"

    def _write_status_file(self) -> None:
        from monoguide.daemon.service._status import DeviceStatus

        error = self.plc_error
        devices = {"plc": DeviceStatus(self.plc_connected, None if error is None else
                                       {"code": error.code, "message": error.message}), **self.devices.status()}
        fault = self.machine.fault if self.machine.state is State.FAULT else None
        try:
            write_status(self.state_dir, ServiceStatus(
                self.machine.state.value, self.since, os.getpid(), time.time(), STATUS_FILE_PERIOD_S, devices,
                self.last_result, None if fault is None else {"code": fault.code, "plc_code": fault.plc_code,
                                                              "message": fault.message}))
        except OSError as exc:
            log.warning("status file: cannot write in %s: %s", self.state_dir, exc)

    async def _shutdown(self) -> None:
        if self.cycle_task is not None:  # an exception ended the loop: let the cycle end first
            self._abort(CycleError("the service ended"))
            with contextlib.suppress(Exception):
                await self.cycle_task
        for task in (self.housekeeping, self.settle_task):
            if task is not None:
                with contextlib.suppress(Exception):
                    await task
        if self.machine.can(Cause.STOP):
            self.machine.fire(Cause.STOP, "the service ended")
        if self.plc_connected:
            try:
                await self.plc.write_status(Status(0))  # nobody may take a stopped service for READY
            except DeviceError as exc:
                log.warning("PLC: status word 0 not written at exit: %s", exc.message)
        with contextlib.suppress(DeviceError):
            await self.plc.close()
        self.plc_connected = False  # a stopped service shows no device connected
        await self.devices.close()
        if self.runner is not None:
            self.runner.close()
        self.since = time.time()
        self._write_status_file()
        self.journal.close()
        log.info("service: stopped (%d cycles this run)", self.finished)


def _summary(row: Any) -> dict[str, Any]:
    return {"cycle": row.number, "status": row.status, "job": row.job, "part_tag": row.part_tag,
            "error_code": row.error_code, "finished_at": row.finished_at}
