"""Nothing reaches the robot unrecorded: the offset's intent before it is sent, its outcome after, and the
settling of every offset whose acknowledgement monoguide did not see (docs/cycle.md, "The offset's intent").

The rule: the robot holds a valid offset only from a cycle the PLC was told RESULT_OK about.

- Before the offset goes on the wire, the journal commits its **intent** (cycle number, the robot request's
  sequence number, the six numbers, and the cycle's job, part tag and start, for the row rebuilt from it). When
  that commit fails, nothing is sent (the cycle ends in ERROR with the journal's code).
- Acknowledged (status 0, exactly that sequence): the outcome ``acknowledged`` is committed with the cycle's
  row. Refused by the program (a negative status for that sequence): ``refused``, the program holds nothing
  from it.
- Anything else after the send (no answer in time, the controller lost, the worker crashed): monoguide
  **settles** it at once if the robot answers — it synchronises with the program, reads which offset the
  program holds (``held`` / ``not_held``) and clears it (command 3), so the robot holds nothing from this
  cycle, and the cycle ends in ERROR with the original code. When the robot cannot say,
  :class:`~monoguide.drivers.errors.RobotOffsetUnconfirmed` (429): FAULT stays latched until the service has
  settled it against the robot's report (after the robot is back) and the PLC pulsed FAULT_RESET.
- At start, an intent without an outcome (the service was killed between sending and committing) gets its
  cycle's row (429) if it has none, and is settled the same way before the cell is READY again.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

from monoguide.daemon.service._journal import CycleEntry, Journal, OffsetIntent
from monoguide.drivers.errors import DeviceDisconnected, RobotCommandRejected, RobotOffsetUnconfirmed
from monoguide.drivers.robot import Robot
from monoguide.solver.errors import MonoguideError

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Settled:
    """What settling an intent found: whether the robot held that offset, and what the journal says of it."""

    cycle: int
    sequence: int
    held: bool
    detail: str


class OffsetLedger:
    """The intents of one journal and the settling of those without an outcome. Blocking (journal, robot):
    call it from worker threads, one call at a time."""

    def __init__(self, journal: Journal) -> None:
        self.journal = journal
        self.unsettled: list[OffsetIntent] = journal.unsettled_intents()
        self.unrecorded: list[tuple[int, str, str, bool]] = []  # settled with the robot, not yet in the journal

    # --- at start -------------------------------------------------------------------------------------

    def recover(self) -> list[int]:
        """Give every unsettled intent whose cycle has no row (the service ended between sending the offset and
        committing the cycle) its row, ERROR ``ROBOT_OFFSET_UNCONFIRMED``, with the job, part tag and start the
        intent carries (an intent of a journal before schema version 3: none, and the intent's time as the start);
        it finished, as far as the journal knows, when the intent was committed. Return those cycle numbers."""
        recovered = []
        for intent in self.unsettled:
            if self.journal.has_cycle(intent.cycle):
                continue
            part = "" if intent.job is None else f" (job {intent.job}, part tag {intent.part_tag})"
            error = RobotOffsetUnconfirmed(
                f"cycle {intent.cycle}{part}: the service ended after its offset (request {intent.sequence}) was "
                f"committed to be sent and before the robot's answer was recorded; the robot may hold it: do not "
                f"grasp (settled against the robot's report when it is reachable)")
            started_at = intent.intended_at if intent.started_at is None else intent.started_at
            self.journal.commit_cycle(CycleEntry(started_at=started_at, finished_at=intent.intended_at,
                                                 job=intent.job, part_tag=intent.part_tag, error=error), intent.cycle)
            log.warning("journal: %s", error.message)
            recovered.append(intent.cycle)
        return recovered

    def unconfirmed_error(self) -> RobotOffsetUnconfirmed | None:
        """The error FAULT shows while an intent is unsettled (None when all are settled)."""
        if not self.unsettled:
            return None
        cycles = ", ".join(f"{i.cycle} (request {i.sequence})" for i in self.unsettled)
        return RobotOffsetUnconfirmed(f"the robot may hold the offset of cycle {cycles}: do not grasp; monoguide "
                                      "settles it against the robot's report once the robot answers")

    # --- during a cycle -------------------------------------------------------------------------------

    def intend(self, cycle: int, sequence: int, registers: tuple[float, ...], D_b: list[list[float]], *,
               job: int | None = None, part_tag: int | None = None, started_at: float | None = None) -> None:
        """Commit the intent (raises, and then nothing may be sent, when the journal cannot). ``job``,
        ``part_tag`` (PLC registers 1 and 3), ``started_at`` (the cycle's Unix start): what the row rebuilt from
        the intent after a kill -9 carries (:meth:`recover`)."""
        self.journal.commit_intent(cycle, sequence, registers, D_b, job=job, part_tag=part_tag,
                                   started_at=started_at)

    def after_failed_write(self, robot: Robot, cycle: int, sequence: int, error: MonoguideError) -> MonoguideError:
        """The write of cycle ``cycle``'s offset (request ``sequence``) failed with ``error`` after it was sent:
        settle it now; return the error the cycle ends with — ``error`` (amended) when the robot holds nothing
        from this cycle, :class:`RobotOffsetUnconfirmed` when it cannot say (then the intent stays unsettled)."""
        if isinstance(error, RobotCommandRejected):  # the program refused exactly this request
            self._journal_outcome(cycle, "refused", f"request {sequence}: {error.message}", cleared=False)
            return error
        intent = self.journal.intent(cycle)
        assert intent is not None, "an intent is committed before the offset is sent"
        try:
            settled = self._settle(robot, intent)
        except Exception as settle_error:  # whatever stopped the settling (a bug too): the robot may hold it
            self.unsettled.append(intent)
            why = (f"{settle_error.code}: {settle_error.message}" if isinstance(settle_error, MonoguideError)
                   else f"unexpected {type(settle_error).__name__}: {settle_error}")
            if not isinstance(settle_error, MonoguideError):
                log.exception("cycle %d: settling the offset failed unexpectedly", cycle)
            return RobotOffsetUnconfirmed(
                f"cycle {cycle}: the offset (request {sequence}) was sent and then {error.code}: {error.message}; "
                f"the robot cannot say now whether it took it ({why}): do not grasp; FAULT until monoguide has "
                "settled it against the robot's report")
        return type(error)(f"{error.message}; {settled.detail}")

    def acknowledged(self, cycle: int, sequence: int) -> tuple[str, str]:
        """The outcome committed with a good cycle's row."""
        return "acknowledged", f"request {sequence} acknowledged with status 0"

    def clear_unreported(self, robot: Robot | None, cycle: int, why: str) -> bool:
        """A good cycle whose result could not be reported (journal or PLC): clear the robot's offset, so it
        holds nothing the PLC was not told about. True when cleared (and journaled where the journal can); when it
        cannot be cleared now (the robot lost too), the offset is unsettled: FAULT 429 until it is."""
        try:
            if robot is None:
                raise DeviceDisconnected("robot: not connected")
            robot.clear_offset()
        except MonoguideError as exc:
            log.error("cycle %d: the robot holds its offset but the PLC was not told (%s); clearing it failed: %s %s; "
                      "it is cleared as soon as the robot answers", cycle, why, exc.code, exc.message)
            intent = self.journal.intent(cycle)
            if intent is not None and all(i.cycle != cycle for i in self.unsettled):
                self.unsettled.append(intent)
            return False
        log.warning("cycle %d: offset cleared from the robot: %s", cycle, why)
        self._journal_outcome(cycle, "acknowledged", f"acknowledged, then cleared: {why}", cleared=True)
        return True

    # --- later, from the service's loop ----------------------------------------------------------------

    def settle_pending(self, robot: Robot) -> list[Settled]:
        """Settle every unsettled intent against the robot (raises the robot's error and keeps the rest when it
        cannot); return what was found."""
        done = []
        while self.unsettled:
            intent = self.unsettled[0]
            done.append(self._settle(robot, intent))
            self.unsettled.pop(0)
        return done

    # --- private ----------------------------------------------------------------------------------------

    def _settle(self, robot: Robot, intent: OffsetIntent) -> Settled:
        held = robot.held_offset()
        took = held.sequence == intent.sequence
        cleared = robot.clear_offset()
        detail = (f"settled: the robot {'took' if took else 'did not take'} the offset of request {intent.sequence} "
                  f"(it reported held request {held.sequence}, {'valid' if held.valid else 'not valid'}); monoguide "
                  f"cleared it (request {cleared}): the robot holds no offset from this cycle")
        log.warning("cycle %d: %s", intent.cycle, detail)
        self._journal_outcome(intent.cycle, "held" if took else "not_held", detail, cleared=True)
        return Settled(intent.cycle, intent.sequence, took, detail)

    def record_pending(self) -> MonoguideError | None:
        """Record the outcomes the journal could not take when they were settled (a full disk); None when all are
        recorded, else the journal's error (FAULT_RESET waits for it)."""
        while self.unrecorded:
            cycle, outcome, detail, cleared = self.unrecorded[0]
            try:
                self.journal.settle_intent(cycle, outcome, detail, cleared=cleared)
            except MonoguideError as exc:
                return exc
            self.unrecorded.pop(0)
            log.info("journal: the outcome of cycle %d's offset (%s) recorded now", cycle, outcome)
        return None

    def _journal_outcome(self, cycle: int, outcome: str, detail: str, *, cleared: bool) -> None:
        try:
            self.journal.settle_intent(cycle, outcome, detail, cleared=cleared)
        except MonoguideError as exc:  # the robot's side is settled; the journal takes it when it can
            self.unrecorded.append((cycle, outcome, detail, cleared))
            log.error("journal: the outcome of cycle %d's offset (%s) not recorded: %s %s; recorded before FAULT "
                      "clears (or settled again at the next start)", cycle, outcome, exc.code, exc.message)
