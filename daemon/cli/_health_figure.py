"""``monoguide health --out health.png``: each part type's recent residual per view, normalised by its degrees of
freedom (1 is what the noise model predicts), against the cycle number."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from monoguide.daemon import figures
from monoguide.daemon.errors import OutputNotWritten

CHART_SIZE = (900, 420)


@figures.draw_style
def draw_health(report: dict[str, Any], path: Path) -> None:
    jobs = sorted(report["jobs"].items())
    figure = figures.new_figure((CHART_SIZE[0], CHART_SIZE[1] * max(1, len(jobs))))
    axes = figure.subplots(max(1, len(jobs)), 1, squeeze=False)[:, 0]
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
    try:
        figures.save_png(figure, path)
    except OSError as exc:
        raise OutputNotWritten(f"--out {path}: cannot write the figure: {exc}") from exc
