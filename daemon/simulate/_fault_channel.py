"""sim-cell's fault channel: each line of its standard input is a fault command, checked, then forwarded to the
device that plays it.

``plc <fault>`` goes to the simulated PLC's standard input, ``robot <fault>`` to the simulated robot
controller's (both at run time; ``none`` clears; ``robot cut [DOWN_S]`` and ``robot cut-after-offset MS [DOWN_S]``
take their numbers),
``camera <failure> [count]`` into the state file as ``"camera_fault": {"failure", "count", "serial"}`` for the
daemon's in-process simulated camera (a new serial per command, so that it applies once). An accepted command
is echoed on stdout as ``fault: <device> <fault>``, a refused one on stderr as ``fault error: <reason>``: a
protocol of its own, which ``monoguide simulate --faults``, the tests and docs/probe.md rely on.

The calibration faults (:data:`CALIBRATION_COMMANDS`; drivers/sim/calibration_faults.py has their geometry) persist
until cleared: ``camera bump DEG MM [AXIS]`` (the camera turned by DEG degrees about and moved MM mm along its own
axis x, y or z, default x: its true mounting ``T_f_c · B``; ``camera bump 0 0`` clears), ``camera focal PCT`` (the
lens's true fx, fy times 1 + PCT/100; ``camera focal 0`` clears), ``pose drift K MM DEG`` (robot pose K, 1-based,
stops MM mm and DEG deg off the taught flange pose, along and about (1, 1, 1)/√3 of the flange, while the robot
reports the stop without it; ``pose drift K 0 0`` clears). The channel keeps the cell's set of them and writes it
whole, as ``camera_fault.calibration`` (``{"bump": {"deg", "mm", "axis"} | null, "focal_pct", "drift": {"K":
{"mm", "deg"}}, "serial"}``), into every camera fault entry it writes, beside the last one-grab failure (its
``serial`` unchanged, so it is not taken up again): a later ``camera black`` keeps them. Echoed in a normal form:
``fault: camera bump 0.1 0 x``.
"""

from __future__ import annotations

import json
import logging
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

from monoguide.daemon.simulate._devices import Device
from monoguide.solver.calibration_faults import AXES

log = logging.getLogger(__name__)

MAX_CAMERA_COUNT = 1000
MAX_CUT_MS = 60_000.0  # robot cut-after-offset MS [DOWN_S]: MS 0..60000, DOWN_S above 0 up to 60 (the simulator's)
CUT_DEFAULT_S = 1.0  # robot cut [DOWN_S], cut-after-offset's DOWN_S: the simulator's default

# the faults each simulated device takes (drivers/sim/plc.py FAULTS, drivers/sim/robot_motion.py FAULT_MODES,
# drivers/sim/camera.py FAILURES): copied, since runtime code never imports the simulator;
# tests/daemon/test_cmd_simcell.py checks that they agree
FAULT_COMMANDS: dict[str, tuple[str, ...]] = {
    "plc": ("none", "trigger-dropped-early", "heartbeat-stopped", "no-ack"),
    "robot": ("none", "stall", "drop", "protective-stop", "never-reach", "no-ack", "program-stopped"),
    "camera": ("timeout", "disconnect", "black", "occluded", "glare"),
}
# the robot's one-shot faults (drivers/sim/robot_motion.py FAULT_ACTIONS): Stop/Play now, the cable pulled now
# (``robot cut [DOWN_S]``), the cut after the next offset (``robot cut-after-offset MS [DOWN_S]``); copied likewise,
# checked by tests/drivers/test_robot_faults.py
ROBOT_ACTIONS: tuple[str, ...] = ("restart", "cut", "cut-after-offset", "reference-part")
# the calibration faults (drivers/sim/calibration_faults.py CALIBRATION_FAULTS): copied likewise, checked by
# tests/daemon/simulate/test_calibration_faults.py; persistent, see the module's doc
CALIBRATION_COMMANDS: dict[str, tuple[str, ...]] = {"camera": ("bump", "focal"), "pose": ("drift",)}
MAX_BUMP_DEG, MAX_BUMP_MM = 10.0, 100.0  # a camera still on its bracket
MAX_FOCAL_PCT = 50.0
MAX_DRIFT_MM, MAX_DRIFT_DEG = 100.0, 10.0

ABSENT = {"plc": "no simulated PLC in this cell (--no-plc, or no [plc] section)",
          "robot": "no simulated robot in this cell ([robot] backend is not sim-ur or sim-kuka)"}


class FaultChannel:
    """The fault commands of standard input. ``devices``: the simulated PLC and robot (None: not in this cell);
    ``camera_fault``: writes a camera fault into the state file (a :class:`ValueError` saying why it cannot; None:
    no simulated camera follows this cell);
    ``echo(line, err=False)``: where the replies go (sim-cell's standard output or error); ``measuring_poses``: the
    robot pose numbers ``pose drift`` takes, 1 to it (None: as many as the simulated robot's spec file lists)."""

    def __init__(self, devices: dict[str, Device | None], camera_fault: Callable[[dict[str, Any]], None] | None,
                 echo: Callable[..., Any], measuring_poses: int | None = None) -> None:
        self._devices, self._camera_fault, self._echo = devices, camera_fault, echo
        self._measuring_poses = measuring_poses  # robot pose numbers 1..N (None: the simulated robot's spec says)
        self._serial = 0
        self._failure: dict[str, Any] = {}  # the last one-grab camera failure written
        self._calibration: dict[str, Any] = {"bump": None, "focal_pct": 0.0, "drift": {}}

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
        devices = dict.fromkeys([*FAULT_COMMANDS, *CALIBRATION_COMMANDS])
        if device not in devices:
            raise ValueError(f"{text!r}: unknown device {device!r}; expected one of {', '.join(devices)}")
        names = FAULT_COMMANDS.get(device, ()) + (ROBOT_ACTIONS if device == "robot" else ()) \
            + CALIBRATION_COMMANDS.get(device, ())
        if not words:
            raise ValueError(f"{text!r}: which fault? {device} takes {', '.join(names)}")
        fault, *rest = words
        if fault not in names:
            raise ValueError(f"{text!r}: unknown {device} fault {fault!r}; expected one of {', '.join(names)}")
        if fault in CALIBRATION_COMMANDS.get(device, ()):
            return device, self._calibration_fault(text, device, fault, rest), None
        if device == "camera":
            return device, fault, self._camera(text, fault, rest)
        if device == "robot" and fault == "cut-after-offset":
            _check_cut(text, rest)
        elif device == "robot" and fault == "cut":
            _check_cut_now(text, rest)
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
        self._write(text, {"failure": failure, "count": count, "serial": self._serial}, self._calibration)
        return count

    def _calibration_fault(self, text: str, device: str, fault: str, rest: list[str]) -> str:
        """A calibration fault into the state file; its normal form (``bump 0.1 0 x``)."""
        if self._camera_fault is None:
            raise ValueError(f"{text!r}: no simulated camera follows this cell ([camera] backend 'sim' and [robot] "
                             f"backend 'sim-ur' or 'sim-kuka' needed): calibration faults are what it renders")
        calibration = {**self._calibration, "drift": dict(self._calibration["drift"])}
        if fault == "bump":
            deg, mm, axis = parse_bump(text, rest)
            calibration["bump"] = {"deg": deg, "mm": mm, "axis": axis} if deg or mm else None
            said = f"bump {deg:g} {mm:g} {axis}"
        elif fault == "focal":
            pct = parse_focal(text, rest)
            calibration["focal_pct"] = pct
            said = f"focal {pct:g}"
        else:
            number, mm, deg = parse_drift(text, rest, self._pose_count(text))
            if mm or deg:
                calibration["drift"][str(number)] = {"mm": mm, "deg": deg}
            else:
                calibration["drift"].pop(str(number), None)
            said = f"drift {number} {mm:g} {deg:g}"
        self._serial += 1
        calibration["serial"] = self._serial
        self._write(text, self._failure, calibration)
        self._calibration = calibration
        return said

    def _write(self, text: str, failure: dict[str, Any], calibration: dict[str, Any]) -> None:
        assert self._camera_fault is not None
        try:
            self._camera_fault({**failure, "calibration": calibration})
        except ValueError as exc:  # the state file cannot be written
            raise ValueError(f"{text!r}: {exc}") from exc
        self._failure = failure

    def _pose_count(self, text: str) -> int:
        """How many measuring poses the simulated robot has (its spec file, named on its command line)."""
        if self._measuring_poses is not None:
            return self._measuring_poses
        robot = self._devices.get("robot")
        if robot is None:
            raise ValueError(f"{text!r}: {ABSENT['robot']}: a pose drift is where the camera follows the robot")
        try:
            argv = [str(a) for a in robot.process.args]  # type: ignore[union-attr]
            spec = json.loads(Path(argv[argv.index("--spec") + 1]).read_text())
            return len(spec["T_b_f_taught"])
        except (ValueError, IndexError, KeyError, TypeError, OSError) as exc:
            raise ValueError(f"{text!r}: cannot tell the simulated robot's measuring poses: {exc}") from exc


def parse_bump(text: str, words: list[str]) -> tuple[float, float, str]:
    """``DEG MM [AXIS]`` of ``camera bump``: (deg, mm, axis), or a :class:`ValueError` naming the bad value."""
    if len(words) not in (2, 3):
        raise ValueError(f"{text!r}: camera bump takes DEG MM [AXIS] (AXIS x, y or z of the camera; default x)")
    deg, mm = _numbers(text, words[:2], ("DEG", "MM"), "camera bump DEG MM [AXIS]")
    axis = words[2] if len(words) == 3 else "x"
    if axis not in AXES:
        raise ValueError(f"{text!r}: axis {axis!r}: expected x, y or z (of the camera frame)")
    _within(text, "DEG", deg, MAX_BUMP_DEG)
    _within(text, "MM", mm, MAX_BUMP_MM)
    return deg, mm, axis


def parse_drift(text: str, words: list[str], poses: int | None = None) -> tuple[int, float, float]:
    """``K MM DEG`` of ``pose drift``: (pose number, mm, deg); K a robot pose number 1..``poses``."""
    if len(words) != 3:
        raise ValueError(f"{text!r}: pose drift takes K MM DEG (K the robot pose number, 1-based)")
    if not words[0].isdigit() or int(words[0]) < 1:
        raise ValueError(f"{text!r}: pose number {words[0]!r}: expected a whole number from 1")
    number = int(words[0])
    if poses is not None and number > poses:
        raise ValueError(f"{text!r}: pose number {number}: the cell has measuring poses 1 to {poses}")
    mm, deg = _numbers(text, words[1:], ("MM", "DEG"), "pose drift K MM DEG")
    _within(text, "MM", mm, MAX_DRIFT_MM)
    _within(text, "DEG", deg, MAX_DRIFT_DEG)
    return number, mm, deg


def parse_focal(text: str, words: list[str]) -> float:
    """``PCT`` of ``camera focal``."""
    (pct,) = _numbers(text, words, ("PCT",), "camera focal PCT")
    _within(text, "PCT", pct, MAX_FOCAL_PCT)
    return pct


def _numbers(text: str, words: list[str], names: tuple[str, ...], usage: str) -> list[float]:
    if len(words) != len(names):
        raise ValueError(f"{text!r}: {usage}")
    out = []
    for name, word in zip(names, words, strict=True):
        try:
            value = float(word)
        except ValueError:
            raise ValueError(f"{text!r}: {name} {word!r} is not a number ({usage})") from None
        if not math.isfinite(value):
            raise ValueError(f"{text!r}: {name} {word!r} is not a finite number ({usage})")
        out.append(value + 0.0)  # -0.0 prints as 0
    return out


def _within(text: str, name: str, value: float, limit: float) -> None:
    if abs(value) > limit:
        raise ValueError(f"{text!r}: {name} {value:g} is beyond +-{limit:g}")


def _check_cut_now(text: str, numbers: list[str]) -> None:
    """``robot cut [DOWN_S]``: DOWN_S above 0 up to 60 s (default 1)."""
    try:
        down_s = float(numbers[0]) if len(numbers) == 1 else CUT_DEFAULT_S
    except ValueError:
        down_s = math.nan
    if len(numbers) > 1 or not 0 < down_s <= MAX_CUT_MS / 1000:
        raise ValueError(f"{text!r}: robot cut takes DOWN_S (seconds, above 0 up to {MAX_CUT_MS / 1000:g}; "
                         "default 1)")


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
