"""``monoguide status``: what the service is doing, read from its state directory (docs/status.md).

The service's status file (``status.json``: state, devices, last result) says what it does; the journal
says what it did. Neither is trusted blindly: a status file whose pid is gone or which has not been
rewritten for a few heartbeats is reported as "no service running".
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path
from typing import Annotated, Any

import typer

from monoguide.daemon.cli import _format as fmt
from monoguide.daemon.cli._console import stdout_console
from monoguide.daemon.cli._policy import EXIT_NOT_RUNNING, fail, reporting_errors
from monoguide.daemon.cli.journal import JsonOption, StateDirOption, cycle_summary, open_journal, print_cycle_lines
from monoguide.daemon.service import JOURNAL_FILE, JournalRow, ServiceStatus, existing_state_dir, liveness, read_status
from monoguide.solver.errors import MonoguideError


def status(
    state_dir: StateDirOption = None,
    last: Annotated[int, typer.Option("--last", help="How many of the newest cycles to show.", min=0)] = 5,
    json_output: JsonOption = False,
) -> None:
    """Show what the service is doing (state, devices, last result) and its last cycles.

    Exit status: 0 the service runs, 3 no service running, 1 the state directory, status file or journal
    cannot be read (the error on standard error)."""
    report: dict[str, Any] = {}
    reporting_errors(lambda: report.update(_gather(existing_state_dir(state_dir), last)))
    if json_output:
        sys.stdout.write(json.dumps(_as_json(report)) + "\n")
    else:
        _print_report(report)
    if report["journal_error"] is not None:
        fail(report["journal_error"])
    if not report["liveness"].running:
        raise typer.Exit(EXIT_NOT_RUNNING)


def _gather(directory: Path, last: int) -> dict[str, Any]:
    service = read_status(directory)
    rows: list[JournalRow] = []
    counter, journal_error = None, None
    if (directory / JOURNAL_FILE).is_file():
        try:
            with open_journal(directory) as journal:
                counter, rows = journal.cycle_counter(), journal.last_cycles(last)[::-1]
        except MonoguideError as error:  # the service part is still worth showing
            journal_error = error
    return {"state_dir": directory, "service": service, "liveness": liveness(service), "counter": counter,
            "rows": rows, "journal_error": journal_error}


def _as_json(report: dict[str, Any]) -> dict[str, Any]:
    service: ServiceStatus | None = report["service"]
    error = report["journal_error"]
    return {
        "state_dir": str(report["state_dir"]),
        "service": {"running": report["liveness"].running, "reason": report["liveness"].reason,
                    "status": None if service is None else service.as_dict()},
        "journal": {"present": report["counter"] is not None, "cycle_counter": report["counter"],
                    "last_cycles": [cycle_summary(row) for row in report["rows"]],
                    "error": None if error is None else error.as_dict()},
    }


def _last_result(result: dict[str, Any]) -> str:
    """``cycle 12 ok, job 1, part roof, part tag 7, finished 14:02:31`` (the error code only when there is one)."""
    words = [f"cycle {result.get('cycle')} {result.get('status')}"]
    if result.get("error_code"):
        words[0] += f" {result['error_code']}"
    words += [f"{key.replace('_', ' ')} {result[key]}" for key in ("job", "part", "part_tag")
              if result.get(key) is not None]
    if isinstance(result.get("finished_at"), int | float):
        words.append(f"finished {fmt.local_time(result['finished_at'])}")
    return ", ".join(words)


def _print_report(report: dict[str, Any]) -> None:
    out = stdout_console()
    service: ServiceStatus | None = report["service"]
    lines = [f"service: {report['liveness'].reason}"]
    if service is not None:
        now = time.time()
        word = "state" if report["liveness"].running else "last state"
        lines.append(f"  {word}: {service.state} since {fmt.local_time(service.since)} ({now - service.since:.0f} s),"
                     f" status written {now - service.updated_at:.1f} s ago")
        if service.fault:
            lines.append(f"  FAULT: {service.fault.get('code')} ({service.fault.get('plc_code')}): "
                         f"{service.fault.get('message')}")
        for name, device in service.devices.items():
            error = device.last_error
            trouble = "" if not error else f", last error {error.get('code')}: {error.get('message')}"
            lines.append(f"  {name}: {'connected' if device.connected else 'NOT connected'}{trouble}")
        if service.last_result:
            lines.append("  last result: " + _last_result(service.last_result))
        if (health := service.calibration_health) and (health.get("latched") or health.get("warning")):
            latched = health.get("latched")
            lines.append(f"  calibration: {latched['code']} latched since cycle {latched['cycle']}: "
                         f"{latched['message']}" if latched else "  calibration: CALIBRATION_WARNING (the residual's "
                         "trend is above its warning level: monoguide health)")
    if report["counter"] is not None:
        lines.append(f"journal: {report['counter']} cycles in {report['state_dir'] / JOURNAL_FILE}")
    elif report["journal_error"] is None:
        lines.append(f"journal: no journal in {report['state_dir']} (no cycle has finished there)")
    for line in lines:
        out.print(line, markup=False, highlight=False, soft_wrap=True)
    if report["rows"]:
        print_cycle_lines(report["rows"])
