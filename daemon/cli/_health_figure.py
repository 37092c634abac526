"""``monoguide health --out health.png``: each part type's recent residual per view, normalised by its degrees of
freedom (1 is what the noise model predicts), against the cycle number; with reference marks, below them each
view's camera deviation from its calibrated pose (mm, deg) with its tolerance and, for a drift, its fitted trend."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from monoguide.daemon import figures
from monoguide.daemon.errors import OutputNotWritten

if TYPE_CHECKING:
    from matplotlib.axes import Axes

CHART_SIZE = (900, 420)


@figures.draw_style
def draw_health(report: dict[str, Any], path: Path) -> None:
    jobs = sorted(report["jobs"].items())
    camera = report.get("camera_deviation")
    panels = max(1, len(jobs)) + (2 if camera else 0)
    figure = figures.new_figure((CHART_SIZE[0], CHART_SIZE[1] * panels))
    axes = figure.subplots(panels, 1, squeeze=False)[:, 0]
    for ax, (job, entry) in zip(axes, jobs, strict=False):
        cycles = np.array(entry["cycles"], dtype=float)
        views = np.array(entry["per_view"], dtype=float)
        for v in range(views.shape[1] if views.ndim == 2 else 0):
            ax.plot(cycles[-len(views):], views[:, v], ".", color=figures.SERIES[v % len(figures.SERIES)],
                    label=f"view {v + 1}")
        ax.plot(cycles, entry["total"], "-", color=figures.REFERENCE, label="all views")
        ax.axhline(1.0, color=figures.BAD, linewidth=0.8, linestyle="--", label="as predicted")
        ax.set_title(f"job {job}: residual / degrees of freedom")
        ax.set_xlabel("cycle")
        figures.legend(ax)
    if not jobs:
        axes[0].set_title("no solved cycle in the journal yet")
    if camera:
        _draw_deviation(axes[-2], camera, "mm", "translation")
        _draw_deviation(axes[-1], camera, "deg", "rotation")
    try:
        figures.save_png(figure, path)
    except OSError as exc:
        raise OutputNotWritten(f"--out {path}: cannot write the figure: {exc}") from exc


def _draw_deviation(ax: Axes, camera: dict[str, Any], unit: str, kind: str) -> None:
    """Each checked view's deviation (``unit``) per cycle, its median tolerance dashed in its colour, the cycles
    beyond tolerance crossed, and a drifting view's fitted trend (the norm of its fitted line)."""
    tops = []
    for v, view in enumerate(camera["views"]):
        if not view["n"]:
            continue
        colour = figures.SERIES[v % len(figures.SERIES)]
        cycles, values = np.array(view["cycles"], dtype=float), np.array(view[unit], dtype=float)
        ax.plot(cycles, values, ".", markersize=3, color=colour, label=f"view {view['view']}")
        tops.append(float(values.max()))
        tolerance = view["tolerance"][unit]
        if tolerance is not None:
            ax.axhline(tolerance, color=colour, linewidth=1.0, linestyle="--",
                       label="tolerance (median, each view's colour)")
            tops.append(tolerance)
        beyond = values > np.array(view[f"tolerance_{unit}"], dtype=float)
        if beyond.any():
            ax.plot(cycles[beyond], values[beyond], "x", color=figures.BAD, label="beyond tolerance")
        slope = view[kind]["trend_per_1000_cycles"]
        if slope is not None and slope["significant"]:
            axes_key = "d_mm" if unit == "mm" else "w_deg"
            mean, b = np.array(view[kind]["mean"][axes_key]), np.array(slope[axes_key]) / camera["per_cycles"]
            fitted = np.linalg.norm(mean + np.outer(cycles - cycles.mean(), b), axis=1)
            ax.plot(cycles, fitted, "-", color=colour, linewidth=1.5,
                    label=f"view {view['view']} drift {slope['norm']:.3g} {unit} / 1000 cycles")
    ax.set_title(f"camera deviation from its calibrated pose ({kind}, {unit}; reference marks)")
    ax.set_xlabel("cycle")
    ax.set_ylabel(unit)
    figures.from_zero(ax, tops, headroom=1.25)
    if not tops:
        ax.set_title(f"camera deviation ({kind}): no view checked in the window (fewer than 2 marks)")
    figures.legend(ax)
