"""What ``monoguide simulate --faults`` injects, and when: every device and PLC fault of the simulated cell, each
with the error codes any of which reports it, sent to sim-cell's standard input before a part and cleared after it;
then the calibration faults (:data:`CALIBRATION_FAULT_PLAN`), a group of its own that persists over several parts.

After :data:`GOOD_BEFORE_FAULTS` good cycle(s) each fault gets its part, with a good one between faults, so a
fault's effect never runs into the next. ``robot <fault>`` is cleared (``robot none``) once its part is done; ``plc
heartbeat-stopped`` after 2.5 heartbeat timeouts (the service must have seen the heartbeat stop, whether or not
a part finished meanwhile); a camera failure lasts its one grab (``camera <failure> 1``).

A calibration fault (``camera bump DEG MM [AXIS]``, ``camera focal PCT``, ``pose drift K MM DEG``; sim-cell's
commands, daemon/simulate/_fault_channel.py) is injected before a part and stays for
:data:`CALIBRATION_FAULT_PARTS` parts, then is cleared (``camera bump 0 0``, ``camera focal 0``, ``pose drift K 0
0``) before a good part. Three, because a calibrated cell's fault is not an event of one cycle: what it costs
depends on where the part lies and on the robot's stop, so one cycle would be a sample of one, and three show
whether it is refused always, sometimes or never while keeping ``--faults`` short. Parts the run has beyond what
the plan needs (``--cycles`` longer) lengthen the calibration faults, shared out evenly (the first get the rest):
``--fault 'camera bump 0.1 0' --cycles 10`` keeps the bump on for parts 2 to 9. Their codes are the ones a
refusal of a calibration fault may give; a cycle under one may also be OK (today's cycle cannot see most of them),
so the summary tells per fault the cycles ok with their grasp error and the cycles refused with their codes,
and expects nothing.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from monoguide.daemon.simulate._fault_channel import CALIBRATION_COMMANDS, parse_bump, parse_drift, parse_focal
from monoguide.drivers.errors import ConfigError

GOOD_BEFORE_FAULTS = 1
HEARTBEAT_CLEAR_AFTER = 2.5  # heartbeat timeouts: `plc heartbeat-stopped` is cleared this long after it started
CALIBRATION_FAULT_PARTS = 3  # parts a calibration fault stays for (at least; see the module's doc)

Fault = tuple[str, str, tuple[str, ...]]  # device, fault, the error codes any of which reports it

# the error codes: those of journal rows, of the line's view, or of the service's log
FAULT_PLAN: tuple[Fault, ...] = (
    ("camera", "timeout", ("DEVICE_TIMEOUT",)),
    ("camera", "disconnect", ("DEVICE_DISCONNECTED", "DEVICE_NOT_FOUND")),
    ("camera", "black", ("LOW_CONTRAST", "HOLE_NOT_FOUND", "BAD_IMAGE", "FEATURE_NOT_FOUND")),
    ("camera", "occluded", ("HOLE_NOT_FOUND", "LOW_CONTRAST", "FEATURE_NOT_FOUND", "HOLE_AMBIGUOUS")),
    ("camera", "glare", ("IMAGE_SATURATED", "HOLE_NOT_FOUND", "HOLE_AMBIGUOUS", "RESIDUAL_TOO_LARGE",
                         "INCONSISTENT_MEASUREMENT", "FEATURE_NOT_FOUND")),
    ("robot", "protective-stop", ("ROBOT_PROTECTIVE_STOP",)),
    ("robot", "never-reach", ("ROBOT_POSITION_TIMEOUT",)),
    ("robot", "no-ack", ("ROBOT_ACK_TIMEOUT",)),
    ("robot", "stall", ("ROBOT_POSITION_TIMEOUT", "DEVICE_TIMEOUT", "ROBOT_ACK_TIMEOUT", "DEVICE_DISCONNECTED")),
    ("robot", "drop", ("DEVICE_DISCONNECTED", "ROBOT_NOT_READY", "DEVICE_TIMEOUT")),
    ("robot", "program-stopped", ("ROBOT_NOT_READY",)),
    ("plc", "trigger-dropped-early", ("PLC_TRIGGER_DROPPED",)),
    ("plc", "no-ack", ("PLC_ACK_TIMEOUT",)),
    ("plc", "heartbeat-stopped", ("PLC_HEARTBEAT_LOST", "CYCLE_ABORTED")),
)

# ``--fail-every N``: one part in N meets one of these, in turn (a one-grab camera failure: the cycle fails in its
# hole finding, the costliest way to fail — the soak's failed cycles)
PERIODIC_FAILURES: tuple[Fault, ...] = tuple(f for f in FAULT_PLAN
                                             if f[0] == "camera" and f[1] in ("black", "occluded"))

# the codes with which today's cycle may refuse a cycle under a calibration fault (it may also not refuse it)
CALIBRATION_CODES: tuple[str, ...] = ("CALIBRATION_SUSPECT", "INCONSISTENT_MEASUREMENT", "RESIDUAL_TOO_LARGE")
# the faults of the calibration-health table (docs/health.md), and a focal change and a pose drift
CALIBRATION_FAULT_PLAN: tuple[Fault, ...] = (
    ("camera", "bump 0 1 x", CALIBRATION_CODES),
    ("camera", "bump 0.1 0 x", CALIBRATION_CODES),
    ("camera", "bump 0.3 0 y", CALIBRATION_CODES),
    ("camera", "focal 0.5", CALIBRATION_CODES),
    ("pose", "drift 1 0.3 0.05", CALIBRATION_CODES),
)


@dataclass(frozen=True)
class InjectedFault:
    """A fault ``simulate --faults`` injected while the line played part ``cycle``."""

    cycle: int
    device: str  # plc | robot | camera
    name: str
    expected: tuple[str, ...]  # error codes any of which reports it
    parts: int = 1  # the parts it stays for (a calibration fault: several)
    calibration: bool = False  # a calibration fault: its cycles may be OK, the summary tells what they cost

    @property
    def label(self) -> str:
        return f"{self.device} {self.name}"


def fault_plan(names: tuple[str, ...] = ()) -> tuple[Fault, ...]:
    """The faults to inject: those of :data:`FAULT_PLAN` named ``"device name"`` (all of it when none are named),
    and calibration faults named by their sim-cell command (``"camera bump 0.1 0"``: any values, in their normal
    form ``("camera", "bump 0.1 0 x", CALIBRATION_CODES)``). A name neither is a :class:`ConfigError`."""
    known = {f"{device} {name}": (device, name, codes) for device, name, codes in FAULT_PLAN}
    out = []
    for wanted in names:
        if wanted in known:
            out.append(known[wanted])
            continue
        device, _, rest = wanted.partition(" ")
        fault, *words = rest.split() or [""]
        if fault not in CALIBRATION_COMMANDS.get(device, ()):
            raise ConfigError(f"--fault {wanted!r}: expected one of {', '.join(known)}, or a calibration fault: "
                              f"camera bump DEG MM [AXIS], camera focal PCT, pose drift K MM DEG")
        try:
            out.append((device, _normal_form(wanted, fault, words), CALIBRATION_CODES))
        except ValueError as exc:
            raise ConfigError(f"--fault {exc}") from None
    return tuple(out) if names else FAULT_PLAN


def faults_to_inject(names: tuple[str, ...] = ()) -> tuple[Fault, ...]:
    """What ``--faults`` injects: the named faults (:func:`fault_plan`), or with none named every device fault of
    :data:`FAULT_PLAN`, then :data:`CALIBRATION_FAULT_PLAN`."""
    return fault_plan(names) if names else FAULT_PLAN + CALIBRATION_FAULT_PLAN


def is_calibration_fault(device: str, name: str) -> bool:
    return name.split()[0] in CALIBRATION_COMMANDS.get(device, ()) if name else False


def cycles_needed_for_faults(names: tuple[str, ...] = ()) -> int:
    """One good cycle first, then each fault (a calibration fault for its parts) followed by a good cycle."""
    return GOOD_BEFORE_FAULTS + sum(1 + _parts(device, name) for device, name, _ in faults_to_inject(names))


def calibration_clear(device: str, name: str) -> str:
    """The sim-cell command that clears a calibration fault: ``camera bump 0 0``, ``camera focal 0``, ``pose drift
    K 0 0``."""
    fault, *words = name.split()
    if fault == "drift":
        return f"pose drift {words[0]} 0 0"
    return f"{device} {fault} 0" + (" 0" if fault == "bump" else "")


class FaultInjector:
    """Sends the faults of ``plan`` to sim-cell's standard input (``send``) as the line plays ``total`` parts, and
    clears them (see the module's doc); :attr:`injected` says which fault went with which part."""

    def __init__(self, send: Callable[[str], None], total: int, plan: tuple[Fault, ...], heartbeat_timeout_s: float,
                 note: Callable[[str], None], clear_latch: Callable[[str], None] | None = None,
                 fail_every: int = 0) -> None:
        self._send, self._note, self._clear_latch = send, note, clear_latch
        self._schedule = _schedule(total, plan)
        self._total = total
        self._fail_every = fail_every  # also one part in this many fails (PERIODIC_FAILURES); 0: none
        self._heartbeat_timeout_s = heartbeat_timeout_s
        # (command, at monotonic time; None: after its parts, how many are left)
        self._clear: tuple[str, float | None, int] | None = None
        self.injected: list[InjectedFault] = []

    def before_part(self, done: int, now: float) -> None:
        """With ``done`` parts finished at monotonic time ``now``: clear the fault whose time is up, inject the one
        due before part ``done + 1`` (once)."""
        if self._clear is not None and self._clear[1] is not None and now >= self._clear[1]:
            self._clear_now()
        if any(f.cycle == done + 1 for f in self.injected):
            return
        if done not in self._schedule:
            self._fail_periodically(done)
            return
        (device, name, expected), parts = self._schedule[done]
        if self._clear is not None:  # the previous fault ends before the next one starts
            self._clear_now()
        calibration = is_calibration_fault(device, name)
        self._send(f"{device} {name}" + (" 1" if device == "camera" and not calibration else ""))
        self.injected.append(InjectedFault(done + 1, device, name, expected, parts, calibration))
        self._note(f"cycle {done + 1}: injecting {device} {name}" + (f" for {parts} parts" if parts > 1 else ""))
        if calibration:
            self._clear = (calibration_clear(device, name), None, parts)
        elif device == "plc" and name == "heartbeat-stopped":
            self._clear = ("plc none", now + HEARTBEAT_CLEAR_AFTER * self._heartbeat_timeout_s, 0)
        elif device != "camera":
            self._clear = (f"{device} none", None, 1)

    def _fail_periodically(self, done: int) -> None:
        """Part ``done + 1`` is one in ``fail_every``: a one-grab camera failure (none while another fault is on, nor
        on the last part: a good one follows each failure, so that READY after it is seen)."""
        if not self._fail_every or (done + 1) % self._fail_every or self._clear is not None or done + 1 >= self._total:
            return
        device, name, expected = PERIODIC_FAILURES[((done + 1) // self._fail_every - 1) % len(PERIODIC_FAILURES)]
        self._send(f"{device} {name} 1")
        self.injected.append(InjectedFault(done + 1, device, name, expected))

    def part_done(self) -> None:
        """A part finished: clear the fault whose parts are done."""
        if self._clear is not None and self._clear[1] is None:
            command, _, left = self._clear
            self._clear = (command, None, left - 1)
            if left <= 1:
                self._clear_now()

    def _clear_now(self) -> None:
        """Clear the fault; a calibration fault's also the service's latch (the operator who put the camera back
        clears it, ``monoguide health --clear``), so that the next fault is judged on its own."""
        assert self._clear is not None
        command = self._clear[0]
        self._send(command)
        self._clear = None
        device, name = command.split(" ", 1)
        if self._clear_latch is not None and is_calibration_fault(device, name):
            self._clear_latch(f"simulate: the calibration fault was cleared ({command})")


def _schedule(total: int, plan: tuple[Fault, ...]) -> dict[int, tuple[Fault, int]]:
    """Which fault to inject after how many finished parts, and for how many parts: a good one first, then each
    fault for its parts and a good part after it; the parts to spare go to the calibration faults."""
    parts = [_parts(device, name) for device, name, _ in plan]
    calibration = [k for k, (device, name, _) in enumerate(plan) if is_calibration_fault(device, name)]
    spare = total - GOOD_BEFORE_FAULTS - sum(1 + n for n in parts)
    if calibration and spare > 0:
        share, rest = divmod(spare, len(calibration))
        for j, k in enumerate(calibration):
            parts[k] += share + (j < rest)
    out, start = {}, GOOD_BEFORE_FAULTS
    for fault, n in zip(plan, parts, strict=True):
        if start + n > total - 1:  # no good part after it
            break
        out[start] = (fault, n)
        start += n + 1
    return out


def _parts(device: str, name: str) -> int:
    return CALIBRATION_FAULT_PARTS if is_calibration_fault(device, name) else 1


def _normal_form(text: str, fault: str, words: list[str]) -> str:
    """A calibration fault's name as sim-cell echoes it (``bump 0.1 0 x``); a :class:`ValueError` naming the value."""
    if fault == "bump":
        deg, mm, axis = parse_bump(text, words)
        return f"bump {deg:g} {mm:g} {axis}"
    if fault == "focal":
        return f"focal {parse_focal(text, words):g}"
    number, mm, deg = parse_drift(text, words)
    return f"drift {number} {mm:g} {deg:g}"
