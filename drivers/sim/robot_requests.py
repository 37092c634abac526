"""What the simulated robot program is told: its requests as it reads them, the fault commands of the simulated
controllers (a mode in force, or a one-shot action) parsed and checked, and the records of what it did with an
offset or a grasp (for the truth file).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Protocol

import numpy as np

FAULT_MODES = ("none", "stall", "drop", "protective-stop", "never-reach", "no-ack", "program-stopped")
# one-shot: they act once, and leave the mode in force as it was; ``reference-part``: the part supply's next part is
# the reference part, exactly as taught, and it stays until grasped (a check job measures it, visit after visit)
FAULT_ACTIONS = ("restart", "cut", "cut-after-offset", "reference-part")
CUT_DOWN_S = 1.0  # cut-after-offset: how long new connections are closed at once (default)
MAX_CUT_MS = 60_000.0


@dataclass(frozen=True)
class Request:
    """One request as the program read it; ``D_b`` None: a field could not be read (KUKA: a RET not ok)."""

    sequence: int
    command: int
    pose_number: int
    D_b: np.ndarray | None
    received: tuple[float, ...]  # the offset as it arrived, in the wire's units


class RequestSource(Protocol):
    """Where the program reads its requests: UR the input registers (``level``: the same request until the daemon
    writes another), KUKA the EKI buffer (each message once)."""

    level: bool

    def next_request(self) -> Request | None: ...


@dataclass(frozen=True)
class FaultCommand:
    """A fault command line, checked: its name and, for ``cut-after-offset``, MS and DOWN_S (``cut``: DOWN_S)."""

    name: str
    after_ms: float = 0.0
    down_s: float = CUT_DOWN_S


@dataclass
class AppliedOffset:
    sequence: int
    part: int
    received: tuple[float, ...]  # as it arrived on the wire, in the wire's units
    D_b: np.ndarray
    grasp_error_mm: float
    grasp_error_deg: float


@dataclass
class Grasp:
    """A grasp the go asked for: run with the held offset, or refused by the interlock (``reason``)."""

    part: int
    held_sequence: int
    outcome: str  # "ran" | "refused"
    reason: str | None  # refused: "stale offset" (one is held, not valid) | "no offset"
    grasp_error_mm: float | None  # ran: the held offset on the part in the cell now; refused: what it would have been
    grasp_error_deg: float | None
    at_s: float

    def record(self) -> dict[str, object]:
        return dataclasses.asdict(self)


def parse_fault(text: str) -> FaultCommand:
    """A fault command line -> :class:`FaultCommand`; ValueError naming what is wrong."""
    name, *args = text.split()
    if name not in FAULT_MODES + FAULT_ACTIONS:
        raise ValueError(f"fault {name!r}: expected one of {', '.join(FAULT_MODES + FAULT_ACTIONS)}")
    if name == "cut":  # the cable pulled now: DOWN_S
        if len(args) > 1:
            raise ValueError(f"fault cut takes [DOWN_S], got {' '.join(args)!r}")
        try:
            down_s = float(args[0]) if args else CUT_DOWN_S
        except ValueError as exc:
            raise ValueError(f"fault cut {args[0]}: DOWN_S is a number of seconds") from exc
        if not 0 < down_s <= MAX_CUT_MS / 1000:
            raise ValueError(f"fault cut {args[0]}: DOWN_S above 0 up to {MAX_CUT_MS / 1000:g}")
        return FaultCommand(name, 0.0, down_s)
    if name != "cut-after-offset":
        if args:
            raise ValueError(f"fault {name} takes nothing more, got {' '.join(args)!r}")
        return FaultCommand(name)
    if not 1 <= len(args) <= 2:
        raise ValueError(f"fault cut-after-offset takes MS [DOWN_S], got {' '.join(args) or 'nothing'}")
    try:
        after_ms, down_s = float(args[0]), float(args[1]) if len(args) == 2 else CUT_DOWN_S
    except ValueError as exc:
        raise ValueError(f"fault cut-after-offset {' '.join(args)}: MS and DOWN_S are numbers") from exc
    if not (0 <= after_ms <= MAX_CUT_MS and 0 < down_s <= MAX_CUT_MS / 1000):
        raise ValueError(f"fault cut-after-offset {' '.join(args)}: MS 0..{MAX_CUT_MS:g}, DOWN_S above 0 up to "
                         f"{MAX_CUT_MS / 1000:g}")
    return FaultCommand(name, after_ms, down_s)
