"""What ``monoguide simulate --faults`` injects, and when: every device and PLC fault of the simulated cell, each
with the error codes any of which reports it, sent to sim-cell's standard input before a part and cleared after it.

After :data:`GOOD_BEFORE_FAULTS` good cycle(s) each fault gets its part, with a good one between faults, so a
fault's effect never runs into the next. ``robot <fault>`` is cleared (``robot none``) once its part is done; ``plc
heartbeat-stopped`` after 2.5 heartbeat timeouts (the service must have seen the heartbeat stop, whether or not
a part finished meanwhile); a camera failure lasts its one grab (``camera <failure> 1``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from monoguide.drivers.errors import ConfigError

GOOD_BEFORE_FAULTS = 1
HEARTBEAT_CLEAR_AFTER = 2.5  # heartbeat timeouts: `plc heartbeat-stopped` is cleared this long after it started

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


@dataclass(frozen=True)
class InjectedFault:
    """A fault ``simulate --faults`` injected while the line played part ``cycle``."""

    cycle: int
    device: str  # plc | robot | camera
    name: str
    expected: tuple[str, ...]  # error codes any of which reports it

    @property
    def label(self) -> str:
        return f"{self.device} {self.name}"


def fault_plan(names: tuple[str, ...] = ()) -> tuple[Fault, ...]:
    """The faults to inject: those of :data:`FAULT_PLAN` named ``"device name"`` (all when none are named)."""
    known = {f"{device} {name}": (device, name, codes) for device, name, codes in FAULT_PLAN}
    for wanted in names:
        if wanted not in known:
            raise ConfigError(f"--fault {wanted!r}: expected one of {', '.join(known)}")
    return tuple(known[n] for n in names) if names else FAULT_PLAN


def cycles_needed_for_faults(names: tuple[str, ...] = ()) -> int:
    """One good cycle first, then each fault followed by a good cycle."""
    return GOOD_BEFORE_FAULTS + 2 * len(fault_plan(names))


class FaultInjector:
    """Sends the faults of ``plan`` to sim-cell's standard input (``send``) as the line plays ``total`` parts, and
    clears them (see the module's doc); :attr:`injected` says which fault went with which part."""

    def __init__(self, send: Callable[[str], None], total: int, plan: tuple[Fault, ...], heartbeat_timeout_s: float,
                 note: Callable[[str], None]) -> None:
        self._send, self._note = send, note
        self._schedule = _schedule(total, plan)
        self._heartbeat_timeout_s = heartbeat_timeout_s
        self._clear: tuple[str, float | None] | None = None  # (command, at monotonic time; None: after the part)
        self.injected: list[InjectedFault] = []

    def before_part(self, done: int, now: float) -> None:
        """With ``done`` parts finished at monotonic time ``now``: clear the fault whose time is up, inject the one
        due before part ``done + 1`` (once)."""
        if self._clear is not None and self._clear[1] is not None and now >= self._clear[1]:
            self._clear_now()
        if done not in self._schedule or any(f.cycle == done + 1 for f in self.injected):
            return
        device, name, expected = self._schedule[done]
        if self._clear is not None:  # the previous fault ends before the next one starts
            self._clear_now()
        self._send(f"{device} {name}" + (" 1" if device == "camera" else ""))
        self.injected.append(InjectedFault(done + 1, device, name, expected))
        self._note(f"cycle {done + 1}: injecting {device} {name}")
        if device == "plc" and name == "heartbeat-stopped":
            self._clear = ("plc none", now + HEARTBEAT_CLEAR_AFTER * self._heartbeat_timeout_s)
        elif device != "camera":
            self._clear = (f"{device} none", None)

    def part_done(self) -> None:
        """A part finished: clear the fault that lasts one part."""
        if self._clear is not None and self._clear[1] is None:
            self._clear_now()

    def _clear_now(self) -> None:
        assert self._clear is not None
        self._send(self._clear[0])
        self._clear = None


def _schedule(total: int, plan: tuple[Fault, ...]) -> dict[int, Fault]:
    """Which fault to inject after how many finished parts: a good one first, then one every other part."""
    return {GOOD_BEFORE_FAULTS + 2 * k: fault for k, fault in enumerate(plan) if GOOD_BEFORE_FAULTS + 2 * k < total - 1}
