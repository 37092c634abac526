"""``drivers/toml_format.py``: matrices one row per line that read back to 1e-12, and edits of a parsed file that
leave its comments above the table they introduce. Ground truth: the text ``tomllib`` reads back, and the
lines of the file around an edit."""

from __future__ import annotations

import tomllib

import numpy as np
import pytest
import tomlkit

from monoguide.drivers.toml_format import (
    add_after_last_value,
    commented,
    inline_table,
    matrix,
    numbers,
    opening_comment,
    replace_section,
)
from monoguide.solver.frames import make_T, rotvec_to_matrix

SOURCE = """\
[reference]  # the taught part
T_cf_w0 = [  # REPLACE
    [1.0, 0.0, 0.0, 0.0],
    [0.0, 1.0, 0.0, 0.0],
    [0.0, 0.0, 1.0, 0.0],
    [0.0, 0.0, 0.0, 1.0],
]  # from the tracker

# One [[measuring_poses]] per view
[[measuring_poses]]
name = "S1"
# a comment of S1

[[measuring_poses]]
name = "S2"

# the devices
[tracker]
baud = 115200
"""


def test_a_matrix_is_one_row_per_line_and_reads_back_to_1e_12() -> None:
    rng = np.random.default_rng(7)
    T = make_T(rotvec_to_matrix(rng.normal(0, 1, 3)), rng.uniform(-3000, 3000, 3))
    doc = tomlkit.document()
    doc["T"] = matrix(T)
    text = doc.as_string()
    lines = text.splitlines()
    assert lines[0] == "T = [" and lines[-1] == "]" and len(lines) == 6
    assert all(line.startswith("    [") and line.endswith("],") and line.count(",") == 4 for line in lines[1:5])
    np.testing.assert_allclose(tomllib.loads(text)["T"], T, rtol=0, atol=1e-12)

    doc = tomlkit.document()
    doc["exact"] = matrix([[1, 2.5], [1e-300, -0.0]], decimals=None)
    doc["short"] = matrix([[1.0, 2.0], [3.0, 4.0]], 1, multiline=False)
    doc["row"] = commented(numbers([450, 900], 1), "mm")
    doc["nests"] = inline_table({"B1": numbers([0, 0, 0], 1)})
    doc["empty"] = inline_table({})
    text = doc.as_string()
    assert tomllib.loads(text) == {"exact": [[1, 2.5], [1e-300, -0.0]], "short": [[1.0, 2.0], [3.0, 4.0]],
                                   "row": [450.0, 900.0], "nests": {"B1": [0.0, 0.0, 0.0]}, "empty": {}}
    assert isinstance(tomllib.loads(text)["exact"][0][0], int)
    assert "short = [[1.0, 2.0], [3.0, 4.0]]\n" in text and "row = [450.0, 900.0]  # mm\n" in text
    assert "nests = { B1 = [0.0, 0.0, 0.0] }\n" in text and "empty = {}\n" in text


def test_a_replaced_matrix_keeps_the_comments_after_its_brackets() -> None:
    doc = tomlkit.parse(SOURCE)
    old = doc["reference"]["T_cf_w0"]
    assert opening_comment(old) == "REPLACE" and opening_comment(doc["tracker"]["baud"]) is None
    doc["reference"]["T_cf_w0"] = matrix(2 * np.eye(4), comment=opening_comment(old))
    text = doc.as_string()
    assert "T_cf_w0 = [  # REPLACE\n    [2.000000000000, 0.0" in text and "\n]  # from the tracker\n" in text
    assert tomllib.loads(text)["reference"]["T_cf_w0"] == (2 * np.eye(4)).tolist()


def test_a_key_added_to_a_table_goes_above_the_comments_that_introduce_the_next_one() -> None:
    doc = tomlkit.parse(SOURCE)
    doc = add_after_last_value(doc, doc["reference"], "T_cf_b", matrix(np.eye(4)))
    doc = add_after_last_value(doc, doc["measuring_poses"][0], "points", tomlkit.item([0]))
    text = doc.as_string()
    assert "\n]  # from the tracker\nT_cf_b = [\n" in text
    assert "\n]\n\n# One [[measuring_poses]] per view\n[[measuring_poses]]\n" in text
    assert 'name = "S1"\npoints = [0]\n# a comment of S1\n' in text
    one, nil = "1.000000000000", "0.000000000000"
    rows = "".join(f"    [{', '.join(one if i == j else nil for j in range(4))}],\n" for i in range(4))
    assert text == SOURCE.replace("tracker\n\n", f"tracker\nT_cf_b = [\n{rows}]\n\n").replace(
        '"S1"\n', '"S1"\npoints = [0]\n')  # and nothing else of the file changed
    data = tomllib.loads(text)
    assert data["reference"]["T_cf_b"] == np.eye(4).tolist() and data["measuring_poses"][0]["points"] == [0]
    assert doc["reference"]["T_cf_b"] == np.eye(4).tolist()  # the document returned holds it as a value


def test_a_key_added_to_a_table_goes_above_its_sub_tables_and_keeps_its_indent() -> None:
    source = ('[camera]\n  T_f_c = 1  # mounting\n\n  # its intrinsics\n  [camera.intrinsics]\n  fx = 2.0\n\n'
              '[tracker]\nbaud = 3')  # no newline at the end
    doc = tomlkit.parse(source)
    doc = add_after_last_value(doc, doc["camera"], "serial", tomlkit.item("A1"))
    doc = add_after_last_value(doc, doc["tracker"], "port", tomlkit.item("/dev/ttyUSB0"))  # the file's last line
    assert doc.as_string() == source.replace("# mounting\n", '# mounting\n  serial = "A1"\n') + \
        '\nport = "/dev/ttyUSB0"\n'
    assert tomllib.loads(doc.as_string()) == {"camera": {"T_f_c": 1, "serial": "A1", "intrinsics": {"fx": 2.0}},
                                              "tracker": {"baud": 3, "port": "/dev/ttyUSB0"}}


def test_a_key_is_set_in_place_where_no_place_is_to_be_kept() -> None:
    doc = tomlkit.parse('pose = { name = "S1" }\n[camera]\n[camera.intrinsics]\nfx = 2.0\n')
    assert add_after_last_value(doc, doc["pose"], "points", tomlkit.item([0])) is doc
    assert add_after_last_value(doc, doc["camera"], "serial", tomlkit.item("A1")) is doc  # no value yet
    assert tomllib.loads(doc.as_string()) == {"pose": {"name": "S1", "points": [0]},
                                              "camera": {"serial": "A1", "intrinsics": {"fx": 2.0}}}


def test_a_table_of_another_document_is_refused_naming_the_key() -> None:
    doc = tomlkit.parse(SOURCE)
    with pytest.raises(ValueError, match=r"'T_cf_b'.*not a table of the document"):
        add_after_last_value(doc, tomlkit.parse(SOURCE)["reference"], "T_cf_b", matrix(np.eye(4)))


def test_a_replaced_section_leaves_the_comments_above_the_next_table() -> None:
    doc = tomlkit.parse(SOURCE)
    poses = tomlkit.aot()
    for name in ("P1", "P2", "P3"):
        pose = tomlkit.table()
        pose["name"] = name
        poses.append(pose)
    replace_section(doc, "measuring_poses", poses)
    text = doc.as_string()
    assert "# a comment of S1" not in text  # the old entries' own comments go with them
    assert text.startswith(SOURCE[:SOURCE.index("[[measuring_poses]]")])  # the comments above stay above
    assert text.endswith('name = "P3"\n\n# the devices\n[tracker]\nbaud = 115200\n')
    assert [p["name"] for p in tomllib.loads(text)["measuring_poses"]] == ["P1", "P2", "P3"]

    new = tomlkit.table()
    new["when"] = "now"
    replace_section(doc, "calibration", new)  # none yet: at the end
    assert doc.as_string().endswith('baud = 115200\n\n[calibration]\nwhen = "now"\n')
