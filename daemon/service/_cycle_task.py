"""The stages of one cycle as the service runs them: each in a worker thread, the PLC watched meanwhile.

:func:`run_stages` calls the runner's ``measure``, ``solve``, ``check`` and ``write`` in turn, each through
``asyncio.to_thread`` so the service's loop keeps polling the PLC, and fires the state machine's transition
after each. Between stages it looks at the abort flag the loop sets (TRIGGER dropped, PLC heartbeat lost,
SIGTERM); ``measure`` also looks at it before each request to the robot and after each wait. The last look
is just before ``write``: after an abort nothing is written to the robot. An abort that arrives while
``write`` runs cannot recall the offset from the robot: the service waits for the robot's answer and
reports what happened (RESULT_OK when the robot acknowledged it) — docs/plc-interface.md.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from monoguide.daemon.cycle import Cause, State
from monoguide.daemon.errors import CycleAborted, CycleError
from monoguide.daemon.service._journal import CycleEntry
from monoguide.daemon.service._plc_link import ZERO_OFFSET, ZERO_QUALITY
from monoguide.drivers.errors import DeviceError, PlcHeartbeatLost, PlcTriggerDropped, RobotOffsetUnconfirmed
from monoguide.drivers.plc_registers import CycleResult, PlcInputs, check_job
from monoguide.solver.errors import MonoguideError

if TYPE_CHECKING:
    from monoguide.daemon.service._loop import _Service

log = logging.getLogger(__name__)


@dataclass
class Outcome:
    """What one cycle produced: its measurement and solution as far as it got, or its error; ``number`` and
    ``sequence`` once the offset's intent was committed (the cycle's number is then fixed)."""

    started_at: float
    measurement: Any = None
    solution: Any = None
    written: bool = False
    error: MonoguideError | None = None
    timings_s: dict[str, float] = field(default_factory=dict)
    number: int | None = None
    sequence: int | None = None


async def run_stages(service: _Service, inputs: PlcInputs) -> Outcome:
    """measure -> solve -> check -> write, firing the transitions; any failure ends in ``outcome.error``."""
    outcome = Outcome(time.time())
    machine = service.machine

    def check_abort() -> None:
        if service.abort.is_set():
            assert service.abort_error is not None
            raise service.abort_error

    async def stage(function: Any, *args: Any) -> Any:
        value = await asyncio.to_thread(function, *args)
        check_abort()
        return value

    try:
        if service.housekeeping is not None:  # the last cycle's journal work first: one journal user at a time
            await service.housekeeping
            service.housekeeping = None
        service.journal.check_identity()  # a journal deleted or replaced: refuse before the robot moves
        job = check_job(inputs, _job_count(service))
        images_dir = None
        if service.settings.keep_images:
            images_dir = service.journal.images_dir / f"cycle-{service.journal.next_number()}"
        devices = (service.devices.handle("camera"), service.devices.handle("robot"))
        if service.runner is None or service.runner_devices != devices:  # first cycle, or a device reopened
            if service.runner is not None:
                service.runner.close()
            service.runner = service.runner_factory(service.config, *devices, images_dir)
            service.runner_devices = devices
        runner = service.runner
        runner.images_dir = images_dir
        outcome.measurement = await stage(runner.measure, job, service.abort, lambda: service.abort_error)
        machine.fire(Cause.VIEWS_MEASURED, f"{len(outcome.measurement.captures)} views")
        outcome.solution = await stage(runner.solve, outcome.measurement)
        machine.fire(Cause.POSE_SOLVED)
        await stage(runner.check, outcome.measurement, outcome.solution)
        machine.fire(Cause.CHECKS_PASSED)
        check_abort()  # the last look: after an abort nothing is written to the robot
        sequence = await _write(service, runner, outcome)
        outcome.written = True
        machine.fire(Cause.OFFSET_ACKNOWLEDGED, f"sequence {sequence}")
        if isinstance(service.abort_error, PlcTriggerDropped | CycleAborted):
            # too late to abort: the robot has the offset, and the PLC is told so (RESULT_OK)
            log.warning("%s came while the offset was being written: the robot acknowledged it (sequence %s); "
                        "reported as RESULT_OK", service.abort_error.code, sequence)
            service.abort.clear()
            service.abort_error = None
    except MonoguideError as exc:
        outcome.error = exc
    if outcome.error is None and machine.state is not State.REPORTING:
        outcome.error = CycleError(f"cycle ended in state {machine.state.value}, not reporting")
    return outcome


async def _write(service: _Service, runner: Any, outcome: Outcome) -> int:
    """The offset to the robot, its intent committed first; a failure after the send is settled at once
    (:meth:`OffsetLedger.after_failed_write`) or ends in ``ROBOT_OFFSET_UNCONFIRMED``."""
    solution, ledger = outcome.solution, service.ledger
    number = service.journal.next_number()

    def before_send(sequence: int) -> None:
        ledger.intend(number, sequence, tuple(float(v) for v in solution.offset), solution.D_b.tolist())
        outcome.number, outcome.sequence = number, sequence

    try:
        return await asyncio.to_thread(runner.write, solution, before_send)
    except MonoguideError as exc:
        if outcome.sequence is None:
            raise  # nothing went to the robot (the journal refused the intent, or the robot was not ready)
        robot = service.devices.handle("robot")
        raise await asyncio.to_thread(ledger.after_failed_write, robot, number, outcome.sequence, exc) from exc


async def report(self: _Service, inputs: PlcInputs, triggered_at: float, outcome: Outcome) -> None:
    """Journal the cycle (committed before DONE), then the result registers, then DONE in its own write. An
    offset the robot may hold but monoguide could not settle (429) is journaled and shown as FAULT, no DONE."""
    error = outcome.error
    if error is None:
        pass  # OFFSET_ACKNOWLEDGED fired by the stages: REPORTING
    elif isinstance(error, PlcHeartbeatLost) and self.machine.can(Cause.HEARTBEAT_LOST):
        self.machine.fire(Cause.HEARTBEAT_LOST, error=error)
    else:
        self.machine.fire(Cause.FAILED, error=error)
    if error is not None:
        self.devices.lost(error)  # reopens the one device whose connection was lost (and says which)
    started = time.monotonic()
    intent_outcome = None
    if error is None and outcome.number is not None:
        intent_outcome = self.ledger.acknowledged(outcome.number, outcome.sequence or 0)
    try:
        number = await asyncio.to_thread(self.journal.commit_cycle, journal_entry(outcome, inputs), outcome.number,
                                         intent_outcome=intent_outcome)
    except MonoguideError as exc:
        if error is None and outcome.number is not None:  # the robot holds an offset nobody can be told of
            await asyncio.to_thread(self.ledger.clear_unreported, self.devices.handle("robot"), outcome.number,
                                    f"the journal could not commit cycle {outcome.number} ({exc.code})")
        if self.machine.can(Cause.REPORT_FAILED):
            self.machine.fire(Cause.REPORT_FAILED, error=exc)
        return
    self.finished += 1
    self.result = result_registers(outcome, number, inputs)
    self.last_result = {"cycle": number, "status": "error" if error else "ok", "job": inputs.job,
                        "part_tag": inputs.part_tag, "error_code": error.code if error else None,
                        "finished_at": time.time()}
    if isinstance(error, RobotOffsetUnconfirmed) and self.machine.can(Cause.OFFSET_UNCONFIRMED):
        self.machine.fire(Cause.OFFSET_UNCONFIRMED, error=error)  # FAULT: register 11 = 429, 13 = this cycle
    if self.machine.state is not State.REPORTING:  # FAULT already: register 11 shows the fault's code,
        self.fault_shown = None  # register 13 the new counter (rewritten by _show)
        return
    try:
        await self.plc.write_result(self.result)
    except DeviceError as exc:
        await self._report_lost(exc, outcome, number)
        return
    self.outcome_ok, self.done_at = error is None, time.monotonic()
    self.machine.fire(Cause.REPORTED, f"cycle {number}: {'RESULT_OK' if error is None else error.code}")
    try:
        await self._show()  # DONE, in its own write after the result registers
    except DeviceError as exc:
        await self._plc_lost(exc)  # the PLC is told nothing; on reconnecting it sees 0 first
        return
    done = time.monotonic()
    if isinstance(self.abort_error, PlcHeartbeatLost) and self.machine.can(Cause.HEARTBEAT_LOST):
        self.machine.fire(Cause.HEARTBEAT_LOST, error=self.abort_error)
    # after DONE, off the cycle: a trigger right after the acknowledgement must find the cycle finished
    self.housekeeping = asyncio.create_task(_housekeeping(self, number, {"plc_journal": done - started,
                                                                        "cycle": done - triggered_at}))


async def _housekeeping(self: _Service, number: int, timings_s: dict[str, float]) -> None:
    """The timings that include the commit and DONE, then the image pruning (the next cycle waits for it)."""
    with contextlib.suppress(MonoguideError):
        await asyncio.to_thread(self.journal.amend_timings, number, timings_s)
    await asyncio.to_thread(_prune_images, self)


def _prune_images(self: _Service) -> None:
    s = self.settings
    try:
        pruned = self.journal.prune_images(int(s.images_max_mb * 1e6), s.images_max_age_days * 86400.0)
    except MonoguideError as exc:
        log.warning("images: pruning failed: %s %s", exc.code, exc.message)
        return
    if pruned.files:
        log.info("images: deleted %d files of %d old cycles (%.1f MB)", pruned.files, pruned.cycles,
                 pruned.bytes_freed / 1e6)


def journal_entry(outcome: Outcome, inputs: PlcInputs) -> CycleEntry:
    """The journal row of a finished (or failed) cycle."""
    m, s = outcome.measurement, outcome.solution
    timings = dict(getattr(m, "timings_s", None) or {})
    timings.update(outcome.timings_s)
    captures = list(getattr(m, "captures", None) or [])
    return CycleEntry(
        started_at=outcome.started_at, finished_at=time.time(), job=inputs.job, part_tag=inputs.part_tag,
        record=getattr(m, "record", None), result=getattr(s, "result", None), error=outcome.error,
        timings_s=timings,
        poses_at_capture=[c.T_b_f.tolist() for c in captures],
        image_paths=[c.image_path for c in captures if c.image_path is not None],
    )


def result_registers(outcome: Outcome, number: int, inputs: PlcInputs) -> CycleResult:
    """Registers 11, 13-33: the offset only when it was written and acknowledged; else zeros and the code."""
    s = outcome.solution
    quality = tuple(float(q) for q in s.quality) if s is not None else ZERO_QUALITY
    if outcome.error is None:
        return CycleResult(0, number, inputs.job, inputs.part_tag, tuple(float(v) for v in s.offset),
                           quality)  # type: ignore[arg-type]
    return CycleResult(outcome.error.plc_code, number, inputs.job, inputs.part_tag, ZERO_OFFSET,
                       quality)  # type: ignore[arg-type]


def _job_count(service: _Service) -> int:
    return getattr(service.config, "job_count", None) or 1
