"""The calibration wizard's report: ``calibration-report.md`` with PNG plots drawn with Pillow.

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
from typing import Any

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from monoguide.daemon.calibration_file import step_summary
from monoguide.daemon.config import CALIBRATION_STEPS, CellConfig, ConfigError, load_cell_config
from monoguide.daemon.simulate_report import nice_top
from monoguide.solver.calibration.errors import CalibrationError
from monoguide.solver.camera import CameraModel
from monoguide.solver.errors import MonoguideError
from monoguide.solver.frames import invert, make_T
from monoguide.solver.planning.prediction import observed_covariance, pose_sigmas

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

MARGIN = (80, 44, 70, 64)  # left, top, right, bottom
BACKGROUND, AXIS, GRID, TEXT = (255, 255, 255), (40, 40, 40), (225, 225, 225), (20, 20, 20)
MM, DEG, BAD, REF = (40, 110, 200), (230, 130, 30), (210, 40, 40), (120, 120, 120)
POSE_COLOURS = [(60, 120, 220), (60, 170, 90), (230, 130, 30), (180, 70, 200), (40, 170, 170), (200, 70, 120)]


class CalibrationReportFailed(CalibrationError):
    """The report could not be written (the directory is not writable); the calibration itself stands."""

    code = "CALIBRATION_REPORT_FAILED"
    plc_code = 729


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
    pictures: dict[str, Image.Image] = {}
    for step, result in steps.items():
        for name, picture in zip(FIGURES[step], _DRAW[step](result, steps, config), strict=True):
            if picture is not None:  # None: not drawable from what is known (the map without the config)
                pictures[name] = picture
    truth = {step: r["truth_error"] for step, r in steps.items() if r.get("truth_error")}
    if truth:
        pictures[TRUTH_FIGURE] = draw_truth_errors(truth)
    try:
        directory.mkdir(parents=True, exist_ok=True)
        for name, picture in pictures.items():
            picture.save(directory / name)
        out = directory / REPORT_NAME
        out.write_text(markdown(session, steps, truth, set(pictures)))
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


def draw_intrinsics(r: dict[str, Any], *_: Any) -> list[Image.Image]:
    per = [float(v) for v in r.get("per_image_rms_px") or []]
    return [_bars(f"reprojection RMS per image (px); all: {_v(r.get('rms_px'))} px",
                  [str(i) for i in range(len(per))], per, "px", MM)]


def draw_point_residuals(step: str) -> Callable[..., list[Image.Image]]:
    def draw(r: dict[str, Any], *_: Any) -> list[Image.Image]:
        res = r.get("residuals_mm") or {}
        labels, values = (list(res), list(res.values())) if isinstance(res, dict) else (
            [str(i + 1) for i in range(len(res))], list(res))
        what = {"cell": "benchmark", "base": "robot pose", "part": "featured hole"}[step]
        return [_bars(f"{TITLES[step]}: residual per {what} (mm); RMS {_v(r.get('rms_mm'))} mm", labels,
                      [float(v) for v in values], "mm", MM, reference=r.get("rms_mm"), reference_label="RMS")]

    return draw


def draw_sfi(r: dict[str, Any], steps: dict[str, dict[str, Any]], config: CellConfig | None
             ) -> list[Image.Image | None]:
    poses = r.get("poses") or []
    spread = _bars("SFi spread over the visits: mm bars (left), deg dots (right scale)",
                   [str(p.get("name")) for p in poses], [float(p.get("spread_mm", math.nan)) for p in poses], "mm", MM,
                   dots=[float(p.get("spread_deg", math.nan)) for p in poses], dots_unit="deg")
    return [spread, draw_measuring_poses(r, steps, config), draw_uncertainty_map(r, steps, config)]


def draw_measuring_poses(r: dict[str, Any], steps: dict[str, dict[str, Any]],
                         config: CellConfig | None) -> Image.Image:
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
    points = config.part.points_w if config is not None else np.zeros((0, 3))
    names = config.part.point_names if config is not None else ()
    image = Image.new("RGB", PLAN_SIZE, BACKGROUND)
    draw = ImageDraw.Draw(image)
    font = ImageFont.load_default()
    draw.text((16, 10), f"measuring poses over the part ({frame}, mm): camera centres, line of sight to the part "
                        f"plane; black: featured holes", fill=TEXT, font=font)
    half = PLAN_SIZE[0] // 2
    for k, (axes, label) in enumerate((((0, 1), "from above: x right, y up"), ((0, 2), "from the side: x right, "
                                                                                     "z up"))):
        ends = [_axis_end(T) for _, T in cams]
        every = np.vstack([points, *(T[:3, 3] for _, T in cams), *ends, np.zeros(3)])[:, axes]
        box = (k * half + 40, 50, (k + 1) * half - 30, PLAN_SIZE[1] - 40)
        to_px = _fit(box, every)
        draw.rectangle(box, outline=GRID)
        draw.text((box[0] + 6, box[1] + 6), label, fill=TEXT, font=font)
        if len(points) >= 3:
            hull = _hull(points[:, axes])
            draw.polygon([to_px(p) for p in hull], outline=REF, fill=(240, 240, 240))
        for name, p in zip(names, points, strict=True):
            x, y = to_px(p[list(axes)])
            draw.ellipse([x - 4, y - 4, x + 4, y + 4], fill=TEXT)
            draw.text((x + 6, y - 14), name, fill=TEXT, font=font)
        for i, ((name, T), end) in enumerate(zip(cams, ends, strict=True)):
            colour = POSE_COLOURS[i % len(POSE_COLOURS)]
            c, e = to_px(T[:3, 3][list(axes)]), to_px(end[list(axes)])
            draw.line([c, e], fill=colour, width=2)
            draw.ellipse([c[0] - 6, c[1] - 6, c[0] + 6, c[1] + 6], fill=colour)
            draw.text((c[0] + 8, c[1] + 4), name, fill=colour, font=font)
    return image


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
                         ) -> Image.Image | None:
    """The calibrated cell's uncertainty map: the predicted sigma over the part's x-y shifts (two heat maps)."""
    grid = uncertainty_grid(r, steps, config) if config is not None else None
    if grid is None:
        return None
    xs, ys, sigma_mm, sigma_deg = grid
    image = Image.new("RGB", PLAN_SIZE, BACKGROUND)
    draw = ImageDraw.Draw(image)
    font = ImageFont.load_default()
    draw.text((16, 10), "the calibrated cell's predicted sigma (Eq. 29, pixel noise and robot repeatability of "
                        "[layout]) with the part shifted in x and y (part frame, mm)", fill=TEXT, font=font)
    half = PLAN_SIZE[0] // 2
    for k, (values, label) in enumerate(((sigma_mm, "sigma of the grasp point (mm)"),
                                         (sigma_deg, "sigma of the rotation (deg)"))):
        box = (k * half + 70, 60, (k + 1) * half - 110, PLAN_SIZE[1] - 60)
        low, high = float(values.min()), float(values.max())
        cw, ch = (box[2] - box[0]) / len(xs), (box[3] - box[1]) / len(ys)
        for iy in range(len(ys)):
            for ix in range(len(xs)):
                x0, y0 = box[0] + ix * cw, box[3] - (iy + 1) * ch
                colour = _heat((values[iy, ix] - low) / (high - low) if high > low else 0.5)
                draw.rectangle([x0, y0, x0 + cw, y0 + ch], fill=colour)
        draw.rectangle(box, outline=AXIS)
        draw.text((box[0], box[1] - 18), label, fill=TEXT, font=font)
        for v, x in ((xs[0], box[0]), (xs[-1], box[2] - 24)):
            draw.text((x, box[3] + 6), f"x {v:+.0f}", fill=TEXT, font=font)
        for v, y in ((ys[0], box[3] - 12), (ys[-1], box[1])):
            draw.text((box[0] - 56, y), f"y {v:+.0f}", fill=TEXT, font=font)
        bar = (box[2] + 14, box[1], box[2] + 30, box[3])
        for j in range(40):
            y0 = bar[3] - (j + 1) * (bar[3] - bar[1]) / 40
            draw.rectangle([bar[0], y0, bar[2], y0 + (bar[3] - bar[1]) / 40], fill=_heat(j / 39))
        draw.text((bar[2] + 4, bar[1]), f"{high:.4g}", fill=TEXT, font=font)
        draw.text((bar[2] + 4, bar[3] - 12), f"{low:.4g}", fill=TEXT, font=font)
    return image


def draw_repeatability(r: dict[str, Any], *_: Any) -> list[Image.Image]:
    image = Image.new("RGB", CHART_SIZE, BACKGROUND)
    draw = ImageDraw.Draw(image)
    draw.text((MARGIN[0], 12), f"repeatability of {_v(r.get('n'))} measurements: sigma per axis (bars) beside the "
                               f"planner's predicted sigma (grey line)", fill=TEXT, font=ImageFont.load_default())
    half = CHART_SIZE[0] // 2
    for k, (key, pred, unit, colour) in enumerate((("sigma_mm", "predicted_sigma_mm", "mm", MM),
                                                   ("sigma_deg", "predicted_sigma_deg", "deg", DEG))):
        box = (k * half + 70, MARGIN[1], (k + 1) * half - 20, CHART_SIZE[1] - MARGIN[3])
        values = [float(v) for v in r.get(key) or []]
        labels = ["x", "y", "z"] if unit == "mm" else ["rx", "ry", "rz"]
        _bar_panel(draw, box, labels[:len(values)], values, unit, colour, reference=r.get(pred),
                   reference_label="predicted")
    return [image]


def draw_accuracy(r: dict[str, Any], *_: Any) -> list[Image.Image]:
    rows = r.get("rows") or []
    return [_bars(f"Table 3 per part pose: dT mm bars (tolerance {_v(r.get('tolerance_mm'))} mm, grey), dR deg dots "
                  f"(right)", [str(i + 1) for i in range(len(rows))], [float(x.get("dT_mm", math.nan)) for x in rows],
                  "mm", MM, dots=[float(x.get("dR_deg", math.nan)) for x in rows], dots_unit="deg",
                  reference=r.get("tolerance_mm"), reference_label="tolerance")]


def draw_truth_errors(truth: dict[str, dict[str, float]]) -> Image.Image:
    """Each step's error against the simulated truth as a fraction of the issue's target (1 = the target);
    errors without a target are listed with their value."""
    labels, values, texts = [], [], []
    for errors in truth.values():
        for key, value in errors.items():
            labels.append(key)
            target = TRUTH_TARGETS.get(key)
            values.append(float(value) / target if target else math.nan)
            texts.append(_v(value))
    return _bars("error against the simulated truth / the issue's target (1 = target; no bar: no target)", labels,
                 values, "x target", MM, reference=1.0, reference_label="target", value_texts=texts)


_DRAW: dict[str, Callable[..., list[Image.Image | None]]] = {
    "intrinsics": draw_intrinsics, "cell": draw_point_residuals("cell"), "base": draw_point_residuals("base"),
    "part": draw_point_residuals("part"), "sfi": draw_sfi, "verify": draw_repeatability, "accuracy": draw_accuracy}


# --- drawing helpers -----------------------------------------------------------------------------


def _bars(title: str, labels: Sequence[str], values: Sequence[float], unit: str, colour: tuple[int, int, int], *,
          dots: Sequence[float] | None = None, dots_unit: str = "", reference: Any = None, reference_label: str = "",
          value_texts: Sequence[str] | None = None) -> Image.Image:
    image = Image.new("RGB", CHART_SIZE, BACKGROUND)
    draw = ImageDraw.Draw(image)
    draw.text((MARGIN[0], 12), title, fill=TEXT, font=ImageFont.load_default())
    box = (MARGIN[0], MARGIN[1], CHART_SIZE[0] - MARGIN[2], CHART_SIZE[1] - MARGIN[3])
    _bar_panel(draw, box, labels, values, unit, colour, dots=dots, dots_unit=dots_unit, reference=reference,
               reference_label=reference_label, value_texts=value_texts)
    return image


def _bar_panel(draw: ImageDraw.ImageDraw, box: tuple[float, float, float, float], labels: Sequence[str],
               values: Sequence[float], unit: str, colour: tuple[int, int, int], *, dots: Sequence[float] | None = None,
               dots_unit: str = "", reference: Any = None, reference_label: str = "",
               value_texts: Sequence[str] | None = None) -> None:
    font = ImageFont.load_default()
    finite = [v for v in values if math.isfinite(v)]
    ref = float(reference) if isinstance(reference, int | float) and math.isfinite(reference) else None
    top = nice_top(max(finite + ([ref] if ref is not None else []), default=0.0))
    left, upper, right, lower = box
    for k in range(5):
        y = lower - (lower - upper) * k / 4
        draw.line([left, y, right, y], fill=GRID)
        draw.text((left - 56, y - 6), f"{top * k / 4:.3g}", fill=TEXT, font=font)
    draw.rectangle(box, outline=AXIS)
    draw.text((left - 56, upper - 20), unit, fill=TEXT, font=font)
    n = max(len(values), 1)
    step = (right - left) / n
    every = max(1, math.ceil(n / 25))  # at most 25 labels along the axis
    for i, (label, value) in enumerate(zip(labels, values, strict=True)):
        x = left + (i + 0.5) * step
        if math.isfinite(value):
            y = lower - (lower - upper) * min(value / top, 1.05)
            draw.rectangle([x - 0.35 * step, y, x + 0.35 * step, lower], fill=colour)
            if value_texts is None and n <= 12:
                draw.text((x - 0.35 * step, y - 13), f"{value:.3g}", fill=TEXT, font=font)
        if value_texts is not None:
            draw.text((x - 0.35 * step, lower - 14), value_texts[i], fill=TEXT, font=font)
        if i % every == 0:
            draw.text((x - 3 * len(label), lower + 6 + 12 * (i // every % 2 if n > 8 else 0)), label, fill=TEXT,
                      font=font)
    if ref is not None:
        y = lower - (lower - upper) * ref / top
        draw.line([left, y, right, y], fill=REF, width=2)
        draw.text((right - 6 * len(reference_label) - 4, y - 14), reference_label, fill=REF, font=font)
    if dots is not None:
        finite_dots = [v for v in dots if math.isfinite(v)]
        dtop = nice_top(max(finite_dots, default=0.0))
        for k in range(5):
            y = lower - (lower - upper) * k / 4
            draw.text((right + 6, y - 6), f"{dtop * k / 4:.3g}", fill=DEG, font=font)
        draw.text((right + 6, upper - 20), dots_unit, fill=DEG, font=font)
        for i, value in enumerate(dots):
            if math.isfinite(value):
                x, y = left + (i + 0.5) * step, lower - (lower - upper) * value / dtop
                draw.ellipse([x - 4, y - 4, x + 4, y + 4], fill=DEG)


def _heat(t: float) -> tuple[int, int, int]:
    """Blue (0) through yellow (0.5) to red (1)."""
    t = min(max(float(t), 0.0), 1.0)
    if t < 0.5:
        u = t / 0.5
        return round(40 + u * 210), round(90 + u * 140), round(200 - u * 160)
    u = (t - 0.5) / 0.5
    return 250 - round(u * 40), 230 - round(u * 190), 40


def _axis_end(T: np.ndarray) -> np.ndarray:
    """Where the camera's line of sight meets the part's plane z = 0 (or 800 mm along it, if it never does)."""
    z = T[:3, 2]
    s = -T[2, 3] / z[2] if abs(z[2]) > 1e-6 and -T[2, 3] / z[2] > 0 else 800.0
    return T[:3, 3] + min(s, 5000.0) * z


def _fit(box: tuple[float, float, float, float], xy: np.ndarray) -> Callable[[np.ndarray], tuple[float, float]]:
    low, high = xy.min(axis=0), xy.max(axis=0)
    pad = 30.0
    scale = min((box[2] - box[0] - 2 * pad) / max(high[0] - low[0], 1.0),
                (box[3] - box[1] - 2 * pad) / max(high[1] - low[1], 1.0))
    cx, cy = (box[0] + box[2]) / 2, (box[1] + box[3]) / 2
    mx, my = (low + high) / 2

    def to_px(p: np.ndarray) -> tuple[float, float]:
        return cx + (float(p[0]) - mx) * scale, cy - (float(p[1]) - my) * scale

    return to_px


def _hull(xy: np.ndarray) -> list[np.ndarray]:
    """Convex hull (monotone chain), counter-clockwise."""
    pts = sorted(map(tuple, np.round(xy, 9)))
    if len(pts) < 3:
        return [np.array(p) for p in pts]

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
    return [np.array(p) for p in lower[:-1] + upper[:-1]]


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
