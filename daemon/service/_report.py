"""A finished cycle reported: journaled (committed before DONE), then the result registers, then DONE in its own
write; an offset the robot may hold but monoguide could not settle (429) is journaled and shown as FAULT, no DONE.

After DONE, off the cycle's path, the housekeeping: the timings that include the commit and DONE, then the image
pruning (the next cycle waits for it: one journal user at a time).
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import logging
import time
from pathlib import Path
from typing import Any

from monoguide.daemon.config import ServiceConfig
from monoguide.daemon.cycle import Cause, CycleStateMachine, State, wait_images
from monoguide.daemon.errors import CycleUnexpected
from monoguide.daemon.service._cycle_task import Abort, Outcome, unexpected
from monoguide.daemon.service._devices import CellDevices
from monoguide.daemon.service._journal import CycleEntry, Journal
from monoguide.daemon.service._offsets import OffsetLedger
from monoguide.daemon.service._plc_link import ZERO_OFFSET, ZERO_QUALITY, PlcLink, Shown, failed_result, status_word
from monoguide.drivers.errors import DeviceError, PlcHeartbeatLost, RobotOffsetUnconfirmed
from monoguide.drivers.plc_registers import CycleResult, PlcInputs
from monoguide.solver.errors import MonoguideError

log = logging.getLogger(__name__)


class CycleReport:
    """Reports each finished cycle to the journal and the PLC; owns the housekeeping task that follows DONE."""

    def __init__(self, machine: CycleStateMachine, journal: Journal, ledger: OffsetLedger, devices: CellDevices,
                 link: PlcLink, shown: Shown, settings: ServiceConfig) -> None:
        self.machine, self.journal, self.ledger, self.devices = machine, journal, ledger, devices
        self.link, self.shown, self.settings = link, shown, settings
        self.housekeeping: asyncio.Task[None] | None = None
        self.uncommitted: list[tuple[CycleEntry, int | None]] = []  # rows the journal could not take yet

    async def report(self, inputs: PlcInputs, triggered_at: float, outcome: Outcome, abort: Abort) -> None:
        machine, error = self.machine, outcome.error
        if error is None:
            pass  # OFFSET_ACKNOWLEDGED fired by the task: REPORTING
        elif isinstance(error, PlcHeartbeatLost) and machine.can(Cause.HEARTBEAT_LOST):
            machine.fire(Cause.HEARTBEAT_LOST, error=error)
        else:
            machine.fire(Cause.FAILED, error=error)
        if error is not None:
            self.devices.lost(error)  # reopens the one device whose connection was lost (and says which)
            # its PNGs on disk before its row names them (the operator page shows them; pruning sizes them once)
            await asyncio.to_thread(wait_images, outcome.seen.images)
        started = time.monotonic()
        number = await self._commit(inputs, outcome)
        if number is None:
            return
        self.shown.finished += 1
        self.shown.result = result_registers(outcome, number, inputs)
        record = getattr(outcome.measurement, "record", None)
        part = record.get("part") if isinstance(record, dict) else None  # None: no part measured (unknown job ...)
        self.shown.last_result = {"cycle": number, "status": "error" if error else "ok", "job": inputs.job,
                                  "part": part, "part_tag": inputs.part_tag,
                                  "error_code": error.code if error else None, "finished_at": time.time()}
        if isinstance(error, RobotOffsetUnconfirmed) and machine.can(Cause.OFFSET_UNCONFIRMED):
            machine.fire(Cause.OFFSET_UNCONFIRMED, error=error)  # FAULT: register 11 = 429, 13 = this cycle
        if machine.state is not State.REPORTING:  # FAULT already: register 11 shows the fault's code,
            self.link.fault_shown = None  # register 13 the new counter (rewritten when the loop shows it)
            return
        try:
            await self.link.write_result(self.shown.result)
        except DeviceError as exc:
            await self._unreported(exc, outcome, number)
            return
        self.shown.outcome_ok, self.shown.done_at = error is None, time.monotonic()
        machine.fire(Cause.REPORTED, f"cycle {number}: {'RESULT_OK' if error is None else error.code}")
        try:  # DONE, in its own write after the result registers
            await self.link.show(status_word(machine.state, self.shown.outcome_ok, self.shown.acknowledged,
                                             self.shown.calibration_warning),
                                 self.shown.result, None)
        except DeviceError as exc:
            await self.link.lost(exc)  # the PLC is told nothing; on reconnecting it sees 0 first
            return
        done = time.monotonic()
        if isinstance(abort.error, PlcHeartbeatLost) and machine.can(Cause.HEARTBEAT_LOST):
            machine.fire(Cause.HEARTBEAT_LOST, error=abort.error)
        # after DONE, off the cycle: a trigger right after the acknowledgement must find the cycle finished
        self.housekeeping = asyncio.create_task(self._housekeeping(number, {"plc_journal": done - started,
                                                                           "cycle": done - triggered_at}))

    async def failed_unexpectedly(self, inputs: PlcInputs, outcome: Outcome | None, exc: Exception) -> None:
        """The report itself raised what it should not (a bug): the cycle is journaled if it was not yet (its error,
        or this one) and, unless DONE was shown already, FAULT latches with :class:`CycleUnexpected` (the PLC may not
        have been told the result); an offset the robot holds from a cycle the PLC was not told of is cleared."""
        error = unexpected(exc, State.REPORTING)
        if outcome is None:
            outcome = Outcome(time.time())
        if outcome.committed is None:
            robot = self.devices.handle("robot")
            if outcome.error is None and outcome.number is not None and robot is not None:
                # a good cycle the PLC was not told of: the robot must not keep its offset
                await asyncio.to_thread(self.ledger.clear_unreported, robot, outcome.number,
                                        f"the report failed ({error.code})")
            if outcome.error is None:
                outcome.fail(error, State.REPORTING, exc)
            try:
                await asyncio.to_thread(self.journal.commit_cycle, journal_entry(outcome, inputs,
                                                                                 self.journal.state_dir))
            except MonoguideError as journal_error:
                log.error("journal: the cycle that failed unexpectedly is not journaled: %s %s", journal_error.code,
                          journal_error.message)
        for cause in (Cause.FAILED, Cause.REPORT_FAILED):  # a cycle reported before the bug (DONE) stays reported
            if self.machine.can(cause):
                self.machine.fire(cause, error=error)

    async def finish_housekeeping(self) -> None:
        """Wait for the last cycle's housekeeping (before the next cycle, and at exit)."""
        if self.housekeeping is not None:
            with contextlib.suppress(Exception):
                await self.housekeeping
            self.housekeeping = None

    async def _commit(self, inputs: PlcInputs, outcome: Outcome) -> int | None:
        """The cycle's row (with its intent's outcome when it was acknowledged); None when the journal refused,
        then FAULT — and a good cycle's offset is cleared from the robot, since nobody can be told of it."""
        intent_outcome = None
        if outcome.error is None and outcome.number is not None:
            intent_outcome = ("acknowledged", f"request {outcome.sequence} acknowledged with status 0")
        entry = journal_entry(outcome, inputs, self.journal.state_dir)
        try:
            outcome.committed = await asyncio.to_thread(self.journal.commit_cycle, entry, outcome.number,
                                                        intent_outcome=intent_outcome)
            return outcome.committed
        except MonoguideError as exc:
            if outcome.error is None and outcome.number is not None:
                await asyncio.to_thread(self.ledger.clear_unreported, self.devices.handle("robot"), outcome.number,
                                        f"the journal could not commit cycle {outcome.number} ({exc.code})")
                # the PLC is never told this cycle's RESULT_OK: its row, when it can be committed, says why
                outcome.fail(type(exc)(f"{exc.message}; the cycle's offset was cleared from the robot, its row "
                                       f"committed once the journal could take it"), State.REPORTING)
                entry = journal_entry(outcome, inputs, self.journal.state_dir)
            self.uncommitted.append((entry, outcome.number))
            if self.machine.can(Cause.REPORT_FAILED):
                self.machine.fire(Cause.REPORT_FAILED, error=exc)
            return None

    async def commit_pending(self) -> MonoguideError | None:
        """Commit the rows (and offset outcomes) the journal could not take when their cycles ended (a full disk), in
        order; None once all are in, else the journal's error (FAULT_RESET waits for it: a cycle that reached BUSY
        is journaled before the next one runs, and its number is never given to another)."""
        if (unrecorded := await asyncio.to_thread(self.ledger.record_pending)) is not None:
            return unrecorded
        while self.uncommitted:
            entry, number = self.uncommitted[0]
            try:
                committed = await asyncio.to_thread(self.journal.commit_cycle, entry, number)
            except MonoguideError as exc:
                return exc
            self.uncommitted.pop(0)
            self.shown.result = dataclasses.replace(self.shown.result, cycle_counter=committed)
            log.info("journal: cycle %d committed now (%s)", committed, entry.error.code if entry.error else "ok")
        return None

    async def _unreported(self, error: DeviceError, outcome: Outcome, number: int) -> None:
        """The result registers could not be written: FAULT says why the cycle ended (its own error, else the
        PLC's); a good cycle's offset is cleared from the robot, since the PLC was not told RESULT_OK."""
        if outcome.error is None and outcome.number is not None:
            robot = self.devices.handle("robot")
            why = f"the PLC could not be told ({error.code})"
            if robot is not None and await asyncio.to_thread(self.ledger.clear_unreported, robot, number, why):
                r = self.shown.result
                self.shown.result = failed_result(error.plc_code, number, r.job, r.part_tag, r.quality)
        self.machine.fire(Cause.REPORT_FAILED, error=outcome.error or error)
        await self.link.lost(error)

    async def _housekeeping(self, number: int, timings_s: dict[str, float]) -> None:
        with contextlib.suppress(MonoguideError):
            await asyncio.to_thread(self.journal.amend_timings, number, timings_s)
        await asyncio.to_thread(self._prune_images)

    def _prune_images(self) -> None:
        s = self.settings
        try:
            pruned = self.journal.prune_images(int(s.images_max_mb * 1e6), s.images_max_age_days * 86400.0)
        except MonoguideError as exc:
            log.warning("images: pruning failed: %s %s", exc.code, exc.message)
            return
        if pruned.files:
            log.info("images: deleted %d files of %d old cycles (%.1f MB)", pruned.files, pruned.cycles,
                     pruned.bytes_freed / 1e6)


def journal_entry(outcome: Outcome, inputs: PlcInputs, state_dir: Path | None = None) -> CycleEntry:
    """The journal row of a finished (or failed) cycle: a failed one with every image it wrote and what each view
    showed (its result's ``views`` and ``failure``, docs/journal.md), whatever stage it failed in."""
    m, s = outcome.measurement, outcome.solution
    timings = dict(getattr(m, "timings_s", None) or {})
    timings.update(outcome.timings_s)
    captures = list(getattr(m, "captures", None) or [])
    images = [c.image_path for c in captures if c.image_path is not None]
    if outcome.error is not None:
        images = images or outcome.seen.image_paths()
    images = [path for path in images if Path(path).is_file()]  # those written (a full disk writes none)
    return CycleEntry(
        started_at=outcome.started_at, finished_at=time.time(), job=inputs.job, part_tag=inputs.part_tag,
        duration_s=time.monotonic() - outcome.started_monotonic,  # a clock step does not change it
        record=getattr(m, "record", None),
        result=getattr(s, "result", None) if outcome.error is None else _failed_result(outcome, state_dir),
        error=outcome.error,
        timings_s=timings,
        poses_at_capture=[c.T_b_f.tolist() for c in captures],
        image_paths=images,
    )


def _failed_result(outcome: Outcome, state_dir: Path | None) -> dict[str, Any]:
    """What a failed cycle still tells: the solve's result when it was refused after solving (its ``status`` then
    ``error``), where it failed (stage, the exception's type, the view and the hole or mark not found, where it was
    expected), every view visited with its image and what was found, and with reference marks each camera's deviation
    (``monoguide health`` reads it)."""
    at = outcome.seen.failed_at
    failure = {"stage": outcome.stage.value if outcome.stage is not None else None, "exception": outcome.exception,
               "unexpected": isinstance(outcome.error, CycleUnexpected), "view": at.view if at else None,
               "point": at.point if at else None,
               "expected_px": list(at.expected_px) if at is not None and at.expected_px is not None else None}
    views = outcome.seen.views()
    for view in views:
        if view["image"] is not None and not Path(view["image"]).is_file():
            view["image"] = None  # not written (a full disk)
        elif view["image"] is not None and state_dir is not None:
            view["image"] = _relative(view["image"], state_dir)
    solved = getattr(outcome.solution, "result", None)  # refused after the solve: the pose that was refused
    result: dict[str, Any] = {**(solved or {}), "status": "error", "failure": failure, "views": views}
    deviation = getattr(outcome.error, "camera_deviation", None)
    if deviation is not None:
        result["camera_deviation"] = deviation
    return result


def _relative(path: str, state_dir: Path) -> str:
    try:
        return str(Path(path).resolve().relative_to(state_dir.resolve()))
    except ValueError:
        return path


def result_registers(outcome: Outcome, number: int, inputs: PlcInputs) -> CycleResult:
    """Registers 11, 13-33: the offset only when it was written and acknowledged; else zeros and the code."""
    s: Any = outcome.solution
    quality = tuple(float(q) for q in s.quality) if s is not None else ZERO_QUALITY
    if outcome.error is None:  # a check job writes nothing: RESULT_OK with no offset
        offset = tuple(float(v) for v in s.offset) if outcome.written else ZERO_OFFSET
        return CycleResult(0, number, inputs.job, inputs.part_tag, offset, quality)  # type: ignore[arg-type]
    return CycleResult(outcome.error.plc_code, number, inputs.job, inputs.part_tag, ZERO_OFFSET,
                       quality)  # type: ignore[arg-type]
