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

from dataclasses import dataclass

TOP_STATES = ("Preoperational", "Halted", "Error", "Operational")  # OPC 40100-1 VisionStateMachineType
AUTOMATIC_STATES = ("Initialized", "Ready", "SingleExecution", "ContinuousExecution")  # ...AutomaticModeStateMachine
NOT_RUNNING = "not running"  # the service state a reader shows when no service runs (status.json says so)

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
