"""What a ``monoguide simulate`` run measured, from three independent witnesses.

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
``offsets_written_on_failure``.
"""

from __future__ import annotations

import json
import math
import statistics
from collections import Counter
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.table import Table

TIMING_KEYS = ("robot_motion", "exposure", "hole_finding", "solve", "checks", "offset_write", "plc_journal",
               "overhead", "cycle")
COMPUTE_KEYS = ("hole_finding", "solve", "checks")
PAPER_REQUIREMENT_MM = 0.5  # the paper's grasp requirement
PERFECT_ROBOT_TARGET = (0.05, 0.005)  # mm, deg: the method's own error, no repeatability noise
OFFSET_MATCH_TOL = 1e-3  # mm / deg: the line reads float32, the robot gets float64 or 6-decimal text
NO_ACK_FAULT = "robot no-ack"  # the robot applies the offset but never acknowledges it (see docs/simulate.md)


@dataclass(frozen=True)
class Targets:
    """The issue's targets (printed, a benchmark: missing one does not fail the run). The grasp error RMS:
    with ``--perfect-robot`` 0.05 mm / 0.005 deg; with the robot's repeatability at or below the layout's
    predicted sigma at the grasp point (``predicted_sigma_*``) and at or below the paper's 0.5 mm."""

    grasp_rms_mm: float
    grasp_rms_deg: float | None  # None: no prediction (the paper states the requirement in mm only)
    overhead_ms: float = 60.0
    compute_ms: float = 150.0
    predicted_sigma_mm: float | None = None  # the layout's predicted sigma at the grasp point for this run
    predicted_sigma_deg: float | None = None

    @classmethod
    def for_run(cls, perfect_robot: bool, predicted_sigma_mm: float | None = None,
                predicted_sigma_deg: float | None = None) -> Targets:
        predicted = {"predicted_sigma_mm": predicted_sigma_mm, "predicted_sigma_deg": predicted_sigma_deg}
        if perfect_robot:
            return cls(*PERFECT_ROBOT_TARGET, **predicted)
        mm = PAPER_REQUIREMENT_MM if predicted_sigma_mm is None else min(predicted_sigma_mm, PAPER_REQUIREMENT_MM)
        return cls(mm, predicted_sigma_deg, **predicted)


@dataclass(frozen=True)
class InjectedFault:
    """A fault ``simulate --faults`` injected while the line played part ``cycle``."""

    cycle: int
    device: str  # plc | robot | camera
    name: str
    expected: tuple[str, ...]  # error codes any of which reports it

    @property
    def label(self) -> str:
        return f"{self.device} {self.name}"


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


def join_cycles(plc_records: Sequence[dict[str, Any]], journal_rows: Iterable[Any], truth: Sequence[dict[str, Any]],
                faults: Sequence[InjectedFault] = ()) -> list[dict[str, Any]]:
    """One JSON-able object per part the line played (see the module's doc); ``journal_rows`` are
    :class:`~monoguide.daemon.service._journal.JournalRow`."""
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


def summarize(cycles: Sequence[dict[str, Any]], truth: Sequence[dict[str, Any]], journal_rows: Iterable[Any] = (),
              faults: Sequence[InjectedFault] = (), rss: dict[str, float] | None = None,
              targets: Targets | None = None, logged_codes: Iterable[str] = ()) -> dict[str, Any]:
    """The run's summary object (the last ``--json`` line), with the targets and whether each was met.
    ``logged_codes``: error codes the service's log names (a PLC fault that ends no cycle is only logged)."""
    rows = list(journal_rows)
    logged = set(logged_codes)
    good = [c for c in cycles if c["status"] == "ok"]
    errors: Counter[str] = Counter()
    counted_rows = set()
    for c in cycles:
        if c["status"] != "ok":
            errors[c["error_code"] or (f"PLC_CODE_{c['plc_code']}" if c["plc_code"] else "NO_CYCLE")] += 1
            counted_rows.add(c["journal_cycle"])
        if c["line_outcome"] not in (None, "acknowledged"):
            errors["LINE_" + str(c["line_outcome"]).upper().replace(" ", "_")] += 1
    for row in rows:  # a cycle the line did not see as one of its parts (a trigger it dropped, say)
        if row.status == "error" and row.number not in counted_rows:
            errors[row.error_code] += 1
    grasped = [c for c in good if c["grasp_error_mm"] is not None]
    mm = [float(c["grasp_error_mm"]) for c in grasped]
    deg = [float(c["grasp_error_deg"]) for c in grasped]
    on_failure, unacknowledged = _offsets_on_failure(cycles, truth, rows)
    timings = {k: _median([c["timings_ms"][k] for c in good if k in c["timings_ms"]]) for k in TIMING_KEYS}
    compute = [sum(c["timings_ms"].get(k, 0.0) for k in COMPUTE_KEYS) for c in good
               if any(k in c["timings_ms"] for k in COMPUTE_KEYS)]
    summary: dict[str, Any] = {
        "summary": True,
        "cycles": len(cycles),
        "ok": len(good),
        "failed": len(cycles) - len(good),
        "errors": dict(sorted(errors.items())),
        "grasped": len(grasped),
        "grasp_rms_mm": _rms(mm),
        "grasp_rms_deg": _rms(deg),
        "grasp_max_mm": max(mm) if mm else None,
        "grasp_max_deg": max(deg) if deg else None,
        "timings_ms_median": timings,
        "overhead_ms_median": timings["overhead"],
        "cycle_ms_median": timings["cycle"],
        "compute_ms_median": _median(compute),
        "offsets_written_on_failure": on_failure,
        "offsets_unacknowledged": unacknowledged,
        **_grasp_counts(truth),
        "rss_mb": None if rss is None else rss.get("rss_mb"),
        "rss_max_mb": None if rss is None else rss.get("rss_max_mb"),
        "faults": [_fault_outcome(f, cycles, logged) for f in faults],
    }
    targets = targets or Targets.for_run(False)
    summary.update({"grasp_target_mm": targets.grasp_rms_mm, "grasp_target_deg": targets.grasp_rms_deg,
                    "predicted_sigma_mm": targets.predicted_sigma_mm,
                    "predicted_sigma_deg": targets.predicted_sigma_deg})
    summary["targets"] = _targets(summary, targets)
    summary["grasp_target_met"] = all(t["met"] for t in summary["targets"] if t["name"].startswith("grasp_"))
    summary["targets_met"] = all(t["met"] for t in summary["targets"])
    return summary


def render(console: Console, cycles: Sequence[dict[str, Any]], summary: dict[str, Any], every_cycle: bool) -> None:
    """The human tables: per cycle (when ``every_cycle``), the summary and the targets."""
    if every_cycle:
        table = Table(title="cycles", title_justify="left")
        for name in ("cycle", "status", "code", "fault", "grasp mm", "grasp deg", "overhead ms", "cycle ms"):
            table.add_column(name, justify="right" if name not in ("status", "code", "fault") else "left")
        for c in cycles:
            table.add_row(str(c["cycle"]), c["status"], c["error_code"] or (str(c["plc_code"] or "") or ""),
                          c["fault"] or "", _fmt(c["grasp_error_mm"], 4), _fmt(c["grasp_error_deg"], 5),
                          _fmt(c["timings_ms"].get("overhead"), 1), _fmt(c["timings_ms"].get("cycle"), 0))
        console.print(table)
    table = Table(title="summary", title_justify="left", show_header=False)
    table.add_column("what")
    table.add_column("value")
    table.add_row("cycles", f"{summary['cycles']} ({summary['ok']} ok, {summary['failed']} failed)")
    table.add_row("grasp error RMS", f"{_fmt(summary['grasp_rms_mm'], 4)} mm, {_fmt(summary['grasp_rms_deg'], 5)} deg"
                  f" over {summary['grasped']} grasped parts")
    table.add_row("grasp error max", f"{_fmt(summary['grasp_max_mm'], 4)} mm, {_fmt(summary['grasp_max_deg'], 5)} deg")
    table.add_row("grasp target", grasp_target_text(summary))
    if summary.get("calibration"):
        table.add_row("calibration", calibration_text(summary["calibration"]))
    split = ", ".join(f"{k} {_fmt(v, 1)}" for k, v in summary["timings_ms_median"].items() if v is not None)
    table.add_row("time split, median ms", split or "-")
    table.add_row("overhead median", f"{_fmt(summary['overhead_ms_median'], 1)} ms (last frame -> offset acknowledged)")
    table.add_row("compute median", f"{_fmt(summary['compute_ms_median'], 1)} ms (hole finding + solve + checks)")
    table.add_row("errors by code", ", ".join(f"{k} {v}" for k, v in summary["errors"].items()) or "none")
    table.add_row("offsets written on failure", str(summary["offsets_written_on_failure"]))
    if summary.get("grasps_ran") or summary.get("grasps_refused"):
        table.add_row("grasps (robot interlock)", f"{summary['grasps_ran']} ran, {summary['grasps_refused']} refused "
                      f"({summary['grasps_refused_stale']} for a stale offset)")
    if summary["offsets_unacknowledged"]:
        table.add_row("offsets applied, not acknowledged", f"{summary['offsets_unacknowledged']} (robot no-ack fault)")
    table.add_row("service memory", f"{_fmt(summary['rss_mb'], 1)} MB resident at the end "
                  f"(max {_fmt(summary['rss_max_mb'], 1)} MB)")
    console.print(table)
    if summary["faults"]:
        faults = Table(title="injected faults", title_justify="left")
        for name in ("cycle", "fault", "expected", "got", "reported", "READY after"):
            faults.add_column(name)
        for f in summary["faults"]:
            faults.add_row(str(f["cycle"]), f["fault"], " | ".join(f["expected"]), f["got"] or "-",
                           "yes" if f["reported"] else "NO", "yes" if f["back_ready"] else "NO")
        console.print(faults)
    targets = Table(title="targets", title_justify="left")
    for name in ("target", "value", "limit", "met"):
        targets.add_column(name)
    for t in summary["targets"]:
        targets.add_row(t["name"], format_value(t["value"]), format_limit(t["limit"]), "yes" if t["met"] else "NO")
    console.print(targets)


# --- private ------------------------------------------------------------------------------------


def _truth_for(offset: Sequence[float] | None, truth: Sequence[dict[str, Any]]) -> dict[str, Any] | None:
    if offset is None:
        return None
    for part in truth:
        applied = part.get("offset_written")
        if applied is not None and _same_offset(applied, offset):
            return part
    return None


def _same_offset(a: Sequence[float], b: Sequence[float]) -> bool:
    return len(a) == len(b) == 6 and all(abs(float(x) - float(y)) <= OFFSET_MATCH_TOL for x, y in zip(a, b,
                                                                                                     strict=True))


def _offsets_on_failure(cycles: Sequence[dict[str, Any]], truth: Sequence[dict[str, Any]],
                        rows: Sequence[Any]) -> tuple[int, int]:
    """(offsets the robot applied with no successful cycle reporting them, those of them during a robot no-ack
    fault: applied by the robot, never acknowledged, reported to the line as an error)."""
    ok_offsets = [c["offset_written"] for c in cycles if c["status"] == "ok" and c["offset_written"] is not None]
    fault_by_row = {c["journal_cycle"]: c["fault"] for c in cycles if c["journal_cycle"] is not None}
    on_failure = unacknowledged = 0
    for part in truth:
        applied = part.get("offset_written")
        if applied is None or any(_same_offset(applied, ok) for ok in ok_offsets):
            continue
        row = next((r for r in rows if r.result and r.result.get("base_offset_xyzabc") is not None
                    and _same_offset(applied, r.result["base_offset_xyzabc"])), None)
        if row is not None and fault_by_row.get(row.number) == NO_ACK_FAULT:
            unacknowledged += 1
        else:
            on_failure += 1
    return on_failure, unacknowledged


def _grasp_counts(truth: Sequence[dict[str, Any]]) -> dict[str, int]:
    """How many grasps the robot program ran and refused (its interlock: no valid offset; stale: one was held)."""
    done = grasps(truth)
    refused = [g for g in done if g.get("outcome") == "refused"]
    return {"grasps_ran": sum(g.get("outcome") == "ran" for g in done), "grasps_refused": len(refused),
            "grasps_refused_stale": sum(g.get("reason") == "stale offset" for g in refused)}


def _fault_outcome(fault: InjectedFault, cycles: Sequence[dict[str, Any]], logged: set[str]) -> dict[str, Any]:
    """Was the fault reported with one of its codes, and did a good cycle follow (READY without a restart)?"""
    hit = [c for c in cycles if c["cycle"] >= fault.cycle][:2]
    got = [c["error_code"] for c in hit if c["error_code"]] + [
        "LINE_" + str(c["line_outcome"]).upper().replace(" ", "_") for c in hit
        if c["line_outcome"] not in (None, "acknowledged")]
    if not any(code in fault.expected for code in got):
        got += [f"{code} (service log)" for code in fault.expected if code in logged]
    later = [c for c in cycles if c["cycle"] > fault.cycle]
    return {"cycle": fault.cycle, "fault": fault.label, "expected": list(fault.expected),
            "got": ", ".join(dict.fromkeys(got)) or None,
            "reported": any(code.split()[0] in fault.expected for code in got),
            "back_ready": any(c["status"] == "ok" for c in later)}


def _targets(summary: dict[str, Any], targets: Targets) -> list[dict[str, Any]]:
    def target(name: str, value: float | None, limit: float | int, le: bool = True) -> dict[str, Any]:
        met = value is not None and (value <= limit if le else value == limit)
        return {"name": name, "value": value, "limit": limit, "met": met}

    out = [target("grasp_rms_mm", summary["grasp_rms_mm"], targets.grasp_rms_mm)]
    if targets.grasp_rms_deg is not None:
        out.append(target("grasp_rms_deg", summary["grasp_rms_deg"], targets.grasp_rms_deg))
    out += [
        target("overhead_ms_median", summary["overhead_ms_median"], targets.overhead_ms),
        target("compute_ms_median", summary["compute_ms_median"], targets.compute_ms),
        target("offsets_written_on_failure", summary["offsets_written_on_failure"], 0, le=False),
    ]
    if summary["faults"]:
        reported = sum(f["reported"] and f["back_ready"] for f in summary["faults"])
        out.append(target("faults_reported_and_ready", reported, len(summary["faults"]), le=False))
    return out


def _rms(values: Sequence[float]) -> float | None:
    return math.sqrt(sum(v * v for v in values) / len(values)) if values else None


def _median(values: Sequence[float]) -> float | None:
    return round(statistics.median(values), 3) if values else None


def _finite(value: Any) -> bool:
    return isinstance(value, int | float) and math.isfinite(value)


def grasp_target_text(summary: dict[str, Any]) -> str:
    """The grasp target and where it comes from, in words."""
    limit = f"RMS <= {_fmt(summary['grasp_target_mm'], 4)} mm"
    if summary.get("grasp_target_deg") is not None:
        limit += f", <= {_fmt(summary['grasp_target_deg'], 5)} deg"
    predicted = (f"predicted sigma at the grasp point {_fmt(summary.get('predicted_sigma_mm'), 4)} mm, "
                 f"{_fmt(summary.get('predicted_sigma_deg'), 5)} deg")
    if summary.get("perfect_robot"):
        return f"{limit} (--perfect-robot; {predicted} for the pixel noise alone)"
    unseen = summary.get("unseen_repeatability_mm")
    detail = "" if unseen is None else (f" with the repeatability the robot's report does not see, "
                                        f"{_fmt(unseen, 4)} mm / {_fmt(summary.get('unseen_repeatability_deg'), 4)}"
                                        f" deg per axis")
    return f"{limit} ({predicted}{detail}; the paper's requirement {PAPER_REQUIREMENT_MM:g} mm)"


def calibration_text(calibration: dict[str, Any]) -> str:
    return f"{calibration['path']} ({', '.join(calibration['values'])}); the simulated cell keeps --config's truth"


def format_limit(limit: float) -> str:
    """A target's limit: as given, a computed one (a predicted sigma) with four significant digits."""
    return str(limit) if isinstance(limit, int) or limit == round(limit, 3) else f"{limit:.4g}"


def format_value(value: float | None) -> str:
    """A target's value: counts as integers, measures with four digits."""
    if isinstance(value, int):
        return str(value)
    return _fmt(value, 4)


def _fmt(value: float | None, digits: int) -> str:
    return "-" if value is None else f"{value:.{digits}f}"
