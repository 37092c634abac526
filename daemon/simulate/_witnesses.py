"""What a ``monoguide simulate`` run measured, from three independent witnesses, joined into one record per part.

- the **line** (the simulated PLC's record of every part it played: outcome, status word, error code, the
  offset it read from registers 16–27),
- the **service's journal** (one row per cycle: result or error code, ``timings_s`` per stage),
- the **truth log** of the simulated cell's part supply (per part: the true pose, the ideal offset, the
  offset the robot actually applied and the grasp error it gave; per grasp the line's go asked for: whether the
  robot program's interlock ran it or refused it, for a stale offset or for none).

A cycle is one part the line played. Its journal row is found by the cycle counter the line read (register
13), else by the part tag; the truth-log line of the part that was grasped is found by the offset the robot
applied being the one the line read (or the journal's result, for a cycle that failed after writing). The
grasp error comes from the truth log only; an offset the robot applied without a successful cycle is an
``offsets_written_on_failure`` (:mod:`._summary`). The service's log is a fourth, weaker witness: the error codes
it names (a PLC-side fault that ends no cycle is only logged).
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

from monoguide.daemon.service import JOURNAL_FILE, Journal, JournalRow
from monoguide.daemon.simulate._fault_plan import InjectedFault

OFFSET_MATCH_TOL = 1e-3  # mm / deg: the line reads float32, the robot gets float64 or 6-decimal text
_CODE_WORD = re.compile(r"\b[A-Z][A-Z0-9]*(?:_[A-Z0-9]+)+\b")


def read_truth_log(path: Path, grasps: bool = False) -> list[dict[str, Any]]:
    """The truth log's part lines (a missing file: none); ``grasps``: its grasp lines too (``{"grasp": {...}}``, one
    per go the simulated line gave), in the file's order."""
    if not Path(path).exists():
        return []
    lines = [json.loads(line) for line in Path(path).read_text().splitlines() if line.strip()]
    return lines if grasps else [line for line in lines if "grasp" not in line]


def grasps(truth: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """The grasp lines of the truth log (``{"grasp": {...}}``): one per go the simulated line gave."""
    return [line["grasp"] for line in truth if isinstance(line.get("grasp"), dict)]


def read_journal_rows(state_dir: Path) -> list[JournalRow]:
    """Every cycle of the service's journal in ``state_dir``, oldest first (no journal: none)."""
    if not (state_dir / JOURNAL_FILE).exists():
        return []
    with Journal(state_dir, read_only=True) as journal:
        return list(reversed(journal.last_cycles(journal.cycle_counter() or 1)))


def logged_codes(log: Path) -> set[str]:
    """Error codes the service named in its log (PLC-side faults that end no cycle are only logged)."""
    try:
        text = log.read_text(errors="replace")
    except OSError:
        return set()
    return set(_CODE_WORD.findall(text))


def join_cycles(plc_records: Sequence[dict[str, Any]], journal_rows: Iterable[Any], truth: Sequence[dict[str, Any]],
                faults: Sequence[InjectedFault] = ()) -> list[dict[str, Any]]:
    """One JSON-able object per part the line played (see the module's doc); ``journal_rows`` are
    :class:`~monoguide.daemon.service.JournalRow`."""
    rows = list(journal_rows)
    by_number = {row.number: row for row in rows}
    by_tag: dict[int, Any] = {}
    for row in sorted(rows, key=lambda r: r.number):
        if row.part_tag is not None:
            by_tag[row.part_tag] = row
    fault_at = {f.cycle: f for f in faults}
    cycles = []
    for index, record in enumerate(plc_records, start=1):
        row = by_number.get(record.get("cycle_counter")) if record.get("cycle_counter") else None
        if row is None or (row.part_tag is not None and row.part_tag != record.get("part_tag")):
            row = by_tag.get(record.get("part_tag"))
        written = record.get("offset_written")
        line_ok = bool(record.get("result_ok")) and written is not None
        if row is not None:
            status = "ok" if row.status == "ok" and line_ok else "error"
            code = row.error_code
            plc_code = row.plc_code
        else:
            status = "ok" if line_ok else ("error" if record.get("error_code") else "no cycle")
            code, plc_code = None, int(record.get("error_code") or 0)
        part = _truth_for(written, truth) if written is not None else None
        fault = fault_at.get(index)
        cycles.append({
            "cycle": index,
            "job": record.get("job"),
            "part_tag": record.get("part_tag"),
            "journal_cycle": None if row is None else row.number,
            "status": status,
            "error_code": code,
            "plc_code": plc_code,
            "line_outcome": record.get("outcome"),
            "fault": None if fault is None else fault.label,
            "truth_part": None if part is None else part.get("part"),
            "grasp_error_mm": None if part is None else part.get("grasp_error_mm"),
            "grasp_error_deg": None if part is None else part.get("grasp_error_deg"),
            "offset_written": written,
            "offset_ideal": None if part is None else part.get("offset_ideal"),
            "offset_solved": None if row is None or not row.result else row.result.get("base_offset_xyzabc"),
            "timings_ms": {} if row is None else {k: round(1000.0 * float(v), 3)
                                                   for k, v in row.timings_s.items() if _finite(v)},
        })
    return cycles


def same_offset(a: Sequence[float], b: Sequence[float]) -> bool:
    """The same six offset values within :data:`OFFSET_MATCH_TOL` (what the line read against what was applied)."""
    return len(a) == len(b) == 6 and all(abs(float(x) - float(y)) <= OFFSET_MATCH_TOL for x, y in zip(a, b,
                                                                                                     strict=True))


# --- private ------------------------------------------------------------------------------------


def _truth_for(offset: Sequence[float] | None, truth: Sequence[dict[str, Any]]) -> dict[str, Any] | None:
    if offset is None:
        return None
    for part in truth:
        applied = part.get("offset_written")
        if applied is not None and same_offset(applied, offset):
            return part
    return None


def _finite(value: Any) -> bool:
    return isinstance(value, int | float) and math.isfinite(value)
