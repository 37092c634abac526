"""The figures monoguide draws (the ``simulate`` and calibration reports, the ``plan`` drawings): one style,
matplotlib's Agg canvas without pyplot, PNG out.

matplotlib is imported only inside these functions, when a figure is drawn: commands that draw nothing
(``--version``, ``status``, ``run``) never load it. A figure is a :class:`matplotlib.figure.Figure` on its own
``FigureCanvasAgg`` (no display, no pyplot state, nothing kept after it is saved). Text is set in the DejaVu
Sans that matplotlib ships, whatever font a machine's ``matplotlibrc`` names, and nothing varies from run to
run (no time, no version written in): the same input gives the same PNG.
"""

from __future__ import annotations

import contextlib
import functools
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, BinaryIO, ParamSpec, TypeVar

import numpy as np

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

DPI = 100  # pixels per inch: a figure of (w, h) px is (w / DPI, h / DPI) inches
MM, DEG, BAD, REFERENCE = "tab:blue", "tab:orange", "tab:red", "0.45"  # the series' colours, everywhere alike
SERIES = ("tab:blue", "tab:green", "tab:orange", "tab:purple", "tab:cyan", "tab:pink", "tab:olive", "tab:red",
          "tab:brown", "tab:gray")
STYLE = {
    "font.family": "DejaVu Sans",  # shipped with matplotlib: the same font on every machine
    "mathtext.fontset": "dejavusans",
    "font.size": 9.0,
    "axes.titlesize": 10.0,
    "axes.labelsize": 9.0,
    "figure.titlesize": 11.0,
    "legend.fontsize": 8.0,
    "axes.grid": True,
    "grid.color": "0.88",
    "axes.axisbelow": True,
    "legend.framealpha": 0.85,
}

P = ParamSpec("P")
R = TypeVar("R")


def draw_style(draw: Callable[P, R]) -> Callable[P, R]:
    """Run ``draw`` in the figures' style: matplotlib's own defaults plus :data:`STYLE`, whatever a
    ``matplotlibrc`` on the machine says, restored afterwards."""

    @functools.wraps(draw)
    def styled(*args: P.args, **kwargs: P.kwargs) -> R:
        with _style():
            return draw(*args, **kwargs)

    return styled


def new_figure(size_px: tuple[int, int]) -> Figure:
    """An empty figure of ``size_px`` (width, height) pixels at :data:`DPI`, on an Agg canvas, laid out by
    matplotlib's constrained layout (labels, legends and colour bars never cut)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    figure = Figure(figsize=(size_px[0] / DPI, size_px[1] / DPI), dpi=DPI, layout="constrained")
    FigureCanvasAgg(figure)
    return figure


def save_png(figure: Figure, path: Path | BinaryIO) -> None:
    """Write ``figure`` to ``path`` as a PNG of exactly its pixel size, then release what it holds (the
    figure is empty afterwards). Raises OSError when the file cannot be written."""
    try:
        with _style():
            figure.savefig(path, format="png", dpi=DPI, metadata={"Software": None})
    finally:
        figure.clear()


def bar_chart(ax: Axes, labels: Sequence[str], values: Sequence[float], *, label: str, colour: str = MM,
              value_texts: Sequence[str] | None = None, reference: float | None = None,
              reference_label: str = "") -> None:
    """One bar per label (NaN: no bar), its value written above it when there are few bars (or
    ``value_texts`` instead), a dashed horizontal ``reference`` line; the axis from 0 (:func:`from_zero`)."""
    x = np.arange(len(values))
    heights = np.asarray(values, dtype=float).reshape(-1)
    bars = ax.bar(x, np.where(np.isfinite(heights), heights, 0.0), width=0.7, color=colour, label=label)
    texts = value_texts if value_texts is not None else (
        [f"{v:.3g}" if np.isfinite(v) else "" for v in heights] if len(heights) <= 12 else None)
    if texts is not None:
        ax.bar_label(bars, labels=list(texts), padding=2, fontsize=7)
    ax.set_xticks(x, list(labels))
    width_px = ax.figure.get_figwidth() * DPI * ax.get_position().width
    if labels and max(map(len, labels)) * 6.5 > 0.9 * width_px / len(labels):  # they would run into each other
        ax.tick_params(axis="x", labelrotation=30)
        for tick in ax.get_xticklabels():
            tick.set_horizontalalignment("right")
    ax.set_xlim(-0.6, max(len(values), 1) - 0.4)
    finite = [float(v) for v in heights if np.isfinite(v)]
    if reference is not None and np.isfinite(reference):
        ax.axhline(float(reference), color=REFERENCE, linewidth=1.5, linestyle="--", label=reference_label)
        finite.append(float(reference))
    from_zero(ax, finite)


def from_zero(ax: Axes, values: Sequence[float], headroom: float = 1.35) -> None:
    """The y axis from 0 to ``headroom`` times the largest of ``values`` (1 for nothing to show), leaving the
    top of the axes to the legend and the values written above the bars."""
    top = max((float(v) for v in values if np.isfinite(v)), default=0.0)
    ax.set_ylim(0.0, top * headroom if top > 0 else 1.0)


def legend(*axes: Axes, loc: str = "upper right") -> None:
    """One legend on the first of ``axes`` with the labelled series of all of them (a twin axis' dots beside
    the bars)."""
    handles, labels = _series(axes)
    if handles:
        axes[0].legend(handles, labels, loc=loc)


def figure_legend(figure: Figure, *axes: Axes, columns: int = 4) -> None:
    """One legend below the panels of ``figure`` for the series of ``axes`` (each label once: the panels of a
    drawing show the same things from two sides)."""
    handles, labels = _series(axes)
    if handles:
        figure.legend(handles, labels, loc="outside lower center", ncols=min(columns, len(handles)))


def label_points(ax: Axes, names: Sequence[str], xy: np.ndarray, colour: str, span: float) -> None:
    """Write each name beside its point ``xy`` (n, 2); points closer than 2 % of ``span`` (data units) share
    one label ("P1, P4": from the side, holes that differ only in y fall on one another)."""
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    groups: list[tuple[np.ndarray, list[str]]] = []
    for name, p in zip(names, xy, strict=True):
        near = next((g for g in groups if np.hypot(*(g[0] - p)) <= 0.02 * max(span, 1e-9)), None)
        if near is None:
            groups.append((p, [str(name)]))
        else:
            near[1].append(str(name))
    for p, group in groups:
        ax.annotate(", ".join(group), (float(p[0]), float(p[1])), xytext=(6, 6), textcoords="offset points",
                    color=colour, fontsize=8)


def outline(xy: np.ndarray) -> np.ndarray:
    """The convex hull (monotone chain) of points ``xy`` (n, 2), counter-clockwise, (m, 2): the part's outline
    through its holes."""
    pts = sorted(map(tuple, np.round(np.asarray(xy, dtype=float), 9)))
    if len(pts) < 3:
        return np.array(pts, dtype=float).reshape(-1, 2)

    def cross(o: tuple, a: tuple, b: tuple) -> float:
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    lower: list[tuple] = []
    upper: list[tuple] = []
    for p in pts:
        while len(lower) >= 2 and cross(lower[-2], lower[-1], p) <= 0:
            lower.pop()
        lower.append(p)
    for p in reversed(pts):
        while len(upper) >= 2 and cross(upper[-2], upper[-1], p) <= 0:
            upper.pop()
        upper.append(p)
    return np.array(lower[:-1] + upper[:-1], dtype=float)


def _series(axes: Sequence[Axes]) -> tuple[list, list[str]]:
    handles, labels = [], []
    for ax in axes:
        for handle, label in zip(*ax.get_legend_handles_labels(), strict=True):
            if label not in labels:
                handles.append(handle)
                labels.append(label)
    return handles, labels


@contextlib.contextmanager
def _style() -> Iterator[None]:
    import matplotlib.style

    with matplotlib.style.context(["default", STYLE]):
        yield
