"""``monoguide simulate --report DIR``: the run as Markdown (``report.md``) with three PNG plots drawn with
matplotlib (``daemon/figures.py``): the grasp error per cycle (``grasp-error.png``), the median time split of
a cycle (``time-split.png``) and the offsets written over the run (``offsets.png``, with the ideal ones)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from monoguide.daemon.figures import (
    BAD,
    DEG,
    MM,
    REFERENCE,
    SERIES,
    draw_style,
    from_zero,
    legend,
    new_figure,
    save_png,
)
from monoguide.daemon.simulate._render import calibration_text, fixed, format_limit, format_value, grasp_target_text
from monoguide.daemon.simulate._summary import TIMING_KEYS

if TYPE_CHECKING:
    from matplotlib.figure import Figure

SIZE = (900, 420)  # width, height px of every plot


def write_report(out_dir: Path, cycles: Sequence[dict[str, Any]], summary: dict[str, Any],
                 command: str) -> list[Path]:
    """Write ``report.md`` and its plots into ``out_dir``; returns the files written."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    pictures = {
        "grasp-error.png": lambda: draw_grasp_error(cycles),
        "time-split.png": lambda: draw_time_split(summary),
        "offsets.png": lambda: draw_offsets(cycles),
    }
    written = []
    for name, draw in pictures.items():
        save_png(draw(), out_dir / name)  # one figure at a time: drawn, written, released
        written.append(out_dir / name)
    (out_dir / "report.md").write_text(markdown(cycles, summary, command, list(pictures)))
    return [out_dir / "report.md", *written]


def markdown(cycles: Sequence[dict[str, Any]], summary: dict[str, Any], command: str, pictures: list[str]) -> str:
    lines = ["# monoguide simulate", "", f"`{command}`", "", "## Summary", "", "| | |", "|---|---|",
             f"| cycles | {summary['cycles']} ({summary['ok']} ok, {summary['failed']} failed) |",
             f"| grasp error RMS | {fixed(summary['grasp_rms_mm'], 4)} mm, {fixed(summary['grasp_rms_deg'], 5)} deg "
             f"({summary['grasped']} grasped parts, from the truth log) |",
             f"| grasp error max | {fixed(summary['grasp_max_mm'], 4)} mm, {fixed(summary['grasp_max_deg'], 5)} deg |",
             f"| grasp target | {grasp_target_text(summary)} |",
             *([f"| calibration | {calibration_text(summary['calibration'])} |"] if summary.get("calibration") else []),
             f"| overhead median | {fixed(summary['overhead_ms_median'], 1)} ms (last frame in hand to offset "
             f"acknowledged) |",
             f"| compute median | {fixed(summary['compute_ms_median'], 1)} ms (hole finding + solve + checks) |",
             f"| cycle median | {fixed(summary['cycle_ms_median'], 0)} ms (trigger to DONE) |",
             f"| errors by code | {', '.join(f'{k} {v}' for k, v in summary['errors'].items()) or 'none'} |",
             f"| offsets written on failure | {summary['offsets_written_on_failure']} |",
             f"| service memory at the end | {fixed(summary['rss_mb'], 1)} MB "
             f"(max {fixed(summary['rss_max_mb'], 1)} MB) |",
             "", "## Targets", "", "| target | value | limit | met |", "|---|---|---|---|"]
    lines += [f"| {t['name']} | {format_value(t['value'])} | {format_limit(t['limit'])} | "
              f"{'yes' if t['met'] else '**no**'} |"
              for t in summary["targets"]]
    if summary["faults"]:
        lines += ["", "## Injected faults", "", "| cycle | fault | expected | got | reported | READY after |",
                  "|---|---|---|---|---|---|"]
        lines += [f"| {f['cycle']} | {f['fault']} | {' / '.join(f['expected'])} | {f['got'] or '-'} | "
                  f"{'yes' if f['reported'] else '**no**'} | {'yes' if f['back_ready'] else '**no**'} |"
                  for f in summary["faults"]]
    if calibration := [f for f in summary["faults"] if f.get("calibration")]:
        lines += ["", "## Calibration faults", "", "Each stays for its cycles, then is cleared; a cycle under one "
                  "may be OK: the grasp error (truth log) says what that cost.", "",
                  "| cycles | fault | ok | refused (codes) | grasp RMS / max of the ok, mm | ok beyond 0.5 mm |",
                  "|---|---|---|---|---|---|"]
        lines += [f"| {_span(f['cycles'])} | {f['fault']} | {f['ok']} of {len(f['cycles'])} | "
                  f"{sum(f['refused'].values())} ({', '.join(f'{k} {v}' for k, v in f['refused'].items()) or '-'}) | "
                  f"{fixed(f['grasp_rms_mm'], 3)} / {fixed(f['grasp_max_mm'], 3)} | {f['ok_beyond_requirement']} |"
                  for f in calibration]
    lines += ["", "## Plots", ""] + [f"![{name}]({name})" for name in pictures]
    lines += ["", "## Time split, median over the good cycles (ms)", "", "| stage | ms |", "|---|---|"]
    lines += [f"| {k} | {fixed(v, 2)} |" for k, v in summary["timings_ms_median"].items()]
    lines += ["", "## Cycles", "", "| cycle | status | code | fault | grasp mm | grasp deg | overhead ms | cycle ms |",
              "|---|---|---|---|---|---|---|---|"]
    lines += [f"| {c['cycle']} | {c['status']} | {c['error_code'] or ''} | {c['fault'] or ''} | "
              f"{fixed(c['grasp_error_mm'], 4)} | {fixed(c['grasp_error_deg'], 5)} | "
              f"{fixed(c['timings_ms'].get('overhead'), 1)} | {fixed(c['timings_ms'].get('cycle'), 0)} |"
              for c in cycles]
    return "\n".join(lines) + "\n"


@draw_style
def draw_grasp_error(cycles: Sequence[dict[str, Any]]) -> Figure:
    """Grasp error per cycle from the truth log: mm at the TCP (bars, left axis) and deg (dots, right axis);
    failed cycles marked with a red x."""
    figure = new_figure(SIZE)
    ax = figure.add_subplot()
    right = ax.twinx()
    right.grid(False)
    good = [c for c in cycles if c["status"] == "ok"]
    mm = [(c["cycle"], c["grasp_error_mm"]) for c in good if c["grasp_error_mm"] is not None]
    deg = [(c["cycle"], c["grasp_error_deg"]) for c in good if c["grasp_error_deg"] is not None]
    failed = [c["cycle"] for c in cycles if c["status"] != "ok"]
    if mm:
        ax.bar(*zip(*mm, strict=True), width=0.6, color=MM, label="grasp error (mm, left)")
    if deg:
        right.plot(*zip(*deg, strict=True), "o", color=DEG, markersize=5, label="grasp error (deg, right)")
    if failed:
        ax.plot(failed, [0.0] * len(failed), "x", color=BAD, markersize=9, markeredgewidth=2, clip_on=False,
                label="failed cycle (no grasp)")
    ax.set_xlabel("cycle (part played by the line)")
    ax.set_ylabel("grasp error at the TCP (mm)")
    right.set_ylabel("grasp error, rotation (deg)", color=DEG)
    right.tick_params(axis="y", colors=DEG)
    ax.xaxis.get_major_locator().set_params(integer=True)
    if cycles:
        ax.set_xlim(min(c["cycle"] for c in cycles) - 0.6, max(c["cycle"] for c in cycles) + 0.6)
    from_zero(ax, [v for _, v in mm])
    from_zero(right, [v for _, v in deg])
    ax.set_title("Grasp error per cycle against the simulated truth (the taught grasp after the written offset)")
    legend(ax, right)
    return figure


@draw_style
def draw_time_split(summary: dict[str, Any]) -> Figure:
    """Median milliseconds per stage of a cycle over the good cycles, one horizontal bar each."""
    figure = new_figure(SIZE)
    ax = figure.add_subplot()
    stages = [(k, summary["timings_ms_median"].get(k)) for k in TIMING_KEYS]
    y = np.arange(len(stages))
    values = [v if v is not None else 0.0 for _, v in stages]
    bars = ax.barh(y, values, height=0.6, color=[SERIES[i % len(SERIES)] for i in range(len(stages))])
    ax.bar_label(bars, labels=[f"{v:.1f}" if v is not None else "(not measured)" for _, v in stages], padding=3)
    ax.set_yticks(y, [name for name, _ in stages])
    ax.invert_yaxis()  # the cycle's order, top to bottom
    ax.set_xlim(0.0, 1.15 * max(values) if max(values) > 0 else 1.0)  # room for the value beside the longest
    ax.set_xlabel("median time per cycle (ms)")
    ax.set_ylabel("stage of the cycle")
    ax.set_title("Time split of a cycle, median over the good cycles (stages overlap: hole finding runs during "
                 "motion)")
    return figure


@draw_style
def draw_offsets(cycles: Sequence[dict[str, Any]]) -> Figure:
    """The base offsets written (dots) and the ideal ones (rings) of the grasped parts, robot base frame:
    x-y in mm (left), A-B in deg (right)."""
    figure = new_figure(SIZE)
    axes = figure.subplots(1, 2)
    for ax, (i, j, unit, colour) in zip(axes, ((0, 1, "mm", MM), (3, 4, "deg", DEG)), strict=True):
        names = ("x", "y") if unit == "mm" else ("A", "B")
        written = np.array([(c["offset_written"][i], c["offset_written"][j]) for c in cycles
                            if c["offset_written"]]).reshape(-1, 2)
        ideal = np.array([(c["offset_ideal"][i], c["offset_ideal"][j]) for c in cycles
                          if c["offset_ideal"]]).reshape(-1, 2)
        ax.plot(ideal[:, 0], ideal[:, 1], "o", markersize=10, markerfacecolor="none", markeredgecolor=REFERENCE,
                markeredgewidth=1.5, label="ideal (truth log)")
        ax.plot(written[:, 0], written[:, 1], "o", markersize=4, color=colour, label="written by the service")
        every = np.vstack([written, ideal])
        span = float(np.abs(every).max()) * 1.1 if every.size and np.abs(every).max() > 0 else 1.0
        ax.set_xlim(-span, span)
        ax.set_ylim(-span, span)
        ax.set_aspect("equal")
        ax.axhline(0.0, color="0.75", linewidth=0.8)
        ax.axvline(0.0, color="0.75", linewidth=0.8)
        ax.set_xlabel(f"offset {names[0]} ({unit})")
        ax.set_ylabel(f"offset {names[1]} ({unit})")
        ax.set_title(f"{names[0]} / {names[1]} ({unit})")
        ax.legend(loc="upper right")
    figure.suptitle("Base offsets over the run, robot base frame: written against ideal")
    return figure


def _span(cycles: list[int]) -> str:
    return "-" if not cycles else str(cycles[0]) if len(cycles) == 1 else f"{cycles[0]}–{cycles[-1]}"
