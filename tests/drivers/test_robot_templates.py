"""The robot programs a robot programmer loads, checked without a controller against the one table both follow
(``drivers/robot_program.py``) and against the manuals' vocabulary (``data/``): URScript blocks and every function
it calls; KRL routines, folds, declarations, every variable set before use, every EKI call with its arity; the EKI
XML against the manual's structure; in both, every register or tag, variable, rule and state of the table."""

from __future__ import annotations

import ipaddress
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
from helpers.template_parsing import (
    KRL_KEYWORDS,
    URSCRIPT_KEYWORDS,
    Line,
    assignments,
    calls,
    krl_dat,
    krl_declared,
    krl_reads_before_write,
    krl_routines,
    rule_blocks,
    split_lines,
    states,
    urscript_structure,
    vocabulary,
)

from monoguide.drivers import kuka_protocol as kuka
from monoguide.drivers import rtde_protocol as rtde
from monoguide.drivers.robot import PROGRAM_BUSY, PROGRAM_STATUS_TEXT
from monoguide.drivers.robot_program import REPORT, REQUEST, RULES, STATES, VARIABLES, Rule

CONFIG = Path(__file__).parents[2] / "config"
UR_SCRIPT = CONFIG / "ur" / "monoguide.script"
KRL_SRC, KRL_DAT = CONFIG / "kuka" / "monoguide.src", CONFIG / "kuka" / "monoguide.dat"
EKI_XML = CONFIG / "kuka" / "monoguide.xml"


@pytest.fixture(scope="module")
def ur() -> list[Line]:
    return split_lines(UR_SCRIPT.read_text(), "#")


@pytest.fixture(scope="module")
def krl() -> list[Line]:
    return split_lines(KRL_SRC.read_text(), ";")


@pytest.fixture(scope="module")
def dat() -> list[Line]:
    return split_lines(KRL_DAT.read_text(), ";")


@pytest.fixture(scope="module")
def eki() -> ET.Element:
    return ET.parse(EKI_XML).getroot()


def _rules(make: str) -> dict[str, Rule]:
    return {rule.name: rule for rule in RULES if make in rule.makes}


# --- the table itself -----------------------------------------------------------------------------


def test_the_table_speaks_the_ports_words() -> None:
    assert {r.status for r in RULES if r.status is not None} <= set(PROGRAM_STATUS_TEXT)
    assert set(PROGRAM_STATUS_TEXT) <= {r.status for r in RULES}, "a status no rule answers"
    assert {r.state for r in RULES} - {"-"} <= set(STATES) and {r.next_state for r in RULES} <= set(STATES)
    assert {r.valid for r in RULES} <= {"set", "clear", "keep"} and {r.held for r in RULES} <= {"sequence", "zero",
                                                                                                "keep"}
    assert [r.name for r in RULES if r.valid == "set"] == ["offset"], "the flag is set only when an offset is stored"
    assert tuple(s.ur for s in REQUEST) == rtde.INPUT_RECIPE
    assert tuple(s.ur for s in REPORT) == tuple(f"output_int_register_{k}" for k in rtde.ANSWER_REGISTERS)


# --- URScript -------------------------------------------------------------------------------------


def test_urscript_blocks_balance_and_it_runs_as_one_program(ur: list[Line]) -> None:
    defined, problems = urscript_structure(ur)
    assert problems == []
    assert defined == ["monoguide", "report", "grasp"]
    top_level = [line.code for line in ur if line.code and not line.code.startswith(" ")]
    assert top_level == ["def monoguide():", "end", "monoguide()"], "a Script node: one program and its call"


def test_urscript_calls_only_functions_of_the_script_manual(ur: list[Line]) -> None:
    manual = {name for _, name in vocabulary("urscript_functions.txt")}
    defined, _ = urscript_structure(ur)
    unknown = sorted({f"{name} (line {n})" for n, name, _ in calls(ur)
                      if name not in manual and name not in defined and name not in URSCRIPT_KEYWORDS})
    assert unknown == []


def test_urscript_reads_and_writes_exactly_the_tables_registers(ur: list[Line]) -> None:
    found = calls(ur)
    reads_int = {int(a[0]) for _, n, a in found if n == "read_input_integer_register"}
    reads_float = {int(a[0]) for _, n, a in found if n == "read_input_float_register"}
    writes = {int(a[0]) for _, n, a in found if n == "write_output_integer_register"}
    assert {f"input_int_register_{k}" for k in reads_int} | {f"input_double_register_{k}" for k in reads_float} == \
        {s.ur for s in REQUEST}
    assert {f"output_int_register_{k}" for k in writes} == {s.ur for s in REPORT}
    # the number is written last, in one place: the daemon takes the rest once it sees its number
    report = [a[0] for _, n, a in found if n == "write_output_integer_register"]
    assert report[-1] == "36" and report.count("36") == 1


def test_urscript_variables_start_as_the_table_says(ur: list[Line]) -> None:
    start = _block(ur, "rule: start", "while True:")
    assigned = {target: value for _, target, value in assignments(start)}
    for variable in VARIABLES:
        assert assigned.get(variable.name) == variable.ur_start, variable.name


def test_urscript_rules_do_what_the_table_says(ur: list[Line]) -> None:
    blocks = rule_blocks(ur, re.compile(r"^\s*def\s"))
    assert set(blocks) == set(_rules("ur"))
    for name, (state, lines) in blocks.items():
        _check_rule(_rules("ur")[name], state, lines, true="True", false="False",
                    reset_offset="offset = p[0, 0, 0, 0, 0, 0]")


def test_urscript_marks_the_tables_states(ur: list[Line]) -> None:
    assert states(ur) == set(STATES)


def test_urscript_registers_are_rtde_only_and_the_go_is_a_plc_input(ur: list[Line]) -> None:
    text = UR_SCRIPT.read_text()
    assert "0-23" in text and "RTDE's own" in text  # 24-47 are RTDE's; a fieldbus cell uses 0-23 for the go
    assert any(n == "get_standard_digital_in" for _, n, _ in calls(ur))


# --- KRL ------------------------------------------------------------------------------------------


def test_krl_routines_blocks_and_the_standard_ini_fold(krl: list[Line]) -> None:
    routines, problems = krl_routines(krl)
    assert problems == []
    assert [r.name for r in routines] == ["monoguide", "TAKE", "GRASP_ON_GO", "ANSWER", "REPORT", "OFFSET_TOO_BIG",
                                          "BUFFERS_IN_STEP", "CLEAR_BUFFERS"]
    folds = [line.comment for line in krl if re.match(r"(END)?FOLD\b", line.comment)]
    assert folds == ["FOLD INI;%{PE}", "FOLD BASISTECH INI", "ENDFOLD (BASISTECH INI)", "FOLD USER INI",
                     "ENDFOLD (USER INI)", "ENDFOLD (INI)"]
    main = routines[0]
    ini = [s.code.strip() for s in main.statements[:4]]
    assert ini == ["GLOBAL INTERRUPT DECL 3 WHEN $STOPMESS==TRUE DO IR_STOPM ( )", "INTERRUPT ON 3",
                   "BAS (#INITMOV,0 )", "BAS (#VEL_PTP,20 )"]


def test_krl_every_local_is_set_before_it_is_used(krl: list[Line]) -> None:
    routines, _ = krl_routines(krl)
    assert [p for r in routines for p in krl_reads_before_write(r)] == []


def test_krl_every_data_list_variable_has_a_value(dat: list[Line]) -> None:
    declared, missing = krl_dat(dat)
    assert missing == []
    assert {v.name for v in VARIABLES} <= set(declared)
    assert declared["XP_MEAS"].startswith("DECL E6POS") and declared["XP_GRASP"].startswith("DECL E6POS")
    assert declared["XA_CALIB"].startswith("DECL E6AXIS"), "calibration poses as joint angles: no flip"
    for line in dat:
        if line.code.strip().startswith(("XP_MEAS[", "XP_GRASP[")):
            assert re.search(r",S \d+,T \d+", line.code), f"line {line.number}: an E6POS with Status and Turn"


def test_krl_names_are_declared(krl: list[Line], dat: list[Line]) -> None:
    """Every name the source uses is a local, a parameter, a routine, a data-list variable, a $config.dat global,
    a system variable ($...), an enum value (#...), a KRL keyword or function: no typo reaches the controller."""
    routines, _ = krl_routines(krl)
    declared, _ = krl_dat(dat)
    known = set(declared) | {r.name for r in routines} | KRL_KEYWORDS | {"TRUE", "FALSE", "BASE_DATA", "TOOL_DATA"}
    known |= {name for _, name in vocabulary("krl_functions.txt")} | {row[0] for row in vocabulary("eki_functions.txt")}
    unknown = []
    for routine in routines:
        local = {n for d in routine.declarations for n in krl_declared(d)} | set(routine.parameters)
        for line in routine.statements:
            code = re.sub(r'"[^"]*"', "", line.code)  # strings aside
            for match in re.finditer(r"(?<![\w$#.])([A-Za-z_]\w*)", code):
                if match.group(1) not in known | local and match.group(1).upper() not in KRL_KEYWORDS:
                    unknown.append(f"line {line.number}: {match.group(1)}")
    assert unknown == []


def test_krl_calls_known_functions_and_eki_with_its_documented_arity(krl: list[Line]) -> None:
    routines, _ = krl_routines(krl)
    eki = {row[0]: (int(row[1]), int(row[2])) for row in vocabulary("eki_functions.txt")}
    krl_functions = {name for _, name in vocabulary("krl_functions.txt")}
    problems = []
    for number, name, arguments in calls(krl):
        if name.startswith("EKI_"):
            if name not in eki:
                problems.append(f"line {number}: {name} is not an EthernetKRL function")
            elif not eki[name][0] <= len(arguments) <= eki[name][1]:
                problems.append(f"line {number}: {name} takes {eki[name]} arguments, given {len(arguments)}")
            elif arguments[0] != '"monoguide"':
                problems.append(f"line {number}: {name} on channel {arguments[0]}")
        elif name.upper() not in KRL_KEYWORDS and name not in {r.name for r in routines} | krl_functions:
            problems.append(f"line {number}: {name} is neither a routine here nor a KRL function")
    assert problems == []
    # EKI_Init opens the channel by its XML file's name
    assert {a[0] for _, n, a in calls(krl) if n == "EKI_Init"} == {f'"{EKI_XML.stem}"'}


def test_krl_checks_ret_after_every_read(krl: list[Line]) -> None:
    """A failed EKI_Get keeps the variable's old value (issue 23, case 8): every read's RET is looked at before the
    next read, and a request with a field not read is refused (rule unreadable, status -1)."""
    codes = [line.code.strip() for line in krl]
    reads = [k for k, c in enumerate(codes) if re.match(r"RET = EKI_Get\w+\(", c)]
    assert len(reads) == len(REQUEST)
    for k in reads:
        assert "RET.Msg_No == 0" in codes[k + 1], f"line {krl[k].number}: {codes[k]} without its RET checked"


def test_krl_reads_and_reports_exactly_the_xmls_tags(krl: list[Line], eki: ET.Element) -> None:
    found = calls(krl)
    gets = {a[1].strip('"') for _, n, a in found if n.startswith("EKI_Get") or n in ("EKI_CheckBuffer",
                                                                                     "EKI_ClearBuffer")}
    sets = {a[1].strip('"') for _, n, a in found if n.startswith("EKI_Set")}
    received = {e.get("Tag") for e in eki.find("RECEIVE").iter("ELEMENT") if e.get("Type")}  # type: ignore[union-attr]
    sent = {e.get("Tag") for e in eki.find("SEND").iter("ELEMENT")}  # type: ignore[union-attr]
    assert gets == received == {s.kuka for s in REQUEST}
    assert sets == sent and {s.kuka for s in REPORT} <= sent
    assert {a[1] for _, n, a in found if n == "EKI_Send"} == {'"Robot"'}


def test_krl_reports_from_one_interrupt_and_answers_status_before_number(krl: list[Line]) -> None:
    routines = {r.name: r for r in krl_routines(krl)[0]}
    senders = {r.name for r in routines.values() if any("EKI_Send" in s.code for s in r.statements)}
    assert senders == {"REPORT"}
    main = [s.code.strip() for s in routines["monoguide"].statements]
    assert "INTERRUPT DECL 20 WHEN $TIMER_FLAG[1]==TRUE DO REPORT( )" in main and "INTERRUPT ON 20" in main
    assert main.index("$TIMER_STOP[1] = FALSE") < main.index("INTERRUPT ON 20")  # the timer runs
    answer = [s.code.strip() for s in routines["ANSWER"].statements]
    assert answer.index("status = result") < answer.index("ack = number")
    assert [s.code.strip() for s in routines["REPORT"].statements][-1] == "$TIMER[1] = -REPORT_MS"


def test_krl_tool_and_base_are_set_before_every_move(krl: list[Line]) -> None:
    for routine in krl_routines(krl)[0]:
        codes = [s.code.strip() for s in routine.statements]
        motions = [k for k, c in enumerate(codes) if re.match(r"(LIN|PTP|CIRC)\s", c) and c != "PTP $AXIS_ACT"]
        if not motions:
            continue
        before = codes[:motions[0]]
        assert any(c.startswith("$TOOL =") for c in before) and any(c.startswith("$BASE =") for c in before), \
            routine.name
        after = codes[motions[-1]:]
        assert "$TOOL = $NULLFRAME" in after or routine.name == "TAKE", f"{routine.name} leaves its tool set"


def test_krl_drains_the_buffer_and_reopens_the_channel(krl: list[Line]) -> None:
    main = [s.code.strip() for s in krl_routines(krl)[0][0].statements]
    drain = main.index('WHILE RET.Buff > 0')
    assert main[drain - 1] == main[drain + 2] == 'RET = EKI_CheckBuffer("monoguide", "Sensor/Request/@Seq")'
    assert "$FLAG[998] = FALSE" in main[:drain], "the flag is reset before the buffer is drained"
    assert "IF alive_was AND NOT $FLAG[997] THEN" in main
    reopen = main.index("IF alive_was AND NOT $FLAG[997] THEN")
    assert main[reopen + 2:reopen + 5] == ['RET = EKI_Clear("monoguide")', 'RET = EKI_Init("monoguide")',
                                           'RET = EKI_Open("monoguide")']


def test_krl_variables_start_as_the_table_says(krl: list[Line]) -> None:
    start = _block(krl, "rule: start", "LOOP")
    assigned = {target: value for _, target, value in assignments(start)}
    for variable in VARIABLES:
        assert assigned.get(variable.name) == variable.kuka_start, variable.name


def test_krl_rules_do_what_the_table_says(krl: list[Line]) -> None:
    blocks = rule_blocks(krl, re.compile(r"^\s*(END|ENDFCT)\s*$"))
    assert set(blocks) == set(_rules("kuka"))
    for name, (state, lines) in blocks.items():
        _check_rule(_rules("kuka")[name], state, lines, true="TRUE", false="FALSE",
                    reset_offset="BASE_DATA[GRASP_BASE] = BASE_DATA[GRASP_BASE_TAUGHT]")


def test_krl_marks_the_tables_states(krl: list[Line]) -> None:
    assert states(krl) == set(STATES)


# --- the EKI XML ----------------------------------------------------------------------------------


def test_eki_xml_has_the_structure_the_manual_gives(eki: ET.Element) -> None:
    """EthernetKRL 2.2, "Configuration": ETHERNETKRL with CONFIGURATION (EXTERNAL, INTERNAL), RECEIVE and SEND."""
    assert eki.tag == "ETHERNETKRL" and [c.tag for c in eki] == ["CONFIGURATION", "RECEIVE", "SEND"]
    configuration = eki.find("CONFIGURATION")
    assert configuration is not None and [c.tag for c in configuration] == ["EXTERNAL", "INTERNAL"]
    assert configuration.findtext("EXTERNAL/TYPE") in ("Client", "Server")
    internal = configuration.find("INTERNAL")
    assert internal is not None
    assert {c.tag for c in internal} <= {"ENVIRONMENT", "BUFFERING", "BUFFSIZE", "TIMEOUT", "ALIVE", "IP", "PORT",
                                         "PROTOCOL", "MESSAGES"}
    assert internal.findtext("ENVIRONMENT") in ("Program", "Submit", "System")
    buffering = internal.find("BUFFERING")
    assert buffering is not None and buffering.get("Mode") in ("FIFO", "LIFO") and 1 <= int(buffering.get("Limit", 0)) \
        <= 512
    assert 1 <= int(internal.find("BUFFSIZE").get("Limit", 0)) <= 65534  # type: ignore[union-attr]
    assert set(internal.find("ALIVE").attrib) <= {"Set_Out", "Set_Flag", "Ping"}  # type: ignore[union-attr]
    if configuration.findtext("EXTERNAL/TYPE") == "Client":  # the robot serves: its own address and port
        ipaddress.IPv4Address(internal.findtext("IP"))
        assert 54600 <= int(internal.findtext("PORT", "0")) <= 54615
    assert internal.findtext("PROTOCOL") in ("TCP", "UDP")
    messages = internal.find("MESSAGES")
    assert messages is None or {messages.get("Logging"), messages.get("Display")} <= {"disabled", "error", "warning",
                                                                                      "info"}
    for part, root in (("RECEIVE", kuka.SENSOR_ROOT), ("SEND", kuka.ROBOT_ROOT)):
        elements = eki.findall(f"{part}/XML/ELEMENT")
        assert elements and [c.tag for c in eki.find(part)] == ["XML"]  # type: ignore[union-attr]
        for element in elements:
            tag = element.get("Tag", "")
            assert re.fullmatch(rf"{root}(/\w+)*(/@\w+)?", tag), tag
            allowed = {"Tag", "Type", "Set_Flag", "Set_Out"} if part == "RECEIVE" else {"Tag"}
            assert set(element.attrib) <= allowed, tag
            if element.get("Type") is not None:
                assert element.get("Type") in ("BOOL", "INT", "REAL", "STRING"), tag
            if element.get("Set_Flag") is not None:
                assert 1 <= int(element.get("Set_Flag", "0")) <= 1024, tag


def test_eki_flags_are_the_ones_the_program_waits_on(eki: ET.Element, krl: list[Line]) -> None:
    alive = eki.find("CONFIGURATION/INTERNAL/ALIVE").get("Set_Flag")  # type: ignore[union-attr]
    received = [e.get("Set_Flag") for e in eki.iter("ELEMENT") if e.get("Tag") == kuka.SENSOR_ROOT]
    code = " ".join(line.code for line in krl)
    assert f"$FLAG[{alive}]" in code and received and f"$FLAG[{received[0]}]" in code
    assert set(re.findall(r"\$FLAG\[(\d+)\]", code)) == {alive, received[0]}


# --- private --------------------------------------------------------------------------------------


def _block(lines: list[Line], start: str, end: str) -> list[Line]:
    first = next(k for k, line in enumerate(lines) if start in line.comment)
    last = next(k for k, line in enumerate(lines) if k > first and line.code.strip() == end)
    return lines[first + 1:last]


def _check_rule(rule: Rule, state: str | None, lines: list[Line], *, true: str, false: str,
                reset_offset: str) -> None:
    """A rule's block sets the flag, the held sequence and the answer as the table has them (and nothing else)."""
    where = f"rule {rule.name}"
    assert state == (rule.next_state if rule.next_state not in ("IDLE", rule.state) else None), where
    assigned = [(target, value) for _, target, value in assignments(lines)]
    valid = [value for target, value in assigned if target == "offset_valid"]
    held = [value for target, value in assigned if target == "held_seq"]
    assert valid == {"set": [true], "clear": [false], "keep": []}[rule.valid], where
    assert held == {"sequence": ["seq"], "zero": ["0"], "keep": []}[rule.held], where
    codes = [line.code.strip() for line in lines]
    if rule.valid == "clear" and rule.name != "start":
        assert reset_offset in codes, f"{where}: the flag cleared, the offset not reset"
    number = "0" if rule.name == "reset" else "seq"
    statuses = [value for target, value in assigned if target == "status"]
    answers = [re.sub(r"\s", "", m.group(1)) for c in codes if (m := re.search(r"ANSWER\(([^)]*)\)", c))]
    numbers = [value for target, value in assigned if target == "ack"]
    if rule.status is None:
        assert not answers and "seq" not in numbers, f"{where} answers nothing"
    elif rule.status == PROGRAM_BUSY:  # busy before the move: the number stays the last answered one
        assert statuses == [str(rule.status)] and not answers and not numbers, where
    else:
        assert answers == [f"{number},{rule.status}"] or (statuses == [str(rule.status)] and numbers == [number]), \
            f"{where}: answers {answers or list(zip(statuses, numbers, strict=False))}, not ({number}, {rule.status})"
