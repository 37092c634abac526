"""``monoguide solve``: measurement records in, part poses out (docs/solve.md, docs/measurement-record.md).

Each record is solved and its result printed as soon as the record has been read, so that ``-`` can
follow a stream. Whatever is wrong with one input (a file that cannot be read, is binary or not UTF-8,
a JSON syntax error, a number or a nesting Python cannot read, a record that does not solve) is one
error for that input, and the batch goes on with the next one.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Annotated, Any

import typer

from monoguide.daemon.cli import _format as fmt
from monoguide.daemon.cli._console import stderr_console, stdout_console
from monoguide.solver.errors import MonoguideError, RecordError
from monoguide.solver.pose import DEFAULT_FALSE_ALARM_RATE, ESTIMATORS
from monoguide.solver.record import error_to_dict, solve_record

JSON_LINES_SUFFIXES = (".jsonl", ".ndjson")
MAX_INT_DIGITS = 308  # no count or coordinate in a record needs more; beyond it float() overflows


def solve(
    records: Annotated[
        list[str],
        typer.Argument(
            help="Record files: .json (one record or a list), .jsonl (one per line), or - for standard input "
            "(records one per line or pretty-printed one after another, each solved as it arrives)."
        ),
    ],
    json_output: Annotated[
        bool, typer.Option("--json", help="One JSON result per record on standard output, errors included.")
    ] = False,
    method: Annotated[str, typer.Option(help=f"Estimator: {', '.join(sorted(ESTIMATORS))}.")] = "ml",
    robust: Annotated[bool, typer.Option(help="Huber loss in the ML refinement (down-weights outliers).")] = False,
    false_alarm_rate: Annotated[
        float, typer.Option(help="Consistency check: the fraction of good measurements that are refused.")
    ] = DEFAULT_FALSE_ALARM_RATE,
) -> None:
    """Solve the part pose T_s1_w of each measurement record and its displacement from the reference.

    A table row per record on standard output: rotation of the part and shift of its grasp point, their
    uncertainty, the base offset when the record carries T_b_s1. A record that fails gets an error line
    on standard error (with --json: a status "error" object) and the batch goes on. Exit status: 0 all
    records solved, 1 any input or record failed (the others' results are still printed), 2 bad options.
    """
    if method not in ESTIMATORS:
        raise typer.BadParameter(f"{method!r}; choose one of {', '.join(sorted(ESTIMATORS))}", param_hint="--method")
    if robust and method != "ml":
        raise typer.BadParameter(f"the Huber loss belongs to --method ml, not {method!r}", param_hint="--robust")
    if not 0.0 < false_alarm_rate < 1.0:  # also refuses nan
        raise typer.BadParameter(f"must lie between 0 and 1, got {false_alarm_rate}", param_hint="--false-alarm-rate")
    report = _JsonReport() if json_output else _TableReport()
    failed = False
    for source, data in _read_records(records):
        row = _solve_one(source, data, method, robust, false_alarm_rate)
        failed |= row["result"]["status"] != "ok"
        report.add(row)
    if failed:
        raise typer.Exit(1)


# --- solving ------------------------------------------------------------------------------------


def _solve_one(source: str, data: Any, method: str, robust: bool, false_alarm_rate: float) -> dict[str, Any]:
    """The printed row of one record: its source, its result object (the spec's), the error against truth."""
    if isinstance(data, MonoguideError):
        return {"source": source, "result": error_to_dict(None, data), "truth_error": None}
    result, truth_error = solve_record(data, method, robust=robust, false_alarm_rate=false_alarm_rate)
    if result.get("status") == "error":
        result["error"]["message"] = f"{source}: {result['error']['message']}"
    return {"source": source, "result": result, "truth_error": truth_error}


# --- reading ------------------------------------------------------------------------------------


def _read_records(paths: list[str]) -> Iterator[tuple[str, Any]]:
    """Yield (where, decoded record or the RecordError that stopped it), one pair per record, in order."""
    for path in paths:
        if path == "-":
            yield from _nonempty("standard input", _json_stream("<stdin>", _stdin_lines()))
            continue
        try:
            text = _read_text(path)
        except RecordError as error:
            yield path, error
            continue
        if not text.strip():
            yield path, RecordError(f"{path}: empty file (no record)")
        elif path.endswith(".json"):
            yield from _json_document(path, text)
        else:
            lines = enumerate(text.splitlines(), start=1)
            decode = _json_lines if path.endswith(JSON_LINES_SUFFIXES) else _json_stream
            yield from _nonempty(path, decode(path, lines))


def _read_text(path: str) -> str:
    """The file's text; a RecordError (one line) when it cannot be read or is not UTF-8 text."""
    try:
        data = Path(path).read_bytes()
    except OSError as error:
        raise RecordError(f"{path}: cannot read: {error.strerror or error}") from None
    nul = data.find(b"\0")
    if nul >= 0:
        raise RecordError(f"{path}: a binary file (NUL byte at offset {nul}), not JSON text")
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as error:
        line = data.count(b"\n", 0, error.start) + 1
        raise RecordError(
            f"{path}: not UTF-8 text (byte 0x{data[error.start]:02x} at offset {error.start}, line {line})"
        ) from None


def _stdin_lines() -> Iterator[tuple[int, str | RecordError]]:
    """Numbered lines of standard input as they arrive; a line that is not text ends it with an error."""
    for number, raw in enumerate(iter(sys.stdin.buffer.readline, b""), start=1):
        try:
            if b"\0" in raw:
                raise UnicodeError("a NUL byte")
            yield number, raw.decode("utf-8-sig" if number == 1 else "utf-8").rstrip("\r\n")
        except UnicodeError as error:
            reason = error.reason if isinstance(error, UnicodeDecodeError) else str(error)
            yield number, RecordError(f"<stdin> line {number}: not UTF-8 text ({reason}): binary data? "
                                      "stopped reading standard input")
            return


def _json_document(path: str, text: str) -> Iterator[tuple[str, Any]]:
    """A ``.json`` file: one JSON value, a record or a list of records."""
    try:
        value = _decode(text)
    except json.JSONDecodeError as error:
        hint = " (one record per line? name the file .jsonl)" if error.msg == "Extra data" else ""
        yield path, RecordError(f"{path}: not JSON at line {error.lineno}, column {error.colno}: {error.msg}{hint}")
        return
    except RecordError as error:
        yield path, RecordError(f"{path}: {error.message}")
        return
    yield from _records_of(path, value)


def _json_lines(name: str, lines: Iterable[tuple[int, str]]) -> Iterator[tuple[str, Any]]:
    """JSON Lines: every non-blank line is one record or list, and every bad line its own error."""
    for number, line in lines:
        if not line.strip():
            continue
        where = f"{name} line {number}"
        try:
            value = _decode(line)
        except json.JSONDecodeError as error:
            yield where, RecordError(f"{where}: not JSON at column {error.colno}: {error.msg}")
            continue
        except RecordError as error:
            yield where, RecordError(f"{where}: {error.message}")
            continue
        yield from _records_of(where, value)


def _json_stream(name: str, lines: Iterable[tuple[int, str | RecordError]]) -> Iterator[tuple[str, Any]]:
    """Records one after another, each on one line (JSON Lines) or over several (pretty-printed).

    A record is yielded at the line that completes it. After a syntax error inside a record that spans
    several lines, its remaining lines (indented, or closing it) are skipped; a line that starts with
    ``{`` or ``[`` in column 1 always starts a new record, so a truncated record loses nothing after it.
    """
    buffer, start, skipping = "", 0, False
    for number, line in lines:
        if isinstance(line, RecordError):
            yield f"{name} line {number}", line
            return
        new_value = line[:1] in ("{", "[")
        if skipping and not new_value and (not line.strip() or line[:1] in " \t}],"):
            continue
        skipping = False
        if buffer and new_value:
            yield f"{name} line {start}", RecordError(
                f"{name} line {start}: the record is incomplete (line {number} starts another one)")
            buffer = ""
        if not buffer:
            if not line.strip():
                continue
            start = number
        buffer += line + "\n"
        where = f"{name} line {start}"
        try:
            value = _decode(buffer)
        except json.JSONDecodeError as error:
            if error.pos >= len(buffer.rstrip()):
                continue  # not complete yet: the next lines carry the rest
            spot = f"column {error.colno}"
            if number > start:  # a record over several lines: which of them
                spot = f"line {start + error.lineno - 1}, {spot}"
            yield where, RecordError(f"{where}: not JSON at {spot}: {error.msg}")
            skipping, buffer = number > start, ""
            continue
        except RecordError as error:
            yield where, RecordError(f"{where}: {error.message}")
            buffer = ""
            continue
        buffer = ""
        yield from _records_of(where, value)
    if buffer:
        yield f"{name} line {start}", RecordError(f"{name} line {start}: the input ends inside this record")


def _records_of(where: str, value: Any) -> Iterator[tuple[str, Any]]:
    """A decoded value is a record, or a list whose items are records."""
    if not isinstance(value, list):
        yield where, value
    elif not value:
        yield where, RecordError(f"{where}: an empty list (no record)")
    else:
        for i, item in enumerate(value):
            yield f"{where}[{i}]", item


def _nonempty(name: str, records: Iterator[tuple[str, Any]]) -> Iterator[tuple[str, Any]]:
    """Pass the records on; an input that held none is an error."""
    empty = True
    for pair in records:
        empty = False
        yield pair
    if empty:
        yield name, RecordError(f"{name}: no record (empty input)")


def _decode(text: str) -> Any:
    """``json.loads`` that turns what Python cannot read (huge integers, deep nesting) into a RecordError.
    A JSONDecodeError is left to the caller, which knows where the text began."""
    try:
        return json.loads(text, parse_int=_parse_int)
    except RecursionError:
        raise RecordError("nested deeper than Python can read (no record is)") from None


def _parse_int(text: str) -> int:
    digits = len(text.lstrip("-"))
    if digits > MAX_INT_DIGITS:
        raise RecordError(f"a number with {digits} digits (a record's numbers have at most {MAX_INT_DIGITS})")
    return int(text)


# --- printing -----------------------------------------------------------------------------------


class _JsonReport:
    """``--json``: the result object of every record, one per line, written as soon as it is known."""

    def add(self, row: dict[str, Any]) -> None:
        sys.stdout.write(json.dumps(row["result"]) + "\n")
        sys.stdout.flush()


class _TableReport:
    """The human table, a row per record as it is solved; error lines go to standard error.

    Rows are plain text in fixed columns (a wide value widens its own row and is never cut), so the
    table can be printed before the whole input has been read.
    """

    COLUMNS = (  # header, width (negative: left-aligned)
        ("record", -20), ("status", -8), ("rms px", 7), ("rot deg", 8), ("grasp mm", 9), ("σ deg", 7),
        ("σ mm", 6), ("vs truth deg mm", 16), ("ms", 7), ("base offset x y z mm, a b c deg", -31),
    )

    def __init__(self) -> None:
        self.out = stdout_console()
        self.err = stderr_console()
        self.header_printed = False

    def add(self, row: dict[str, Any]) -> None:
        if not self.header_printed:
            self._print(self.out, self._line([header for header, _ in self.COLUMNS]))
            self.header_printed = True
        result = row["result"]
        label = result.get("id") or row["source"]
        if result["status"] != "ok":
            error = result["error"]
            self._print(self.out, self._line([label, error["code"]]))
            self._print(self.err, f"{error['code']} {error['message']}")
            return
        truth = row["truth_error"]
        self._print(self.out, self._line([
            label,
            "ok",
            f"{result['rms_px']:.3f}",
            f"{result['rotation_deg']:.4f}",
            f"{result['grasp_shift_mm']:.3f}",
            f"{result['sigma_rot_deg']:.4f}",
            f"{result['sigma_trans_mm']:.3f}",
            "" if truth is None else f"{truth[0]:.4f} {truth[1]:.3f}",
            f"{result['time_ms']:.1f}",
            fmt.xyzabc(result.get("base_offset_xyzabc")),
        ]))

    def _line(self, cells: list[str]) -> str:
        parts = []
        for (_, width), cell in zip(self.COLUMNS, cells, strict=False):
            parts.append(cell.ljust(-width) if width < 0 else cell.rjust(width))
        return "  ".join(parts).rstrip()

    @staticmethod
    def _print(console: Any, line: str) -> None:
        console.print(line, markup=False, highlight=False, soft_wrap=True)
        console.file.flush()
