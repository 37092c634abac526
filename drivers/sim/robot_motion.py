"""The simulated robot program, shared by the simulated UR and KUKA controllers (protocol-free).

It plays the state machine of ``config/ur/`` and ``config/kuka/`` as :mod:`monoguide.drivers.robot_program`
tables it (every answer, validity flag and held sequence goes through :meth:`SimRobotProgram._rule`, by the
rule's name): in its loop, when idle, it answers the cell's grasp go first, then the request registers (UR: as
they are now, retained across a program restart) or every message in its buffer (KUKA: oldest first). On a request
to go to pose number k it moves there in ``move_time_s`` and stops at the taught flange pose plus the cell's
repeatability noise, then reports k in position and acknowledges (101.. are the base-calibration poses, the
spec's ``T_b_f_calibration``); an offset ``D_b`` within its limits is stored and acknowledged and scored: the
**grasp error**, ``pose_trans(D_b, grasp)`` against the ideal grasp pose ``T_b_w · T_b_w0⁻¹ · T_b_g0`` that
fits the true part exactly. On the go, the grasp runs with the held offset when it is valid (scored again, on
the part in the cell now) and is refused when it is not; both are logged (``grasps``).

The truth comes from the robot spec file that :meth:`SimCell.write_robot_spec` writes (re-read when it
changes: a new part); what the robot did goes to a truth file (:func:`read_truth`) that the in-process
simulated camera follows (:meth:`SimCell.set_actual_flange_pose`) and tests score against: its stops (true:
``T_b_f``, ``stops``; as reported: ``T_b_f_reported``, ``stops_reported``, which see only the share
``reported_repeatability_fraction`` of each stop's deviation), the offsets it took, its grasps, at every
moment what it holds (``held_sequence``, ``offset_valid``) and, with a part supply, the part in the cell
(``T_cf_w``, ``part_type``, ``reference_part``: :attr:`PartSupply.reference_state`).

Faults (:data:`FAULT_MODES` and :data:`FAULT_ACTIONS`, at start ``--fault`` or at run time one per line on
standard input; ``none`` clears a mode and every one-shot still armed): modes, from the next request on:
``stall`` (the controller freezes: nothing answered, nothing sent), ``drop`` (it closes every connection),
``protective-stop`` (safety stop, no motion), ``never-reach`` (moves but never arrives; also a move under way),
``no-ack`` (offsets are neither taken nor acknowledged: the part keeps no offset); at once ``program-stopped`` (the
program is not running; ``none`` starts it again from the beginning, as Play after Stop). One-shot: ``restart``
(Stop/Play now: the program stops for ``RESTART_DOWN_S`` and starts again, its variables reset, the UR request
registers as they were), ``cut [DOWN_S]`` (the cable pulled now: every connection closed, any new one closed at once
for DOWN_S s, default 1; the program runs on), ``cut-after-offset MS [DOWN_S]`` (when the next offset request
arrives, MS ms later every
connection is closed and any new one closed at once for DOWN_S s, default 1; the program runs on and takes the
offset on its own schedule, as after a cable pull), ``reference-part`` (the part supply's next part is the
reference part). ``none`` disarms a cut-after-offset whose offset has not come yet and a reference part that has
not arrived yet; a cut under way ends (the controller takes connections again); a reference part in the cell stays
until grasped. What the robot adapter reports for each (``drivers/errors.py``): stall ``DEVICE_TIMEOUT``
(402), drop ``DEVICE_DISCONNECTED`` (403), protective-stop ``ROBOT_PROTECTIVE_STOP`` (422), never-reach
``ROBOT_POSITION_TIMEOUT`` (423), no-ack ``ROBOT_ACK_TIMEOUT`` (424), program-stopped and restart
``ROBOT_NOT_READY`` (421; KUKA's restart closes the channel: ``DEVICE_DISCONNECTED``).

Order of truth and wire: every step of the program and the truth file that says what it did are one synchronous
call (:meth:`SimController.step <monoguide.drivers.sim.robot_serve.SimController.step>`, no ``await`` between
them), and the controllers send their state only from other tasks of the same event loop; so the truth file
(stops, ``in_position``, the offset held, the part's ``T_cf_w``) is on disk before a client can see it on the wire.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import os
from dataclasses import dataclass, field

import numpy as np

from monoguide.drivers.robot import (
    CALIBRATION_POSE_BASE,
    COMMAND_CLEAR,
    COMMAND_GOTO,
    COMMAND_NONE,
    COMMAND_OFFSET,
    PROGRAM_BUSY,
    PROGRAM_OK,
    PROGRAM_SYNCHRONISED,
)
from monoguide.drivers.robot_program import RULE
from monoguide.drivers.sim.part_supply import PartSupply
from monoguide.drivers.sim.robot_requests import (  # re-exported: the controllers and tests import them from here
    CUT_DOWN_S,
    FAULT_ACTIONS,
    FAULT_MODES,
    AppliedOffset,
    FaultCommand,
    Grasp,
    Request,
    RequestSource,
    parse_fault,
)
from monoguide.drivers.sim.robot_truth import (  # re-exported: the simulated camera and tests import them from here
    TRUTH_FORMAT,
    RobotSpec,
    file_mtime,
    follow_truth,
    grasp_error,
    load_robot_spec,
    offset_size,
    read_truth,
    write_truth,
)
from monoguide.solver.frames import compose, invert, make_T, matrix_to_rotvec, rotvec_to_matrix

__all__ = ["CUT_DOWN_S", "FAULT_ACTIONS", "FAULT_MODES", "TRUTH_FORMAT", "AppliedOffset", "FaultCommand", "Grasp",
           "Request", "RequestSource", "RobotSpec", "SimRobotProgram", "file_mtime", "follow_truth", "grasp_error",
           "load_robot_spec", "offset_size", "parse_fault", "read_truth", "write_truth"]

log = logging.getLogger("monoguide.sim.robot")

MAX_OFFSETS_KEPT = 200
RESTART_DOWN_S = 0.3  # Stop ... Play: how long the program is not running
# the program's own limits for an offset, as the templates have them: the grasp point's shift and the rotation
MAX_OFFSET_SHIFT_MM = 100.0
MAX_OFFSET_TURN_DEG = 10.0


@dataclass
class SimRobotProgram:
    """The robot program's state and its answers. Time is passed in (``now``, seconds), never read."""

    spec: RobotSpec
    rng: np.random.Generator
    move_time_s: float = 0.5
    fault: str = "none"
    supply: PartSupply | None = None  # presents a new part at each request of measuring pose 1
    grasp_time_s: float = 0.1
    T_b_f: np.ndarray = field(default_factory=lambda: np.eye(4))
    safety: str = "NORMAL"
    state: str = "IDLE"
    program_running: bool = True
    # the program variables (robot_program.VARIABLES)
    last_seq: int = 0
    ack_sequence: int = 0
    in_position: int = 0
    program_status: int = PROGRAM_OK
    held_sequence: int = 0
    offset_valid: bool = False
    offset: np.ndarray = field(default_factory=lambda: np.eye(4))  # the held offset (identity when not valid)
    requests: int = 0  # new numbered requests taken
    offsets: list[AppliedOffset] = field(default_factory=list)
    grasps: list[Grasp] = field(default_factory=list)
    stops: dict[int, np.ndarray] = field(default_factory=dict)
    stops_reported: dict[int, np.ndarray] = field(default_factory=dict)  # what the controller reported there
    commands_applied: int = 0
    starts: int = 0
    _move: tuple[float, np.ndarray, np.ndarray, int, int] | None = None  # start, from, to, number, seq
    _grasp_end: float | None = None
    _go_pending: int = 0
    _stopped_until: float | None = None  # a restart under way: the program starts again then
    _cut: FaultCommand | None = None
    _events: list[dict[str, object]] = field(default_factory=list)
    _unseen: np.ndarray = field(default_factory=lambda: np.eye(4))  # reported = true · _unseen (this stop's)

    def __post_init__(self) -> None:
        self.T_b_f = self._stop_at(1)  # the robot stands at measuring pose S1 when the controller starts
        command = parse_fault(self.fault)
        self.fault = "none"
        self._start(None)
        if command.name != "none":
            self.command(command, 0.0)
        self.commands_applied = 0

    # --- the loop ---------------------------------------------------------------------------------

    def step(self, now: float, source: RequestSource) -> bool:
        """One pass of the program's loop at ``now``: a restart's start, the motion or grasp under way, then (idle)
        the go and the requests. Returns whether anything the program holds or reports changed."""
        changed = False
        if self._stopped_until is not None and now >= self._stopped_until:
            self._start(source)
            changed = True
        if not self.program_running or self.safety != "NORMAL":
            return changed
        if self._advance(now):
            return True  # a move or grasp just ended and was answered: the loop's next pass reads the inputs
        while self.state == "IDLE":
            if self._go_pending:
                self._go_pending -= 1
                self._go(now)
                changed = True
                continue
            request = source.next_request()
            if request is None:
                break
            changed |= self._take(request, now)
            if source.level:
                break  # UR: the registers once a cycle
        return changed

    def go(self) -> None:
        """The cell's grasp go rises (the simulated PLC's, forwarded by sim-cell). A program that is not running or
        stands in a safety stop does not see it; the line drops its go when the answer does not come."""
        if not self.program_running or self.safety != "NORMAL":
            log.info("grasp go not seen: the program is %s", "stopped" if not self.program_running else self.safety)
            return
        self._go_pending += 1

    def take_events(self) -> list[dict[str, object]]:
        """What happened since the last call that the controller passes on (grasps; the program stopped/started)."""
        events, self._events = self._events, []
        return events

    def take_cut(self) -> FaultCommand | None:
        """An offset request has arrived at the controller: the armed cut-after-offset, once."""
        cut, self._cut = self._cut, None
        return cut

    @property
    def faulted(self) -> bool:
        """A fault mode is in effect (it acts on every new request)."""
        return self.fault != "none"

    # --- faults -------------------------------------------------------------------------------------

    def command(self, fault: FaultCommand, now: float) -> None:
        """Apply a fault command (:func:`parse_fault`): a mode from the next request on (``program-stopped`` at
        once), an action now."""
        self.commands_applied += 1
        log.info("fault %s (was %s)", fault.name, self.fault)
        if fault.name == "restart":
            self._stop(now + RESTART_DOWN_S)
            return
        if fault.name == "cut-after-offset":
            self._cut = fault
            return
        if fault.name == "cut":  # the controller's connections, not the program: it runs on
            return
        if fault.name == "reference-part":
            if self.supply is not None:
                self.supply.reference_next = True
            return
        if fault.name == "none":  # every armed one-shot too: a cut not yet taken, a reference part not yet arrived
            self._cut = None
            if self.supply is not None:
                self.supply.reference_next = False
        was = self.fault
        self.fault = fault.name
        if fault.name != "protective-stop":
            self.safety = "NORMAL"
        if fault.name == "program-stopped":
            self._stop(None)
        elif was == "program-stopped" and not self.program_running and self._stopped_until is None:
            self._stopped_until = now  # Play: the program starts again from the beginning at its next step

    # --- the truth ----------------------------------------------------------------------------------

    @property
    def T_b_f_reported(self) -> np.ndarray:
        """The flange pose the controller reports (its encoders): the true one less the part of the stop's
        deviation from the taught pose that the encoders do not see (``reported_fraction``)."""
        return compose(self.T_b_f, self._unseen)

    def reload(self, spec: RobotSpec) -> None:
        if spec.part != self.spec.part:
            log.info("new part %d in the cell", spec.part)
        self.spec = spec

    def truth(self) -> dict[str, object]:
        """What the robot did and holds, for the truth file."""
        return {
            "format": TRUTH_FORMAT,
            "pid": os.getpid(),
            "part": self.spec.part,
            "in_position": self.in_position,
            "fault": self.fault,
            "commands_applied": self.commands_applied,
            "program_running": self.program_running,
            "starts": self.starts,
            "state": self.state,
            "last_seq": self.last_seq,
            "ack_sequence": self.ack_sequence,
            "program_status": self.program_status,
            "held_sequence": self.held_sequence,
            "offset_valid": self.offset_valid,
            "T_b_f": self.T_b_f.tolist(),
            **({"T_cf_w": self.supply.T_cf_w.tolist(), "part_type": self.supply.job,
                "reference_part": self.supply.reference_state} if self.supply is not None else {}),
            "stops": {str(k): T.tolist() for k, T in self.stops.items()},
            "T_b_f_reported": self.T_b_f_reported.tolist(),
            "stops_reported": {str(k): T.tolist() for k, T in self.stops_reported.items()},
            "offsets": [
                {"sequence": o.sequence, "part": o.part, "received": list(o.received), "D_b": o.D_b.tolist(),
                 "grasp_error_mm": o.grasp_error_mm, "grasp_error_deg": o.grasp_error_deg}
                for o in self.offsets[-MAX_OFFSETS_KEPT:]
            ],
            "grasps": [g.record() for g in self.grasps[-MAX_OFFSETS_KEPT:]],
        }

    # --- private: the rules -----------------------------------------------------------------------------

    def _rule(self, name: str, sequence: int | None = None) -> None:
        """Apply rule ``name`` of the table: its answer (with ``sequence``), the validity flag, the held sequence."""
        rule = RULE[name]
        if rule.valid == "set":
            self.offset_valid = True
        elif rule.valid == "clear":
            self.offset_valid = False
            self.offset = np.eye(4)  # the grasp base holds no offset at rest (KUKA: BASE_DATA reset to the taught)
        if rule.held == "sequence":
            assert sequence is not None
            self.held_sequence = sequence
        elif rule.held == "zero":
            self.held_sequence = 0
        if rule.status is not None:
            assert sequence is not None
            self.program_status = rule.status  # status first, the number last: the daemon reads it with the number
            if rule.status != PROGRAM_BUSY:  # busy: the number stays the last one answered
                self.ack_sequence = sequence
            self._events.append({"event": "answer", "ack_sequence": self.ack_sequence, "program_status":
                                 self.program_status, "in_position": self.in_position,
                                 "held_sequence": self.held_sequence, "offset_valid": self.offset_valid})

    def _start(self, source: RequestSource | None) -> None:
        """The program starts: every variable as the table has it at start; UR's last_seq is the request already in
        the registers (not replayed)."""
        self._stopped_until = None
        self.program_running = True
        self.state = "IDLE"
        self._move = self._grasp_end = None
        self._go_pending = 0
        self.in_position = 0
        self.program_status = PROGRAM_OK
        self.ack_sequence = 0
        self.last_seq = 0
        if source is not None and source.level and (request := source.next_request()) is not None:
            self.last_seq = request.sequence
        self._rule("start")
        self.starts += 1
        self._events.append({"event": "started", "last_seq": self.last_seq})
        log.info("program starts (last_seq %d)", self.last_seq)

    def _stop(self, restart_at: float | None) -> None:
        self.program_running = False
        self._stopped_until = restart_at
        self._move = self._grasp_end = None
        self.state = "IDLE"
        self._events.append({"event": "stopped"})
        log.info("program stops%s", "" if restart_at is None else f" (starts again at {restart_at:.3f} s)")

    def _take(self, request: Request, now: float) -> bool:
        seq = request.sequence
        if seq == 0:
            if (self.last_seq, self.ack_sequence, self.program_status, self.offset_valid) == (
                    0, 0, PROGRAM_SYNCHRONISED, False):
                return False  # UR: the register still 0, already answered
            self.last_seq = 0
            self._rule("reset", 0)
            return True
        if seq == self.last_seq:
            return False  # rule "repeat"
        self.last_seq = seq
        self.requests += 1
        log.info("request %d: command %d pose %d offset %s", seq, request.command, request.pose_number,
                 " ".join(f"{v:.9g}" for v in request.received))
        if self.fault == "protective-stop":
            self.safety = "PROTECTIVE_STOP"  # the program pauses; the request is never executed
            return True
        if request.D_b is None:
            self._rule("unreadable", seq)
        elif request.command == COMMAND_NONE:
            self._rule("sync", seq)
        elif request.command == COMMAND_GOTO:
            self._goto(seq, request.pose_number, now)
        elif request.command == COMMAND_OFFSET:
            self._store_offset(seq, request.D_b, request.received)
        elif request.command == COMMAND_CLEAR:
            self._rule("clear", seq)
        else:
            self._rule("unknown", seq)
        return True

    def _goto(self, seq: int, number: int, now: float) -> None:
        if not (1 <= number <= len(self.spec.T_b_f_taught)
                or CALIBRATION_POSE_BASE < number <= CALIBRATION_POSE_BASE + len(self.spec.T_b_f_calibration)):
            self._rule("bad-pose", seq)
            return
        if self.supply is not None and self.supply.starts_cycle(number):  # a cycle starts: the next part arrives
            T_b_w = self.supply.arrive()
            kind = {} if self.supply.T_b_g0_type is None else {"T_b_w0": self.supply.T_b_w0_type,
                                                                "T_b_g0": self.supply.T_b_g0_type}
            self.spec = dataclasses.replace(self.spec, T_b_w=T_b_w, part=self.supply.part, **kind)
        self.in_position = 0
        self._rule("goto", seq)
        self.state = "MOVING"
        self._move = (now, self.T_b_f.copy(), self._stop_at(number), number, seq)

    def _store_offset(self, seq: int, D_b: np.ndarray, received: tuple[float, ...]) -> None:
        if self.fault == "no-ack":  # the program never takes it: nothing stored, nothing acknowledged
            log.info("offset %d not taken (fault no-ack)", seq)
            return
        shift_mm, turn_deg = offset_size(D_b, self.spec.T_b_g0)
        if shift_mm > MAX_OFFSET_SHIFT_MM or turn_deg > MAX_OFFSET_TURN_DEG:
            log.info("offset %d refused: %.2f mm / %.3f deg at the grasp point (limits %g mm / %g deg)", seq,
                     shift_mm, turn_deg, MAX_OFFSET_SHIFT_MM, MAX_OFFSET_TURN_DEG)
            self._rule("offset-refused", seq)
            return
        error_mm, error_deg = grasp_error(D_b, self.spec.T_b_g0, self.spec.T_b_w, self.spec.T_b_w0)
        self.offsets.append(AppliedOffset(seq, self.spec.part, received, np.array(D_b, dtype=float), error_mm,
                                          error_deg))
        if self.supply is not None:
            self.supply.offset_applied(self.spec.part, D_b, error_mm, error_deg)
        log.info("offset %d for part %d: grasp error %.4f mm %.5f deg", seq, self.spec.part, error_mm, error_deg)
        self._rule("offset", seq)
        self.offset = np.array(D_b, dtype=float)

    def _go(self, now: float) -> None:
        s = self.spec
        D_b = self.offset if self.offset_valid else self._held_D_b()
        error = grasp_error(D_b, s.T_b_g0, s.T_b_w, s.T_b_w0) if self.offset_valid or self.held_sequence \
            else (None, None)
        if self.offset_valid:
            grasp = Grasp(s.part, self.held_sequence, "ran", None, *error, now)
            self.state = "GRASPING"  # rule "grasp": the flag clears once the grasp has run (_advance)
            self._grasp_end = now + self.grasp_time_s
        else:
            grasp = Grasp(s.part, self.held_sequence, "refused", "stale offset" if self.held_sequence else "no offset",
                          *error, now)
            self._rule("grasp-refused")
            self._grasped(grasp)
        self.grasps.append(grasp)
        log.info("grasp of part %d %s (held offset %d%s)", s.part, grasp.outcome, grasp.held_sequence,
                 f", {grasp.reason}" if grasp.reason else "")

    def _grasped(self, grasp: Grasp) -> None:
        """A grasp has run or was refused: an event for the controller, a line in the part supply's truth log."""
        self._events.append({"event": "grasp", **grasp.record()})
        if self.supply is not None and self.supply.log_path is not None:
            with self.supply.log_path.open("a") as f:
                f.write(json.dumps({"grasp": grasp.record()}) + "\n")

    def _held_D_b(self) -> np.ndarray:
        """The offset the program last took (what a grasp without the interlock would use), identity if none."""
        held = [o for o in self.offsets if o.sequence == self.held_sequence]
        return held[-1].D_b if held else np.eye(4)

    def _advance(self, now: float) -> bool:
        """The motion (or grasp) under way, to time ``now``; True when it ended."""
        if self.state == "GRASPING":
            assert self._grasp_end is not None
            if now < self._grasp_end:
                return False
            self._grasp_end = None
            self.state = "IDLE"
            self._rule("grasp")
            self._grasped(self.grasps[-1])
            return True
        if self._move is None:
            return False
        start, T_from, T_to, number, sequence = self._move
        s = 1.0 if self.move_time_s <= 0 else min(1.0, (now - start) / self.move_time_s)
        if self.fault == "never-reach":
            s = min(s, 0.5)
        self.T_b_f = _interpolate(T_from, T_to, s)
        if s < 1.0:
            return False
        self._move = None
        self.state = "IDLE"
        self.in_position = number
        self.stops[number] = T_to.copy()
        self.stops_reported[number] = compose(T_to, self._unseen)
        self._rule("arrived", sequence)
        log.info("in position at S%d (request %d)", number, sequence)
        return True

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


# --- functions ------------------------------------------------------------------------------------


def _interpolate(T_from: np.ndarray, T_to: np.ndarray, s: float) -> np.ndarray:
    if s >= 1.0:
        return T_to.copy()
    dR = T_from[:3, :3].T @ T_to[:3, :3]
    R = T_from[:3, :3] @ rotvec_to_matrix(s * matrix_to_rotvec(dR))
    return make_T(R, (1.0 - s) * T_from[:3, 3] + s * T_to[:3, 3])
