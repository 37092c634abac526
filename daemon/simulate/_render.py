"""A ``monoguide simulate`` run for people: the tables on the terminal (per cycle, the summary, the injected faults,
the targets) and the words for a summary's values that the report (``report.md``) shares."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from rich.console import Console
from rich.table import Table

from monoguide.daemon.simulate._summary import PAPER_REQUIREMENT_MM


def render(console: Console, cycles: Sequence[dict[str, Any]], summary: dict[str, Any], every_cycle: bool) -> None:
    """The human tables: per cycle (when ``every_cycle``), the summary and the targets."""
    if every_cycle:
        table = Table(title="cycles", title_justify="left")
        for name in ("cycle", "status", "code", "fault", "grasp mm", "grasp deg", "overhead ms", "cycle ms"):
            table.add_column(name, justify="right" if name not in ("status", "code", "fault") else "left")
        for c in cycles:
            table.add_row(str(c["cycle"]), c["status"], c["error_code"] or (str(c["plc_code"] or "") or ""),
                          c["fault"] or "", fixed(c["grasp_error_mm"], 4), fixed(c["grasp_error_deg"], 5),
                          fixed(c["timings_ms"].get("overhead"), 1), fixed(c["timings_ms"].get("cycle"), 0))
        console.print(table)
    table = Table(title="summary", title_justify="left", show_header=False)
    table.add_column("what")
    table.add_column("value")
    table.add_row("cycles", f"{summary['cycles']} ({summary['ok']} ok, {summary['failed']} failed)")
    table.add_row("grasp error RMS", f"{fixed(summary['grasp_rms_mm'], 4)} mm, "
                  f"{fixed(summary['grasp_rms_deg'], 5)} deg over {summary['grasped']} grasped parts")
    table.add_row("grasp error max",
                  f"{fixed(summary['grasp_max_mm'], 4)} mm, {fixed(summary['grasp_max_deg'], 5)} deg")
    per_job = summary.get("jobs") or {}
    if len(per_job) > 1:
        for job, of_job in per_job.items():
            table.add_row(f"job {job} grasp error", f"RMS {fixed(of_job['grasp_rms_mm'], 4)} mm, "
                          f"{fixed(of_job['grasp_rms_deg'], 5)} deg, max {fixed(of_job['grasp_max_mm'], 4)} mm over "
                          f"{of_job['grasped']} grasped of {of_job['cycles']}")
            table.add_row(f"job {job} grasp target", grasp_target_text({**summary, **of_job}))
    else:
        table.add_row("grasp target", grasp_target_text(summary))
    if summary.get("calibration"):
        table.add_row("calibration", calibration_text(summary["calibration"]))
    split = ", ".join(f"{k} {fixed(v, 1)}" for k, v in summary["timings_ms_median"].items() if v is not None)
    table.add_row("time split, median ms", split or "-")
    table.add_row("overhead median",
                  f"{fixed(summary['overhead_ms_median'], 1)} ms (last frame -> offset acknowledged)")
    table.add_row("compute median", f"{fixed(summary['compute_ms_median'], 1)} ms (hole finding + solve + checks)")
    table.add_row("errors by code", ", ".join(f"{k} {v}" for k, v in summary["errors"].items()) or "none")
    table.add_row("offsets written on failure", str(summary["offsets_written_on_failure"]))
    if summary.get("grasps_ran") or summary.get("grasps_refused"):
        table.add_row("grasps (robot interlock)", f"{summary['grasps_ran']} ran, {summary['grasps_refused']} refused "
                      f"({summary['grasps_refused_stale']} for a stale offset)")
    if summary["offsets_unacknowledged"]:
        table.add_row("offsets applied, not acknowledged", f"{summary['offsets_unacknowledged']} (robot no-ack fault)")
    table.add_row("service memory", f"{fixed(summary['rss_mb'], 1)} MB resident at the end "
                  f"(max {fixed(summary['rss_max_mb'], 1)} MB)")
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


def grasp_target_text(summary: dict[str, Any]) -> str:
    """The grasp target and where it comes from, in words: with a prediction, the ratio RMS / sigma and its
    bound for the run's number of grasps (docs/simulate.md, "The grasp target")."""
    limit = f"RMS <= {fixed(summary['grasp_target_mm'], 4)} mm"
    if summary.get("grasp_target_deg") is not None:
        limit += f", <= {fixed(summary['grasp_target_deg'], 5)} deg"
    predicted = (f"predicted sigma at the grasp point {fixed(summary.get('predicted_sigma_mm'), 4)} mm, "
                 f"{fixed(summary.get('predicted_sigma_deg'), 5)} deg")
    if summary.get("perfect_robot"):
        return f"{limit} (--perfect-robot; {predicted} for the pixel noise alone)"
    unseen = summary.get("unseen_repeatability_mm")
    detail = "" if unseen is None else (f" with the repeatability the robot's report does not see, "
                                        f"{fixed(unseen, 4)} mm / {fixed(summary.get('unseen_repeatability_deg'), 4)} "
                                        f"deg per axis")
    return (f"{limit} ({predicted}{detail}{ratio_text(summary.get('grasp_vs_predicted') or {})}; the paper's "
            f"requirement {PAPER_REQUIREMENT_MM:g} mm)")


def ratio_text(judged: dict[str, dict[str, Any]]) -> str:
    """``; RMS / sigma 1.06 mm, 0.94 deg, met below 1.17 / 1.19 (the 99 % bound for 30 grasps)``, or nothing."""
    if not judged:
        return ""
    ratios = ", ".join(f"{fixed(j['ratio'], 2)} {unit}" for unit, j in judged.items())
    bounds = " / ".join(fixed(j["bound_ratio"], 2) for j in judged.values())
    first = next(iter(judged.values()))
    return (f"; RMS / sigma {ratios}, met up to {bounds} (the upper {first['level']:.0%} bound for {first['n']} "
            f"grasps of the predicted error)")


def calibration_text(calibration: dict[str, Any]) -> str:
    return f"{calibration['path']} ({', '.join(calibration['values'])}); the simulated cell keeps --config's truth"


def format_limit(limit: float) -> str:
    """A target's limit: as given, a computed one (a predicted sigma) with four significant digits."""
    return str(limit) if isinstance(limit, int) or limit == round(limit, 3) else f"{limit:.4g}"


def format_value(value: float | None) -> str:
    """A target's value: counts as integers, measures with four digits."""
    if isinstance(value, int):
        return str(value)
    return fixed(value, 4)


def fixed(value: float | None, digits: int) -> str:
    """``value`` with ``digits`` decimals; ``-`` for none."""
    return "-" if value is None else f"{value:.{digits}f}"
