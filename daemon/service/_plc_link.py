"""What the PLC sees in each state of the cell (docs/plc-interface.md), and the PLC's own inputs as edges.

Kept apart from the service's loop so that the contract — which status bits belong to which state — is
in one short table that docs/plc-interface.md can be checked against.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from monoguide.daemon.cycle import CYCLE_STATES, State
from monoguide.drivers.plc_registers import Control, CycleResult, Status

POLL_S = 0.02  # the PLC's registers 0-3 are read this often
ZERO_OFFSET = (0.0,) * 6
ZERO_QUALITY = (0.0,) * 3


def status_word(state: State, outcome_ok: bool | None, acknowledged: bool) -> Status:
    """The status word (register 10) shown in ``state``.

    ``outcome_ok``: in AWAITING_ACK, whether the cycle's offset was written (RESULT_OK) or not (ERROR);
    ``acknowledged``: RESULT_ACK was seen, DONE/RESULT_OK/ERROR are cleared while TRIGGER and RESULT_ACK
    fall (READY follows once both are low).
    """
    if state is State.IDLE:
        return Status.READY
    if state in CYCLE_STATES or state is State.REPORTING:
        return Status.BUSY
    if state is State.AWAITING_ACK:
        if acknowledged:
            return Status(0)
        return Status.DONE | (Status.RESULT_OK if outcome_ok else Status.ERROR)
    if state is State.FAULT:
        return Status.FAULT
    return Status(0)  # STARTING, STOPPED: neither READY nor BUSY


@dataclass
class Edges:
    """Rising edges of the control word between two reads."""

    previous: Control = field(default_factory=lambda: Control(0))

    def update(self, control: Control) -> Control:
        rising = Control(control & ~self.previous)
        self.previous = control
        return rising


def failed_result(plc_code: int, counter: int, job: int, part_tag: int,
                  quality: tuple[float, float, float] = ZERO_QUALITY) -> CycleResult:
    """The result registers of a cycle that wrote nothing to the robot: offset 0, the error's code."""
    return CycleResult(plc_code, counter, job, part_tag, ZERO_OFFSET, quality)
