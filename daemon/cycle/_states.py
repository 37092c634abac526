"""The measuring cycle as a declared state machine: the states, the table of allowed transitions, the latch.

One cycle runs idle -> measuring -> solving -> checking -> writing -> reporting -> awaiting_ack -> idle
Every transition is named by its cause (:class:`Cause`); the table :data:`TRANSITIONS` says,
for each state, which causes may happen there and where each leads. A cause the table does not list for
the current state is a bug in the caller and raises :class:`IllegalTransition` — the machine never guesses.

- **Any failure** during a cycle (measuring .. writing) is ``FAILED`` with the error that caused it: the
  cycle goes to reporting (journal, then the PLC sees ERROR with the error's ``plc_code``), nothing is
  written to the robot, and after the PLC's acknowledgement the cell is idle again.
- **FAULT is a latch**: PLC heartbeat lost, the journal unable to commit, no acknowledgement from the
  PLC, or an offset sent to the robot whose fate monoguide could not settle (``OFFSET_UNCONFIRMED``). It
  is left only by ``FAULT_RESET`` (the caller checks that the heartbeat is back, every offset settled and
  the journal still in place) — or by the service stopping (``STOP``).
- **STARTING** is the not-ready state: status word 0 written, devices (re)connecting. The cell enters
  idle (READY) only through ``DEVICES_CONNECTED``.

Modelled on bluesky's ``RunEngineStateMachine`` (``run_engine.py``): states and allowed transitions are
data, so the table can be documented and walked by a test.
"""

from __future__ import annotations

import enum
import logging
import time
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass

from monoguide.daemon.errors import IllegalTransition
from monoguide.solver.errors import MonoguideError

log = logging.getLogger(__name__)

# plc_code ranges of the service: 600-609 this state machine, 610-619 the service (sd_notify, run),
# 620-629 the journal (daemon/service/_journal.py).


class State(enum.Enum):
    """Where the cell is. ``value`` is what logs, ``STATUS=`` and the journal show."""

    STARTING = "starting"  # status word 0 written, devices connecting; not READY
    IDLE = "idle"  # READY: waiting for a trigger
    MEASURING = "measuring"  # visiting the measuring poses, grabbing, finding holes
    SOLVING = "solving"  # pose, covariance, perspective correction
    CHECKING = "checking"  # residual, sigma, envelope, robot pose at capture
    WRITING = "writing"  # the base offset to the robot, waiting for its acknowledgement
    REPORTING = "reporting"  # journal commit, then result registers, then DONE to the PLC
    AWAITING_ACK = "awaiting_ack"  # DONE shown; waiting for RESULT_ACK and TRIGGER low
    FAULT = "fault"  # latched; left only by FAULT_RESET (or STOP)
    STOPPED = "stopped"  # the service has ended; terminal


class Cause(enum.Enum):
    """Why the cell changes state. Causes marked *error* must carry the error that caused them."""

    DEVICES_CONNECTED = "devices connected"
    DEVICE_LOST = "device lost"
    TRIGGER = "trigger"
    VIEWS_MEASURED = "views measured"
    POSE_SOLVED = "pose solved"
    CHECKS_PASSED = "checks passed"
    REFERENCE_CHECKED = "calibration check passed"  # the check job: nothing to write
    OFFSET_ACKNOWLEDGED = "offset acknowledged by the robot"
    FAILED = "failed"  # error: any failure of the cycle, including trigger dropped and shutdown abort
    REPORTED = "reported"  # journal committed, DONE shown
    RESULT_ACKNOWLEDGED = "result acknowledged"  # RESULT_ACK seen, TRIGGER and RESULT_ACK low again
    HEARTBEAT_LOST = "PLC heartbeat lost"  # error
    REPORT_FAILED = "report failed"  # error: the journal could not commit or the PLC could not be told
    ACK_TIMEOUT = "no acknowledgement"  # error: the PLC never acknowledged DONE
    OFFSET_UNCONFIRMED = "offset unconfirmed"  # error: the robot may hold an offset monoguide could not settle
    FAULT_RESET = "fault reset"
    STOP = "stop"


ERROR_CAUSES = frozenset({Cause.FAILED, Cause.HEARTBEAT_LOST, Cause.REPORT_FAILED, Cause.ACK_TIMEOUT,
                          Cause.OFFSET_UNCONFIRMED})

CYCLE_STATES = (State.MEASURING, State.SOLVING, State.CHECKING, State.WRITING)
"""The states of a running cycle (the PLC sees BUSY); a failure in any of them is reported as ERROR."""


def _cycle_state(next_on_success: tuple[Cause, State]) -> dict[Cause, State]:
    cause, target = next_on_success
    return {cause: target, Cause.FAILED: State.REPORTING, Cause.HEARTBEAT_LOST: State.FAULT}


TRANSITIONS: Mapping[State, Mapping[Cause, State]] = {
    State.STARTING: {
        Cause.DEVICES_CONNECTED: State.IDLE,
        Cause.HEARTBEAT_LOST: State.FAULT,
        Cause.OFFSET_UNCONFIRMED: State.FAULT,  # the journal holds an offset intent without an outcome
        Cause.STOP: State.STOPPED,
    },
    State.IDLE: {
        Cause.TRIGGER: State.MEASURING,
        Cause.DEVICE_LOST: State.STARTING,
        Cause.HEARTBEAT_LOST: State.FAULT,
        Cause.STOP: State.STOPPED,
    },
    State.MEASURING: _cycle_state((Cause.VIEWS_MEASURED, State.SOLVING)),
    State.SOLVING: _cycle_state((Cause.POSE_SOLVED, State.CHECKING)),
    State.CHECKING: {**_cycle_state((Cause.CHECKS_PASSED, State.WRITING)), Cause.REFERENCE_CHECKED: State.REPORTING},
    State.WRITING: _cycle_state((Cause.OFFSET_ACKNOWLEDGED, State.REPORTING)),
    State.REPORTING: {
        Cause.REPORTED: State.AWAITING_ACK,
        Cause.REPORT_FAILED: State.FAULT,
        Cause.HEARTBEAT_LOST: State.FAULT,
        Cause.OFFSET_UNCONFIRMED: State.FAULT,  # journaled; the robot may hold the offset: no DONE
    },
    State.AWAITING_ACK: {
        Cause.RESULT_ACKNOWLEDGED: State.IDLE,
        Cause.DEVICE_LOST: State.STARTING,  # the PLC's connection lost: it sees status 0 on reconnecting
        Cause.ACK_TIMEOUT: State.FAULT,
        Cause.HEARTBEAT_LOST: State.FAULT,
        Cause.STOP: State.STOPPED,
    },
    State.FAULT: {
        Cause.FAULT_RESET: State.STARTING,
        Cause.STOP: State.STOPPED,
    },
    State.STOPPED: {},
}
"""For each state, the causes allowed there and the state each leads to. Anything else raises."""


@dataclass(frozen=True)
class Transition:
    """One logged change of state: when (``time.time()`` seconds), from, to, why."""

    at: float
    source: State
    target: State
    cause: Cause
    detail: str = ""
    error: MonoguideError | None = None


class CycleStateMachine:
    """Holds the current state, performs transitions by cause, logs each and keeps the recent history.

    ``error`` is the error of the current cycle from ``FAILED`` until the next ``TRIGGER`` (what the PLC's
    error register and the journal show); ``fault`` is the error that latched FAULT, until ``FAULT_RESET``.
    """

    def __init__(
        self,
        state: State = State.STARTING,
        history_limit: int = 1000,
        clock: Callable[[], float] = time.time,
    ) -> None:
        self._state = state
        self._clock = clock
        self.history: deque[Transition] = deque(maxlen=history_limit)
        self.error: MonoguideError | None = None
        self.fault: MonoguideError | None = None

    @property
    def state(self) -> State:
        return self._state

    def allowed(self) -> Mapping[Cause, State]:
        """The causes allowed in the current state and where each leads."""
        return TRANSITIONS[self._state]

    def can(self, cause: Cause) -> bool:
        return cause in TRANSITIONS[self._state]

    def fire(self, cause: Cause, detail: str = "", error: MonoguideError | None = None) -> State:
        """Perform the transition ``cause`` leads to from the current state; return the new state.

        Raises :class:`IllegalTransition` when the table has no such transition, or when an error cause
        comes without its error (or another cause with one); the state is then unchanged.
        """
        source = self._state
        target = TRANSITIONS[source].get(cause)
        if target is None:
            allowed = ", ".join(c.name for c in TRANSITIONS[source]) or "none (terminal)"
            raise IllegalTransition(
                f"cause {cause.name} is not allowed in state {source.name} (allowed there: {allowed})"
            )
        if (cause in ERROR_CAUSES) != (error is not None):
            needs = "needs the error that caused it" if cause in ERROR_CAUSES else "carries no error"
            raise IllegalTransition(f"cause {cause.name} in state {source.name} {needs}")
        self._state = target
        if cause is Cause.TRIGGER:
            self.error = None
        elif cause is Cause.FAILED:
            self.error = error
        if target is State.FAULT:
            self.fault = error
        elif cause is Cause.FAULT_RESET:
            self.fault = None
        transition = Transition(self._clock(), source, target, cause, detail, error)
        self.history.append(transition)
        _log(transition)
        return target


def _log(transition: Transition) -> None:
    why = transition.cause.value
    if transition.detail:
        why += f": {transition.detail}"
    if transition.error is not None:
        why += f" [{transition.error.code} {transition.error.plc_code}] {transition.error.message}"
    level = logging.WARNING if transition.error is not None else logging.INFO
    log.log(level, "cycle %s -> %s (%s)", transition.source.value, transition.target.value, why)
