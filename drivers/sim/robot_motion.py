"""The simulated robot program, shared by the simulated UR and KUKA controllers (protocol-free).

It plays the part of the robot program of ``config/ur/`` and ``config/kuka/``: on a request to go to
measuring pose number k it moves there in ``move_time_s`` and stops at the taught flange pose plus the
cell's repeatability noise, then reports k in position and acknowledges the request's sequence number
(numbers 101.. are the base-calibration poses, the spec's ``T_b_f_calibration``, alike); on
an offset ``D_b`` it applies it to the taught grasp pose (``pose_trans(D_b, grasp)``), acknowledges, and
scores it: the **grasp error**, that grasp pose against the ideal one ``T_b_w · T_b_w0⁻¹ · T_b_g0`` which
fits the true part exactly, logged with the part and the sequence number.

The truth comes from the robot spec file that :meth:`SimCell.write_robot_spec` writes (re-read when it
changes: a new part); what the robot did goes to a truth file (:func:`read_truth`) that the in-process
simulated camera follows (:meth:`SimCell.set_actual_flange_pose`) and tests score against.

What the controller reports is not all of the truth: its flange pose (``T_b_f_reported``, on the wire) sees
only the share ``reported_repeatability_fraction`` of each stop's deviation from the taught pose (the spec's
key; 1 when absent: the report is the true stop), as a real robot's encoders miss backlash, flex and heat. The
truth file keeps both: ``T_b_f`` and ``stops`` (true: where the camera stands), ``T_b_f_reported`` and
``stops_reported``.

Failure modes (:data:`FAULT_MODES`), set at start (``--fault``) or at run time (``--commands``: one fault
per line on standard input, ``none`` clears it; :meth:`SimRobotProgram.set_fault`), each applied from the
next request on: ``stall`` (the controller freezes: nothing answered, nothing sent), ``drop`` (it closes
every connection), ``protective-stop`` (safety stop, no motion), ``never-reach`` (moves but never arrives;
also a move under way), ``no-ack`` (offsets are neither taken nor acknowledged: the part keeps no offset);
and at once ``program-stopped`` (the robot program is not running). ``none`` ends a stall and a protective
stop: the controller answers again and its safety is back to normal. What the robot adapter (and so the
service, on the PLC) reports for each (``drivers/errors.py``): stall ``DEVICE_TIMEOUT`` (402), drop
``DEVICE_DISCONNECTED`` (403), protective-stop ``ROBOT_PROTECTIVE_STOP`` (422), never-reach
``ROBOT_POSITION_TIMEOUT`` (423), no-ack ``ROBOT_ACK_TIMEOUT`` (424), program-stopped ``ROBOT_NOT_READY``
(421).

Order of truth and wire: the move that arrives and the truth file that says so are one synchronous step
of the program loop (:meth:`SimRobotProgram.tick` then :func:`write_truth`, no ``await`` between them), and
the controllers send their state only from other tasks of the same event loop; so the truth file (stops,
``in_position``, the part's ``T_cf_w``) is on disk before a client can see "in position" on the wire.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import json
import logging
import math
import os
import signal
import sys
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from monoguide.drivers.robot import (
    CALIBRATION_POSE_BASE,
    COMMAND_GOTO,
    COMMAND_NONE,
    COMMAND_OFFSET,
    PROGRAM_BAD_POSE,
    PROGRAM_BUSY,
    PROGRAM_OK,
    PROGRAM_UNKNOWN_COMMAND,
)
from monoguide.drivers.sim.cell import ROBOT_SPEC_FORMAT, SimCell
from monoguide.drivers.sim.part_supply import PartSupply
from monoguide.solver.frames import (
    compose,
    invert,
    make_T,
    matrix_to_rotvec,
    pose_difference,
    rotvec_to_matrix,
)

log = logging.getLogger("monoguide.sim.robot")

TRUTH_FORMAT = "monoguide.sim-robot-truth/1"
FAULT_MODES = ("none", "stall", "drop", "protective-stop", "never-reach", "no-ack", "program-stopped")
MAX_OFFSETS_KEPT = 200


@dataclass(frozen=True)
class RobotSpec:
    """What the simulated robot knows of the cell (all in its base frame, mm)."""

    part: int
    seed: int
    repeatability_mm: float
    repeatability_deg: float
    T_b_f_taught: tuple[np.ndarray, ...]
    T_b_w0: np.ndarray
    T_b_w: np.ndarray
    T_b_g0: np.ndarray
    T_b_f_calibration: tuple[np.ndarray, ...] = ()  # base-calibration poses 1..N: wire pose numbers 101..100+N
    reported_fraction: float = 1.0  # share of each stop's deviation the controller's reported pose sees


@dataclass
class AppliedOffset:
    sequence: int
    part: int
    received: tuple[float, ...]  # as it arrived on the wire, in the wire's units
    D_b: np.ndarray
    grasp_error_mm: float
    grasp_error_deg: float


@dataclass
class SimRobotProgram:
    """The robot program's state and its answers. Time is passed in (``now``, seconds), never read."""

    spec: RobotSpec
    rng: np.random.Generator
    move_time_s: float = 0.5
    fault: str = "none"
    T_b_f: np.ndarray = field(default_factory=lambda: np.eye(4))
    in_position: int = 0
    ack_sequence: int = 0
    program_status: int = PROGRAM_OK
    safety: str = "NORMAL"
    last_sequence: int = 0
    requests: int = 0
    offsets: list[AppliedOffset] = field(default_factory=list)
    stops: dict[int, np.ndarray] = field(default_factory=dict)
    supply: PartSupply | None = None  # presents a new part at each request of measuring pose 1
    _move: tuple[float, np.ndarray, np.ndarray, int, int] | None = None  # start, from, to, number, seq
    stops_reported: dict[int, np.ndarray] = field(default_factory=dict)  # what the controller reported there
    _unseen: np.ndarray = field(default_factory=lambda: np.eye(4))  # reported = true · _unseen (this stop's)

    def __post_init__(self) -> None:
        if self.fault not in FAULT_MODES:
            raise ValueError(f"fault must be one of {FAULT_MODES}, got {self.fault!r}")
        self.T_b_f = self._stop_at(1)  # the robot starts at measuring pose S1
        self.in_position = 1

    def set_fault(self, fault: str) -> None:
        """Change the failure mode at run time (``none``: clear it); a protective stop ends with its mode."""
        if fault not in FAULT_MODES:
            raise ValueError(f"fault {fault!r}: expected one of {', '.join(FAULT_MODES)}")
        if fault != "protective-stop":
            self.safety = "NORMAL"
        log.info("fault %s (was %s)", fault, self.fault)
        self.fault = fault

    @property
    def T_b_f_reported(self) -> np.ndarray:
        """The flange pose the controller reports (its encoders): the true one less the part of the stop's
        deviation from the taught pose that the encoders do not see (``reported_fraction``)."""
        return compose(self.T_b_f, self._unseen)

    @property
    def program_running(self) -> bool:
        return self.fault != "program-stopped"

    @property
    def faulted(self) -> bool:
        """A request has arrived and the configured fault is now in effect."""
        return self.fault != "none" and self.requests > 0

    def handle(self, sequence: int, command: int, pose_number: int, D_b: np.ndarray | None,
               received: tuple[float, ...], now: float) -> bool:
        """React to the request registers (the program polls them): a new ``sequence`` with a command is a
        new request; the same one again is ignored. Returns whether it was new."""
        if sequence == 0:
            self.last_sequence = 0  # the daemon (re)connected: the next number is new whatever it is
            return False
        if command == COMMAND_NONE or sequence == self.last_sequence:
            return False
        self.last_sequence = sequence
        self.requests += 1
        log.info("request %d: command %d pose %d offset %s", sequence, command, pose_number,
                 " ".join(f"{v:.9g}" for v in received))
        if self.fault == "protective-stop":
            self.safety = "PROTECTIVE_STOP"
            self._move = None
            return True
        if command == COMMAND_GOTO:
            if not (1 <= pose_number <= len(self.spec.T_b_f_taught)
                    or CALIBRATION_POSE_BASE < pose_number <= CALIBRATION_POSE_BASE + len(self.spec.T_b_f_calibration)):
                self._answer(sequence, PROGRAM_BAD_POSE)
                return True
            if pose_number == 1 and self.supply is not None:  # a cycle starts: the next part arrives
                self.spec = dataclasses.replace(self.spec, T_b_w=self.supply.arrive(), part=self.supply.part)
            self.in_position = 0
            self.program_status = PROGRAM_BUSY
            self._move = (now, self.T_b_f.copy(), self._stop_at(pose_number), pose_number, sequence)
        elif command == COMMAND_OFFSET and D_b is not None:
            self._apply_offset(sequence, D_b, received)
        else:
            self._answer(sequence, PROGRAM_UNKNOWN_COMMAND)
        return True

    def tick(self, now: float) -> None:
        """Advance the motion to time ``now``."""
        if self._move is None:
            return
        start, T_from, T_to, number, sequence = self._move
        s = 1.0 if self.move_time_s <= 0 else min(1.0, (now - start) / self.move_time_s)
        if self.fault == "never-reach":
            s = min(s, 0.5)
        self.T_b_f = _interpolate(T_from, T_to, s)
        if s >= 1.0:
            self._move = None
            self.in_position = number
            self.stops[number] = T_to.copy()
            self.stops_reported[number] = compose(T_to, self._unseen)
            self._answer(sequence, PROGRAM_OK)
            log.info("in position at S%d (request %d)", number, sequence)

    def reload(self, spec: RobotSpec) -> None:
        if spec.part != self.spec.part:
            log.info("new part %d in the cell", spec.part)
        self.spec = spec

    def truth(self) -> dict[str, object]:
        """What the robot did, for the truth file."""
        return {
            "format": TRUTH_FORMAT,
            "pid": os.getpid(),
            "part": self.spec.part,
            "in_position": self.in_position,
            "fault": self.fault,
            "T_b_f": self.T_b_f.tolist(),
            **({"T_cf_w": self.supply.T_cf_w.tolist()} if self.supply is not None else {}),
            "stops": {str(k): T.tolist() for k, T in self.stops.items()},
            "T_b_f_reported": self.T_b_f_reported.tolist(),
            "stops_reported": {str(k): T.tolist() for k, T in self.stops_reported.items()},
            "offsets": [
                {"sequence": o.sequence, "part": o.part, "received": list(o.received), "D_b": o.D_b.tolist(),
                 "grasp_error_mm": o.grasp_error_mm, "grasp_error_deg": o.grasp_error_deg}
                for o in self.offsets[-MAX_OFFSETS_KEPT:]
            ],
        }

    # --- private --------------------------------------------------------------------------------

    def _stop_at(self, number: int) -> np.ndarray:
        s = self.spec
        rotvec = self.rng.normal(0.0, math.radians(s.repeatability_deg), 3)
        shift = self.rng.normal(0.0, s.repeatability_mm, 3)
        noise = make_T(rotvec_to_matrix(rotvec), shift)
        # the controller's report sees the share reported_fraction of this deviation (backlash, flex, heat: not all)
        seen = make_T(rotvec_to_matrix(s.reported_fraction * rotvec), s.reported_fraction * shift)
        self._unseen = compose(invert(noise), seen)
        if number > CALIBRATION_POSE_BASE:  # a base-calibration pose (monoguide calibrate)
            return compose(s.T_b_f_calibration[number - CALIBRATION_POSE_BASE - 1], noise)
        return compose(s.T_b_f_taught[number - 1], noise)

    def _apply_offset(self, sequence: int, D_b: np.ndarray, received: tuple[float, ...]) -> None:
        if self.fault == "no-ack":  # the program never takes it: nothing applied, nothing acknowledged
            log.info("offset %d not taken (fault no-ack)", sequence)
            return
        error_mm, error_deg = grasp_error(D_b, self.spec.T_b_g0, self.spec.T_b_w, self.spec.T_b_w0)
        self.offsets.append(AppliedOffset(sequence, self.spec.part, received, np.array(D_b, dtype=float),
                                          error_mm, error_deg))
        if self.supply is not None:
            self.supply.offset_applied(self.spec.part, D_b, error_mm, error_deg)
        log.info("offset %d for part %d: grasp error %.4f mm %.5f deg", sequence, self.spec.part, error_mm,
                 error_deg)
        self._answer(sequence, PROGRAM_OK)

    def _answer(self, sequence: int, status: int) -> None:
        self.program_status = status
        self.ack_sequence = sequence


async def run_program(program: SimRobotProgram, spec_path: Path, truth_path: Path, now: Callable[[], float],
                      stalled: Callable[[], bool], stop: asyncio.Event, period_s: float = 0.02) -> None:
    """The program's loop in a simulated controller: re-read the spec when it changes (a new part), move,
    write the truth file; nothing moves while the controller is stalled."""
    spec_mtime = file_mtime(spec_path)
    while not stop.is_set():
        if (mtime := file_mtime(spec_path)) != spec_mtime:
            spec_mtime = mtime
            try:
                program.reload(load_robot_spec(spec_path))
            except (OSError, ValueError, KeyError) as exc:
                log.warning("keeping the old spec, cannot re-read %s: %s", spec_path, exc)
        if not stalled():  # one synchronous step: the truth is on disk before any task sends the new state
            program.tick(now())
            write_truth(truth_path, program.truth())
        with contextlib.suppress(asyncio.TimeoutError):
            await asyncio.wait_for(stop.wait(), period_s)
    if program.supply is not None:  # the controller stops: the part in the cell leaves
        program.supply.close()


async def serve_controller(client_handler: Callable[..., object], host: str, port: int,
                           program: Callable[[asyncio.Event], object], drop_all: Callable[[], None],
                           command: Callable[[str], None] | None = None) -> int:
    """Listen on ``host:port``, print ``LISTEN robot host:port``, run the program loop, until SIGTERM/SIGINT
    or until the parent process is gone; then close every connection. ``command``: called in the loop with
    each line of standard input (fault commands); the end of the input is fine."""
    # noted before LISTEN is printed: the parent may act on that line and die at once (a test killing a
    # sim-cell), and a parent noted after its death would be init's pid, never gone: an orphan for good
    parent = os.getppid()
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for s in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(s, stop.set)
    server = await asyncio.start_server(client_handler, host, port, reuse_address=True)  # type: ignore[arg-type]
    print(f"LISTEN robot {host}:{port}", flush=True)
    task = loop.create_task(program(stop))  # type: ignore[arg-type]
    if command is not None:
        threading.Thread(target=_read_commands, args=(loop, command), daemon=True).start()
    while not stop.is_set() and os.getppid() == parent:
        with contextlib.suppress(asyncio.TimeoutError):
            await asyncio.wait_for(stop.wait(), 0.2)
    stop.set()
    server.close()
    drop_all()
    await task
    return 0


def _read_commands(loop: asyncio.AbstractEventLoop, command: Callable[[str], None]) -> None:
    """Standard input, one command a line, each handed to the event loop (a thread: reading blocks)."""
    for text in sys.stdin:
        if text.strip():
            loop.call_soon_threadsafe(command, text.strip())


def apply_command(program: SimRobotProgram, truth_path: Path, text: str) -> bool:
    """Apply one fault command line (a bad one is said on stderr, ``error: ...``, and changes nothing) and write
    the fault in force into the truth file at once, even while stalled (a test waits for it there). True when
    the controller is to answer again (the fault in force is not a stall)."""
    try:
        program.set_fault(text)
        applied = True
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr, flush=True)
        applied = False
    write_truth(truth_path, program.truth())
    return applied and program.fault != "stall"


def grasp_error(D_b: np.ndarray, T_b_g0: np.ndarray, T_b_w: np.ndarray, T_b_w0: np.ndarray) -> tuple[float, float]:
    """The grasp pose offset ``D_b`` makes of the taught one, ``D_b · T_b_g0`` (what ``pose_trans`` does),
    against the ideal one ``T_b_w · T_b_w0⁻¹ · T_b_g0``: (distance mm at the TCP, angle deg)."""
    angle_deg, distance_mm = pose_difference(compose(D_b, T_b_g0), compose(T_b_w, invert(T_b_w0), T_b_g0))
    return distance_mm, angle_deg


def load_robot_spec(path: Path) -> RobotSpec:
    data = json.loads(Path(path).read_text())
    if data.get("format") != ROBOT_SPEC_FORMAT:
        raise ValueError(f"{path}: format must be {ROBOT_SPEC_FORMAT!r}, got {data.get('format')!r}")
    m = {k: np.asarray(data[k], dtype=float) for k in ("T_b_w0", "T_b_w", "T_b_g0")}
    return RobotSpec(int(data["part"]), int(data["seed"]), float(data["repeatability_mm"]),
                     float(data["repeatability_deg"]),
                     tuple(np.asarray(T, dtype=float) for T in data["T_b_f_taught"]), **m,
                     T_b_f_calibration=tuple(np.asarray(T, dtype=float) for T in data.get("T_b_f_calibration", ())),
                     reported_fraction=float(data.get("reported_repeatability_fraction", 1.0)))


def write_truth(path: Path, truth: dict[str, object]) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(truth))
    os.replace(tmp, path)


def read_truth(path: Path) -> dict[str, object]:
    """The truth file of a simulated controller (what it did); matrices as nested lists."""
    data = json.loads(Path(path).read_text())
    if data.get("format") != TRUTH_FORMAT:
        raise ValueError(f"{path}: format must be {TRUTH_FORMAT!r}, got {data.get('format')!r}")
    return data


def follow_truth(cell: SimCell, path: Path) -> int:
    """Let an in-process :class:`SimCell` (the simulated camera's) stand where the simulated controller's robot
    stands: every stop it made, then its current measuring pose; and hold the part the controller's part
    supply presents (``T_cf_w``), when it has one. Returns that pose number (0: moving)."""
    truth = read_truth(path)
    if truth.get("T_cf_w") is not None:
        cell.set_part_pose(np.asarray(truth["T_cf_w"], dtype=float))
    stops = {int(k): np.asarray(T, dtype=float) for k, T in truth["stops"].items()}  # type: ignore[union-attr]
    current = int(truth["in_position"])  # type: ignore[call-overload]
    for number in sorted(stops, key=lambda k: k == current):  # the current stop last: it sets current_pose
        if 1 <= number <= cell.n_measuring_poses:  # not the base-calibration poses (101..): no camera pose
            cell.set_actual_flange_pose(number - 1, stops[number])
    return current


def file_mtime(path: Path) -> int:
    try:
        return path.stat().st_mtime_ns
    except OSError:
        return -1


def _interpolate(T_from: np.ndarray, T_to: np.ndarray, s: float) -> np.ndarray:
    if s >= 1.0:
        return T_to.copy()
    dR = T_from[:3, :3].T @ T_to[:3, :3]
    R = T_from[:3, :3] @ rotvec_to_matrix(s * matrix_to_rotvec(dR))
    return make_T(R, (1.0 - s) * T_from[:3, 3] + s * T_to[:3, 3])
