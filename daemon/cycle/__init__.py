"""One measuring cycle: the state machine of its states and the blocking work of each (docs/cycle.md).

The states are light; the runner needs OpenCV and SciPy, so it is loaded when it is first asked for (a reader
of the service's state, ``monoguide status``, never pays for it).
"""

from __future__ import annotations

from typing import Any

from monoguide.daemon.cycle._memory import trim_malloc, tune_malloc
from monoguide.daemon.cycle._residual import Residual
from monoguide.daemon.cycle._seen import FailedAt, Sought, ViewsSeen, wait_images
from monoguide.daemon.cycle._states import CYCLE_STATES, ERROR_CAUSES, TRANSITIONS, Cause, CycleStateMachine, State

__all__ = ["CYCLE_STATES", "ERROR_CAUSES", "TRANSITIONS", "Cause", "CycleRunner", "CycleStateMachine", "FailedAt",
           "Residual", "Sought", "State", "ViewsSeen", "trim_malloc", "tune_malloc",
           "wait_images"]
_RUNNER = ("CycleRunner",)


def __getattr__(name: str) -> Any:
    if name in _RUNNER:
        from monoguide.daemon.cycle import _runner

        return getattr(_runner, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
