"""One cycle as the service runs it: each stage in a worker thread, the PLC watched meanwhile.

:class:`CycleTask` calls the runner's ``measure``, ``solve``, ``check`` and ``write`` in turn, each through
``asyncio.to_thread`` so the service's loop keeps polling the PLC, and fires the state machine's transition
after each. Between stages it looks at the :class:`Abort` the loop requests (TRIGGER dropped, PLC heartbeat lost,
SIGTERM); ``measure`` also looks at it before each request to the robot and after each wait. The last look is
just before ``write``: after an abort nothing is written to the robot. An abort that arrives while ``write`` runs
cannot recall the offset from the robot: the task waits for the robot's answer and reports what happened
(RESULT_OK when the robot acknowledged it) — docs/plc-interface.md. Before the offset is sent, its intent is
committed; a write that fails after the send is settled (:mod:`monoguide.daemon.service._offsets`).
"""

from __future__ import annotations

import asyncio
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

from monoguide.daemon.config import CellConfig
from monoguide.daemon.cycle import Cause, CycleStateMachine, Residual, State, ViewsSeen
from monoguide.daemon.errors import CycleAborted, CycleError, CycleUnexpected, PartNotCalibrated, drop_tracebacks
from monoguide.daemon.service._devices import CellDevices
from monoguide.daemon.service._journal import Journal
from monoguide.daemon.service._offsets import OffsetLedger
from monoguide.drivers.errors import PlcTriggerDropped
from monoguide.drivers.plc_registers import CHECK_JOB, PlcInputs, check_job
from monoguide.solver.errors import CalibrationSuspect, InconsistentMeasurement, MonoguideError

if TYPE_CHECKING:
    from monoguide.daemon.service._health import CalibrationHealth
    from monoguide.daemon.service._plc_link import Shown

log = logging.getLogger(__name__)

RunnerFactory = Callable[[CellConfig, Any, Any, "Path | None"], Any]


@dataclass
class Outcome:
    """What one cycle produced: its measurement and solution as far as it got, or its error; ``number`` and
    ``sequence`` once the offset's intent was committed (the cycle's number is then fixed).

    ``started_at`` is the trigger's Unix time (the journal's), ``started_monotonic`` the same moment on the monotonic
    clock (the cycle's duration); ``seen`` what each view visited showed (kept for a failed cycle's journal row);
    ``stage`` the state the cycle failed in and ``exception`` the type of what was raised there."""

    started_at: float
    started_monotonic: float = field(default_factory=time.monotonic)
    measurement: Any = None
    solution: Any = None
    written: bool = False
    error: MonoguideError | None = None
    timings_s: dict[str, float] = field(default_factory=dict)
    number: int | None = None
    sequence: int | None = None
    seen: ViewsSeen = field(default_factory=ViewsSeen)
    stage: State | None = None
    exception: str | None = None
    committed: int | None = None  # the journal row's number, once committed

    def fail(self, error: MonoguideError, stage: State, raised: BaseException | None = None) -> None:
        """The cycle ended by ``error`` in ``stage``; ``raised`` what the stage raised when that was not ``error``
        itself (an unexpected exception wrapped in :class:`CycleUnexpected`; the first one named stays named)."""
        self.error, self.stage = error, stage
        self.exception = self.exception or type(raised if raised is not None else error).__name__

    def release(self) -> None:
        """After the cycle was reported: let go of the measurement, the solution and the error's tracebacks (the
        frames of the stages, with their images), so that a failed cycle keeps no more memory than a good one."""
        drop_tracebacks(self.error)
        self.measurement = self.solution = None


class Abort:
    """The loop's request that the running cycle end (the first reason wins); the cycle looks at it."""

    def __init__(self) -> None:
        self.event = threading.Event()
        self.error: MonoguideError | None = None

    def request(self, error: MonoguideError) -> None:
        if not self.event.is_set():
            self.error = error
            self.event.set()
            log.warning("cycle abort requested: %s %s", error.code, error.message)

    def clear(self) -> None:
        self.event.clear()
        self.error = None

    def check(self) -> None:
        """Raise the requested error, if any."""
        if self.event.is_set():
            assert self.error is not None
            raise self.error

    @property
    def requested(self) -> bool:
        return self.event.is_set()


class Runners:
    """A cycle runner per job (part type), each built the first time its job is asked for and kept while the camera
    and the robot stay the same objects (a device reopened: new ones, the old ones closed). A job switch is a
    lookup: no reconnect, no reload."""

    def __init__(self, config: CellConfig, factory: RunnerFactory) -> None:
        self.config, self.factory = config, factory
        self.runners: dict[int, Any] = {}
        self._devices: tuple[Any, Any] | None = None

    @property
    def jobs(self) -> tuple[int, ...]:
        """The job rule's one source: the config's part types."""
        return self.config.jobs

    def check_calibrated(self, job: int) -> None:
        """:class:`PartNotCalibrated` for a part type the wizard has not calibrated in a calibrated cell, and for every
        job of a calibrated cell whose reference marks were not surveyed in its cell frame."""
        if (gap := self.config.cell_calibration_gap()) is not None:
            raise PartNotCalibrated(f"job {job}: the cell's calibration in {self.config.path} is incomplete: {gap}; "
                                    f"nothing moved (monoguide calibrate marks --config {self.config.path})")
        if (gap := self.config.calibration_gap(job)) is not None:
            part = self.config.for_job(job)
            raise PartNotCalibrated(f"job {job} ({part.part_name}): not calibrated in {self.config.path}: {gap}; "
                                    f"nothing moved (monoguide calibrate --job {job} --config {self.config.path})")

    def for_devices(self, job: int, camera: Any, robot: Any, images_dir: Path | None) -> Any:
        if self._devices != (camera, robot):
            self.close()
            self._devices = (camera, robot)
        runner = self.runners.get(job)
        if runner is None:
            runner = self.runners[job] = self.factory(self.config.for_job(job), camera, robot, images_dir)
        runner.images_dir = images_dir
        return runner

    def close(self) -> None:
        for runner in self.runners.values():
            runner.close()
        self.runners.clear()
        self._devices = None


class CycleTask:
    """The stages of one cycle: measure -> solve -> check -> write, firing the transitions."""

    def __init__(self, machine: CycleStateMachine, journal: Journal, ledger: OffsetLedger, devices: CellDevices,
                 runners: Runners, abort: Abort, keep_images: bool, health: CalibrationHealth | None = None,
                 shown: Shown | None = None) -> None:
        self.machine, self.journal, self.ledger, self.devices = machine, journal, ledger, devices
        self.runners, self.abort, self.keep_images = runners, abort, keep_images
        self.health, self.shown = health, shown

    async def run(self, inputs: PlcInputs, triggered_at: float | None = None) -> Outcome:
        """Never raises (but for cancellation): any failure ends in ``outcome.error`` with the stage it struck in —
        an exception no stage should raise (a bug) as :class:`CycleUnexpected` naming it, its traceback in the log;
        success leaves the machine in REPORTING. ``triggered_at``: the trigger's ``time.monotonic()``."""
        outcome = Outcome(time.time(), time.monotonic() if triggered_at is None else triggered_at)
        try:
            await self._stages(inputs, outcome)
        except MonoguideError as exc:
            outcome.fail(exc, self.machine.state)
        except Exception as exc:  # a bug: the cycle is journaled and reported all the same
            stage = self.machine.state
            log.exception("cycle: unexpected %s in state %s", type(exc).__name__, stage.value)
            outcome.fail(unexpected(exc, stage), stage, exc)
            drop_tracebacks(exc)
        if outcome.error is None and self.machine.state is not State.REPORTING:
            outcome.fail(CycleError(f"cycle ended in state {self.machine.state.value}, not reporting"),
                         self.machine.state)
        return outcome

    async def _stages(self, inputs: PlcInputs, outcome: Outcome) -> None:
        machine = self.machine
        self.journal.check_identity()  # a journal deleted or replaced: refuse before the robot moves
        self.devices.require()  # a device lost between the trigger and now
        job = check_job(inputs, self.runners.jobs)
        checking = job == CHECK_JOB  # the calibration check: the first part type's reference part, as taught
        part_job = self.runners.jobs[0] if checking else job
        self.runners.check_calibrated(part_job)
        if self.health is not None and not checking:  # a check runs while latched: it may clear the latch
            self.health.check_latch()
        images_dir = self.journal.images_dir / f"cycle-{self.journal.next_number()}" if self.keep_images else None
        runner = self.runners.for_devices(part_job, self.devices.handle("camera"), self.devices.handle("robot"),
                                          images_dir)
        marks_only = checking and getattr(runner, "has_marks", False)  # a check of the marks needs no part
        outcome.measurement = await self._stage(runner.measure, part_job, self.abort.event, lambda: self.abort.error,
                                                not marks_only, outcome.seen)
        machine.fire(Cause.VIEWS_MEASURED, f"{len(outcome.measurement.captures)} views")
        if checking:
            await self._check(runner, outcome)
            return
        try:
            outcome.solution = await self._stage(runner.solve, outcome.measurement)
        except (InconsistentMeasurement, CalibrationSuspect) as exc:  # evidence for the trend monitor too
            await self._observe(job, getattr(exc, "residual", None), exc)
            raise
        await self._observe(job, getattr(outcome.solution, "residual", None))  # a stand-in runner's has none
        machine.fire(Cause.POSE_SOLVED)
        await self._stage(runner.check, outcome.measurement, outcome.solution)
        machine.fire(Cause.CHECKS_PASSED)
        self.abort.check()  # the last look: after an abort nothing is written to the robot
        sequence = await self._write(runner, outcome, inputs)
        outcome.written = True
        machine.fire(Cause.OFFSET_ACKNOWLEDGED, f"sequence {sequence}")
        if isinstance(self.abort.error, PlcTriggerDropped | CycleAborted):
            # too late to abort: the robot has the offset, and the PLC is told so (RESULT_OK)
            log.warning("%s came while the offset was being written: the robot acknowledged it (sequence %s); "
                        "reported as RESULT_OK", self.abort.error.code, sequence)
            self.abort.clear()

    async def _check(self, runner: Any, outcome: Outcome) -> None:
        """The check job's solve and comparison with the reference (``daemon.cycle._check``): a pass clears the
        calibration latch and ends the cycle OK with nothing written; a failure latches CALIBRATION_SUSPECT."""
        from monoguide.daemon.cycle._check import solve_and_check

        number, at = self.journal.next_number(), datetime.now(UTC).isoformat(timespec="seconds")
        more = []
        if outcome.measurement.parsed is not None:  # the reference part: the poses visited again, averaged together
            for _ in range(max(getattr(getattr(runner, "checks", None), "check_visits", 1), 1) - 1):
                more.append(await self._stage(runner.measure, outcome.measurement.job, self.abort.event,
                                              lambda: self.abort.error, True, outcome.seen))
        try:
            outcome.solution, found = await self._stage(solve_and_check, runner, outcome.measurement, *more)
            self.machine.fire(Cause.POSE_SOLVED)
        except CalibrationSuspect as failed:
            if self.health is not None:
                self.health.latch(failed, number, at, CHECK_JOB)
            raise
        finally:
            if self.health is not None and self.shown is not None:
                self.shown.calibration_warning = self.health.warning
        if self.health is not None:
            self.health.clear(f"a passing check job (cycle {number}: {found['summary']})")
            if self.shown is not None:
                self.shown.calibration_warning = self.health.warning
        self.machine.fire(Cause.REFERENCE_CHECKED, found["summary"])

    async def _observe(self, job: int, residual: Residual | None, refused: MonoguideError | None = None) -> None:
        """The solve's residual into the part type's trend monitor; its alarm refuses the cycle (CALIBRATION_SUSPECT,
        latched), in place of the consistency test's own refusal, which does not say why."""
        if self.health is None or residual is None:
            return
        try:  # in a worker thread: the first may wait for the monitors' levels, the loop must not
            await asyncio.to_thread(self.health.observe, job, self.journal.next_number(),
                                    datetime.now(UTC).isoformat(timespec="seconds"), residual)
        except CalibrationSuspect as alarm:
            if refused is not None:
                if hasattr(refused, "camera_deviation"):  # what the marks measured stays in the journal
                    alarm.camera_deviation = refused.camera_deviation  # type: ignore[attr-defined]
                raise alarm from refused
            raise
        finally:
            if self.shown is not None:
                self.shown.calibration_warning = self.health.warning

    async def _stage(self, function: Any, *args: Any) -> Any:
        value = await asyncio.to_thread(function, *args)
        self.abort.check()
        return value

    async def _write(self, runner: Any, outcome: Outcome, inputs: PlcInputs) -> int:
        """The offset to the robot, its intent committed first; a failure after the send — an unexpected exception
        too — is settled at once (:meth:`OffsetLedger.after_failed_write`) or ends in ``ROBOT_OFFSET_UNCONFIRMED``."""
        solution, ledger = outcome.solution, self.ledger
        number = self.journal.next_number()

        def before_send(sequence: int) -> None:
            ledger.intend(number, sequence, tuple(float(v) for v in solution.offset), solution.D_b.tolist(),
                          job=inputs.job, part_tag=inputs.part_tag, started_at=outcome.started_at)
            outcome.number, outcome.sequence = number, sequence

        try:
            return await asyncio.to_thread(runner.write, solution, before_send)
        except Exception as exc:
            if outcome.sequence is None:
                raise  # nothing went to the robot (the journal refused the intent, or the robot was not ready)
            failed = exc if isinstance(exc, MonoguideError) else unexpected(exc, State.WRITING)
            if failed is not exc:
                log.exception("cycle: unexpected %s while writing the offset (sequence %d sent)", type(exc).__name__,
                              outcome.sequence)
                outcome.exception = type(exc).__name__
            robot = self.devices.handle("robot")
            raise await asyncio.to_thread(ledger.after_failed_write, robot, number, outcome.sequence, failed) from exc


def unexpected(exc: BaseException, stage: State) -> CycleUnexpected:
    """What the PLC and the journal are told of an exception no stage should raise."""
    text = str(exc) or "(no message)"
    return CycleUnexpected(f"unexpected {type(exc).__name__} in state {stage.value}: {text} (a bug: the service log "
                           "has its traceback; nothing was written to the robot unless the journal says so)")
