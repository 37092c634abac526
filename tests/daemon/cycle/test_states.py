"""The cycle's state machine: the table is the one issue 10 describes, and walking it works or raises."""

from __future__ import annotations

import itertools
import logging

import pytest

from monoguide.daemon.cycle import ERROR_CAUSES, TRANSITIONS, Cause, CycleStateMachine, State
from monoguide.daemon.errors import IllegalTransition
from monoguide.drivers.errors import DeviceTimeout
from monoguide.solver.errors import MonoguideError

S, C = State, Cause
# Written out from the issue's text, independently of the module's table: a good cycle, the failure path
# from every cycle state, the heartbeat fault from everywhere the service is alive, the latch, stopping.
EXPECTED = {
    (S.STARTING, C.DEVICES_CONNECTED): S.IDLE,
    (S.STARTING, C.HEARTBEAT_LOST): S.FAULT,
    (S.STARTING, C.OFFSET_UNCONFIRMED): S.FAULT,
    (S.STARTING, C.STOP): S.STOPPED,
    (S.IDLE, C.TRIGGER): S.MEASURING,
    (S.IDLE, C.DEVICE_LOST): S.STARTING,
    (S.IDLE, C.HEARTBEAT_LOST): S.FAULT,
    (S.IDLE, C.STOP): S.STOPPED,
    (S.MEASURING, C.VIEWS_MEASURED): S.SOLVING,
    (S.SOLVING, C.POSE_SOLVED): S.CHECKING,
    (S.CHECKING, C.CHECKS_PASSED): S.WRITING,
    (S.CHECKING, C.REFERENCE_CHECKED): S.REPORTING,  # the check job: nothing to write
    (S.WRITING, C.OFFSET_ACKNOWLEDGED): S.REPORTING,
    **{(state, C.FAILED): S.REPORTING for state in (S.MEASURING, S.SOLVING, S.CHECKING, S.WRITING)},
    **{(state, C.HEARTBEAT_LOST): S.FAULT for state in (S.MEASURING, S.SOLVING, S.CHECKING, S.WRITING)},
    (S.REPORTING, C.REPORTED): S.AWAITING_ACK,
    (S.REPORTING, C.REPORT_FAILED): S.FAULT,
    (S.REPORTING, C.HEARTBEAT_LOST): S.FAULT,
    (S.REPORTING, C.OFFSET_UNCONFIRMED): S.FAULT,
    (S.AWAITING_ACK, C.RESULT_ACKNOWLEDGED): S.IDLE,
    (S.AWAITING_ACK, C.DEVICE_LOST): S.STARTING,  # the PLC's own connection lost after DONE
    (S.AWAITING_ACK, C.ACK_TIMEOUT): S.FAULT,
    (S.AWAITING_ACK, C.HEARTBEAT_LOST): S.FAULT,
    (S.AWAITING_ACK, C.STOP): S.STOPPED,
    (S.FAULT, C.FAULT_RESET): S.STARTING,
    (S.FAULT, C.STOP): S.STOPPED,
}
ALL_PAIRS = list(itertools.product(State, Cause))


def _error() -> MonoguideError:
    return DeviceTimeout("robot: not in position at measuring pose 2 within 10 s")


def _fire(machine: CycleStateMachine, cause: Cause, detail: str = "") -> State:
    return machine.fire(cause, detail, error=_error() if cause in ERROR_CAUSES else None)


def test_the_table_is_the_issues_table() -> None:
    declared = {(state, cause): target for state, row in TRANSITIONS.items() for cause, target in row.items()}
    assert declared == EXPECTED
    assert set(TRANSITIONS) == set(State)


@pytest.mark.parametrize(("state", "cause"), ALL_PAIRS, ids=lambda v: v.name)
def test_every_pair_of_state_and_cause_works_or_raises(state: State, cause: Cause) -> None:
    machine = CycleStateMachine(state)
    if (state, cause) in EXPECTED:
        assert _fire(machine, cause) is EXPECTED[state, cause]
        assert machine.state is EXPECTED[state, cause]
        (transition,) = machine.history
        assert (transition.source, transition.target, transition.cause) == (state, EXPECTED[state, cause], cause)
    else:
        with pytest.raises(IllegalTransition, match=f"{cause.name} is not allowed in state {state.name}"):
            _fire(machine, cause)
        assert machine.state is state and not machine.history


def test_every_state_is_reachable_and_none_but_stopped_is_a_dead_end() -> None:
    reached, frontier = {S.STARTING}, [S.STARTING]
    while frontier:
        for target in TRANSITIONS[frontier.pop()].values():
            if target not in reached:
                reached.add(target)
                frontier.append(target)
    assert reached == set(State)
    assert [state for state in State if not TRANSITIONS[state]] == [S.STOPPED]


def test_a_good_cycle_logs_each_transition_with_its_cause(caplog: pytest.LogCaptureFixture) -> None:
    machine = CycleStateMachine()
    caplog.set_level(logging.INFO, logger="monoguide.daemon.cycle._states")
    for cause in (C.DEVICES_CONNECTED, C.TRIGGER, C.VIEWS_MEASURED, C.POSE_SOLVED, C.CHECKS_PASSED,
                  C.OFFSET_ACKNOWLEDGED, C.REPORTED, C.RESULT_ACKNOWLEDGED):
        machine.fire(cause, detail="job 1 tag 77" if cause is C.TRIGGER else "")
    assert machine.state is S.IDLE and machine.error is None
    assert [t.target for t in machine.history] == [S.IDLE, S.MEASURING, S.SOLVING, S.CHECKING, S.WRITING,
                                                   S.REPORTING, S.AWAITING_ACK, S.IDLE]
    assert len(caplog.records) == 8
    assert caplog.records[1].getMessage() == "cycle idle -> measuring (trigger: job 1 tag 77)"


@pytest.mark.parametrize("failing_state", [S.MEASURING, S.SOLVING, S.CHECKING, S.WRITING], ids=lambda s: s.name)
def test_any_failure_reports_its_code_and_returns_to_idle(failing_state: State,
                                                          caplog: pytest.LogCaptureFixture) -> None:
    machine = CycleStateMachine(failing_state)
    error = _error()
    machine.fire(C.FAILED, error=error)
    assert machine.state is S.REPORTING and machine.error is error and machine.error.plc_code == 402
    assert "[DEVICE_TIMEOUT 402] robot: not in position" in caplog.text
    # the offset is never written: from reporting the only ways on are reported, or a fault
    assert C.OFFSET_ACKNOWLEDGED not in machine.allowed()
    machine.fire(C.REPORTED)
    machine.fire(C.RESULT_ACKNOWLEDGED)
    assert machine.state is S.IDLE and machine.error is error  # still shown until the next trigger
    machine.fire(C.TRIGGER)
    assert machine.error is None


def test_the_fault_latch_is_left_only_by_a_fault_reset() -> None:
    machine = CycleStateMachine(S.WRITING)
    lost = _error()
    machine.fire(C.HEARTBEAT_LOST, error=lost)
    assert machine.state is S.FAULT and machine.fault is lost
    for cause in Cause:
        if cause not in (C.FAULT_RESET, C.STOP):
            with pytest.raises(IllegalTransition):
                _fire(machine, cause)
            assert machine.state is S.FAULT and machine.fault is lost
    machine.fire(C.FAULT_RESET, detail="heartbeat back, FAULT_RESET pulsed")
    assert machine.state is S.STARTING and machine.fault is None
    machine.fire(C.DEVICES_CONNECTED)
    assert machine.state is S.IDLE


def test_an_error_cause_needs_its_error_and_others_refuse_one() -> None:
    machine = CycleStateMachine(S.MEASURING)
    with pytest.raises(IllegalTransition, match="FAILED in state MEASURING needs the error"):
        machine.fire(C.FAILED)
    with pytest.raises(IllegalTransition, match="VIEWS_MEASURED in state MEASURING carries no error"):
        machine.fire(C.VIEWS_MEASURED, error=_error())
    assert machine.state is S.MEASURING and not machine.history


def test_history_is_bounded_and_timed() -> None:
    ticks = iter(range(100))
    machine = CycleStateMachine(S.IDLE, history_limit=3, clock=lambda: float(next(ticks)))
    for _ in range(3):
        machine.fire(C.DEVICE_LOST)
        machine.fire(C.DEVICES_CONNECTED)
    assert [t.at for t in machine.history] == [3.0, 4.0, 5.0]
    assert machine.history[-1].cause is C.DEVICES_CONNECTED
