"""``docs/plc-interface.md`` says what the code does: its error-code table lists exactly the error classes
(every module imported, as ``tests/test_error_codes.py`` does), and its worked example's register values are
those the encoder writes (checked against ``struct``).

After adding an error class, regenerate the generated parts of the document with
``.venv/bin/python tests/drivers/test_plc_interface_doc.py --write``.
"""

from __future__ import annotations

import importlib
import pkgutil
import re
import struct
import sys
from pathlib import Path

from monoguide.drivers.plc_registers import CycleResult, Status, encode_result
from monoguide.solver.errors import all_error_classes

DOC = Path(__file__).parents[2] / "docs" / "plc-interface.md"
PACKAGES = ("monoguide.solver", "monoguide.drivers", "monoguide.daemon")
SENTENCE_END = re.compile(r"(?<=[a-z)])\.\s+(?=[A-Z`])")  # "e.g. the tracker" does not end a sentence
BLOCK = re.compile(r"(<!-- generated: (?P<name>[a-z-]+) -->\n)(?P<body>.*?)(<!-- end generated -->)", re.S)

# the worked example: job 1, part tag 4711, the 37th finished cycle, an offset written and acknowledged
EXAMPLE_OFFSET = (12.5, -3.25, 0.75, 1.5, -0.5, 0.125)  # x, y, z mm, A, B, C deg
EXAMPLE_QUALITY = (0.0625, 0.03125, 0.0078125)  # rms px, sigma mm, sigma deg (exact in float32)
EXAMPLE_HEARTBEAT = 812
EXAMPLE = CycleResult(0, 37, 1, 4711, EXAMPLE_OFFSET, EXAMPLE_QUALITY)


def _import_everything() -> None:
    for package_name in PACKAGES:
        package = importlib.import_module(package_name)
        for info in pkgutil.walk_packages(package.__path__, prefix=f"{package_name}."):
            importlib.import_module(info.name)


def error_table() -> str:
    _import_everything()
    lines = ["| register 11 (`plc_code`) | `code` | class | meaning |", "|---|---|---|---|",
             "| 0 | — | — | no error (the last cycle wrote its offset) |"]
    for cls in sorted(all_error_classes(), key=lambda c: c.plc_code):
        text = " ".join((cls.__doc__ or "").split()) or cls.code.lower().replace("_", " ")
        meaning = SENTENCE_END.split(text)[0].rstrip(".").replace("|", "\\|")
        lines.append(f"| {cls.plc_code} | `{cls.code}` | `{cls.__module__}.{cls.__qualname__}` | {meaning} |")
    return "\n".join(lines) + "\n"


def example_table(word_order: str = "big") -> str:
    names = ["x mm", "y mm", "z mm", "A deg", "B deg", "C deg", "RMS px", "σ position mm", "σ rotation deg"]
    status = int(Status.DONE | Status.RESULT_OK)
    lines = ["| reg | value (hex) | meaning |", "|---|---|---|",
             f"| 10 | {status} (0x{status:04X}) | status word DONE + RESULT_OK (written last, in its own write) |",
             f"| 11 | {EXAMPLE.error_code} (0x0000) | error code: none |",
             f"| 12 | {EXAMPLE_HEARTBEAT} (0x{EXAMPLE_HEARTBEAT:04X}) | monoguide heartbeat (rewritten as it stood) |",
             f"| 13 | {EXAMPLE.cycle_counter} (0x{EXAMPLE.cycle_counter:04X}) | cycle counter |",
             f"| 14 | {EXAMPLE.job} (0x{EXAMPLE.job:04X}) | echoed job number |",
             f"| 15 | {EXAMPLE.part_tag} (0x{EXAMPLE.part_tag:04X}) | echoed part tag |"]
    for i, (name, value) in enumerate(zip(names, (*EXAMPLE_OFFSET, *EXAMPLE_QUALITY), strict=True)):
        high, low = struct.unpack(">HH", struct.pack(">f", value))
        first, second = (high, low) if word_order == "big" else (low, high)
        lines.append(f"| {16 + 2 * i}, {17 + 2 * i} | 0x{first:04X}, 0x{second:04X} | {name} = {value:g} |")
    return "\n".join(lines) + "\n"


GENERATED = {"error-codes": error_table, "worked-example": example_table}


def render(text: str) -> str:
    return BLOCK.sub(lambda m: m.group(1) + GENERATED[m.group("name")]() + m.group(4), text)


def test_the_generated_parts_of_the_document_are_current() -> None:
    text = DOC.read_text()
    assert {m.group("name") for m in BLOCK.finditer(text)} == set(GENERATED)
    assert render(text) == text, ("docs/plc-interface.md is stale: run .venv/bin/python "
                                  "tests/drivers/test_plc_interface_doc.py --write")


def test_every_plc_error_class_is_in_the_table() -> None:
    text = DOC.read_text()
    for code, number in (("PLC_VALUE_INVALID", 451), ("PLC_HEARTBEAT_LOST", 452), ("PLC_TRIGGER_DROPPED", 453),
                         ("PLC_ACK_TIMEOUT", 454), ("PLC_UNKNOWN_JOB", 455), ("DEVICE_TIMEOUT", 402)):
        assert f"| {number} | `{code}` |" in text


def test_the_worked_example_is_what_the_encoder_writes() -> None:
    words = encode_result(EXAMPLE, EXAMPLE_HEARTBEAT)
    rows = [line for line in example_table().splitlines() if re.match(r"\| 1[1-9]|\| [23]\d", line)]
    cells = [cell.strip() for row in rows for cell in row.split("|")[2:3]]
    documented = [int(v.split()[0], 0) if "," not in v else None for v in cells]
    pairs = [[int(w, 16) for w in v.split(", ")] for v in cells if "," in v]
    assert len(documented) == 14 and len(pairs) == 9
    assert documented[:5] == words[:5]
    assert [w for pair in pairs for w in pair] == words[5:]


if __name__ == "__main__":
    if sys.argv[1:] != ["--write"]:
        sys.exit("usage: test_plc_interface_doc.py --write")
    DOC.write_text(render(DOC.read_text()))
    print(f"wrote {DOC}")
