"""The calibration report's figures, drawn with matplotlib (``daemon.figures``): each step's charts
(``CHART_SIZE``) and plans (``_report_plans``), and the errors against the simulated truth.

:func:`draw_step` gives a step's figures in the order of :data:`~._report_sections.FIGURES` (None where one is
not drawable from what is known); nothing here writes a file.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from monoguide.daemon.calibrate._report_plans import draw_measuring_poses, draw_uncertainty_map
from monoguide.daemon.calibrate._report_sections import TITLES, TRUTH_TARGETS, shown
from monoguide.daemon.config import CellConfig
from monoguide.daemon.figures import DEG, MM, bar_chart, draw_style, from_zero, legend, new_figure

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

CHART_SIZE = (900, 420)  # width, height px of every chart


def draw_step(step: str, r: dict[str, Any], steps: dict[str, dict[str, Any]], config: CellConfig | None
              ) -> list[Figure | None]:
    """The figures of ``step``'s section from its result ``r`` (``steps``: every step's; ``config``: the cell's,
    for the part's outline and the uncertainty map)."""
    return _DRAW[step](r, steps, config)


@draw_style
def draw_truth_errors(truth: dict[str, dict[str, float]]) -> Figure:
    """Each step's error against the simulated truth as a fraction of its target (1 = the target); errors
    without a target are listed with their value and no bar."""
    labels, values, texts = [], [], []
    for errors in truth.values():
        for key, value in errors.items():
            labels.append(key)
            target = TRUTH_TARGETS.get(key)
            values.append(float(value) / target if target else math.nan)
            texts.append(shown(value))
    figure, ax = _chart("Calibration against the simulated truth: each error as a fraction of its target")
    bar_chart(ax, labels, values, label="error / target (value written above)", value_texts=texts,
              reference=1.0, reference_label="the target")
    ax.set_xlabel("error of a step (no bar: no target)")
    ax.set_ylabel("error / target (1 = on target)")
    legend(ax)
    return figure


# --- the charts of each step -----------------------------------------------------------------------


@draw_style
def _draw_intrinsics(r: dict[str, Any], *_: Any) -> list[Figure]:
    per = [float(v) for v in r.get("per_image_rms_px") or []]
    figure, ax = _chart(f"{TITLES['intrinsics']}: reprojection RMS per plate image")
    bar_chart(ax, [str(i) for i in range(len(per))], per, label="RMS of the image",
              reference=_number(r.get("rms_px")), reference_label=f"RMS of all images, {shown(r.get('rms_px'))} px")
    ax.set_xlabel("plate image")
    ax.set_ylabel("reprojection RMS (px)")
    legend(ax)
    return [figure]


@draw_style
def _draw_marks(r: dict[str, Any], *_: Any) -> list[Figure]:
    marks = r.get("marks") or []
    figure, ax = _chart(f"{TITLES['marks']}: each mark's distance from its nominal position")
    bar_chart(ax, [str(m.get("name")) for m in marks], [_number(m.get("deviation_mm")) for m in marks],
              label="the mark's distance from its nominal", reference=_number(r.get("tolerance_mm")),
              reference_label=f"tolerance, {shown(r.get('tolerance_mm'))} mm")
    ax.set_xlabel("reference mark")
    ax.set_ylabel("distance from the nominal (mm)")
    legend(ax)
    return [figure]


def _draw_point_residuals(step: str) -> Callable[..., list[Figure]]:
    what = {"cell": "benchmark", "base": "robot pose", "part": "featured hole"}[step]

    @draw_style
    def draw(r: dict[str, Any], *_: Any) -> list[Figure]:
        res = r.get("residuals_mm") or {}
        labels, values = (list(res), list(res.values())) if isinstance(res, dict) else (
            [str(i + 1) for i in range(len(res))], list(res))
        figure, ax = _chart(f"{TITLES[step]}: residual per {what} of the fit")
        bar_chart(ax, labels, [float(v) for v in values], label=f"residual of the {what}",
                  reference=_number(r.get("rms_mm")), reference_label=f"RMS, {shown(r.get('rms_mm'))} mm")
        ax.set_xlabel(what)
        ax.set_ylabel("residual (mm)")
        legend(ax)
        return [figure]

    return draw


def _draw_sfi(r: dict[str, Any], steps: dict[str, dict[str, Any]], config: CellConfig | None
              ) -> list[Figure | None]:
    return [_draw_sfi_spread(r), draw_measuring_poses(r, steps, config), draw_uncertainty_map(r, steps, config)]


@draw_style
def _draw_sfi_spread(r: dict[str, Any]) -> Figure:
    """Each measuring-pose frame SFi's spread over its visits: mm (bars, left), deg (dots, right)."""
    poses = r.get("poses") or []
    figure, ax = _chart(f"{TITLES['sfi']}: spread of each frame over its visits")
    bar_chart(ax, [str(p.get("name")) for p in poses], [_number(p.get("spread_mm")) for p in poses],
              label="spread, position (mm, left)")
    right = _dots(ax, [_number(p.get("spread_deg")) for p in poses], label="spread, rotation (deg, right)")
    ax.set_xlabel("measuring pose")
    ax.set_ylabel("spread over the visits, position (mm)")
    right.set_ylabel("spread over the visits, rotation (deg)", color=DEG)
    legend(ax, right)
    return figure


@draw_style
def _draw_repeatability(r: dict[str, Any], *_: Any) -> list[Figure]:
    figure = new_figure(CHART_SIZE)
    for ax, (key, pred, unit, colour, labels, what) in zip(figure.subplots(1, 2), (
            ("sigma_mm", "predicted_sigma_mm", "mm", MM, ("x", "y", "z"), "position"),
            ("sigma_deg", "predicted_sigma_deg", "deg", DEG, ("rx", "ry", "rz"), "rotation")), strict=True):
        values = [float(v) for v in r.get(key) or []]
        bar_chart(ax, labels[:len(values)], values, label="measured σ", colour=colour,
                  reference=_number(r.get(pred)),
                  reference_label=f"planner's predicted σ, {shown(r.get(pred))} {unit}")
        ax.set_xlabel(f"{what} axis")
        ax.set_ylabel(f"σ of the {what} ({unit})")
        ax.set_title(f"{what} ({unit})")
        legend(ax)
    figure.suptitle(f"{TITLES['verify']}: repeatability of {shown(r.get('n'))} measurements of the reference part")
    return [figure]


@draw_style
def _draw_accuracy(r: dict[str, Any], *_: Any) -> list[Figure]:
    rows = r.get("rows") or []
    figure, ax = _chart(f"{TITLES['accuracy']}: errors per part pose against the tolerance")
    bar_chart(ax, [str(i + 1) for i in range(len(rows))], [_number(x.get("dT_mm")) for x in rows],
              label="dT, position (mm, left)", reference=_number(r.get("tolerance_mm")),
              reference_label=f"tolerance, {shown(r.get('tolerance_mm'))} mm")
    right = _dots(ax, [_number(x.get("dR_deg")) for x in rows], label="dR, rotation (deg, right)",
                  reference=_number(r.get("tolerance_deg")),
                  reference_label=f"tolerance, {shown(r.get('tolerance_deg'))} deg")
    ax.set_xlabel("part pose (row of Table 3)")
    ax.set_ylabel("dT: position error (mm)")
    right.set_ylabel("dR: rotation error (deg)", color=DEG)
    legend(ax, right)
    return [figure]


_DRAW: dict[str, Callable[..., list[Figure | None]]] = {
    "intrinsics": _draw_intrinsics, "cell": _draw_point_residuals("cell"), "marks": _draw_marks,
    "base": _draw_point_residuals("base"),
    "part": _draw_point_residuals("part"), "sfi": _draw_sfi, "verify": _draw_repeatability,
    "accuracy": _draw_accuracy}


# --- drawing helpers -----------------------------------------------------------------------------


def _chart(title: str) -> tuple[Figure, Axes]:
    figure = new_figure(CHART_SIZE)
    ax = figure.add_subplot()
    ax.set_title(title)
    return figure, ax


def _dots(ax: Axes, values: Sequence[float], *, label: str, reference: float | None = None,
          reference_label: str = "") -> Axes:
    """``values`` as dots on a right-hand axis of ``ax`` (with a dotted ``reference`` line), returned."""
    right = ax.twinx()
    right.grid(False)
    right.plot(np.arange(len(values)), values, "o", color=DEG, markersize=6, label=label)
    shown_values = list(values)
    if reference is not None and math.isfinite(reference):
        right.axhline(reference, color=DEG, linewidth=1.2, linestyle=":", label=reference_label)
        shown_values.append(reference)
    right.tick_params(axis="y", colors=DEG)
    from_zero(right, shown_values)
    return right


def _number(value: Any) -> float:
    """A finite float, or NaN (no bar, no line) for anything else."""
    return float(value) if isinstance(value, int | float) and not isinstance(value, bool) else math.nan
