"""The calibration wizard's report: ``calibration-report.md`` with PNG plots drawn with matplotlib.

:func:`write_report` reads a calibration session (the JSON object of ``calibration-session.json``,
docs/calibration.md) and draws what its steps hold, any subset of them: the residual per point of the cell
frame, the robot base and the part frame, the spread of each measuring-pose frame SFi over its visits, the
measuring poses over the part's outline (from above and from the side, part frame), the calibrated cell's
uncertainty map (the predicted sigma over the part's x-y shifts), the repeatability beside the
planner's predicted sigma, Table 3 (the accuracy step's Markdown) and, with ``--sim``, each step's error against
the simulated truth beside the issue's targets.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from monoguide.daemon.calibrate._file import step_summary
from monoguide.daemon.config import CALIBRATION_STEPS, CellConfig, load_cell_config
from monoguide.daemon.errors import CalibrationReportFailed, ConfigError
from monoguide.daemon.figures import (
    DEG,
    MM,
    REFERENCE,
    SERIES,
    bar_chart,
    draw_style,
    figure_legend,
    from_zero,
    label_points,
    legend,
    new_figure,
    outline,
    save_png,
)
from monoguide.solver.camera import CameraModel
from monoguide.solver.errors import MonoguideError
from monoguide.solver.frames import invert, make_T
from monoguide.solver.planning.prediction import observed_covariance, pose_sigmas

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

__all__ = ["CHART_SIZE", "FIGURES", "PLAN_SIZE", "REPORT_NAME", "CalibrationReportFailed", "write_report"]

REPORT_NAME = "calibration-report.md"
CHART_SIZE = (900, 420)  # width, height px of every chart
PLAN_SIZE = (1200, 560)  # the measuring poses and the uncertainty map: two panels side by side
MAP_STEPS = 11  # the uncertainty map's grid over the envelope's x and y
# step -> the figures its section shows (truth-errors.png: --sim, every step with a truth_error)
FIGURES: dict[str, tuple[str, ...]] = {
    "intrinsics": ("intrinsics-residuals.png",),
    "cell": ("residuals-cell.png",),
    "base": ("residuals-base.png",),
    "part": ("residuals-part.png",),
    "sfi": ("sfi-spread.png", "measuring-poses.png", "uncertainty-map.png"),
    "verify": ("repeatability.png",),
    "accuracy": ("accuracy.png",),
}
TRUTH_FIGURE = "truth-errors.png"
# the issue's targets on the simulated cell, for the truth errors' plot
TRUTH_TARGETS = {"focal_rel_error": 0.001, "base_mm": 0.05, "base_deg": 0.005, "sfi_mm_max": 0.05,
                 "sfi_deg_max": 0.01}
TITLES = {"intrinsics": "1 Camera intrinsics", "cell": "2 Cell frame CF", "base": "3 Robot base BF",
          "part": "4 Part frame WF and T_cf_w0", "sfi": "5 Measuring-pose frames SFi", "verify": "6 Verification",
          "accuracy": "7 Accuracy validation (Table 3)"}


def write_report(directory: Path, session: dict[str, Any], config: CellConfig | None = None) -> Path:
    """Write ``calibration-report.md`` and its PNGs into ``directory`` (created); returns the Markdown's path.
    ``config``: the cell config for the part's outline (default: the session's ``config``, when it loads)."""
    directory = Path(directory)
    steps = {k: v for k, v in (session.get("steps") or {}).items() if k in CALIBRATION_STEPS and isinstance(v, dict)}
    if config is None and session.get("config"):
        try:
            config = load_cell_config(session["config"])
        except ConfigError:
            config = None
    truth = {step: r["truth_error"] for step, r in steps.items() if r.get("truth_error")}
    out, pictures = directory / REPORT_NAME, set()
    try:
        directory.mkdir(parents=True, exist_ok=True)
        for step, result in steps.items():  # a step's figures at a time: drawn, written, released
            for name, figure in zip(FIGURES[step], _DRAW[step](result, steps, config), strict=True):
                if figure is not None:  # None: not drawable from what is known (the map without the config)
                    save_png(figure, directory / name)
                    pictures.add(name)
        if truth:
            save_png(draw_truth_errors(truth), directory / TRUTH_FIGURE)
            pictures.add(TRUTH_FIGURE)
        out.write_text(markdown(session, steps, truth, pictures))
    except OSError as exc:
        raise CalibrationReportFailed(f"{directory}: cannot write the calibration report: {exc}") from exc
    return out


# --- Markdown ------------------------------------------------------------------------------------


def markdown(session: dict[str, Any], steps: dict[str, dict[str, Any]], truth: dict[str, dict[str, float]],
             pictures: set[str]) -> str:
    lines = ["# Calibration report", "", "| | |", "|---|---|",
             f"| cell config | `{session.get('config', '-')}` |",
             f"| simulated cell | {'yes (--sim)' if session.get('sim') else 'no'} |",
             f"| started | {session.get('started', '-')} |"]
    lines += [f"| {name} | {value} |" for name, value in (session.get("devices") or {}).items()]
    if session.get("options"):
        lines.append("| options | " + ", ".join(f"{k} {v}" for k, v in session["options"].items()) + " |")
    lines += ["", "## Steps", "", "| step | done | summary |", "|---|---|---|"]
    refused = session.get("refused") or {}
    for step in CALIBRATION_STEPS:
        if step in steps:
            summary = {k: v for k, v in step_summary(step, steps[step]).items()
                       if k != "done" and not k.startswith("truth_")}
            lines.append(f"| {TITLES[step]} | {steps[step].get('done', 'yes')} | "
                         f"{', '.join(f'{k} {_v(v)}' for k, v in summary.items())} |")
        elif step in refused:
            r = refused[step]
            lines.append(f"| {TITLES[step]} | **refused** {r.get('at', '')} | {r.get('code', '')} "
                         f"({r.get('plc_code', '')}): {r.get('message', '')} |")
        else:
            lines.append(f"| {TITLES[step]} | not done | |")
    for step in CALIBRATION_STEPS:
        if step in steps:
            lines += ["", f"## {TITLES[step]}", "", *_SECTION[step](steps[step])]
            lines += [""] + [f"![{name}]({name})" for name in FIGURES[step] if name in pictures]
    if truth:
        lines += ["", "## Against the simulated truth", "", "| step | error | value | issue target |",
                  "|---|---|---|---|"]
        for step, errors in truth.items():
            lines += [f"| {step} | {k} | {_v(v)} | {_v(TRUTH_TARGETS[k]) if k in TRUTH_TARGETS else ''} |"
                      for k, v in errors.items()]
        lines += ["", f"![{TRUTH_FIGURE}]({TRUTH_FIGURE})"]
    return "\n".join(lines) + "\n"


def _intrinsics_md(r: dict[str, Any]) -> list[str]:
    cam = r.get("camera") or {}
    out = ["| " + " | ".join(cam) + " |", "|" + "---|" * len(cam),
           "| " + " | ".join(f"{v:.8g}" if isinstance(v, float) else _v(v) for v in cam.values()) + " |", "",
           f"Reprojection RMS {_v(r.get('rms_px'))} px over {_v(r.get('images'))} images."]
    rejected = r.get("rejected") or {}
    out += [f"Rejected image {k}: {why}" for k, why in rejected.items()]
    return out


def _points_md(r: dict[str, Any], label: str) -> list[str]:
    res = r.get("residuals_mm") or {}
    items = res.items() if isinstance(res, dict) else ((str(i + 1), v) for i, v in enumerate(res))
    out = [f"Residual RMS {_v(r.get('rms_mm'))} mm" + (f" ({r['method']})" if r.get("method") else "") + ".", "",
           f"| {label} | residual (mm) |", "|---|--:|"]
    return out + [f"| {k} | {_v(v)} |" for k, v in items]


def _base_md(r: dict[str, Any]) -> list[str]:
    out = _points_md(r, "pose")
    out.insert(1, f"The base's 1-sigma: {_v(r.get('sigma_mm'))} mm, {_v(r.get('sigma_deg'))} deg; the SMR on the "
                  f"flange at {_v(r.get('smr_f'))} mm.")
    return out


def _sfi_md(r: dict[str, Any]) -> list[str]:
    out = ["| pose | spread (mm) | spread (deg) | s.e.m. (mm) | s.e.m. (deg) | visits |", "|---|--:|--:|--:|--:|--:|"]
    out += [f"| {p.get('name')} | {_v(p.get('spread_mm'))} | {_v(p.get('spread_deg'))} | {_v(p.get('sem_mm'))} | "
            f"{_v(p.get('sem_deg'))} | {_v(p.get('visits'))} |" for p in r.get("poses") or []]
    return [*out, "", f"Hand-eye T_f_c from the poses: spread {_v(r.get('T_f_c_spread_mm'))} mm, "
                      f"{_v(r.get('T_f_c_spread_deg'))} deg."]


def _verify_md(r: dict[str, Any]) -> list[str]:
    return [f"{_v(r.get('n'))} measurements of the reference part.", "",
            "| | x / rx | y / ry | z / rz | predicted |", "|---|--:|--:|--:|--:|",
            "| sigma (mm) | " + " | ".join(_v(v) for v in r.get("sigma_mm") or ["-"] * 3)
            + f" | {_v(r.get('predicted_sigma_mm'))} |",
            "| sigma (deg) | " + " | ".join(_v(v) for v in r.get("sigma_deg") or ["-"] * 3)
            + f" | {_v(r.get('predicted_sigma_deg'))} |",
            "", f"Largest excursion from the mean: {_v(r.get('max_mm'))} mm, {_v(r.get('max_deg'))} deg."]


def _accuracy_md(r: dict[str, Any]) -> list[str]:
    verdict = {True: "**passed**", False: "**failed**", None: "no verdict"}[r.get("passed")]
    return [str(r.get("markdown") or ""), "",
            f"RMS dR {_v(r.get('rms_dR_deg'))} deg, dT {_v(r.get('rms_dT_mm'))} mm: {verdict} (tolerance "
            f"{_v(r.get('tolerance_mm'))} mm, {_v(r.get('tolerance_deg'))} deg per pose)."]


_SECTION: dict[str, Callable[[dict[str, Any]], list[str]]] = {
    "intrinsics": _intrinsics_md, "cell": lambda r: _points_md(r, "benchmark"), "base": _base_md,
    "part": lambda r: _points_md(r, "hole"), "sfi": _sfi_md, "verify": _verify_md, "accuracy": _accuracy_md}


# --- figures -------------------------------------------------------------------------------------


@draw_style
def draw_intrinsics(r: dict[str, Any], *_: Any) -> list[Figure]:
    per = [float(v) for v in r.get("per_image_rms_px") or []]
    figure, ax = _chart(f"{TITLES['intrinsics']}: reprojection RMS per plate image")
    bar_chart(ax, [str(i) for i in range(len(per))], per, label="RMS of the image",
              reference=_number(r.get("rms_px")), reference_label=f"RMS of all images, {_v(r.get('rms_px'))} px")
    ax.set_xlabel("plate image")
    ax.set_ylabel("reprojection RMS (px)")
    legend(ax)
    return [figure]


def draw_point_residuals(step: str) -> Callable[..., list[Figure]]:
    what = {"cell": "benchmark", "base": "robot pose", "part": "featured hole"}[step]

    @draw_style
    def draw(r: dict[str, Any], *_: Any) -> list[Figure]:
        res = r.get("residuals_mm") or {}
        labels, values = (list(res), list(res.values())) if isinstance(res, dict) else (
            [str(i + 1) for i in range(len(res))], list(res))
        figure, ax = _chart(f"{TITLES[step]}: residual per {what} of the fit")
        bar_chart(ax, labels, [float(v) for v in values], label=f"residual of the {what}",
                  reference=_number(r.get("rms_mm")), reference_label=f"RMS, {_v(r.get('rms_mm'))} mm")
        ax.set_xlabel(what)
        ax.set_ylabel("residual (mm)")
        legend(ax)
        return [figure]

    return draw


def draw_sfi(r: dict[str, Any], steps: dict[str, dict[str, Any]], config: CellConfig | None
             ) -> list[Figure | None]:
    return [draw_sfi_spread(r), draw_measuring_poses(r, steps, config), draw_uncertainty_map(r, steps, config)]


@draw_style
def draw_sfi_spread(r: dict[str, Any]) -> Figure:
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
def draw_measuring_poses(r: dict[str, Any], steps: dict[str, dict[str, Any]],
                         config: CellConfig | None) -> Figure:
    """The calibrated cameras SFi (dot, line of sight to the part's plane) over the part's holes and outline,
    in the reference part's frame: from above (x right, y up) and from the side (x right, z up)."""
    if "part" in steps:
        T_cf_w0 = np.asarray(steps["part"]["T_cf_w0"], dtype=float)
    elif config is not None:
        T_cf_w0 = config.reference.T_cf_w0
    else:
        T_cf_w0 = np.eye(4)
    frame = "part frame" if "part" in steps or config is not None else "cell frame"
    T_w_cf = invert(T_cf_w0)
    cams = [(str(p.get("name")), T_w_cf @ np.asarray(p["T_cf_si"], dtype=float)) for p in r.get("poses") or []]
    centres = np.array([T[:3, 3] for _, T in cams]).reshape(-1, 3)
    ends = np.array([_axis_end(T) for _, T in cams]).reshape(-1, 3)
    points = config.part.points_w if config is not None else np.zeros((0, 3))
    names = config.part.point_names if config is not None else ()
    figure = new_figure(PLAN_SIZE)
    panels = figure.subplots(1, 2)
    for ax, (a, b, view) in zip(panels, ((0, 1, "from above: x right, y up"), (0, 2, "from the side: x right, z up")),
                                strict=True):
        span = float(np.ptp(np.vstack([points, centres, ends, np.zeros((1, 3))])[:, [a, b]], axis=0).max())
        if len(points) >= 3:
            hull = outline(points[:, [a, b]])
            ax.fill(hull[:, 0], hull[:, 1], facecolor="0.93", edgecolor=REFERENCE, label="part outline (holes)")
        if len(points):
            ax.plot(points[:, a], points[:, b], "o", color="black", markersize=5, label="featured hole")
            label_points(ax, names, points[:, [a, b]], "black", span)
        for i, ((name, _), c, e) in enumerate(zip(cams, centres, ends, strict=True)):
            colour = SERIES[i % len(SERIES)]
            ax.plot([c[a], e[a]], [c[b], e[b]], "-", color=colour, linewidth=1.5)
            ax.plot(c[a], c[b], "o", color=colour, markersize=7, label=f"{name}: camera and its line of sight")
        label_points(ax, [name for name, _ in cams], centres[:, [a, b]], "0.2", span)
        ax.margins(0.08)
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_xlabel(f"x ({frame}, mm)")
        ax.set_ylabel(f"{'yz'[b - 1]} ({frame}, mm)")
        ax.set_title(view)
    figure_legend(figure, *panels, columns=3)
    figure.suptitle(f"Measuring poses over the part ({frame}, mm, to scale)")
    return figure


def uncertainty_grid(r: dict[str, Any], steps: dict[str, dict[str, Any]], config: CellConfig
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """The calibrated cell's predicted sigma (Eq. 29) of the grasp point (mm) and of the rotation (deg), with the
    layout's pixel noise and robot repeatability, for the part shifted over the envelope's x and y (part
    frame): (xs, ys, sigma_mm (ny, nx), sigma_deg (ny, nx)); None when the layout is degenerate."""
    layout = config.layout
    camera = CameraModel(**steps["intrinsics"]["camera"]) if "intrinsics" in steps else config.camera.intrinsics
    T_cf_w0 = np.asarray(steps["part"]["T_cf_w0"], dtype=float) if "part" in steps else config.reference.T_cf_w0
    calibrated = {p.get("name"): np.asarray(p["T_cf_si"], dtype=float) for p in r.get("poses") or []}
    T_w0_cf = invert(T_cf_w0)
    T_w0_si = [T_w0_cf @ calibrated.get(p.name, p.T_cf_si) for p in config.measuring_poses]
    observed = [(i, k) for i, pose in enumerate(config.measuring_poses) for k in pose.points]
    points = config.part.points_w
    grasp = config.part.grasp_point_w if config.part.grasp_point_w is not None else points.mean(axis=0)
    sigma_px = layout.sigma_px if layout else 0.1
    rep_mm, rep_deg = (layout.repeatability_mm, layout.repeatability_deg) if layout else (0.05, 0.01)
    half_x, half_y = (layout.envelope.translation_mm[:2] if layout else (50.0, 50.0))
    xs, ys = np.linspace(-half_x, half_x, MAP_STEPS), np.linspace(-half_y, half_y, MAP_STEPS)
    sigma_mm, sigma_deg = np.empty((len(ys), len(xs))), np.empty((len(ys), len(xs)))
    try:
        for iy, y in enumerate(ys):
            for ix, x in enumerate(xs):
                T_w_w0 = make_T(np.eye(3), -np.array([x, y, 0.0]))  # the part moved by (x, y)
                T_w_si = [T_w_w0 @ T for T in T_w0_si]
                cov = observed_covariance(camera, points, T_w_si, observed, sigma_px, rep_mm, rep_deg)
                s = pose_sigmas(cov, invert(T_w_si[0]), grasp)
                sigma_mm[iy, ix], sigma_deg[iy, ix] = s.sigma_trans_mm, s.sigma_rot_deg
    except MonoguideError:
        return None
    return xs, ys, sigma_mm, sigma_deg


def draw_uncertainty_map(r: dict[str, Any], steps: dict[str, dict[str, Any]], config: CellConfig | None
                         ) -> Figure | None:
    """The calibrated cell's uncertainty map: the predicted sigma over the part's x-y shifts (two colour maps)."""
    grid = uncertainty_grid(r, steps, config) if config is not None else None
    return None if grid is None else _uncertainty_figure(*grid)


@draw_style
def draw_repeatability(r: dict[str, Any], *_: Any) -> list[Figure]:
    figure = new_figure(CHART_SIZE)
    for ax, (key, pred, unit, colour, labels, what) in zip(figure.subplots(1, 2), (
            ("sigma_mm", "predicted_sigma_mm", "mm", MM, ("x", "y", "z"), "position"),
            ("sigma_deg", "predicted_sigma_deg", "deg", DEG, ("rx", "ry", "rz"), "rotation")), strict=True):
        values = [float(v) for v in r.get(key) or []]
        bar_chart(ax, labels[:len(values)], values, label="measured σ", colour=colour,
                  reference=_number(r.get(pred)), reference_label=f"planner's predicted σ, {_v(r.get(pred))} {unit}")
        ax.set_xlabel(f"{what} axis")
        ax.set_ylabel(f"σ of the {what} ({unit})")
        ax.set_title(f"{what} ({unit})")
        legend(ax)
    figure.suptitle(f"{TITLES['verify']}: repeatability of {_v(r.get('n'))} measurements of the reference part")
    return [figure]


@draw_style
def draw_accuracy(r: dict[str, Any], *_: Any) -> list[Figure]:
    rows = r.get("rows") or []
    figure, ax = _chart(f"{TITLES['accuracy']}: errors per part pose against the tolerance")
    bar_chart(ax, [str(i + 1) for i in range(len(rows))], [_number(x.get("dT_mm")) for x in rows],
              label="dT, position (mm, left)", reference=_number(r.get("tolerance_mm")),
              reference_label=f"tolerance, {_v(r.get('tolerance_mm'))} mm")
    right = _dots(ax, [_number(x.get("dR_deg")) for x in rows], label="dR, rotation (deg, right)",
                  reference=_number(r.get("tolerance_deg")),
                  reference_label=f"tolerance, {_v(r.get('tolerance_deg'))} deg")
    ax.set_xlabel("part pose (row of Table 3)")
    ax.set_ylabel("dT: position error (mm)")
    right.set_ylabel("dR: rotation error (deg)", color=DEG)
    legend(ax, right)
    return [figure]


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
            texts.append(_v(value))
    figure, ax = _chart("Calibration against the simulated truth: each error as a fraction of its target")
    bar_chart(ax, labels, values, label="error / target (value written above)", value_texts=texts,
              reference=1.0, reference_label="the target")
    ax.set_xlabel("error of a step (no bar: no target)")
    ax.set_ylabel("error / target (1 = on target)")
    legend(ax)
    return figure


_DRAW: dict[str, Callable[..., list[Figure | None]]] = {
    "intrinsics": draw_intrinsics, "cell": draw_point_residuals("cell"), "base": draw_point_residuals("base"),
    "part": draw_point_residuals("part"), "sfi": draw_sfi, "verify": draw_repeatability, "accuracy": draw_accuracy}


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
    shown = list(values)
    if reference is not None and math.isfinite(reference):
        right.axhline(reference, color=DEG, linewidth=1.2, linestyle=":", label=reference_label)
        shown.append(reference)
    right.tick_params(axis="y", colors=DEG)
    from_zero(right, shown)
    return right


@draw_style
def _uncertainty_figure(xs: np.ndarray, ys: np.ndarray, sigma_mm: np.ndarray, sigma_deg: np.ndarray) -> Figure:
    figure = new_figure(PLAN_SIZE)
    for ax, (values, what, unit) in zip(figure.subplots(1, 2), ((sigma_mm, "grasp point", "mm"),
                                                               (sigma_deg, "rotation", "deg")), strict=True):
        mesh = ax.pcolormesh(xs, ys, values, shading="nearest", cmap="viridis", vmin=float(values.min()),
                             vmax=float(values.max()))
        figure.colorbar(mesh, ax=ax, shrink=0.9).set_label(f"predicted σ of the {what} ({unit})")
        ax.grid(False)
        ax.set_aspect("equal")
        ax.set_xlabel("part shifted in x (part frame, mm)")
        ax.set_ylabel("part shifted in y (part frame, mm)")
        ax.set_title(f"σ of the {what} ({unit})")
    figure.suptitle("The calibrated cell's predicted σ (Eq. 29, pixel noise and robot repeatability of [layout]) "
                    "over the envelope")
    return figure


def _number(value: Any) -> float:
    """A finite float, or NaN (no bar, no line) for anything else."""
    return float(value) if isinstance(value, int | float) and not isinstance(value, bool) else math.nan


def _axis_end(T: np.ndarray) -> np.ndarray:
    """Where the camera's line of sight meets the part's plane z = 0 (or 800 mm along it, if it never does)."""
    z = T[:3, 2]
    s = -T[2, 3] / z[2] if abs(z[2]) > 1e-6 and -T[2, 3] / z[2] > 0 else 800.0
    return T[:3, 3] + min(s, 5000.0) * z


def _v(value: Any) -> str:
    if value is None:
        return "-"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return f"{value:.4g}" if math.isfinite(value) else "-"
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_v(v) for v in value) + "]"
    return str(value)
