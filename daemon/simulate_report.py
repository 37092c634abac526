"""``monoguide simulate --report DIR``: the run as Markdown (``report.md``) with three PNG plots drawn with
Pillow: the grasp error per cycle (``grasp-error.png``), the median time split of a cycle
(``time-split.png``) and the offsets written over the run (``offsets.png``, with the ideal ones)."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from PIL import Image, ImageDraw, ImageFont

from monoguide.daemon.simulate_summary import (
    TIMING_KEYS,
    calibration_text,
    format_limit,
    format_value,
    grasp_target_text,
)

SIZE = (900, 420)
MARGIN = (80, 40, 30, 60)  # left, top, right, bottom
BACKGROUND, AXIS, GRID, TEXT = (255, 255, 255), (40, 40, 40), (225, 225, 225), (20, 20, 20)
MM, DEG, BAD, IDEAL = (40, 110, 200), (230, 130, 30), (210, 40, 40), (150, 150, 150)
STAGE_COLOURS = [(40, 110, 200), (90, 170, 90), (230, 130, 30), (150, 90, 200), (200, 70, 120), (60, 170, 170),
                 (160, 160, 60), (210, 40, 40), (90, 90, 90)]

Mapping = Callable[[float, float], tuple[float, float]]


def write_report(out_dir: Path, cycles: Sequence[dict[str, Any]], summary: dict[str, Any],
                 command: str) -> list[Path]:
    """Write ``report.md`` and its plots into ``out_dir``; returns the files written."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    pictures = {
        "grasp-error.png": draw_grasp_error(cycles),
        "time-split.png": draw_time_split(summary),
        "offsets.png": draw_offsets(cycles),
    }
    written = []
    for name, picture in pictures.items():
        picture.save(out_dir / name)
        written.append(out_dir / name)
    (out_dir / "report.md").write_text(markdown(cycles, summary, command, list(pictures)))
    return [out_dir / "report.md", *written]


def markdown(cycles: Sequence[dict[str, Any]], summary: dict[str, Any], command: str, pictures: list[str]) -> str:
    lines = ["# monoguide simulate", "", f"`{command}`", "", "## Summary", "", "| | |", "|---|---|",
             f"| cycles | {summary['cycles']} ({summary['ok']} ok, {summary['failed']} failed) |",
             f"| grasp error RMS | {_f(summary['grasp_rms_mm'], 4)} mm, {_f(summary['grasp_rms_deg'], 5)} deg "
             f"({summary['grasped']} grasped parts, from the truth log) |",
             f"| grasp error max | {_f(summary['grasp_max_mm'], 4)} mm, {_f(summary['grasp_max_deg'], 5)} deg |",
             f"| grasp target | {grasp_target_text(summary)} |",
             *([f"| calibration | {calibration_text(summary['calibration'])} |"] if summary.get("calibration") else []),
             f"| overhead median | {_f(summary['overhead_ms_median'], 1)} ms (last frame in hand to offset "
             f"acknowledged) |",
             f"| compute median | {_f(summary['compute_ms_median'], 1)} ms (hole finding + solve + checks) |",
             f"| cycle median | {_f(summary['cycle_ms_median'], 0)} ms (trigger to DONE) |",
             f"| errors by code | {', '.join(f'{k} {v}' for k, v in summary['errors'].items()) or 'none'} |",
             f"| offsets written on failure | {summary['offsets_written_on_failure']} |",
             f"| service memory at the end | {_f(summary['rss_mb'], 1)} MB (max {_f(summary['rss_max_mb'], 1)} MB) |",
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
    lines += ["", "## Plots", ""] + [f"![{name}]({name})" for name in pictures]
    lines += ["", "## Time split, median over the good cycles (ms)", "", "| stage | ms |", "|---|---|"]
    lines += [f"| {k} | {_f(v, 2)} |" for k, v in summary["timings_ms_median"].items()]
    lines += ["", "## Cycles", "", "| cycle | status | code | fault | grasp mm | grasp deg | overhead ms | cycle ms |",
              "|---|---|---|---|---|---|---|---|"]
    lines += [f"| {c['cycle']} | {c['status']} | {c['error_code'] or ''} | {c['fault'] or ''} | "
              f"{_f(c['grasp_error_mm'], 4)} | {_f(c['grasp_error_deg'], 5)} | "
              f"{_f(c['timings_ms'].get('overhead'), 1)} | {_f(c['timings_ms'].get('cycle'), 0)} |" for c in cycles]
    return "\n".join(lines) + "\n"


def draw_grasp_error(cycles: Sequence[dict[str, Any]]) -> Image.Image:
    """Grasp error per cycle: mm (bars, left) and deg (dots, right scale); failed cycles marked red."""
    image, draw = _canvas("grasp error per cycle (truth log): mm bars, deg dots (right scale); red x: failed cycle")
    n = max(len(cycles), 1)
    mm = [c["grasp_error_mm"] for c in cycles]
    deg = [c["grasp_error_deg"] for c in cycles]
    top_mm = nice_top(max([v for v in mm if v is not None], default=0.0))
    top_deg = nice_top(max([v for v in deg if v is not None], default=0.0))
    to_px = _axes(draw, (0.5, n + 0.5), (0.0, top_mm), "cycle", "mm", integer_x=True)
    right = _right_scale(draw, top_deg, "deg")
    width = max(2.0, 0.6 * (SIZE[0] - MARGIN[0] - MARGIN[2]) / n)
    for c, v_mm, v_deg in zip(cycles, mm, deg, strict=True):
        x, y0 = to_px(c["cycle"], 0.0)
        if c["status"] != "ok":
            _cross(draw, (x, y0 - 8), BAD)
            continue
        if v_mm is not None:
            draw.rectangle([x - width / 2, to_px(c["cycle"], v_mm)[1], x + width / 2, y0], fill=MM)
        if v_deg is not None:
            y = right(v_deg)
            draw.ellipse([x - 3, y - 3, x + 3, y + 3], fill=DEG)
    return image


def draw_time_split(summary: dict[str, Any]) -> Image.Image:
    """Median milliseconds per stage over the good cycles, one horizontal bar each."""
    image, draw = _canvas("time split, median over the good cycles (ms); stages overlap (hole finding runs "
                          "during motion)")
    stages = [(k, summary["timings_ms_median"].get(k)) for k in TIMING_KEYS]
    top = nice_top(max([v for _, v in stages if v is not None], default=0.0))
    left, upper, right, lower = MARGIN[0] + 40, MARGIN[1], SIZE[0] - MARGIN[2] - 60, SIZE[1] - MARGIN[3]
    step = (lower - upper) / len(stages)
    font = _font()
    for i, ((name, value), colour) in enumerate(zip(stages, STAGE_COLOURS, strict=True)):
        y = upper + i * step
        draw.text((8, y + step / 2 - 6), name, fill=TEXT, font=font)
        if value is not None:
            x = left + (right - left) * value / top
            draw.rectangle([left, y + 0.2 * step, x, y + 0.8 * step], fill=colour)
            draw.text((x + 4, y + step / 2 - 6), f"{value:.1f}", fill=TEXT, font=font)
        else:
            draw.text((left + 4, y + step / 2 - 6), "(not measured)", fill=IDEAL, font=font)
    draw.line([left, upper, left, lower], fill=AXIS)
    draw.text((left, lower + 8), f"0 .. {top:g} ms", fill=TEXT, font=font)
    return image


def draw_offsets(cycles: Sequence[dict[str, Any]]) -> Image.Image:
    """The offsets written (dots) and the ideal ones (grey rings) of the grasped parts: x-y in mm, A-B in deg."""
    image = Image.new("RGB", SIZE, BACKGROUND)
    draw = ImageDraw.Draw(image)
    font = _font()
    draw.text((MARGIN[0], 12), "offsets over the run: written (dots), ideal (grey rings), robot base frame",
              fill=TEXT, font=font)
    half = SIZE[0] // 2
    for k, (i, j, unit, label) in enumerate(((0, 1, "mm", "x / y"), (3, 4, "deg", "A / B"))):
        written = [(c["offset_written"][i], c["offset_written"][j]) for c in cycles if c["offset_written"]]
        ideal = [(c["offset_ideal"][i], c["offset_ideal"][j]) for c in cycles if c["offset_ideal"]]
        every = written + ideal or [(0.0, 0.0)]
        span = max(max(abs(a), abs(b)) for a, b in every)
        top = nice_top(span)
        box = (k * half + 60, 40, (k + 1) * half - 20, SIZE[1] - 50)
        to_px = _axes_in(draw, box, (-top, top), (-top, top), f"{label} ({unit})")
        for a, b in ideal:
            x, y = to_px(a, b)
            draw.ellipse([x - 6, y - 6, x + 6, y + 6], outline=IDEAL, width=2)
        for a, b in written:
            x, y = to_px(a, b)
            draw.ellipse([x - 3, y - 3, x + 3, y + 3], fill=MM if unit == "mm" else DEG)
    return image


# --- private ------------------------------------------------------------------------------------


def _font() -> ImageFont.ImageFont | ImageFont.FreeTypeFont:
    return ImageFont.load_default()


def _canvas(title: str) -> tuple[Image.Image, ImageDraw.ImageDraw]:
    image = Image.new("RGB", SIZE, BACKGROUND)
    draw = ImageDraw.Draw(image)
    draw.text((MARGIN[0], 12), title, fill=TEXT, font=_font())
    return image, draw


def _axes(draw: ImageDraw.ImageDraw, x_range: tuple[float, float], y_range: tuple[float, float], x_label: str,
          y_label: str, integer_x: bool = False) -> Mapping:
    box = (MARGIN[0], MARGIN[1], SIZE[0] - MARGIN[2] - 50, SIZE[1] - MARGIN[3])
    to_px = _mapping(box, x_range, y_range)
    font = _font()
    for k in range(5):
        v = y_range[0] + (y_range[1] - y_range[0]) * k / 4
        _, y = to_px(x_range[0], v)
        draw.line([box[0], y, box[2], y], fill=GRID)
        draw.text((8, y - 6), f"{v:.4g}", fill=TEXT, font=font)
    draw.rectangle(box, outline=AXIS)
    first, last = math.ceil(x_range[0]), math.floor(x_range[1])
    every = max(1, (last - first + 1) // 12) if integer_x else 1
    for v in range(first, last + 1, every):
        x, _ = to_px(v, y_range[0])
        draw.text((x - 6, box[3] + 6), str(v), fill=TEXT, font=font)
    draw.text(((box[0] + box[2]) / 2 - 20, box[3] + 26), x_label, fill=TEXT, font=font)
    draw.text((8, box[1] - 22), y_label, fill=TEXT, font=font)
    return to_px


def _right_scale(draw: ImageDraw.ImageDraw, top: float, label: str) -> Callable[[float], float]:
    box = (MARGIN[0], MARGIN[1], SIZE[0] - MARGIN[2] - 50, SIZE[1] - MARGIN[3])
    font = _font()
    for k in range(5):
        v = top * k / 4
        y = box[3] - (box[3] - box[1]) * k / 4
        draw.text((box[2] + 6, y - 6), f"{v:.3g}", fill=DEG, font=font)
    draw.text((box[2] + 6, box[1] - 22), label, fill=DEG, font=font)
    return lambda v: box[3] - (box[3] - box[1]) * v / top


def _axes_in(draw: ImageDraw.ImageDraw, box: tuple[float, float, float, float], x_range: tuple[float, float],
             y_range: tuple[float, float], label: str) -> Mapping:
    to_px = _mapping(box, x_range, y_range)
    font = _font()
    draw.rectangle(box, outline=AXIS)
    x0, y0 = to_px(0.0, 0.0)
    draw.line([box[0], y0, box[2], y0], fill=GRID)
    draw.line([x0, box[1], x0, box[3]], fill=GRID)
    draw.text((box[0], box[3] + 6), f"{x_range[0]:g}", fill=TEXT, font=font)
    draw.text((box[2] - 30, box[3] + 6), f"{x_range[1]:g}", fill=TEXT, font=font)
    draw.text((box[0] - 50, box[1]), f"{y_range[1]:g}", fill=TEXT, font=font)
    draw.text(((box[0] + box[2]) / 2 - 20, box[3] + 24), label, fill=TEXT, font=font)
    return to_px


def _mapping(box: tuple[float, float, float, float], x_range: tuple[float, float],
             y_range: tuple[float, float]) -> Mapping:
    (x0, x1), (y0, y1) = x_range, y_range
    sx = (box[2] - box[0]) / ((x1 - x0) or 1.0)
    sy = (box[3] - box[1]) / ((y1 - y0) or 1.0)
    return lambda x, y: (box[0] + (x - x0) * sx, box[3] - (y - y0) * sy)


def _cross(draw: ImageDraw.ImageDraw, at: tuple[float, float], colour: tuple[int, int, int]) -> None:
    x, y = at
    draw.line([x - 5, y - 5, x + 5, y + 5], fill=colour, width=2)
    draw.line([x - 5, y + 5, x + 5, y - 5], fill=colour, width=2)


def nice_top(value: float) -> float:
    """The smallest of 1, 2, 2.5, 5 x 10^k at or above ``value`` (1 for nothing to show)."""
    if not value or value <= 0 or not math.isfinite(value):
        return 1.0
    power = 10.0 ** math.floor(math.log10(value))
    for step in (1.0, 2.0, 2.5, 5.0, 10.0):
        if value <= step * power * (1 + 1e-9):
            return step * power
    return 10.0 * power


def _f(value: float | None, digits: int) -> str:
    return "-" if value is None else f"{value:.{digits}f}"
