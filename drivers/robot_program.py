"""The robot program, as one table: what it reads and reports, its variables, its states and what each event does.

Both templates (``config/ur/monoguide.script``, ``config/kuka/monoguide.src``) run this state machine, the
simulated controllers play it (``drivers/sim/robot_motion.py`` applies :data:`RULES` by name), and
``tests/drivers/test_robot_templates.py`` checks the templates against it: the registers and XML tags, every
variable and its value at start, every rule (marked ``rule: <name>`` in each template) with its answer and
what it does to the validity flag and the held sequence. ``docs/robot-interface.md`` is this table in words.

The grasp interlock: ``offset_valid`` is set only when an offset is stored and cleared by everything else that
can make it stale (a measuring request, sequence 0, the program's start, a grasp, any refusal, command 3); the
grasp runs in the program's own loop on the cell's go (a PLC input) and is refused while the flag is clear.
``held_seq`` is the sequence number of the last offset the program took (0: none since its start or the last
command 3); the daemon settles an offset whose acknowledgement it did not see against it.
"""

from __future__ import annotations

from dataclasses import dataclass

from monoguide.drivers.robot import (
    COMMAND_CLEAR,
    COMMAND_GOTO,
    COMMAND_NONE,
    COMMAND_OFFSET,
    PROGRAM_BAD_POSE,
    PROGRAM_BUSY,
    PROGRAM_OFFSET_REJECTED,
    PROGRAM_OK,
    PROGRAM_SYNCHRONISED,
    PROGRAM_UNKNOWN_COMMAND,
)


@dataclass(frozen=True)
class Signal:
    """One value on the wire: its name here, its UR RTDE register, its KUKA EKI XML path."""

    name: str
    ur: str
    kuka: str
    meaning: str


@dataclass(frozen=True)
class Variable:
    """A program variable (the same name in both templates) and its value at every program start."""

    name: str
    ur_start: str  # the URScript expression it starts with
    kuka_start: str  # the KRL expression
    meaning: str


@dataclass(frozen=True)
class Rule:
    """What the program does on ``event`` in state ``state``: the state it goes to, its answer (``status``,
    with the request's sequence number; None: no answer), and what happens to the validity flag (``valid``:
    "set", "clear", "keep") and to the held sequence (``held``: "sequence" the request's number, "zero",
    "keep"). ``makes``: the templates that have the rule (KUKA alone reads messages that can be unreadable)."""

    name: str
    event: str
    state: str
    next_state: str
    status: int | None
    valid: str
    held: str
    makes: tuple[str, ...] = ("ur", "kuka")


REQUEST = (
    Signal("sequence", "input_int_register_24", "Sensor/Request/@Seq",
           "the request's number, 1..2^31-1 then 1 again; 0: the daemon (re)connected"),
    Signal("command", "input_int_register_25", "Sensor/Request/@Command",
           f"{COMMAND_NONE} none (with a new number: synchronise), {COMMAND_GOTO} go to pose, "
           f"{COMMAND_OFFSET} store the offset, {COMMAND_CLEAR} forget the offset"),
    Signal("pose", "input_int_register_26", "Sensor/Request/@Pose",
           "command 1: measuring pose k (1 = S1) or base-calibration pose 100 + j"),
    Signal("offset_x", "input_double_register_24", "Sensor/Offset/@X", "offset translation x (UR m, KUKA mm)"),
    Signal("offset_y", "input_double_register_25", "Sensor/Offset/@Y", "offset translation y"),
    Signal("offset_z", "input_double_register_26", "Sensor/Offset/@Z", "offset translation z"),
    Signal("offset_r1", "input_double_register_27", "Sensor/Offset/@A",
           "offset rotation: UR rotation vector rx (rad); KUKA A (deg, about z)"),
    Signal("offset_r2", "input_double_register_28", "Sensor/Offset/@B", "UR ry (rad); KUKA B (deg, about y')"),
    Signal("offset_r3", "input_double_register_29", "Sensor/Offset/@C", "UR rz (rad); KUKA C (deg, about x'')"),
)

REPORT = (
    Signal("ack", "output_int_register_36", "Robot/Handshake/@Ack", "the number of the last request answered"),
    Signal("in_position", "output_int_register_37", "Robot/Handshake/@InPosition",
           "the pose number the robot stands at (0: moving, or none since the start)"),
    Signal("status", "output_int_register_38", "Robot/Handshake/@Status", "the answer to request ack"),
    Signal("held", "output_int_register_39", "Robot/Handshake/@Held",
           "held_seq: the number of the offset the program took last (0: none)"),
    Signal("valid", "output_int_register_40", "Robot/Handshake/@Valid",
           "offset_valid as 0/1: the grasp would run with the held offset"),
)

VARIABLES = (
    Variable("last_seq", "read_input_integer_register(24)", "0",
             "the last request taken; UR starts with the request already in the registers (no replay after Stop/"
             "Play), KUKA with a fresh channel"),
    Variable("ack", "0", "0", "reported: the last request answered"),
    Variable("in_pos", "0", "0", "reported: the pose number the robot stands at"),
    Variable("status", "0", "0", "reported: the answer to ack"),
    Variable("held_seq", "0", "0", "reported: the number of the offset taken last"),
    Variable("offset_valid", "False", "FALSE", "reported: the grasp interlock"),
    Variable("go_was", "get_standard_digital_in(go_input)", "$IN[GO_IN]",
             "the go input as last seen (a go already high at the start is not a new one)"),
)

STATES = ("IDLE", "MOVING", "GRASPING")

RULES = (
    Rule("start", "the program starts (Play, or a restart after Stop)", "-", "IDLE", None, "clear", "zero"),
    Rule("reset", "sequence 0 (the daemon connected)", "IDLE", "IDLE", PROGRAM_SYNCHRONISED, "clear", "keep"),
    Rule("repeat", "the number last taken again (UR: a register not yet changed)", "IDLE", "IDLE", None, "keep",
         "keep"),
    Rule("sync", "command 0 with a new number", "IDLE", "IDLE", PROGRAM_OK, "keep", "keep"),
    Rule("goto", "command 1 with a taught pose number", "IDLE", "MOVING", PROGRAM_BUSY, "clear", "keep"),
    Rule("arrived", "the move of a command 1 has ended (standing still)", "MOVING", "IDLE", PROGRAM_OK, "keep",
         "keep"),
    Rule("bad-pose", "command 1 with a pose number the program does not have", "IDLE", "IDLE", PROGRAM_BAD_POSE,
         "clear", "keep"),
    Rule("offset", "command 2 within the program's limits", "IDLE", "IDLE", PROGRAM_OK, "set", "sequence"),
    Rule("offset-refused", "command 2 outside the program's limits", "IDLE", "IDLE", PROGRAM_OFFSET_REJECTED,
         "clear", "keep"),
    Rule("clear", "command 3", "IDLE", "IDLE", PROGRAM_OK, "clear", "zero"),
    Rule("unknown", "any other command", "IDLE", "IDLE", PROGRAM_UNKNOWN_COMMAND, "clear", "keep"),
    Rule("unreadable", "a request whose fields could not all be read (KUKA: a RET not ok)", "IDLE", "IDLE",
         PROGRAM_UNKNOWN_COMMAND, "clear", "keep", makes=("kuka",)),
    Rule("grasp", "the go rises while the offset is valid", "IDLE", "GRASPING", None, "clear", "keep"),
    Rule("grasp-refused", "the go rises while the offset is not valid", "IDLE", "IDLE", None, "clear", "keep"),
)
RULE = {rule.name: rule for rule in RULES}

# The cell's go and the program's answers to the PLC (the templates' defaults; the robot programmer wires them)
GRASP_SIGNALS = {
    "ur": {"go": "get_standard_digital_in(go_input)", "done": "set_standard_digital_out(done_output",
           "refused": "set_standard_digital_out(refused_output"},
    "kuka": {"go": "$IN[GO_IN]", "done": "$OUT[DONE_OUT]", "refused": "$OUT[REFUSED_OUT]"},
}
