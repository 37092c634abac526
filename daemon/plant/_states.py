"""The service's states (docs/cycle-states.md) as OPC 40100-1's vision state machines show them.

``VisionStateMachine`` (VisionStateMachineType) has four top states; in ``Operational`` its sub-machine
``AutomaticModeStateMachine`` (VisionAutomaticModeStateMachineType) says whether the system waits for a start
(``Ready``) or executes one (``SingleExecution``: a cycle from the PLC's TRIGGER until its RESULT_ACK).
monoguide has no manual or continuous mode, so ``Initialized`` and ``ContinuousExecution`` are never shown.

| service state | VisionStateMachine | AutomaticModeStateMachine |
|---|---|---|
| no service running, ``stopped`` | Halted | (not active) |
| ``starting`` | Preoperational | (not active) |
| ``idle`` | Operational | Ready |
| ``measuring`` .. ``reporting``, ``awaiting_ack`` | Operational | SingleExecution |
| ``fault`` | Error | (not active) |
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

TOP_STATES = ("Preoperational", "Halted", "Error", "Operational")  # OPC 40100-1 VisionStateMachineType
AUTOMATIC_STATES = ("Initialized", "Ready", "SingleExecution", "ContinuousExecution")  # ...AutomaticModeStateMachine
NOT_RUNNING = "not running"  # the service state a reader shows when no service runs (status.json says so)

# the transitions without a cause (``...Auto``) of the published machines, by the states they join: monoguide's states
# change by themselves (the PLC's TRIGGER, a fault, FAULT_RESET), never by a method of the server
TOP_TRANSITIONS = {
    ("Halted", "Preoperational"): "HaltedToPreoperationalAuto",
    ("Preoperational", "Halted"): "PreoperationalToHaltedAuto",
    ("Preoperational", "Error"): "PreoperationalToErrorAuto",
    ("Preoperational", "Operational"): "PreoperationalToOperationalAuto",
    ("Operational", "Halted"): "OperationalToHaltedAuto",
    ("Operational", "Preoperational"): "OperationalToPreoperationalAuto",
    ("Operational", "Error"): "OperationalToErrorAuto",
    ("Error", "Halted"): "ErrorToHaltedAuto",
    ("Error", "Preoperational"): "ErrorToPreoperationalAuto",
    ("Error", "Operational"): "ErrorToOperationalAuto",
}
AUTOMATIC_TRANSITIONS = {
    ("Ready", "SingleExecution"): "ReadyToSingleExecutionAuto",
    ("SingleExecution", "Ready"): "SingleExecutionToReadyAuto",
}

_EXECUTING = ("measuring", "solving", "checking", "writing", "reporting", "awaiting_ack")


@dataclass(frozen=True)
class VisionState:
    top: str  # one of TOP_STATES
    automatic: str | None  # one of AUTOMATIC_STATES while Operational, else None (the sub-machine is not active)


def vision_state(service_state: str, running: bool) -> VisionState:
    """The 40100 states of the service in ``service_state`` (a status.json state); ``running``: its liveness."""
    if not running or service_state == "stopped":
        return VisionState("Halted", None)
    if service_state == "starting":
        return VisionState("Preoperational", None)
    if service_state == "fault":
        return VisionState("Error", None)
    if service_state == "idle":
        return VisionState("Operational", "Ready")
    if service_state in _EXECUTING:
        return VisionState("Operational", "SingleExecution")
    raise ValueError(f"service state {service_state!r} has no vision state")


def transitions(source: str, target: str, table: dict[tuple[str, str], str]) -> list[tuple[str, str, str]]:
    """The published transitions (name, from, to) that lead from ``source`` to ``target``, fewest first: the plant
    reads the service's state every ``poll_s`` and may have missed one between (Halted to Operational is
    HaltedToPreoperationalAuto, PreoperationalToOperationalAuto). Empty when they are the same state."""
    if source == target:
        return []
    paths: deque[list[tuple[str, str, str]]] = deque([[]])
    seen = {source}
    while paths:
        path = paths.popleft()
        at = path[-1][2] if path else source
        for (start, end), name in table.items():
            if start != at or end in seen:
                continue
            step = [*path, (name, start, end)]
            if end == target:
                return step
            seen.add(end)
            paths.append(step)
    raise ValueError(f"no transition from {source!r} to {target!r}")
