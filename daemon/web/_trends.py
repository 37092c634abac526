"""The *Trends* page's charts, drawn on the server as PNG (``daemon/figures.py``: matplotlib's Agg, no script in
the browser): the base offset x y z a b c, the quality (reprojection RMS, chi-square, predicted sigmas, cycle
time) and the errors by code over time, for the last N cycles or the last H hours."""

from __future__ import annotations

import io
from collections import Counter
from dataclasses import dataclass
from typing import Any

import numpy as np

from monoguide.daemon import figures
from monoguide.daemon.service import CycleQuery, Journal
from monoguide.daemon.web._cycles import BadQuery
from monoguide.daemon.web._rows import CycleRow, find_rows

CHARTS = ("offset", "quality", "errors")
DEFAULT_LAST, MAX_LAST = 500, 5000
SIZE_PX = (1100, 560)


@dataclass(frozen=True)
class TrendWindow:
    last: int  # at most this many of the newest cycles
    hours: float | None  # and only those of the last this many hours

    def as_query(self) -> str:
        return f"last={self.last}" + (f"&hours={self.hours:g}" if self.hours is not None else "")


def trend_window(params: dict[str, str]) -> TrendWindow:
    unknown = sorted(set(params) - {"last", "hours"})
    if unknown:
        raise BadQuery(f"unknown parameter {unknown[0]!r}; the trends take last and hours")
    last_text, hours_text = params.get("last", "").strip(), params.get("hours", "").strip()
    if last_text and (not last_text.isdigit() or not 1 <= int(last_text) <= MAX_LAST):
        raise BadQuery(f"last {last_text[:40]!r}: a whole number 1..{MAX_LAST}")
    hours = None
    if hours_text:
        try:
            hours = float(hours_text)
        except ValueError:
            hours = -1.0
        if not 0 < hours <= 24 * 366:
            raise BadQuery(f"hours {hours_text[:40]!r}: a number of hours up to a year")
    return TrendWindow(int(last_text) if last_text else DEFAULT_LAST, hours)


def trend_rows(journal: Journal, window: TrendWindow, now: float) -> tuple[list[CycleRow], list[str]]:
    """The window's cycles, oldest first (pages of the journal's query, newest down), and what of them could not be
    read."""
    since = None if window.hours is None else now - window.hours * 3600.0
    rows: list[CycleRow] = []
    notes: list[str] = []
    before = 0
    while len(rows) < window.last:
        asked = CycleQuery(finished_from=since, before=before, limit=min(500, window.last - len(rows)))
        page, missed = find_rows(journal, asked)
        rows += page
        notes += missed
        if len(page) < asked.limit or not page:
            break
        before = page[-1].number
    return rows[::-1], notes


def chart_png(name: str, rows: list[CycleRow]) -> bytes:
    """Chart ``name`` (one of :data:`CHARTS`) of ``rows`` as PNG bytes."""
    draw = {"offset": _offset, "quality": _quality, "errors": _errors}[name]
    figure = figures.new_figure(SIZE_PX)
    draw(figure, rows)
    out = io.BytesIO()
    figures.save_png(figure, out)
    return out.getvalue()


# --- private ------------------------------------------------------------------------------------


def _series(rows: list[CycleRow], pick: Any) -> tuple[np.ndarray, np.ndarray]:
    """The cycles with a value (the rows' values are finite, within ``_rows.MAX_VALUE``)."""
    x, y = [], []
    for row in rows:
        value = pick(row)
        if value is not None:
            x.append(row.number)
            y.append(float(value))
    return np.asarray(x), np.asarray(y)


@figures.draw_style
def _offset(figure: Any, rows: list[CycleRow]) -> None:
    mm, deg = figure.subplots(2, 1, sharex=True)
    for k, (axis, ax) in enumerate(zip("xyzabc", [mm] * 3 + [deg] * 3, strict=True)):
        x, y = _series(rows, lambda r, k=k: None if r.offset is None else r.offset[k])
        ax.plot(x, y, ".-", markersize=3, linewidth=0.8, color=figures.SERIES[k % 3], label=axis)
    mm.set_ylabel("x y z, mm")
    deg.set_ylabel("a b c, deg")
    deg.set_xlabel("cycle")
    mm.set_title("base offset written to the robot")
    figures.legend(mm)
    figures.legend(deg)


@figures.draw_style
def _quality(figure: Any, rows: list[CycleRow]) -> None:
    axes = figure.subplots(2, 2, sharex=True).ravel()
    panels = [
        ("reprojection RMS, px", lambda r: r.rms_px),
        ("chi-square", lambda r: r.chi2),
        ("predicted sigma, mm (grasp point) / deg x10", lambda r: r.sigma_mm),
        ("cycle time, s", lambda r: r.cycle_s),
    ]
    for k, (ax, (title, pick)) in enumerate(zip(axes, panels, strict=True)):
        x, y = _series(rows, pick)
        ax.plot(x, y, ".-", markersize=3, linewidth=0.8, color=figures.MM if k == 2 else figures.SERIES[k])
        ax.set_title(title)
    x, y = _series(rows, lambda r: None if r.sigma_deg is None else 10 * r.sigma_deg)
    axes[2].plot(x, y, ".-", markersize=3, linewidth=0.8, color=figures.DEG, label="sigma rotation x10, deg")
    axes[2].plot([], [], ".-", color=figures.MM, label="sigma position, mm")
    figures.legend(axes[2])
    for ax in axes[2:]:
        ax.set_xlabel("cycle")


@figures.draw_style
def _errors(figure: Any, rows: list[CycleRow]) -> None:
    ax = figure.subplots()
    failed = [r for r in rows if r.failed]
    ax.set_title(f"errors by code: {len(failed)} of {len(rows)} cycles")
    if not rows:
        return
    bins = np.linspace(rows[0].number, rows[-1].number + 1, min(40, len(rows)) + 1)
    codes = [code for code, _ in Counter(r.error_code or "unknown" for r in failed).most_common()]
    bottom = np.zeros(len(bins) - 1)
    for k, code in enumerate(codes):
        counts, _ = np.histogram([r.number for r in failed if (r.error_code or "unknown") == code], bins)
        ax.bar(bins[:-1], counts, width=np.diff(bins), align="edge", bottom=bottom, label=code,
               color=figures.SERIES[k % len(figures.SERIES)])
        bottom += counts
    ax.set_xlabel("cycle")
    ax.set_ylabel("failed cycles per bin")
    figures.from_zero(ax, list(bottom))
    figures.legend(ax)
