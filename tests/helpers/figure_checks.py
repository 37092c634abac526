"""What a reader of a figure relies on, read from matplotlib's own objects before the figure is saved: the
labels of its axes and their units, its colour bars and their range, its legend, its titles."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import pytest

UNIT = re.compile(r"\((?:[^()]*, )?(mm|deg|px|ms)(?:, log scale)?\)")


def unit(label: str | None) -> str | None:
    """The unit a label names in its parentheses ("grasp error (mm)", "x (part frame, mm)"), or None."""
    found = UNIT.search(label or "")
    return found.group(1) if found else None


def describe(figure: Any) -> dict[str, Any]:
    """The readable content of a matplotlib Figure, as plain data (it outlives the figure, which saving empties).

    size: (w, h) px; axes: each plotting axes (colour bars apart) with its x label (None for a twin axis, whose
    x axis is hidden), y label, whether it is drawn to scale (equal aspect), its x and y range, the labels of
    its series, its bars' heights, its lines' points by label, its tick labels and annotations; colorbars:
    (label, vmin, vmax, the values it colours) of each; legend: the entries of every legend; titles: the
    figure's and the axes' titles."""
    import numpy as np

    mappables = [m for ax in figure.axes for m in (*ax.images, *ax.collections) if getattr(m, "colorbar", None)]
    bars = {id(m.colorbar.ax) for m in mappables}
    axes = []
    for ax in figure.axes:
        if id(ax) in bars:
            continue
        axes.append({
            "x": ax.get_xlabel() if ax.xaxis.get_visible() else None,
            "y": ax.get_ylabel(),
            "equal": ax.get_aspect() == 1.0,
            "xlim": tuple(float(v) for v in ax.get_xlim()),
            "ylim": tuple(float(v) for v in ax.get_ylim()),
            "series": ax.get_legend_handles_labels()[1],
            "bars": [[float(p.get_height()) for p in c] for c in ax.containers],
            "barh": [[float(p.get_width()) for p in c] for c in ax.containers],
            "points": {line.get_label(): (np.asarray(line.get_xdata(), dtype=float),
                                          np.asarray(line.get_ydata(), dtype=float)) for line in ax.lines},
            "xticks": [t.get_text() for t in ax.get_xticklabels()],
            "yticks": [t.get_text() for t in ax.get_yticklabels()],
            "texts": [t.get_text() for t in ax.texts],
        })
    legends = [*figure.legends, *(ax.get_legend() for ax in figure.axes if ax.get_legend() is not None)]
    suptitle = figure.get_suptitle()
    return {
        "size": tuple(round(v * figure.dpi) for v in figure.get_size_inches()),
        "axes": axes,
        "colorbars": [(m.colorbar.ax.get_ylabel(), float(m.norm.vmin), float(m.norm.vmax),
                       np.array(m.get_array(), dtype=float)) for m in mappables],
        "legend": [t.get_text() for leg in legends for t in leg.get_texts()],
        "titles": [t for t in [suptitle, *(ax.get_title() for ax in figure.axes)] if t],
    }


def capture(monkeypatch: pytest.MonkeyPatch, module: Any) -> dict[str, dict[str, Any]]:
    """Record what every figure ``module`` saves through its ``save_png`` shows (by file name), just before it
    is written; the files are still written."""
    seen: dict[str, dict[str, Any]] = {}
    save = module.save_png

    def recording(figure: Any, path: Path) -> None:
        seen[Path(path).name] = describe(figure)
        save(figure, path)

    monkeypatch.setattr(module, "save_png", recording)
    return seen


def assert_readable(seen: dict[str, Any]) -> None:
    """Every axis labelled, every colour bar with a unit, a legend when more than one series is drawn, a title."""
    assert seen["titles"], "no title"
    for ax in seen["axes"]:
        assert ax["y"], f"an unlabelled y axis in {seen['titles']}"
        assert ax["x"] is None or ax["x"], f"an unlabelled x axis in {seen['titles']}"
    for label, *_ in seen["colorbars"]:
        assert unit(label), f"colour bar without a unit: {label!r}"
    series = sum(len(ax["series"]) for ax in seen["axes"])
    assert series <= 1 or seen["legend"], f"{series} series and no legend in {seen['titles']}"
