"""The template checks can fail: each defect issue 23 found in the templates, planted again in a copy, is caught
by the check that guards against it (the checks of ``test_robot_templates.py``, run on the copy)."""

from __future__ import annotations

import importlib.util
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
from helpers.template_parsing import split_lines


def _load_checks():
    """The sibling test module, loaded by its path (tests are imported by path, not as packages)."""
    path = Path(__file__).with_name("test_robot_templates.py")
    spec = importlib.util.spec_from_file_location("robot_template_checks", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


checks = _load_checks()

UR_TEXT = checks.UR_SCRIPT.read_text()
KRL_TEXT = checks.KRL_SRC.read_text()
XML_TEXT = checks.EKI_XML.read_text()
DRAIN = checks.test_krl_drains_the_buffer_and_reopens_the_channel

UR_DEFECTS = [
    # case 2: last_seq from 0 at the start replays the registers after Stop/Play
    ("last_seq = read_input_integer_register(24)", "last_seq = 0",
     checks.test_urscript_variables_start_as_the_table_says),
    # case 1: a refused grasp that leaves the flag (and the old offset) as it was
    ("        # rule: grasp-refused\n        offset_valid = False\n", "        # rule: grasp-refused\n",
     checks.test_urscript_rules_do_what_the_table_says),
    # the flag set by something other than a stored offset
    ("        # rule: sync\n        status = 0\n",
     "        # rule: sync\n        offset_valid = True\n        status = 0\n",
     checks.test_urscript_rules_do_what_the_table_says),
    # an offset stored without its sequence number held
    ("          held_seq = seq\n", "", checks.test_urscript_rules_do_what_the_table_says),
    # a function that is not in the Script Manual
    ("seq = read_input_integer_register(24)\n", "seq = read_input_int_register(24)\n",
     checks.test_urscript_calls_only_functions_of_the_script_manual),
    # the number written before the status
    ("    write_output_integer_register(38, status_now)\n    write_output_integer_register(36, ack_now)",
     "    write_output_integer_register(36, ack_now)\n    write_output_integer_register(38, status_now)",
     checks.test_urscript_reads_and_writes_exactly_the_tables_registers),
    # a block closed twice
    ("    set_tcp(p[0, 0, 0, 0, 0, 0])\n  end\n", "    set_tcp(p[0, 0, 0, 0, 0, 0])\n  end\n  end\n",
     checks.test_urscript_blocks_balance_and_it_runs_as_one_program),
]

KRL_DEFECTS = [
    # case 7: a bare INI (a template fold, not a statement)
    ("  ;FOLD INI;%{PE}", "  INI\n  ;FOLD INI;%{PE}", checks.test_krl_routines_blocks_and_the_standard_ini_fold),
    # case 7: variables read by EKI_Get never initialised
    ("  seq = 0\n  cmd = 0\n", "  cmd = 0\n", checks.test_krl_every_local_is_set_before_it_is_used),
    # case 7: EKI_Init of a name that is not the XML file's
    ('RET = EKI_Init("monoguide")               ;', 'RET = EKI_Init("monoguide_eki")           ;',
     checks.test_krl_calls_known_functions_and_eki_with_its_documented_arity),
    # an EKI call with the wrong number of arguments
    ('RET = EKI_GetInt("monoguide", "Sensor/Request/@Pose", k)', 'RET = EKI_GetInt("monoguide", k)',
     checks.test_krl_calls_known_functions_and_eki_with_its_documented_arity),
    # case 8: RET not checked after a read
    ('  RET = EKI_GetReal("monoguide", "Sensor/Offset/@C", o.C)\n  readable = readable AND (RET.Msg_No == 0)\n',
     '  RET = EKI_GetReal("monoguide", "Sensor/Offset/@C", o.C)\n', checks.test_krl_checks_ret_after_every_read),
    # case 3: the flag reset after the buffer was read (one flag for many messages: the second one is lost)
    ('    $FLAG[998] = FALSE                      ; reset first: a message arriving while we drain sets it again\n'
     '    go_now = $IN[GO_IN]\n', "    go_now = $IN[GO_IN]\n", DRAIN),
    ("      TAKE( )\n", "      TAKE( )\n      $FLAG[998] = FALSE\n", DRAIN),
    # case 6: the channel never opened again after a disconnect
    ('      RET = EKI_Clear("monoguide")\n      RET = EKI_Init("monoguide")\n      RET = EKI_Open("monoguide")\n',
     "", DRAIN),
    # case 5: a second sender beside the timer interrupt
    ("  ack = number\n", '  ack = number\n  RET = EKI_Send("monoguide", "Robot")\n',
     checks.test_krl_reports_from_one_interrupt_and_answers_status_before_number),
    # case 9: tool and base set once, not before the grasp's moves
    ("    $TOOL = TOOL_DATA[GRIPPER_TOOL]         ; tool and base before every move\n", "",
     checks.test_krl_tool_and_base_are_set_before_every_move),
    # case 1: a clear that leaves the offset in the persistent grasp base (touch-up would bake it in)
    ("    ; rule: clear\n    offset_valid = FALSE\n    BASE_DATA[GRASP_BASE] = BASE_DATA[GRASP_BASE_TAUGHT]\n",
     "    ; rule: clear\n    offset_valid = FALSE\n", checks.test_krl_rules_do_what_the_table_says),
    # a name that is declared nowhere (a typo)
    ("  in_pos = k\n", "  in_position = k\n", checks.test_krl_names_are_declared),
]

XML_DEFECTS = [
    ("<PORT>54600</PORT>", "<PORT>12345</PORT>"),
    ('<ELEMENT Tag="Sensor/Offset/@X" Type="REAL"/>', '<ELEMENT Tag="Sensor/Offset/@X" Type="DOUBLE"/>'),
    ('<BUFFERING Mode="FIFO" Limit="16"/>', '<BUFFERING Mode="FIFO" Limit="1000"/>'),
    ("<ENVIRONMENT>Program</ENVIRONMENT>", "<ENVIRONMENT>Cell</ENVIRONMENT>"),
]


@pytest.mark.parametrize(("good", "bad", "check"), UR_DEFECTS, ids=[d[2].__name__ + str(k) for k, d in
                                                                     enumerate(UR_DEFECTS)])
def test_each_urscript_defect_is_caught(good: str, bad: str, check: object) -> None:
    assert UR_TEXT.count(good) == 1, good
    check(split_lines(UR_TEXT, "#"))  # type: ignore[operator]  # the template as it is passes
    with pytest.raises(AssertionError):
        check(split_lines(UR_TEXT.replace(good, bad), "#"))  # type: ignore[operator]


@pytest.mark.parametrize(("good", "bad", "check"), KRL_DEFECTS, ids=[d[2].__name__ + str(k) for k, d in
                                                                      enumerate(KRL_DEFECTS)])
def test_each_krl_defect_is_caught(good: str, bad: str, check: object) -> None:
    assert KRL_TEXT.count(good) == 1, good
    dat = split_lines(checks.KRL_DAT.read_text(), ";")
    arguments = (dat,) if check is checks.test_krl_names_are_declared else ()
    check(split_lines(KRL_TEXT, ";"), *arguments)  # type: ignore[operator]
    with pytest.raises(AssertionError):
        check(split_lines(KRL_TEXT.replace(good, bad), ";"), *arguments)  # type: ignore[operator]


@pytest.mark.parametrize(("good", "bad"), XML_DEFECTS)
def test_each_eki_xml_defect_is_caught(good: str, bad: str) -> None:
    assert XML_TEXT.count(good) == 1, good
    checks.test_eki_xml_has_the_structure_the_manual_gives(ET.fromstring(XML_TEXT))
    with pytest.raises(AssertionError):
        checks.test_eki_xml_has_the_structure_the_manual_gives(ET.fromstring(XML_TEXT.replace(good, bad)))


def test_a_data_list_variable_without_a_value_is_caught() -> None:
    from helpers.template_parsing import krl_dat

    text = checks.KRL_DAT.read_text()
    assert krl_dat(split_lines(text, ";"))[1] == []
    planted = text.replace("  XA_CALIB[24]={", "  ;XA_CALIB[24]={").replace("DECL INT ack=0", "DECL INT ack")
    assert krl_dat(split_lines(planted, ";"))[1] == ["ack", "XA_CALIB[24]"]
