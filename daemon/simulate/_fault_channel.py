"""sim-cell's fault channel: each line of its standard input is a fault command, checked, then forwarded to the
device that plays it.

``plc <fault>`` goes to the simulated PLC's standard input, ``robot <fault>`` to the simulated robot
controller's (both at run time; ``none`` clears; ``robot cut-after-offset MS [DOWN_S]`` takes its numbers),
``camera <failure> [count]`` into the state file as ``"camera_fault": {"failure", "count", "serial"}`` for the
daemon's in-process simulated camera (a new serial per command, so that it applies once). An accepted command
is echoed on stdout as ``fault: <device> <fault>``, a refused one on stderr as ``fault error: <reason>``: a
protocol of its own, which ``monoguide simulate --faults``, the tests and docs/probe.md rely on.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from typing import Any

from monoguide.daemon.simulate._devices import Device

log = logging.getLogger(__name__)

MAX_CAMERA_COUNT = 1000
MAX_CUT_MS = 60_000.0  # robot cut-after-offset MS [DOWN_S]: MS 0..60000, DOWN_S above 0 up to 60 (the simulator's)

# the faults each simulated device takes (drivers/sim/plc.py FAULTS, drivers/sim/robot_motion.py FAULT_MODES,
# drivers/sim/camera.py FAILURES): copied, since runtime code never imports the simulator;
# tests/daemon/test_cmd_simcell.py checks that they agree
FAULT_COMMANDS: dict[str, tuple[str, ...]] = {
    "plc": ("none", "trigger-dropped-early", "heartbeat-stopped", "no-ack"),
    "robot": ("none", "stall", "drop", "protective-stop", "never-reach", "no-ack", "program-stopped"),
    "camera": ("timeout", "disconnect", "black", "occluded", "glare"),
}
# the robot's one-shot faults (drivers/sim/robot_motion.py FAULT_ACTIONS): Stop/Play now, the cut after the next
# offset (``robot cut-after-offset MS [DOWN_S]``); copied likewise, checked by tests/drivers/test_robot_faults.py
ROBOT_ACTIONS: tuple[str, ...] = ("restart", "cut-after-offset")

ABSENT = {"plc": "no simulated PLC in this cell (--no-plc, or no [plc] section)",
          "robot": "no simulated robot in this cell ([robot] backend is not sim-ur or sim-kuka)"}


class FaultChannel:
    """The fault commands of standard input. ``devices``: the simulated PLC and robot (None: not in this cell);
    ``camera_fault``: writes a camera fault into the state file (a :class:`ValueError` saying why it cannot; None:
    no simulated camera follows this cell);
    ``echo(line, err=False)``: where the replies go (sim-cell's standard output or error)."""

    def __init__(self, devices: dict[str, Device | None], camera_fault: Callable[[dict[str, Any]], None] | None,
                 echo: Callable[..., Any]) -> None:
        self._devices, self._camera_fault, self._echo = devices, camera_fault, echo
        self._serial = 0

    def handle(self, text: str) -> None:
        """One line of standard input: forwarded and echoed, or refused with the reason (the cell runs on)."""
        if text.startswith("#"):
            return
        try:
            device, fault, count = self._forward(text)
        except ValueError as exc:
            self._echo(f"fault error: {exc}", err=True)
            return
        log.info("fault %s %s%s", device, fault, f" x{count}" if count is not None else "")
        self._echo(f"fault: {device} {fault}")

    def _forward(self, text: str) -> tuple[str, str, int | None]:
        device, *words = text.split()
        if device not in FAULT_COMMANDS:
            raise ValueError(f"{text!r}: unknown device {device!r}; expected one of {', '.join(FAULT_COMMANDS)}")
        names = FAULT_COMMANDS[device] + (ROBOT_ACTIONS if device == "robot" else ())
        if not words:
            raise ValueError(f"{text!r}: which fault? {device} takes {', '.join(names)}")
        fault, *rest = words
        if fault not in names:
            raise ValueError(f"{text!r}: unknown {device} fault {fault!r}; expected one of {', '.join(names)}")
        if device == "camera":
            return device, fault, self._camera(text, fault, rest)
        if device == "robot" and fault == "cut-after-offset":
            _check_cut(text, rest)
        elif rest:
            raise ValueError(f"{text!r}: {device} {fault} takes nothing more, got {' '.join(rest)!r}")
        target = self._devices.get(device)
        if target is None:
            raise ValueError(f"{text!r}: {ABSENT[device]}")
        try:
            target.send(" ".join([fault, *rest]))
        except OSError as exc:
            raise ValueError(f"{text!r}: the simulated {device} (pid {target.process.pid}) is gone: {exc}") from exc
        return device, fault, None

    def _camera(self, text: str, failure: str, rest: list[str]) -> int:
        if self._camera_fault is None:
            raise ValueError(f"{text!r}: no simulated camera follows this cell ([camera] backend 'sim' and [robot] "
                             f"backend 'sim-ur' or 'sim-kuka' needed)")
        if len(rest) > 1 or (rest and not rest[0].isdigit()) or not 1 <= (count := int(rest[0]) if rest else 1) \
                <= MAX_CAMERA_COUNT:
            raise ValueError(f"{text!r}: count must be a whole number of grabs, 1 to {MAX_CAMERA_COUNT}")
        self._serial += 1
        try:
            self._camera_fault({"failure": failure, "count": count, "serial": self._serial})
        except ValueError as exc:  # the state file cannot be written
            raise ValueError(f"{text!r}: {exc}") from exc
        return count


def _check_cut(text: str, numbers: list[str]) -> None:
    """``robot cut-after-offset MS [DOWN_S]``: MS 0..60000 ms, DOWN_S above 0 up to 60 s (default 1)."""
    try:
        values = [float(v) for v in numbers]
    except ValueError:
        values = []
    if not 1 <= len(numbers) <= 2 or len(values) != len(numbers) or not all(math.isfinite(v) for v in values) \
            or not 0 <= values[0] <= MAX_CUT_MS or (len(values) == 2 and not 0 < values[1] <= MAX_CUT_MS / 1000):
        raise ValueError(f"{text!r}: robot cut-after-offset takes MS (0 to {MAX_CUT_MS:g}) and optionally DOWN_S "
                         f"(seconds, above 0 up to {MAX_CUT_MS / 1000:g}; default 1)")
