"""``monoguide health``: how well the cell's calibration still fits what the camera sees (docs/health.md).

Read-only, from the state directory: the trend monitors and the latch the service keeps
(``calibration-health.json``: each part type's CUSUM against its warning and alarm levels, the cycles since the
calibration) and the journal's recent cycles (each solved cycle's whitened residual per view, normalised by its
degrees of freedom: 1 is what the noise model predicts). Per part type and view: the recent mean and its trend
(the least-squares slope per 100 cycles); with ``--config``, the calibration's date and the days since. With
reference marks (docs/cycle-marks.md), per view the camera's deviation from its calibrated pose over the recent
cycles: its scatter (the robot's repeatability), its mean and its drift per 1,000 cycles against the tolerance, and
a verdict (``_health_marks``, ``solver.trend_pose``). ``--out health.png`` draws the normalised residual (and the
camera's deviation) over the recent cycles, ``--json`` prints one object.

Exit status: 0 healthy, 1 a warning, a latched alarm (``CALIBRATION_SUSPECT``) or a camera drifting or beyond its
tolerance, 2 bad options, no state directory or an unreadable journal.
"""

from __future__ import annotations

import json
import sys
from datetime import UTC, datetime
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer

from monoguide.daemon.cli import _health_marks
from monoguide.daemon.cli._console import stdout_console
from monoguide.daemon.cli._policy import EXIT_FAILED, EXIT_OK, EXIT_USAGE, fail
from monoguide.daemon.cli.journal import open_journal
from monoguide.daemon.config import load_cell_config
from monoguide.daemon.errors import NoJournal
from monoguide.daemon.service import HEALTH_FILE, STATE_DIR_HELP, existing_state_dir
from monoguide.daemon.service._health import request_clear
from monoguide.drivers.errors import ConfigError
from monoguide.solver.errors import MonoguideError
from monoguide.solver.trend import TrendMonitor


def health(
    state_dir: Annotated[Path | None, typer.Option("--state-dir", help=STATE_DIR_HELP)] = None,
    config: Annotated[Path | None, typer.Option("--config", "-c", help="the cell config: the calibration's date")
                      ] = None,
    last: Annotated[int, typer.Option("--last", min=2, help="the recent cycles the means and trends are of")] = 200,
    out: Annotated[Path | None, typer.Option("--out", help="draw the recent residuals (and the camera's "
                                             "deviations) into this PNG")] = None,
    json_out: Annotated[bool, typer.Option("--json", help="one JSON object on standard output")] = False,
    clear: Annotated[str | None, typer.Option("--clear", help="REASON: after inspecting the cell, clear a latched "
                                              "CALIBRATION_SUSPECT and restart the trend monitors (logged)")] = None,
) -> None:
    """The calibration's health: the trend monitors, their levels, the residual per view and its trend; with marks, the
    camera's deviation per view (its scatter, its drift)."""
    try:
        directory = existing_state_dir(state_dir)
        if clear is not None:
            try:
                path = request_clear(directory, clear)
            except (ValueError, OSError) as exc:
                raise ConfigError(f"--clear: {exc}") from exc
            stdout_console().print(f"clear requested ({path}): the service clears the latch and restarts its trend "
                                   "monitors between cycles (or at its next start); its log and the health file keep "
                                   "the reason", markup=False)
            raise typer.Exit(EXIT_OK)
        report = gather(directory, last, config)
    except MonoguideError as exc:
        fail(exc, status=EXIT_USAGE)
    if out is not None:
        from monoguide.daemon.cli._health_figure import draw_health

        draw_health(report, out)
    if json_out:
        sys.stdout.write(json.dumps(report) + "\n")
    else:
        _print(report)
    camera = report["camera_deviation"]
    raise typer.Exit(EXIT_FAILED if report["latched"] or report["warning"] or (camera and camera["warning"])
                     else EXIT_OK)


def gather(directory: Path, last: int, config: Path | None = None) -> dict[str, Any]:
    """The report: the monitors (from the service's file), per part type and view the recent residual, per view the
    camera's deviation (``camera_deviation``: None without marks)."""
    kept = _read_health(directory / HEALTH_FILE)
    rows = []
    try:
        with open_journal(directory) as journal:
            rows = journal.last_cycles(last)[::-1]
    except NoJournal:
        pass
    jobs: dict[str, dict[str, Any]] = {}
    for row in rows:
        residual = (row.result or {}).get("calibration_residual") if isinstance(row.result, dict) else None
        if row.status != "ok" or not isinstance(residual, dict):
            continue
        entry = jobs.setdefault(str(row.job), {"cycles": [], "total": [], "views": []})
        entry["cycles"].append(row.number)
        entry["total"].append(residual["chi2"] / max(residual["dof"], 1))
        per_view = [x / k if k else 0.0 for x, k in residual.get("per_view") or []]
        entry["views"].append(per_view)
    out: dict[str, Any] = {"state_dir": str(directory), "calibration": kept.get("calibration"),
                           "latched": kept.get("latched"), "cleared": kept.get("cleared"), "monitors": {}, "jobs": {}}
    for job, state in (kept.get("monitors") or {}).items():
        try:
            r = TrendMonitor.from_state(state).reading()
        except ValueError as exc:
            stdout_console().print(f"note: job {job}: the trend monitor's state is unreadable: {exc}", markup=False)
            continue
        out["monitors"][job] = {"statistic": r.statistic, "warning_level": r.warning_level, "alarm_level":
                                r.alarm_level, "cycles": r.cycles, "alarm_cycle": r.alarm_cycle, "warning": r.warning,
                                "alarm": r.alarm, "dof": state.get("dof")}
    for job, entry in jobs.items():
        views = np.array([v for v in entry["views"] if len(v) == len(entry["views"][-1])], dtype=float)
        cycles = np.array(entry["cycles"][-len(views):], dtype=float)
        out["jobs"][job] = {"cycles": entry["cycles"], "total": entry["total"],
                            "views": [_mean_and_trend(cycles, views[:, v]) for v in range(views.shape[1])]
                            if views.size else [], "per_view": views.tolist()}
    out["warning"] = bool(out["latched"]) or any(m["warning"] or m["alarm"] for m in out["monitors"].values())
    out["cycles_in_window"] = len(rows)
    out["camera_deviation"] = _health_marks.summarise(rows, last)
    if config is not None:
        cell = load_cell_config(config)
        out["reference_marks"] = len(cell.reference_marks)
        date = (cell.calibration or {}).get("date")
        out["calibration_date"] = date
        out["days_since_calibration"] = (None if date is None else
                                         (datetime.now(UTC) - datetime.fromisoformat(date)).total_seconds() / 86400)
    return out


def _mean_and_trend(cycles: np.ndarray, values: np.ndarray) -> dict[str, float | None]:
    """The mean, and the least-squares slope per 100 cycles (None with fewer than 3 cycles)."""
    slope = float(np.polyfit(cycles, values, 1)[0]) * 100.0 if len(values) >= 3 and np.ptp(cycles) > 0 else None
    return {"mean": float(values.mean()), "trend_per_100_cycles": slope, "n": len(values)}


def _read_health(path: Path) -> dict[str, Any]:
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        return {}
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        stdout_console().print(f"note: {path}: cannot read the calibration health: {exc}", markup=False)
        return {}
    return data if isinstance(data, dict) else {}


def _print(report: dict[str, Any]) -> None:
    out = stdout_console()
    lines = [f"calibration health of {report['state_dir']}"]
    if report.get("calibration_date"):
        lines.append(f"  calibrated {report['calibration_date']} ({report['days_since_calibration']:.1f} days ago)")
    latched = report["latched"]
    lines.append(f"  LATCHED {latched['code']} since cycle {latched['cycle']} ({latched['at']}): {latched['message']}"
                 if latched else "  no alarm latched")
    if not report["monitors"]:
        lines.append("  no trend monitor yet (no cycle has been solved since the calibration)")
    for job, m in sorted(report["monitors"].items()):
        state = "ALARM" if m["alarm"] else "WARNING" if m["warning"] else "ok"
        lines.append(f"  job {job}: {state}: trend statistic {m['statistic']:.2f} (warning {m['warning_level']:.2f}, "
                     f"alarm {m['alarm_level']:.2f}) over {m['cycles']} cycles since the calibration"
                     + (f", alarm at cycle {m['alarm_cycle']} of them" if m.get("alarm_cycle") else ""))
    for job, entry in sorted(report["jobs"].items()):
        lines.append(f"  job {job}: residual / its degrees of freedom over the last {len(entry['total'])} solved "
                     f"cycles (1 = as the noise model predicts): mean {np.mean(entry['total']):.2f}")
        for v, view in enumerate(entry["views"]):
            trend = view["trend_per_100_cycles"]
            lines.append(f"    view {v + 1}: mean {view['mean']:.2f}"
                         + ("" if trend is None else f", trend {trend:+.3f} per 100 cycles"))
    lines += _health_marks.lines(report["camera_deviation"], journal_empty=not report["cycles_in_window"],
                                 configured_marks=report.get("reference_marks"))
    for line in lines:
        out.print(line, markup=False, highlight=False, soft_wrap=True)
