"""The journal's rows read back (:class:`JournalRow`, :class:`OffsetIntent`), each column decoded on its own.

Reading a row never raises for what it holds: a column that cannot be decoded — text that is not UTF-8, not JSON,
JSON of another shape than the journal writes (docs/journal.md), a string where a number belongs, a null where
a value belongs — is read as its empty value (``None``, ``{}``, ``[]``, ``0``, ``""``) and the row's ``damaged``
names the column and why (``"result_json: not JSON (Expecting value at char 0)"``). One damaged row then costs
its readers that row, never the journal.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from monoguide.daemon.service._journal_schema import INTENT_OUTCOMES

Shape = Callable[[Any], "str | None"]  # what is wrong with a decoded value, None when it has the column's shape

_RESULT_NUMBERS = ("rms_px", "rotation_deg", "grasp_shift_mm", "sigma_rot_deg", "sigma_trans_mm", "time_ms")
_RESULT_TEXTS = ("status", "method")
_RESULT_MATRICES = ("T_s1_w", "base_offset")


@dataclass(frozen=True)
class JournalRow:
    """A cycle read back from the journal.

    ``duration_s``: the cycle's duration as the service measured it (a monotonic clock); for a row written
    before schema version 3, ``finished_at - started_at`` when that is not negative, else None.
    ``base_offset_xyzabc``: the base offset (x y z mm, A B C deg) of the cycle: its result's, else the one its
    offset intent carried (a row rebuilt at start has no result), else None. ``damaged``: the columns that could
    not be decoded and why (they read as empty values); empty for a sound row.
    """

    number: int
    started_at: float
    finished_at: float
    job: int | None
    part_tag: int | None
    status: str
    error_code: str | None
    plc_code: int
    error_message: str | None
    record: dict[str, Any] | None
    result: dict[str, Any] | None
    timings_s: dict[str, float]
    poses_at_capture: list[list[list[float]]]
    image_paths: list[str]
    images_pruned_at: float | None
    duration_s: float | None = None
    base_offset_xyzabc: list[float] | None = None
    damaged: tuple[str, ...] = ()


@dataclass(frozen=True)
class OffsetIntent:
    """An offset committed before it was sent to the robot, and what became of it (``outcome`` None: not
    settled yet — the robot may hold it). ``job``, ``part_tag``, ``started_at``: the cycle's (None in an intent
    of a journal before schema version 3). ``damaged`` as :attr:`JournalRow.damaged`."""

    cycle: int
    sequence: int
    registers: tuple[float, ...]  # x, y, z (mm), A, B, C (deg): PLC registers 16-27
    D_b: list[list[float]]
    intended_at: float
    outcome: str | None
    cleared: bool
    settled_at: float | None
    detail: str | None
    job: int | None = None
    part_tag: int | None = None
    started_at: float | None = None
    damaged: tuple[str, ...] = ()


class UndecodableText(str):
    """Stored text that is not UTF-8, read as its decoding with replacement characters; ``raw`` the stored bytes
    (what a query must compare with: ``CAST(? AS TEXT)`` of them)."""

    raw: bytes

    def __new__(cls, raw: bytes) -> UndecodableText:
        text = super().__new__(cls, raw.decode("utf-8", "replace"))
        text.raw = raw
        return text


def journal_text(raw: bytes) -> str:
    """The journal connections' ``text_factory``: a text value that is not UTF-8 fails its column, not the query."""
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError:
        return UndecodableText(raw)


def stored_text(text: str) -> str | bytes:
    """The value to bind to find ``text`` again (with ``CAST(? AS TEXT)``): its stored bytes when not UTF-8."""
    return text.raw if isinstance(text, UndecodableText) else text


def row_from(found: Sequence[Any]) -> JournalRow:
    """The row of ``cycle_select``'s columns: the cycle's 16, then its intent's ``offset_json`` (or NULL)."""
    (number, started_at, finished_at, job, part_tag, status, error_code, plc_code, error_message,
     record, result, timings, poses, images, pruned_at, duration_s, intent_offset) = found
    c = _Columns()
    started, finished = c.number("started_at", started_at), c.number("finished_at", finished_at)
    status_text = c.text("status", status, choices=("ok", "error"))
    code = c.text("error_code", error_code, optional=True)
    if status_text == "error" and error_code is None:
        c.damaged.append("error_code: null on a failed cycle")
    sound = len(c.damaged)
    result_value = c.json("result_json", result, _result, None, optional=True)
    if status_text == "ok" and result_value is None and len(c.damaged) == sound:  # NULL, or the JSON null
        c.damaged.append("result_json: null on a good cycle")
    duration = c.number("duration_s", duration_s, optional=True, minimum=0.0)
    if duration_s is None and started is not None and finished is not None and finished >= started:
        duration = finished - started
    offset = result_value.get("base_offset_xyzabc") if result_value else None
    if offset is None and intent_offset is not None:
        offset = list(c.json("offset_intent.offset_json", intent_offset, _offset, {}).get("registers", [])) or None
    return JournalRow(
        number, started or 0.0, finished or 0.0, c.integer("job", job, optional=True),
        c.integer("part_tag", part_tag, optional=True), status_text or "", code,
        c.integer("plc_code", plc_code) or 0, c.text("error_message", error_message, optional=True),
        c.json("record_json", record, _record, None, optional=True), result_value,
        c.json("timings_json", timings, timings_shape, {}), c.json("poses_json", poses, _poses, []),
        c.json("images_json", images, images_shape, []), c.number("images_pruned_at", pruned_at, optional=True),
        duration, offset, tuple(c.damaged))


def intent_from_row(found: Sequence[Any]) -> OffsetIntent:
    """The intent of ``intent_select``'s columns."""
    (cycle, sequence, offset, intended_at, outcome, cleared, settled_at, detail, job, part_tag, started_at) = found
    c = _Columns()
    data = c.json("offset_json", offset, _offset, {})
    return OffsetIntent(
        cycle, c.integer("sequence", sequence) or 0, tuple(data.get("registers", ())), data.get("D_b", []),
        c.number("intended_at", intended_at) or 0.0,
        c.text("outcome", outcome, optional=True, choices=INTENT_OUTCOMES),
        bool(c.integer("cleared", cleared)), c.number("settled_at", settled_at, optional=True),
        c.text("detail", detail, optional=True), c.integer("job", job, optional=True),
        c.integer("part_tag", part_tag, optional=True), c.number("started_at", started_at, optional=True),
        tuple(c.damaged))


def decoded_json(column: str, stored: Any, shape: Shape, empty: Any) -> tuple[Any, tuple[str, ...]]:
    """One JSON column decoded on its own (as a row's are): its value, or ``empty`` and why not."""
    c = _Columns()
    return c.json(column, stored, shape, empty), tuple(c.damaged)


def timings_shape(value: Any) -> str | None:
    """``timings_json``: an object of numbers (seconds)."""
    if not isinstance(value, dict):
        return _not(value, "an object")
    return next((f"{stage!r} is {_kind(s)}, not a number" for stage, s in value.items() if not _finite(s)), None)


def images_shape(value: Any) -> str | None:
    """``images_json``: a list of paths."""
    if not isinstance(value, list):
        return _not(value, "a list")
    return next((f"image {i + 1} is {_kind(path)}, not a path" for i, path in enumerate(value)
                 if not isinstance(path, str)), None)


# --- private ----------------------------------------------------------------------------------------------------


class _Columns:
    """One row's columns decoded one at a time; ``damaged`` collects what could not be and why."""

    def __init__(self) -> None:
        self.damaged: list[str] = []

    def number(self, column: str, stored: Any, *, optional: bool = False, minimum: float | None = None
               ) -> float | None:
        if stored is None and optional:
            return None
        if not _finite(stored) or (minimum is not None and stored < minimum):
            self.damaged.append(f"{column}: {_kind(stored)}, not a{' non-negative' if minimum == 0 else ''} number")
            return None
        return float(stored)

    def integer(self, column: str, stored: Any, *, optional: bool = False) -> int | None:
        if stored is None and optional:
            return None
        if not isinstance(stored, int) or isinstance(stored, bool):
            self.damaged.append(f"{column}: {_kind(stored)}, not a whole number")
            return None
        return stored

    def text(self, column: str, stored: Any, *, optional: bool = False,
             choices: tuple[str, ...] | None = None) -> str | None:
        if stored is None and optional:
            return None
        if isinstance(stored, UndecodableText):
            self.damaged.append(f"{column}: {_not_utf8(stored.raw)}")
            return None
        if not isinstance(stored, str) or (choices is not None and stored not in choices):
            wanted = "text" if choices is None else " or ".join(repr(choice) for choice in choices)
            self.damaged.append(f"{column}: {_kind(stored)}, not {wanted}")
            return None
        return stored

    def json(self, column: str, stored: Any, shape: Shape, empty: Any, *, optional: bool = False) -> Any:
        if stored is None:
            if not optional:
                self.damaged.append(f"{column}: null, where the journal always writes a value")
            return empty
        if isinstance(stored, UndecodableText):
            self.damaged.append(f"{column}: {_not_utf8(stored.raw)}")
            return empty
        if not isinstance(stored, str):
            self.damaged.append(f"{column}: {_kind(stored)}, not JSON text")
            return empty
        try:
            value = json.loads(stored, parse_constant=_refuse_constant)
        except json.JSONDecodeError as exc:
            at = "" if exc.msg.endswith(" at") else " at"  # "Unterminated string starting at"
            self.damaged.append(f"{column}: not JSON ({exc.msg}{at} char {exc.pos})")
            return empty
        except ValueError as exc:
            self.damaged.append(f"{column}: not strict JSON ({exc})")
            return empty
        if value is None and optional:
            return None
        wrong = shape(value)
        if wrong is not None:
            self.damaged.append(f"{column}: {wrong}")
            return empty
        return value


def _refuse_constant(name: str) -> float:
    raise ValueError(f"{name} is no JSON number")


def _record(value: Any) -> str | None:
    """``record_json``: an object, with the parts every reader prints in their shape."""
    if not isinstance(value, dict):
        return _not(value, "an object")
    for key, wanted in (("views", list), ("observations", list), ("part", str)):
        if key in value and not isinstance(value[key], wanted):
            return f"{key} is {_kind(value[key])}, not {'a list' if wanted is list else 'text'}"
    if value.get("id") is not None and not isinstance(value["id"], str):
        return f"id is {_kind(value['id'])}, not text"
    if value.get("sigma_px") is not None and not _finite(value["sigma_px"]):
        return f"sigma_px is {_kind(value['sigma_px'])}, not a number"
    for i, observation in enumerate(value.get("observations", [])):
        if not (isinstance(observation, dict) and isinstance(observation.get("view"), int)
                and isinstance(observation.get("point"), int) and _numbers(observation.get("pixel"), 2)):
            return f"observation {i + 1} is not {{\"view\": i, \"point\": j, \"pixel\": [u, v]}}"
    return None


def _result(value: Any) -> str | None:
    """``result_json``: an object whose numbers every reader summarises are numbers (or null)."""
    if not isinstance(value, dict):
        return _not(value, "an object")
    for key in _RESULT_NUMBERS:
        if value.get(key) is not None and not _finite(value[key]):
            return f"{key} is {_kind(value[key])}, not a number"
    for key in _RESULT_TEXTS:
        if value.get(key) is not None and not isinstance(value[key], str):
            return f"{key} is {_kind(value[key])}, not text"
    for key in _RESULT_MATRICES:
        if value.get(key) is not None and not _matrix(value[key]):
            return f"{key} is not a 4x4 matrix"
    if value.get("base_offset_xyzabc") is not None and not _numbers(value["base_offset_xyzabc"], 6):
        return "base_offset_xyzabc is not six numbers"
    return None


def _offset(value: Any) -> str | None:
    """``offset_json``: ``{"registers": six numbers, "D_b": 4x4}``."""
    if not isinstance(value, dict):
        return _not(value, "an object")
    if not _numbers(value.get("registers"), 6):
        return "registers are not six numbers"
    D_b = value.get("D_b")
    if not (isinstance(D_b, list) and all(isinstance(row, list) and all(_finite(v) for v in row) for row in D_b)):
        return "D_b is not a matrix"
    return None


def _poses(value: Any) -> str | None:
    """``poses_json``: a list of 4x4 matrices."""
    if not isinstance(value, list):
        return _not(value, "a list")
    return next((f"pose {i + 1} is not a 4x4 matrix" for i, T in enumerate(value) if not _matrix(T)), None)



def _matrix(value: Any) -> bool:
    return isinstance(value, list) and len(value) == 4 and all(_numbers(row, 4) for row in value)


def _numbers(value: Any, count: int) -> bool:
    return isinstance(value, list) and len(value) == count and all(_finite(v) for v in value)


def _finite(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def _not(value: Any, wanted: str) -> str:
    return f"{_kind(value)}, not {wanted}"


def _kind(value: Any) -> str:
    """What a stored or decoded value is, with a glimpse of it: ``a string ('3.5')``."""
    if value is None:
        return "null"
    kinds = ((bool, "a boolean"), (int | float, "a number"), (str, "a string"), (list, "a list"),
             (dict, "an object"), (bytes, "a blob"))
    kind = next((name for cls, name in kinds if isinstance(value, cls)), type(value).__name__)
    shown = repr(value)
    return f"{kind} ({shown if len(shown) <= 40 else shown[:37] + '...'})"


def _not_utf8(raw: bytes) -> str:
    try:
        raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        return f"not UTF-8 text (byte {raw[exc.start]:#04x} at {exc.start})"
    return "not UTF-8 text"
