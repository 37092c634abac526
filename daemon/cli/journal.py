"""``monoguide journal list|show|resolve|export``: past cycles from the service's journal (docs/journal.md).

Read-only: the journal is written by the service alone. ``resolve`` solves a stored measurement record
again with today's solver (the same code path as ``monoguide solve``) and prints it beside the stored
result; ``export`` writes the stored records as JSON lines that ``monoguide solve`` reads.
"""

from __future__ import annotations

import dataclasses
import json
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Annotated, Any

import typer

from monoguide.daemon.cli import _format as fmt
from monoguide.daemon.cli._console import say, stderr_console, stdout_console
from monoguide.daemon.cli._policy import reporting_errors
from monoguide.daemon.errors import CycleWithoutRecord, JournalEntryMissing, JournalError, NoJournal
from monoguide.daemon.service import (
    JOURNAL_FILE,
    MAX_PAGE,
    STATE_DIR_HELP,
    CycleQuery,
    Journal,
    JournalRow,
    OffsetIntent,
    existing_state_dir,
)

app = typer.Typer(
    name="journal",
    help="Past cycles from the service's journal: list, show, solve again, export as records.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)

StateDirOption = Annotated[str | None, typer.Option("--state-dir", help=STATE_DIR_HELP, show_default=False)]
JsonOption = Annotated[bool, typer.Option("--json", help="JSON on standard output, for machines.")]
LIST_COLUMNS = (  # header, width (negative: left-aligned)
    ("cycle", 6), ("finished", -19), ("job", 4), ("part", -8), ("tag", 6), ("status", -24), ("rms px", 7),
    ("rot deg", 8), ("grasp mm", 9), ("base offset x y z mm, a b c deg", -44), ("total s", 8), ("stages s", -1),
)


def open_journal(given_state_dir: Path | str | None) -> Journal:
    """The journal of the state directory, which must exist and hold one (nothing is created)."""
    directory = existing_state_dir(given_state_dir)
    if not (directory / JOURNAL_FILE).is_file():
        raise NoJournal(f"no journal in {directory} ({JOURNAL_FILE} missing): no cycle has finished here")
    return Journal(directory, read_only=True)


def _cycles_of_job(journal: Journal, job: int, last: int) -> list[JournalRow]:
    """The ``last`` newest cycles of ``job`` (0: all), newest first, a page at a time through the job's index."""
    rows: list[JournalRow] = []
    while not last or len(rows) < last:
        page = journal.find_cycles(CycleQuery(job=job, before=rows[-1].number if rows else 0,
                                              limit=min(last - len(rows), MAX_PAGE) if last else MAX_PAGE))
        rows += page
        if not page:
            break
    return rows


def part_name(row: JournalRow) -> str | None:
    """The part type's name the cycle's record carries (None: a cycle without a record, or before part types)."""
    return row.record.get("part") if isinstance(row.record, dict) else None


def cycle_summary(row: JournalRow) -> dict[str, Any]:
    """The one-line facts of a cycle, as ``journal list --json`` prints them (``damaged``: what of the row could
    not be read, its values then empty)."""
    result = row.result or {}
    return {
        "number": row.number, "started_at": row.started_at, "finished_at": row.finished_at, "job": row.job,
        "part": part_name(row),
        "part_tag": row.part_tag, "status": row.status, "error_code": row.error_code, "plc_code": row.plc_code,
        "error_message": row.error_message, "rms_px": result.get("rms_px"), "rotation_deg": result.get("rotation_deg"),
        "grasp_shift_mm": result.get("grasp_shift_mm"), "base_offset_xyzabc": row.base_offset_xyzabc,
        "duration_s": row.duration_s, "timings_s": row.timings_s, "damaged": list(row.damaged),
    }


def print_cycle_lines(rows: list[JournalRow]) -> None:
    """The human table of ``journal list`` (rows in the order given), a fixed-column line per cycle."""
    out = stdout_console()
    say(out, _columns([header for header, _ in LIST_COLUMNS]))
    for row in rows:
        if row.damaged:  # its number, and why the rest cannot be trusted
            say(out, f"{row.number:>{LIST_COLUMNS[0][1]}}  unreadable: {'; '.join(row.damaged)}")
            continue
        s = cycle_summary(row)
        say(out, _columns([
            str(row.number), fmt.local_time(row.finished_at), fmt.text(row.job), fmt.text(part_name(row)),
            fmt.text(row.part_tag),
            "ok" if row.status == "ok" else f"{row.error_code} ({row.plc_code})", fmt.number(s["rms_px"], 3),
            fmt.number(s["rotation_deg"], 4), fmt.number(s["grasp_shift_mm"], 3), fmt.xyzabc(s["base_offset_xyzabc"]),
            fmt.number(s["duration_s"], 2), " ".join(f"{stage} {sec:.3f}" for stage, sec in row.timings_s.items()),
        ]))


@app.command("list")
def list_cycles(
    state_dir: StateDirOption = None,
    last: Annotated[int, typer.Option("--last", help="How many of the newest cycles; 0 for all.", min=0)] = 20,
    job: Annotated[int | None, typer.Option("--job", help="Only the cycles of this job (part type).", min=1,
                                            max=65535)] = None,
    json_output: JsonOption = False,
) -> None:
    """One line per cycle, newest last: number, time, job, part, part tag, status or error code, RMS, rotation,
    grasp shift, base offset, durations; a damaged row as its number and what is unreadable. With --json one object
    per line."""
    def run() -> None:
        with open_journal(state_dir) as journal:
            if job is None:
                rows = journal.last_cycles(last or max(journal.cycle_counter(), 1))[::-1]
            else:
                rows = _cycles_of_job(journal, job, last)[::-1]
        if json_output:
            _write_lines(json.dumps(cycle_summary(row)) for row in rows)
        else:
            print_cycle_lines(rows)
    reporting_errors(run)


@app.command("show")
def show(
    number: Annotated[int, typer.Argument(help="The cycle number (PLC register 13).")],
    state_dir: StateDirOption = None,
    json_output: JsonOption = False,
) -> None:
    """One cycle in full: outcome, timings, result, measurement record, robot poses at capture, images."""
    def run() -> None:
        with open_journal(state_dir) as journal:
            row = journal.cycle(number)
            intent = journal.intent(number)
            images = [journal.state_dir / path for path in row.image_paths]  # a stored absolute path stays
        if json_output:
            _write_lines([json.dumps({**dataclasses.asdict(row),
                                      "offset_intent": None if intent is None else dataclasses.asdict(intent)})])
        else:
            _print_cycle(row, images, intent)
    reporting_errors(run)


@app.command("resolve")
def resolve(
    number: Annotated[int, typer.Argument(help="The cycle number (PLC register 13).")],
    state_dir: StateDirOption = None,
    method: Annotated[str, typer.Option(help="Estimator: ml (maximum likelihood) or paper (the paper's).")] = "ml",
    robust: Annotated[bool, typer.Option(help="Huber loss in the ML refinement (down-weights outliers).")] = False,
    config: Annotated[Path | None, typer.Option("--config", "-c", help="the cell config the service ran with: "
                                                "its [camera] T_f_c takes the robot's repeatability at the flange, "
                                                "as the cycle does")] = None,
    json_output: JsonOption = False,
) -> None:
    """Solve the cycle's stored measurement record again with today's solver; print both results and
    their difference (deg, mm). Exit 1 when today's solve fails. Give the cell's --config to weight the views
    exactly as the cycle did (the record does not carry the camera's mounting on the flange)."""
    from monoguide.solver.pose import ESTIMATORS  # the solver's libraries only for the command that solves

    if method not in ESTIMATORS:
        raise typer.BadParameter(f"{method!r}; choose one of {', '.join(sorted(ESTIMATORS))}", param_hint="--method")
    if robust and method != "ml":
        raise typer.BadParameter(f"the Huber loss belongs to --method ml, not {method!r}", param_hint="--robust")
    outcome: dict[str, Any] = {}

    def run() -> None:
        from monoguide.daemon.config import load_cell_config
        from monoguide.solver.record import solve_record

        T_f_c = load_cell_config(config).camera.T_f_c if config is not None else None
        with open_journal(state_dir) as journal:
            row = journal.cycle(number)
        unreadable = _damage_of(row, "record_json")
        if unreadable:
            raise CycleWithoutRecord(f"cycle {number}: its measurement record is unreadable ({unreadable}); nothing "
                                     "to solve again")
        if row.record is None:
            raise CycleWithoutRecord(f"cycle {number} failed before its measurement record existed"
                                     f" ({row.error_code}: {row.error_message}); nothing to solve again")
        today, truth_error = solve_record(row.record, method, robust=robust, T_f_c=T_f_c)
        if today.get("status") == "error":
            today["error"]["message"] = f"cycle {number}: {today['error']['message']}"
        stored = row.result if row.result is not None else {
            "status": "error", "error": {"code": row.error_code, "message": row.error_message}}
        if _damage_of(row, "result_json"):
            stored = {"status": "unreadable", "damaged": [_damage_of(row, "result_json")]}
        outcome.update(cycle=number, stored=stored, today=today, difference=_difference(stored, today))
        if json_output:
            _write_lines([json.dumps(outcome)])
        else:
            _print_resolve(outcome, truth_error, row)
    reporting_errors(run)
    if outcome["today"]["status"] != "ok":
        raise typer.Exit(1)


@app.command("export")
def export(
    state_dir: StateDirOption = None,
    first: Annotated[int | None, typer.Option("--from", help="First cycle number (default: the first).", min=1)] = None,
    last: Annotated[int | None, typer.Option("--to", help="Last cycle number (default: the newest).", min=1)] = None,
    output: Annotated[Path | None, typer.Option("-o", "--output", help="File to write (default: standard output).")]
    = None,
) -> None:
    """Write the measurement records of cycles --from..--to as JSON lines, which `monoguide solve` reads.

    Records are as the cycle stored them; one without an id gets "cycle-N". Cycles that failed before
    a record existed are skipped (counted on standard error), and so are those whose record is unreadable (named
    there)."""
    if first is not None and last is not None and first > last:
        raise typer.BadParameter(f"--from {first} lies after --to {last}", param_hint="--from")

    def run() -> None:
        with open_journal(state_dir) as journal:
            start, end = first or 1, last or journal.cycle_counter()
            lines, skipped, unreadable = [], 0, []
            for row in _cycles(journal, start, end):
                if _damage_of(row, "record_json"):
                    unreadable.append(str(row.number))
                    continue
                if row.record is None:
                    skipped += 1
                    continue
                record = row.record if row.record.get("id") else {**row.record, "id": f"cycle-{row.number}"}
                lines.append(json.dumps(record))
        if output is None:
            _write_lines(lines)
        else:
            try:
                output.write_text("".join(line + "\n" for line in lines))
            except OSError as exc:
                raise JournalError(f"cannot write {output}: {exc.strerror or exc}") from exc
        where = "standard output" if output is None else str(output)
        damaged = f"; cycles {', '.join(unreadable)} skipped: their record is unreadable" if unreadable else ""
        say(stderr_console(), f"exported {len(lines)} records of cycles {start}..{end} to {where}"
               f" ({skipped} cycles without a record skipped{damaged})")
    reporting_errors(run)


# --- private ------------------------------------------------------------------------------------


def _damage_of(row: JournalRow, column: str) -> str:
    """Why ``column`` of ``row`` is unreadable ("" when it is sound)."""
    return next((why for why in row.damaged if why.startswith(f"{column}: ")), "")


def _cycles(journal: Journal, start: int, end: int) -> Iterator[JournalRow]:
    for number in range(start, end + 1):
        try:
            yield journal.cycle(number)
        except JournalEntryMissing:
            continue


def _difference(stored: dict[str, Any], today: dict[str, Any]) -> dict[str, Any] | None:
    import numpy as np

    from monoguide.solver import frames

    """How far today's pose lies from the stored one: rotation deg, the grasp point's shift mm, and the base
    offset's rotation deg and translation mm. None unless both solved."""
    if stored.get("status") != "ok" or today.get("status") != "ok":
        return None
    T_stored, T_today = np.array(stored["T_s1_w"]), np.array(today["T_s1_w"])
    grasp = np.array([today["grasp_point_w"]])
    moved = frames.transform_points(T_today, grasp) - frames.transform_points(T_stored, grasp)
    difference = {"rotation_deg": frames.pose_difference(T_stored, T_today)[0],
                  "grasp_point_mm": float(np.linalg.norm(moved)), "base_offset_deg": None, "base_offset_mm": None}
    if stored.get("base_offset") is not None and today.get("base_offset") is not None:
        deg, mm = frames.pose_difference(np.array(stored["base_offset"]), np.array(today["base_offset"]))
        difference.update(base_offset_deg=deg, base_offset_mm=mm)
    return difference


def _print_cycle(row: JournalRow, images: list[Path], intent: OffsetIntent | None = None) -> None:
    """``journal show``: the row as far as it can be read; a damaged row says first what is unreadable."""
    import numpy as np

    from monoguide.solver import frames

    out = stdout_console()
    outcome = "ok" if row.status == "ok" else f"{row.error_code} ({row.plc_code}): {row.error_message}"
    lines = [f"cycle {row.number}: {outcome}"]
    lines += [f"  UNREADABLE {why}" for why in row.damaged]
    lines += [
        f"  started {_time(row.started_at, _damage_of(row, 'started_at'))}, finished"
        f" {_time(row.finished_at, _damage_of(row, 'finished_at'))}"
        f" ({fmt.number(row.duration_s, 2)} s); job {fmt.text(row.job)}, part tag {fmt.text(row.part_tag)}",
        "  timings s: " + (", ".join(f"{stage} {s:.3f}" for stage, s in row.timings_s.items()) or "-"),
        "  offset sent to the robot: " + _intent_text(intent),
        f"  base offset x y z mm, a b c deg: {fmt.xyzabc(row.base_offset_xyzabc) or '-'}",
    ]
    result = row.result
    if result is not None and result.get("status") == "ok":
        def number(key: str, digits: int) -> str:  # a check job's result has no pose: "-"
            return fmt.number(result.get(key), digits)

        lines += [
            f"  result: rms {number('rms_px', 3)} px, rotation {number('rotation_deg', 4)} deg, grasp shift"
            f" {number('grasp_shift_mm', 3)} mm, σ {number('sigma_rot_deg', 4)} deg {number('sigma_trans_mm', 3)}"
            f" mm, method {fmt.text(result.get('method'))}",
            "  T_s1_w: " + ("-" if result.get("T_s1_w") is None else json.dumps(result["T_s1_w"])),
        ]
    record = row.record
    if record is None:
        lines.append("  record: unreadable" if _damage_of(row, "record_json")
                     else "  record: none (the cycle failed before one existed)")
    else:
        observations = record.get("observations", [])
        lines.append(f"  record: id {record.get('id')}, {len(record.get('views', []))} views,"
                     f" {len(observations)} observations, sigma {record.get('sigma_px', 0.1)} px,"
                     f" T_b_s1 {fmt.yes(record.get('T_b_s1'))}, truth {fmt.yes(record.get('truth'))}")
        lines += [f"    view {o['view']} point {o['point']}: pixel {o['pixel'][0]:.3f} {o['pixel'][1]:.3f}"
                  for o in observations]
    lines.append(f"  robot poses at capture (T_b_f), x y z mm, a b c deg: {len(row.poses_at_capture) or 'none'}")
    lines += [f"    capture {i + 1}: {fmt.xyzabc(list(frames.T_to_kuka_frame(np.array(T))))}"
              for i, T in enumerate(row.poses_at_capture)]
    pruned = f" (deleted {fmt.local_time(row.images_pruned_at)})" if row.images_pruned_at is not None else ""
    lines.append(f"  images{pruned}: {len(images) or 'none'}")
    lines += [f"    {path}{'' if path.exists() else ' (missing)'}" for path in images]
    for line in lines:
        say(out, line)


def _time(unix_s: float, damage: str) -> str:
    return "unreadable" if damage else fmt.local_time(unix_s)


def _intent_text(intent: OffsetIntent | None) -> str:
    """The offset sent to the robot and what became of it, as ``journal show`` says it."""
    if intent is None:
        return "no"
    offset = fmt.xyzabc(list(intent.registers)) if intent.registers else "unreadable"
    fate = (intent.outcome + (", then cleared" if intent.cleared else "") if intent.outcome
            else "NOT SETTLED: the robot may hold it")
    damaged = "".join(f" (UNREADABLE {why})" for why in intent.damaged)
    return f"request {intent.sequence}, x y z mm, a b c deg: {offset}; {fate}{damaged}"


def _print_resolve(outcome: dict[str, Any], truth_error: tuple[float, float] | None, row: JournalRow) -> None:
    out = stdout_console()
    stored, today, diff = outcome["stored"], outcome["today"], outcome["difference"]

    def field(result: dict[str, Any], key: str, digits: int) -> str:
        return fmt.number(result.get(key), digits) if result.get("status") == "ok" else "-"

    def state(result: dict[str, Any]) -> str:
        if result.get("status") in ("ok", "unreadable"):
            return str(result["status"])
        return str((result.get("error") or {}).get("code") or row.error_code)

    rows = [("status", state(stored), state(today), ""),
            ("rms px", field(stored, "rms_px", 3), field(today, "rms_px", 3), ""),
            ("rotation deg", field(stored, "rotation_deg", 4), field(today, "rotation_deg", 4),
             "" if diff is None else f"{diff['rotation_deg']:.4f} deg between the poses"),
            ("grasp shift mm", field(stored, "grasp_shift_mm", 3), field(today, "grasp_shift_mm", 3),
             "" if diff is None else f"{diff['grasp_point_mm']:.4f} mm at the grasp point"),
            ("σ deg / mm", f"{field(stored, 'sigma_rot_deg', 4)} / {field(stored, 'sigma_trans_mm', 3)}",
             f"{field(today, 'sigma_rot_deg', 4)} / {field(today, 'sigma_trans_mm', 3)}", ""),
            ("base offset", fmt.xyzabc(stored.get("base_offset_xyzabc")) or "-",
             fmt.xyzabc(today.get("base_offset_xyzabc")) or "-",
             "" if diff is None or diff["base_offset_mm"] is None
             else f"{diff['base_offset_deg']:.4f} deg {diff['base_offset_mm']:.4f} mm"),
            ("method", str(stored.get("method", "-")), str(today.get("method", "-")), "")]
    say(out, f"cycle {outcome['cycle']} solved again (stored {fmt.local_time(row.finished_at)})")
    for name, before, now, difference in rows:
        say(out, f"  {name:<15} stored {before:<40} today {now:<40} {difference}".rstrip())
    if truth_error is not None:
        say(out, f"  today vs the record's truth: {truth_error[0]:.4f} deg,"
                    f" {truth_error[1]:.3f} mm at the grasp point")
    if today["status"] != "ok":
        say(stderr_console(), f"{today['error']['code']} {today['error']['message']}")


def _columns(cells: list[str]) -> str:
    parts = [cell.ljust(-width) if width < 0 else cell.rjust(width) for (_, width), cell in zip(LIST_COLUMNS, cells,
                                                                                                 strict=True)]
    return "  ".join(parts).rstrip()


def _write_lines(lines: Iterator[str] | list[str]) -> None:
    for line in lines:
        sys.stdout.write(line + "\n")
    sys.stdout.flush()




