"""The service: the PLC handshake over Modbus TCP driving the measuring cycle (docs/service.md).

One asyncio loop reads the PLC's registers 0-3 every :data:`POLL_S` (:class:`PlcLink`), and runs the cycle's
blocking stages (:class:`CycleTask`) in worker threads, so that the PLC is watched while a stage runs: TRIGGER
dropped while BUSY aborts the cycle (:class:`PlcTriggerDropped`), a PLC heartbeat that stands still latches FAULT
(:class:`PlcHeartbeatLost`), SIGTERM aborts it (``CycleAborted``). An abort is seen by the stage at its next check
and never leads to a write to the robot; an abort that comes while the offset is being written waits for the
robot's answer and then reports truthfully (docs/plc-interface.md).

Every state change goes through :class:`CycleStateMachine`; the PLC's status word follows the state
(:func:`status_word`). A finished cycle is committed to the journal before the PLC sees DONE
(:class:`CycleReport`). An offset the robot may hold but monoguide could not confirm is settled with the robot
from here, before the cell is READY again (:class:`OffsetLedger`).
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import logging
import os
import time
from pathlib import Path
from typing import Any

from monoguide.daemon.config import CellConfig, ServiceConfig, require_sections
from monoguide.daemon.cycle import CYCLE_STATES, Cause, CycleStateMachine, State, trim_malloc
from monoguide.daemon.errors import CycleAborted, CycleError, drop_tracebacks
from monoguide.daemon.service._cycle_task import Abort, CycleTask, RunnerFactory, Runners
from monoguide.daemon.service._devices import CellDevices, cell_devices
from monoguide.daemon.service._health import CalibrationHealth
from monoguide.daemon.service._journal import Journal
from monoguide.daemon.service._offsets import OffsetLedger
from monoguide.daemon.service._plc_link import POLL_S, PlcLink, Shown, status_word
from monoguide.daemon.service._report import CycleReport
from monoguide.daemon.service._sd_notify import Notifier, watchdog_interval_s
from monoguide.daemon.service._status import DeviceStatus, ServiceStatus, write_status
from monoguide.drivers.errors import DeviceError, PlcAckTimeout, PlcHeartbeatLost, PlcTriggerDropped
from monoguide.drivers.plc import Plc
from monoguide.drivers.plc_registers import Control, CycleResult, PlcInputs
from monoguide.solver.errors import MonoguideError

log = logging.getLogger(__name__)

STATUS_FILE_PERIOD_S = 1.0  # status.json rewritten at least this often
LOOP_STALE_S = 2.0  # no poll for this long: the loop is not healthy (no heartbeat, no WATCHDOG=1)
STOP_GRACE_S = 2.0  # on SIGTERM, how long a reported result waits for the PLC's acknowledgement
SETTLE_RETRY_S = 2.0  # an unconfirmed offset: how often the robot is asked again while it cannot say
DEVICE_WATCH_S = 0.1  # between cycles, the devices are asked this often whether they still answer (5 polls)


async def run_service(config: CellConfig, state_dir: Path, *, stop: asyncio.Event | None = None,
                      max_cycles: int | None = None, notifier: Notifier | None = None,
                      devices: CellDevices | None = None, runner_factory: RunnerFactory | None = None,
                      plc: Plc | None = None) -> None:
    """Run the cell until ``stop`` is set or ``max_cycles`` cycles were reported and acknowledged.

    ``devices``, ``runner_factory`` and ``plc`` default to the config's (daemon/assembly.py and the cycle's
    ``CycleRunner``); tests of the handshake alone pass their own.
    """
    require_sections(config, ("plc",), command="run")
    from monoguide.daemon.cycle import tune_malloc

    tune_malloc()  # frame-sized buffers back to the system when freed: resident memory stays flat (docs/cycle.md)
    if plc is None:
        from monoguide.daemon.assembly import build_plc

        plc = build_plc(config)
    service = Service(config, Path(state_dir), plc, devices or cell_devices(config), runner_factory or _cycle_runner,
                      stop or asyncio.Event(), max_cycles, notifier or Notifier())
    await service.run()


def _cycle_runner(config: CellConfig, camera: Any, robot: Any, images_dir: Path | None) -> Any:
    from monoguide.daemon.cycle import CycleRunner

    return CycleRunner(config, camera, robot, images_dir)


class Service:
    """The loop: the PLC polled and answered, one cycle at a time, the state shown (status word, status file,
    ``STATUS=``), unconfirmed offsets settled, a clean stop."""

    def __init__(self, config: CellConfig, state_dir: Path, plc: Plc, devices: CellDevices,
                 runner_factory: RunnerFactory, stop: asyncio.Event, max_cycles: int | None,
                 notifier: Notifier) -> None:
        assert config.plc is not None
        self.config, self.state_dir, self.devices = config, state_dir, devices
        self.stop, self.max_cycles, self.notifier = stop, max_cycles, notifier
        self.ack_timeout_s = config.plc.ack_timeout_s
        state_dir.mkdir(parents=True, exist_ok=True)
        self.journal = Journal(state_dir)
        self.ledger = OffsetLedger(self.journal)
        self.ledger.recover()  # intents of a killed service get their cycle's row (429) before anything else
        self.machine = CycleStateMachine()
        self.link = PlcLink(plc, self.journal, config.plc.heartbeat_timeout_s)
        self.shown = Shown.from_journal(self.journal)
        settings = config.service or ServiceConfig()
        self.runners = Runners(config, runner_factory)
        self.abort = Abort()
        self.health = CalibrationHealth(state_dir, config)
        self.shown.calibration_warning = self.health.warning
        self.task = CycleTask(self.machine, self.journal, self.ledger, devices, self.runners, self.abort,
                              settings.keep_images, self.health, self.shown)
        self.report = CycleReport(self.machine, self.journal, self.ledger, devices, self.link, self.shown, settings)
        self.cycle_task: asyncio.Task[None] | None = None
        self.settle_task: asyncio.Task[None] | None = None
        self.watch_task: asyncio.Task[None] | None = None  # the devices asked between cycles
        self.next_watch = 0.0
        self.settle_next_try = 0.0
        self.stop_deadline: float | None = None
        self.last_poll = time.monotonic()
        self.reported_state: State | None = None
        self.since = time.time()
        self.ready_sent = False

    # --- the loop -----------------------------------------------------------------------------------

    async def run(self) -> None:
        log.info("service: state directory %s, cycle counter %d, PLC %s", self.state_dir,
                 self.shown.result.cycle_counter, self.link.address)
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
        if not self.link.connected:
            await self.link.connect(now, self.shown, self._shown_result)
        else:
            await self._poll(now)
        self._settle_offsets(now)
        self._watch_devices(now)
        await self._follow()
        return False

    def _enough_cycles(self) -> bool:
        return (self.max_cycles is not None and self.shown.finished >= self.max_cycles
                and self.machine.state in (State.IDLE, State.FAULT, State.STARTING))

    async def _stopping(self, now: float) -> bool:
        if self.stop_deadline is None:
            log.info("service: stopping (%s)",
                     "signal" if self.stop.is_set() else f"{self.shown.finished} cycles done")
            self.notifier.stopping()
            self.stop_deadline = now + STOP_GRACE_S
        state = self.machine.state
        if self.settle_task is not None:
            return False  # asking the robot which offset it holds: let it answer (its waits have timeouts)
        if self.cycle_task is not None:
            if state in (State.MEASURING, State.SOLVING, State.CHECKING):
                self.abort.request(CycleAborted(f"the service is stopping (in state {state.value})"))
            return False  # a write in progress finishes; the result is reported
        if state is State.AWAITING_ACK and self.link.connected and now < max(self.stop_deadline,
                                                                            self.shown.done_at + STOP_GRACE_S):
            return False  # give the PLC a moment to read and acknowledge the last result
        self.machine.fire(Cause.STOP, "SIGTERM" if self.stop.is_set() else f"--cycles {self.max_cycles} reached")
        return True

    async def _poll(self, now: float) -> None:
        try:
            inputs = await self.link.read(now)
        except DeviceError as exc:
            await self._plc_lost(exc)
            return
        latch, control = self.link.latch, inputs.control
        rising = latch.read(control)
        state = self.machine.state
        log.debug("poll: %r rising %r state %s", inputs, rising, state)
        try:
            self.link.watch.check(now)
        except PlcHeartbeatLost as exc:
            self._fail_hard(exc)
            return
        if state is State.IDLE and not self._follow_devices():  # a device lost since the last poll: not READY
            state = self.machine.state
        if state in CYCLE_STATES and self.cycle_task is not None and Control.TRIGGER not in control:
            self.abort.request(PlcTriggerDropped(f"register 0 (control word): TRIGGER dropped while BUSY (in state "
                                                 f"{state.value})"))
        if state is State.AWAITING_ACK:
            self._await_ack(inputs, now)
        elif latch.take_trigger(control):  # a rising edge, or a low seen since the last start (latched)
            if state is State.IDLE and self.cycle_task is None and self.stop_deadline is None:
                self._start_cycle(inputs, now)
            else:
                log.warning("trigger ignored: not READY (state %s, job %d, part tag %d)", state.value, inputs.job,
                            inputs.part_tag)
        latch.saw(control)
        if state is State.FAULT and Control.FAULT_RESET in rising:
            await self._fault_reset(now)

    def _fail_hard(self, error: MonoguideError) -> None:
        """PLC heartbeat lost: FAULT now, or through the running cycle (which must end first)."""
        if self.cycle_task is not None:
            self.abort.request(error)
        elif self.machine.can(Cause.HEARTBEAT_LOST):
            self.machine.fire(Cause.HEARTBEAT_LOST, error=error)

    def _await_ack(self, inputs: PlcInputs, now: float) -> None:
        """DONE shown: RESULT_ACK seen -> DONE, RESULT_OK, ERROR cleared; then, once TRIGGER and RESULT_ACK have
        each been seen low (not necessarily in one read), READY. A TRIGGER seen low and already high again by
        then is the next part's: its cycle starts at once."""
        control, latch, shown = inputs.control, self.link.latch, self.shown
        if not shown.acknowledged and latch.take_trigger(control):
            log.warning("trigger ignored: not READY (DONE shown, no RESULT_ACK yet; job %d, part tag %d)", inputs.job,
                        inputs.part_tag)
        if not shown.acknowledged and Control.RESULT_ACK in control:
            shown.acknowledged = True
            latch.acknowledging(control)
        if shown.acknowledged and latch.acknowledged(control):
            self.machine.fire(Cause.RESULT_ACKNOWLEDGED, f"cycle {shown.result.cycle_counter}")
            if Control.TRIGGER in control and self.stop_deadline is None and latch.take_trigger(control):
                log.info("TRIGGER already high again for the next part (job %d, part tag %d): starting it",
                         inputs.job, inputs.part_tag)
                self._start_cycle(inputs, now)
        elif now - shown.done_at > self.ack_timeout_s:
            self.machine.fire(Cause.ACK_TIMEOUT, error=PlcAckTimeout(
                f"register 0 (control word) = 0x{int(control):04X}: no RESULT_ACK with TRIGGER low within "
                f"{self.ack_timeout_s:g} s of DONE (cycle {shown.result.cycle_counter})"))

    async def _fault_reset(self, now: float) -> None:
        """FAULT_RESET's rising edge: FAULT clears when the heartbeat runs, no cycle is ending, every offset the
        robot may hold is settled, the journal is still the file the service opened, and every cycle that ended
        without its row (a full disk) has it now."""
        why = None
        if self.cycle_task is not None:
            why = "the aborted cycle is still ending"
        elif not self.link.watch.alive(now):
            why = "the PLC heartbeat is not back"
        elif (unconfirmed := self.ledger.unconfirmed_error()) is not None:
            why = f"{unconfirmed.code}: {unconfirmed.message}"
        else:
            try:
                self.journal.check_identity()
            except MonoguideError as exc:
                why = f"{exc.code}: {exc.message}"
        if why is None and (uncommitted := await self.report.commit_pending()) is not None:
            why = f"the journal still cannot take a finished cycle: {uncommitted.code}: {uncommitted.message}"
        if why is None:
            self.machine.fire(Cause.FAULT_RESET, "FAULT_RESET pulsed, PLC heartbeat running")
        else:
            log.warning("FAULT_RESET ignored: %s", why)

    def _settle_offsets(self, now: float) -> None:
        """An offset the robot may hold (429): ask the robot, once it is connected, no cycle runs, and not more
        often than every SETTLE_RETRY_S."""
        if (not self.ledger.unsettled or self.settle_task is not None or self.cycle_task is not None
                or (self.watch_task is not None and not self.watch_task.done())):
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

    async def _plc_lost(self, error: DeviceError) -> None:
        await self.link.lost(error)
        if self.cycle_task is not None:
            self.abort.request(error)
        elif self.machine.state in (State.IDLE, State.AWAITING_ACK):
            self.machine.fire(Cause.DEVICE_LOST, f"PLC {self.link.address}")

    def _follow_devices(self) -> bool:
        """STARTING -> IDLE once every device and the PLC are connected, IDLE -> STARTING as soon as one is not;
        True when the cell is ready."""
        state, ready = self.machine.state, self.devices.connected and self.link.connected
        if state is State.STARTING and ready and self.cycle_task is None and self.stop_deadline is None:
            self.machine.fire(Cause.DEVICES_CONNECTED, ", ".join(["plc", *self.devices.slots]))
            if not self.ready_sent:
                self.ready_sent = self.notifier.ready(self._status_line()) or True
        elif state is State.IDLE and not ready:
            self.machine.fire(Cause.DEVICE_LOST, ", ".join(n for n, s in self.devices.slots.items() if not s.connected)
                              or "plc")
        return ready

    def _watch_devices(self, now: float) -> None:
        """Between cycles, every :data:`DEVICE_WATCH_S`: ask the devices whether they still answer (one question at
        a time, never beside a cycle or a settling, which use the robot themselves)."""
        if (self.machine.state is State.IDLE and self.cycle_task is None and self.settle_task is None
                and self.stop_deadline is None and (self.watch_task is None or self.watch_task.done())
                and now >= self.next_watch):
            self.next_watch = now + DEVICE_WATCH_S
            self.watch_task = asyncio.create_task(self.devices.watch())

    async def _follow(self) -> None:
        """Follow the devices (STARTING <-> IDLE), then show the state: status word, status file, STATUS=."""
        self._follow_devices()
        if self.machine.state is not self.reported_state:
            self.reported_state, self.since = self.machine.state, time.time()
            self._write_status_file()
            self.notifier.status(self._status_line())
        if self.link.connected:
            fault = self.machine.fault if self.machine.state is State.FAULT else None
            if self.cycle_task is None:
                self.health.take_clear_request()  # `monoguide health --clear`: between cycles
            self.shown.calibration_warning = self.health.warning  # also once the monitors are restored at start
            word = status_word(self.machine.state, self.shown.outcome_ok, self.shown.acknowledged,
                               self.shown.calibration_warning, stopping=self.stop_deadline is not None)
            try:
                await self.link.show(word, self._shown_result(), fault)
            except DeviceError as exc:
                await self._plc_lost(exc)

    def _shown_result(self) -> CycleResult:
        """The result registers as the PLC must see them now: in FAULT, register 11 says why."""
        fault = self.machine.fault if self.machine.state is State.FAULT else None
        result = self.shown.result
        return result if fault is None else dataclasses.replace(result, error_code=fault.plc_code)

    # --- one cycle ----------------------------------------------------------------------------------

    def _start_cycle(self, inputs: PlcInputs, now: float) -> None:
        self.abort.clear()
        self.shown.new_cycle()
        self.machine.fire(Cause.TRIGGER, f"job {inputs.job}, part tag {inputs.part_tag}")
        self.cycle_task = asyncio.create_task(self._cycle(inputs, now))

    async def _cycle(self, inputs: PlcInputs, triggered_at: float) -> None:
        """The one way a cycle ends, whatever ended it: journaled with what it captured, the PLC told, its memory
        released (:meth:`Outcome.release`). The task never raises; a bug in the report latches FAULT."""
        outcome = None
        try:
            if self.watch_task is not None:  # a question to the devices still under way: they answer one at a time
                await self.watch_task
            await self.report.finish_housekeeping()  # the last cycle's journal work first: one user at a time
            outcome = await self.task.run(inputs, triggered_at)
            await self.report.report(inputs, triggered_at, outcome, self.abort)
        except Exception as exc:  # a bug of the report: say so loudly, journal the cycle, latch FAULT
            log.exception("cycle: unexpected failure while reporting")
            try:
                await self.report.failed_unexpectedly(inputs, outcome, exc)
            except Exception:
                log.exception("cycle: the unexpected failure could not be journaled")
            drop_tracebacks(exc)
        finally:
            if outcome is not None:
                outcome.release()
            await asyncio.to_thread(trim_malloc)  # what the cycle freed, back to the system (after DONE)
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
        last = self.shown.last_result
        result = "no cycle yet" if last is None else (
            f"cycle {last['cycle']} {last['status']}" + (f" {last['error_code']}" if last["error_code"] else ""))
        fault = self.machine.fault
        return f"{self.machine.state.value}" + (f" ({fault.code})" if fault else "") + f"; last: {result}"

    def _write_status_file(self) -> None:
        error = self.link.error
        devices = {"plc": DeviceStatus(self.link.connected, None if error is None else
                                       {"code": error.code, "message": error.message}), **self.devices.status()}
        fault = self.machine.fault if self.machine.state is State.FAULT else None
        try:
            write_status(self.state_dir, ServiceStatus(
                self.machine.state.value, self.since, os.getpid(), time.time(), STATUS_FILE_PERIOD_S, devices,
                self.shown.last_result, None if fault is None else {"code": fault.code, "plc_code": fault.plc_code,
                                                                    "message": fault.message}, self.link.registers(),
                self.health.summary()))
        except OSError as exc:
            log.warning("status file: cannot write in %s: %s", self.state_dir, exc)

    async def _shutdown(self) -> None:
        if self.cycle_task is not None:  # an exception ended the loop: let the cycle end first
            self.abort.request(CycleError("the service ended"))
            with contextlib.suppress(Exception):
                await self.cycle_task
        await self.report.finish_housekeeping()
        if (uncommitted := await self.report.commit_pending()) is not None:
            log.error("journal: a finished cycle could not be committed before the stop (%s %s); an offset it sent "
                      "gets its row at the next start", uncommitted.code, uncommitted.message)
        if self.watch_task is not None:
            with contextlib.suppress(Exception):
                await self.watch_task
        if self.settle_task is not None:
            with contextlib.suppress(Exception):
                await self.settle_task
        if self.machine.can(Cause.STOP):
            self.machine.fire(Cause.STOP, "the service ended")
        await self.link.close()  # status word 0 first: nobody may take a stopped service for READY
        await self.devices.close()
        self.runners.close()
        self.since = time.time()
        self._write_status_file()
        self.journal.close()
        log.info("service: stopped (%d cycles this run)", self.shown.finished)
