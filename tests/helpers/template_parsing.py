"""Just enough of URScript and KRL to check the robot templates statically: code without comments, block structure,
calls with their arguments, assignments, and the blocks that follow each ``rule:`` marker. Not a compiler: the
checks built on it are named in ``test_robot_templates.py``; what only a controller can tell is listed in
docs/robot-interface.md."""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

DATA = Path(__file__).parent / "data"
IDENTIFIER = re.compile(r"\$?[A-Za-z_]\w*")
CALL = re.compile(r"(?<![\w$.])([A-Za-z_]\w*)\s*\(")
ASSIGNMENT = re.compile(r"^\s*([A-Za-z_$][\w$]*(?:\[[^\]]*\])?(?:\.\w+)?)\s*=(?!=)\s*(.*?)\s*$")
MARKER = re.compile(r"rule:\s*([a-z-]+)(?:\s*\[([A-Z]+)\])?")
STATE = re.compile(r"\[(IDLE|MOVING|GRASPING)\]")


@dataclass(frozen=True)
class Line:
    number: int  # 1-based, in the file
    code: str  # without its comment
    comment: str


def vocabulary(name: str) -> list[list[str]]:
    """A vocabulary list of ``data/``: its lines split in words, comments aside."""
    text = (DATA / name).read_text()
    return [line.split() for line in text.splitlines() if line.strip() and not line.startswith("#")]


def split_lines(text: str, comment: str) -> list[Line]:
    """Every line with its code and its comment apart (``comment`` the marker; none inside a string literal)."""
    lines = []
    for number, raw in enumerate(text.splitlines(), start=1):
        code, rest, in_string = [], "", False
        for k, ch in enumerate(raw):
            if ch == '"':
                in_string = not in_string
            if ch == comment and not in_string:
                rest = raw[k + 1:]
                break
            code.append(ch)
        lines.append(Line(number, "".join(code).rstrip(), rest.strip()))
    return lines


def call_arguments(code: str, start: int) -> list[str]:
    """The arguments of the call whose ``(`` is at ``start``: split at top-level commas, strings kept whole."""
    depth, in_string, current, arguments = 0, False, [], []
    for ch in code[start:]:
        if ch == '"':
            in_string = not in_string
        if not in_string:
            if ch in "([{":
                depth += 1
                if depth == 1 and ch == "(":
                    continue
            elif ch in ")]}":
                depth -= 1
                if depth == 0:
                    arguments.append("".join(current).strip())
                    break
            elif ch == "," and depth == 1:
                arguments.append("".join(current).strip())
                current = []
                continue
        current.append(ch)
    return [a for a in arguments if a] if arguments != [""] else []


def calls(lines: list[Line]) -> list[tuple[int, str, list[str]]]:
    """Every call in the code: (line number, name, arguments)."""
    found = []
    for line in lines:
        for match in CALL.finditer(line.code):
            found.append((line.number, match.group(1), call_arguments(line.code, match.end() - 1)))
    return found


def assignments(lines: list[Line]) -> list[tuple[int, str, str]]:
    """Every assignment statement: (line number, target, value)."""
    return [(line.number, m.group(1), m.group(2)) for line in lines if (m := ASSIGNMENT.match(line.code))]


def rule_blocks(lines: list[Line], ends: re.Pattern[str]) -> dict[str, tuple[str | None, list[Line]]]:
    """For each ``rule: <name> [STATE]`` comment: the state it names and the lines that follow it, up to the next
    marker or a line matching ``ends`` (the end of a routine)."""
    blocks: dict[str, tuple[str | None, list[Line]]] = {}
    current: list[Line] | None = None
    for line in lines:
        if match := MARKER.search(line.comment):
            assert match.group(1) not in blocks, f"line {line.number}: rule {match.group(1)} marked twice"
            current = []
            blocks[match.group(1)] = (match.group(2), current)
            continue
        if current is not None:
            if ends.match(line.code):
                current = None
                continue
            current.append(line)
    return blocks


def states(lines: list[Line]) -> set[str]:
    return {m.group(1) for line in lines for m in STATE.finditer(line.comment)}


# --- URScript -------------------------------------------------------------------------------------------


URSCRIPT_OPENERS = re.compile(r"^\s*(def|if|while|thread)\b")
URSCRIPT_END = re.compile(r"^\s*end\s*$")
URSCRIPT_KEYWORDS = {"def", "if", "elif", "while", "not", "and", "or", "return", "thread", "run", "join", "kill",
                     "p", "global", "local", "halt"}


def urscript_structure(lines: list[Line]) -> tuple[list[str], list[str]]:
    """(the functions it defines, problems of its def/if/while ... end structure)."""
    depth, defined, problems = 0, [], []
    for line in lines:
        if match := URSCRIPT_OPENERS.match(line.code):
            depth += 1
            if match.group(1) == "def":
                defined.append(re.match(r"^\s*def\s+(\w+)\s*\(", line.code).group(1))  # type: ignore[union-attr]
                if not line.code.rstrip().endswith(":"):
                    problems.append(f"line {line.number}: a def line ends with ':'")
        elif URSCRIPT_END.match(line.code):
            depth -= 1
            if depth < 0:
                problems.append(f"line {line.number}: an 'end' without its block")
                depth = 0
    if depth:
        problems.append(f"{depth} block(s) never closed with 'end'")
    return defined, problems


# --- KRL ------------------------------------------------------------------------------------------------


KRL_ROUTINE = re.compile(r"^\s*(DEF|DEFFCT)\s+(?:(\w+)\s+)?(\w+)\s*\(([^)]*)\)", re.IGNORECASE)
KRL_ROUTINE_END = re.compile(r"^\s*(END|ENDFCT)\s*$", re.IGNORECASE)
KRL_BLOCKS = {"IF": "ENDIF", "LOOP": "ENDLOOP", "WHILE": "ENDWHILE", "FOR": "ENDFOR", "SWITCH": "ENDSWITCH",
              "REPEAT": "UNTIL"}
KRL_KEYWORDS = {"IF", "THEN", "ELSE", "WHILE", "UNTIL", "AND", "OR", "NOT", "EXOR", "WHEN", "DO", "RETURN", "CASE",
                "SWITCH", "FOR", "TO", "STEP", "WAIT", "SEC", "LIN", "PTP", "CIRC", "DECL", "DEF", "DEFFCT",
                "INTERRUPT", "GLOBAL", "ON", "OFF", "INT", "REAL", "BOOL", "CHAR", "FRAME", "E6POS", "E6AXIS", "POS",
                "AXIS", "DEFAULT", "LOOP", "ENDLOOP", "ENDIF", "ENDFOR", "ENDWHILE", "ENDSWITCH", "REPEAT", "END",
                "ENDFCT"}


@dataclass
class KrlRoutine:
    name: str
    kind: str  # DEF | DEFFCT
    parameters: list[str]
    declarations: list[Line]
    statements: list[Line]


def krl_routines(lines: list[Line]) -> tuple[list[KrlRoutine], list[str]]:
    """The routines of a .src (DEF ... END, DEFFCT ... ENDFCT) and problems of their structure: unbalanced
    blocks, declarations after statements, folds that do not nest."""
    routines: list[KrlRoutine] = []
    problems: list[str] = []
    current: KrlRoutine | None = None
    blocks: list[tuple[str, int]] = []
    folds: list[tuple[str, int]] = []
    for line in lines:
        fold = re.match(r"(FOLD|ENDFOLD)\b\s*(.*)", line.comment) if not line.code.strip() else None
        if fold:
            if fold.group(1).upper() == "FOLD":
                folds.append((fold.group(2).split(";")[0].strip(), line.number))
            elif not folds:
                problems.append(f"line {line.number}: ;ENDFOLD without ;FOLD")
            else:
                folds.pop()
            continue
        code = line.code.strip()
        if not code or code.startswith("&"):
            continue
        if match := KRL_ROUTINE.match(code):
            if current is not None:
                problems.append(f"line {line.number}: {match.group(3)} begins inside {current.name}")
            params = [p.split(":")[0].strip() for p in match.group(4).split(",") if p.strip()]
            current = KrlRoutine(match.group(3), match.group(1).upper(), params, [], [])
            routines.append(current)
            blocks = []
            continue
        if KRL_ROUTINE_END.match(code):
            if current is None:
                problems.append(f"line {line.number}: {code} outside a routine")
            else:
                want = "END" if current.kind == "DEF" else "ENDFCT"
                if code.upper() != want:
                    problems.append(f"line {line.number}: {current.name} ends with {code}, not {want}")
                if blocks:
                    problems.append(f"{current.name}: {', '.join(b for b, _ in blocks)} never closed")
            current = None
            continue
        if current is None:
            problems.append(f"line {line.number}: code outside a routine: {code}")
            continue
        word = code.split()[0].upper().rstrip("(")
        if word == "DECL" and not code.upper().startswith("DECL INTERRUPT"):
            if current.statements:
                problems.append(f"line {line.number}: a declaration after statements in {current.name}")
            current.declarations.append(line)
            continue
        current.statements.append(line)
        if word in KRL_BLOCKS:
            blocks.append((word, line.number))
        elif word in KRL_BLOCKS.values():
            if not blocks or KRL_BLOCKS[blocks[-1][0]] != word:
                problems.append(f"line {line.number}: {word} closes {blocks[-1][0] if blocks else 'nothing'}")
            else:
                blocks.pop()
    if folds:
        problems.append(f"folds never closed: {folds}")
    return routines, problems


def krl_declared(declaration: Line) -> list[str]:
    """The names a ``DECL [GLOBAL] TYPE a, b[4], c=0`` line declares."""
    words = declaration.code.strip().split(None, 1)[1]
    if words.upper().startswith("GLOBAL "):
        words = words.split(None, 1)[1]
    names = words.split(None, 1)[1]
    return [re.match(r"\s*(\w+)", part).group(1) for part in names.split(",")]  # type: ignore[union-attr]


def krl_reads_before_write(routine: KrlRoutine) -> list[str]:
    """Locals of ``routine`` whose first use is not an assignment of the whole variable (read uninitialised)."""
    problems = []
    locals_ = [n for d in routine.declarations for n in krl_declared(d) if n not in routine.parameters]
    for name in locals_:
        word = re.compile(rf"(?<![\w$.]){re.escape(name)}\b", re.IGNORECASE)
        first = next((s for s in routine.statements if word.search(s.code)), None)
        if first is None:
            problems.append(f"{routine.name}: {name} declared, never used")
        elif not re.match(rf"^\s*{re.escape(name)}\s*=(?!=)", first.code, re.IGNORECASE):
            problems.append(f"{routine.name}: line {first.number} uses {name} before it is set: {first.code.strip()}")
    return problems


def krl_dat(lines: list[Line]) -> tuple[dict[str, str], list[str]]:
    """The data list's declarations (name -> its DECL line) and those left without a value."""
    declared: dict[str, str] = {}
    sizes: dict[str, int] = {}
    values: set[str] = set()
    for line in lines:
        code = line.code.strip()
        if code.upper().startswith("DECL "):
            for part in code.split(None, 2)[2].split(","):
                match = re.match(r"\s*(\w+)(?:\[(\d+)\])?\s*(=)?", part)
                assert match is not None, code
                declared[match.group(1)] = code
                if match.group(2):
                    sizes[match.group(1)] = int(match.group(2))
                elif match.group(3):
                    values.add(match.group(1))
        elif match := re.match(r"^(\w+)\[(\d+)\]\s*=", code):
            values.add(f"{match.group(1)}[{match.group(2)}]")
    missing = [n for n in declared if n not in sizes and n not in values]
    missing += [f"{n}[{k}]" for n, size in sizes.items() for k in range(1, size + 1) if f"{n}[{k}]" not in values]
    return declared, missing
