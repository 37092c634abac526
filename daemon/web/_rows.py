"""A journal row as the pages can show it, whatever the row holds: every column checked once, here, for the type
and range the pages draw with (a time a time, a pixel two finite numbers within reach, a pose a finite 4x4), a
value that is not taken as missing and named in :attr:`CycleRow.unreadable`, so the page shows the rest and says
what it could not show. Nothing above this module reads a :class:`JournalRow` or its JSON itself.

The journal decodes each row's JSON columns; a row it cannot decode (its JSON damaged, a number past what JSON's
reader takes) raises there, and :func:`read_cycle` and :func:`find_rows` stand a row in for it that says so: one
damaged row takes no page down with it.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Any

import numpy as np

from monoguide.daemon.service import CycleQuery, Journal, JournalRow

MAX_PX = 1e6  # a pixel farther off the image than this is no pixel of it
MAX_VALUE = 1e15  # a number beyond this is shown as missing (it cannot be drawn or formatted)
MAX_TEXT = 20_000  # characters of a message shown
NEAR = 32  # numbers below a damaged row's neighbour a list looks through one by one for its number
MAX_SKIP = 64  # steps doubling beyond (any gap within 2**64)
# what the journal raises for a row it cannot decode (json's errors are ValueErrors; nesting past the recursion
# limit; a column of another type than the decoder takes)
UNDECODABLE = (ValueError, TypeError, RecursionError)
_CODE = re.compile(r"^[A-Z][A-Z0-9_]{0,63}$")


@dataclass(frozen=True)
class CycleRow:
    """One cycle as the pages show it: each value of its type, or None (or empty) when the row's was not."""

    number: int
    started_at: float | None
    finished_at: float | None
    duration_s: float | None  # how long the cycle took
    job: int | None
    part_tag: int | None
    status: str  # "ok" or "error" ("error" too for a row that cannot be read)
    error_code: str | None
    plc_code: int | None
    error_message: str | None
    record: dict[str, Any] | None  # as journaled (``_overlay`` checks what it draws from)
    result: dict[str, Any]  # as journaled, {} when none
    timings_s: dict[str, float]
    poses_at_capture: tuple[np.ndarray | None, ...]  # T_b_f at each capture, None where not a finite 4x4
    image_paths: tuple[str | None, ...]
    images_pruned_at: float | None
    unreadable: tuple[str, ...] = ()  # what of the row could not be shown, and why

    @property
    def failed(self) -> bool:
        return self.status != "ok"

    @property
    def offset(self) -> tuple[float, ...] | None:
        """The base offset x, y, z mm, a, b, c deg."""
        return numbers(self.result.get("base_offset_xyzabc"), 6)

    @property
    def rms_px(self) -> float | None:
        return finite(self.result.get("rms_px"))

    @property
    def sigma_mm(self) -> float | None:
        return finite(self.result.get("sigma_trans_mm"))

    @property
    def sigma_deg(self) -> float | None:
        return finite(self.result.get("sigma_rot_deg"))

    @property
    def chi2(self) -> float | None:
        consistency = self.result.get("consistency")
        return finite(consistency.get("chi2")) if isinstance(consistency, dict) else None

    @property
    def dof(self) -> int | None:
        consistency = self.result.get("consistency")
        return whole(consistency.get("dof"), 0, 10**6) if isinstance(consistency, dict) else None

    @property
    def cycle_s(self) -> float | None:
        return self.timings_s.get("cycle")


def cycle_row(row: JournalRow) -> CycleRow:
    """``row`` checked column by column."""
    bad: list[str] = []

    def take(name: str, value: Any, check: Any) -> Any:
        if value is None:
            return None
        checked = check(value)
        if checked is None:
            bad.append(f"{name}: {_shown(value)} is not {_WHAT[check]}")
        return checked

    bad.extend(f"{damage}: cannot be read" for damage in row.damaged)
    started = take("started_at", row.started_at, finite)
    finished = take("finished_at", row.finished_at, finite)
    status = row.status if row.status in ("ok", "error") else "error"
    if status != row.status:
        bad.append(f"status: {_shown(row.status)} is neither ok nor error")
    code = take("error_code", row.error_code, _code)
    record = take("record", row.record, _mapping)
    result = take("result", row.result, _mapping) or {}
    timings = _timings(row.timings_s, bad)
    poses = _listed("poses", row.poses_at_capture, matrix4, bad)
    images = _listed("images", row.image_paths, _path, bad)
    return CycleRow(
        row.number, started, finished, take("duration_s", row.duration_s, finite), take("job", row.job, _register),
        take("part_tag", row.part_tag, _register), status, code, take("plc_code", row.plc_code, _register),
        take("error_message", row.error_message, _text), record, result, timings, poses, images,
        take("images_pruned_at", row.images_pruned_at, finite), tuple(bad))


def read_cycle(journal: Journal, number: int) -> CycleRow:
    """Cycle ``number`` (:class:`JournalEntryMissing` when there is none), or a row saying it cannot be read."""
    try:
        return cycle_row(journal.cycle(number))
    except UNDECODABLE as exc:
        return unreadable_row(number, exc)


def find_rows(journal: Journal, query: CycleQuery) -> tuple[list[CycleRow], list[str]]:
    """The rows ``query`` finds, newest first, and what could not be read among them: a row the journal cannot
    decode is left out and named; the readable rows around it are read as many at a time as read together."""
    rows: list[CycleRow] = []
    notes: list[str] = []
    before = query.before
    while len(rows) < query.limit:
        want = query.limit - len(rows)
        try:
            found = journal.find_cycles(_page(query, before, want))
        except UNDECODABLE as exc:
            readable = _readable(journal, query, before, want)
            found = journal.find_cycles(_page(query, before, readable)) if readable else []
            rows += [cycle_row(r) for r in found]
            before = found[-1].number if found else before
            damaged = _damaged_below(journal, query, before)
            if damaged is None:
                notes.append(f"a row below {_below(before)} cannot be read ({_why(exc)}); the rows further down are "
                             "not listed: open them by number")
                break
            top = before - 1 if before > 0 else journal.cycle_counter()
            notes.append(f"cycle {damaged}: its row cannot be read" + (
                f", nor can any other row of this list above it up to cycle {top}" if damaged < top else "")
                + f" ({_why(exc)})")
            before = damaged
            continue
        rows += [cycle_row(r) for r in found]
        if len(found) < want:
            break
        before = found[-1].number
    return rows, notes


def unreadable_row(number: int, exc: BaseException) -> CycleRow:
    return CycleRow(number, None, None, None, None, None, "error", None, None, None, None, {}, {}, (), (), None,
                    (f"the row cannot be read: {_why(exc)}",))


# --- values -------------------------------------------------------------------------------------


def finite(value: Any, limit: float = MAX_VALUE) -> float | None:
    """``value`` as a float when it is a finite number within ``limit``, else None."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    try:
        number = float(value)
    except OverflowError:
        return None
    return number if math.isfinite(number) and abs(number) <= limit else None


def whole(value: Any, low: int, high: int) -> int | None:
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
        return None
    return value


def numbers(value: Any, count: int, limit: float = MAX_VALUE) -> tuple[float, ...] | None:
    """``count`` finite numbers (a list of them), else None."""
    if not isinstance(value, list | tuple) or len(value) != count:
        return None
    out = tuple(finite(v, limit) for v in value)
    return None if any(v is None for v in out) else out  # type: ignore[return-value]


def pixel(value: Any) -> tuple[float, float] | None:
    """An image point (u, v) within :data:`MAX_PX` of the origin, else None."""
    found = numbers(value, 2, MAX_PX)
    return None if found is None else (found[0], found[1])


def matrix4(value: Any) -> np.ndarray | None:
    """A finite 4x4 (a list of 4 lists of 4 numbers), else None."""
    if not isinstance(value, list | tuple) or len(value) != 4:
        return None
    found = [numbers(line, 4) for line in value]
    return None if any(line is None for line in found) else np.array(found, float)


def point3(value: Any) -> np.ndarray | None:
    found = numbers(value, 3)
    return None if found is None else np.array(found, float)


def text(value: Any, limit: int = 200) -> str | None:
    return value[:limit] if isinstance(value, str) else None


# --- private ------------------------------------------------------------------------------------


def _register(value: Any) -> int | None:
    return whole(value, -(2**63), 2**63 - 1)


def _code(value: Any) -> str | None:
    return value if isinstance(value, str) and _CODE.match(value) else None


def _mapping(value: Any) -> dict[str, Any] | None:
    return value if isinstance(value, dict) else None


def _text(value: Any) -> str | None:
    return text(value, MAX_TEXT)


def _path(value: Any) -> str | None:
    return value if isinstance(value, str) and 0 < len(value) <= 4096 and "\x00" not in value else None


_WHAT = {finite: "a finite number", _register: "a whole number", _code: "an error code", _mapping: "an object",
         _text: "text", _path: "a file name", matrix4: "a 4x4 of finite numbers"}


def _timings(value: Any, bad: list[str]) -> dict[str, float]:
    if not isinstance(value, dict):
        if value is not None:
            bad.append(f"timings: {_shown(value)} is not an object of seconds")
        return {}
    out = {}
    for name, seconds in value.items():
        checked = finite(seconds)
        if checked is None:
            bad.append(f"timings.{_shown(name)}: {_shown(seconds)} is not a number of seconds")
        else:
            out[str(name)[:80]] = checked
    return out


def _listed(name: str, value: Any, check: Any, bad: list[str]) -> tuple[Any, ...]:
    if not isinstance(value, list):
        if value is not None:
            bad.append(f"{name}: {_shown(value)} is not a list")
        return ()
    out = tuple(check(v) for v in value)
    for k, (given, checked) in enumerate(zip(value, out, strict=True)):
        if checked is None:
            bad.append(f"{name}[{k}]: {_shown(given)} is not {_WHAT[check]}")
    return out


def _page(query: CycleQuery, before: int, limit: int) -> CycleQuery:
    return CycleQuery(query.status, query.error_code, query.job, query.finished_from, query.finished_to, before, limit)


def _damaged_below(journal: Journal, query: CycleQuery, before: int) -> int | None:
    """The damaged row ``query`` finds first below ``before`` (the lowest of those next to each other): the highest
    ``x`` below ``before`` whose query reads, since the one below ``x + 1`` then finds damaged row ``x``.

    Sought one number at a time for :data:`NEAR` numbers (a journal numbers its cycles one after the other), past a
    gap in the numbers in steps doubling down, then halving back up and looking :data:`NEAR` numbers above each
    damaged row found for a higher one (a few hundred queries at most)."""
    top = before if before > 0 else journal.cycle_counter() + 1
    found = _highest_reading(journal, query, top - 1, max(top - 1 - NEAR, 0))
    if found is not None:
        return found
    high, step, low = max(top - NEAR, 1), 2, None
    for _ in range(MAX_SKIP):  # down in steps doubling, to a number whose query reads
        x = max(high - step, 1)
        if _reads(journal, query, x):
            low = x
            break
        if x == 1:
            return None
        high, step = x, step * 2
    for _ in range(MAX_SKIP):  # then up: reads below low, not below high
        if low is None:
            return None
        while high - low > 1:
            middle = (low + high) // 2
            low, high = (middle, high) if _reads(journal, query, middle) else (low, middle)
        above = _highest_reading(journal, query, min(low + 1 + NEAR, top - 1), low + 1)
        if above is None:
            return low
        high = above + 1 if above < min(low + 1 + NEAR, top - 1) else high
        low = above
    return low


def _highest_reading(journal: Journal, query: CycleQuery, start: int, stop: int) -> int | None:
    """The highest ``x`` from ``start`` down to (not including) ``stop`` whose query reads."""
    return next((x for x in range(start, stop, -1) if _reads(journal, query, x)), None)


def _readable(journal: Journal, query: CycleQuery, before: int, want: int) -> int:
    """How many of the ``want`` rows ``query`` finds below ``before`` read before the first that does not (halving:
    the first ``k`` read together exactly when ``k`` is below that one's place)."""
    low, high = 0, want  # the first low read, the first high do not
    while high - low > 1:
        middle = (low + high) // 2
        try:
            journal.find_cycles(_page(query, before, middle))
        except UNDECODABLE:
            high = middle
        else:
            low = middle
    return low


def _reads(journal: Journal, query: CycleQuery, before: int) -> bool:
    try:
        journal.find_cycles(_page(query, before, 1))
    except UNDECODABLE:
        return False
    return True


def _below(before: int) -> str:
    return f"cycle {before}" if before > 0 else "the newest"


def _why(exc: BaseException) -> str:
    return f"{type(exc).__name__}: {str(exc)[:200]}"


def _shown(value: Any) -> str:
    if isinstance(value, list | dict):  # of any depth: named by its kind, not written out
        return f"a {type(value).__name__} of {len(value)}"
    return repr(value)[:60]
