"""The calibration wizard's report: ``calibration-report.md`` beside the session, with its figures as PNGs.

:func:`write_report` reads a calibration session (the JSON object of ``calibration-session.json``,
docs/calibration.md) and writes what its steps hold, any subset of them: a header (the config, the devices,
the options), a summary table of every step (done, refused or not done), a section per step done with its
figures (``_report_figures``: the residual per point of the cell frame, the robot base and the part frame, the
spread of each measuring-pose frame SFi, the measuring poses over the part, the calibrated cell's uncertainty
map, the repeatability beside the planner's predicted sigma, Table 3) and, with ``--sim``, each step's error
against the simulated truth beside the issue's targets.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from monoguide.daemon.calibrate._report_figures import draw_step, draw_truth_errors
from monoguide.daemon.calibrate._report_sections import FIGURES, REPORT_NAME, TITLES, TRUTH_FIGURE, TRUTH_TARGETS, shown
from monoguide.daemon.calibrate._summary import step_summary
from monoguide.daemon.config import CALIBRATION_STEPS, CellConfig, load_cell_config
from monoguide.daemon.errors import CalibrationReportFailed, ConfigError
from monoguide.daemon.figures import save_png

__all__ = ["CalibrationReportFailed", "markdown", "write_report"]


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
            for name, figure in zip(FIGURES[step], draw_step(step, result, steps, config), strict=True):
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


# --- the Markdown ------------------------------------------------------------------------------------


def markdown(session: dict[str, Any], steps: dict[str, dict[str, Any]], truth: dict[str, dict[str, float]],
             pictures: set[str]) -> str:
    """The report's text: the header, the steps' table, a section per step done (its figures among
    ``pictures``), the truth errors."""
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
                         f"{', '.join(f'{k} {shown(v)}' for k, v in summary.items())} |")
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
            lines += [f"| {step} | {k} | {shown(v)} | {shown(TRUTH_TARGETS[k]) if k in TRUTH_TARGETS else ''} |"
                      for k, v in errors.items()]
        lines += ["", f"![{TRUTH_FIGURE}]({TRUTH_FIGURE})"]
    return "\n".join(lines) + "\n"


def _intrinsics_md(r: dict[str, Any]) -> list[str]:
    cam = r.get("camera") or {}
    out = ["| " + " | ".join(cam) + " |", "|" + "---|" * len(cam),
           "| " + " | ".join(f"{v:.8g}" if isinstance(v, float) else shown(v) for v in cam.values()) + " |", "",
           f"Reprojection RMS {shown(r.get('rms_px'))} px over {shown(r.get('images'))} images."]
    rejected = r.get("rejected") or {}
    out += [f"Rejected image {k}: {why}" for k, why in rejected.items()]
    return out


def _points_md(r: dict[str, Any], label: str) -> list[str]:
    res = r.get("residuals_mm") or {}
    items = res.items() if isinstance(res, dict) else ((str(i + 1), v) for i, v in enumerate(res))
    out = [f"Residual RMS {shown(r.get('rms_mm'))} mm" + (f" ({r['method']})" if r.get("method") else "") + ".", "",
           f"| {label} | residual (mm) |", "|---|--:|"]
    return out + [f"| {k} | {shown(v)} |" for k, v in items]


def _marks_md(r: dict[str, Any]) -> list[str]:
    out = [f"{len(r.get('marks') or [])} reference marks surveyed in their hidden-point nests; deviation from the "
           f"nominal: largest {shown(r.get('max_deviation_mm'))} mm ({r.get('max_deviation_mark', '-')}), RMS "
           f"{shown(r.get('rms_deviation_mm'))} mm (tolerance {shown(r.get('tolerance_mm'))} mm). The measured "
           "position_cf go into [[reference_marks]].", "",
           "| mark | x (mm) | y (mm) | z (mm) | deviation (mm) | dx dy dz (mm) | tracker RMS (mm) |",
           "|---|--:|--:|--:|--:|--:|--:|"]
    for m in r.get("marks") or []:
        x, y, z = (f"{float(v):.3f}" for v in m.get("position_cf") or [float("nan")] * 3)
        out.append(f"| {m.get('name')} | {x} | {y} | {z} | {shown(m.get('deviation_mm'))} | "
                   f"{shown(m.get('deviation_cf'))} | {shown(m.get('tracker_rms_mm'))} |")
    return out


def _base_md(r: dict[str, Any]) -> list[str]:
    out = _points_md(r, "pose")
    out.insert(1, f"The base's 1-sigma: {shown(r.get('sigma_mm'))} mm, {shown(r.get('sigma_deg'))} deg; the SMR on the "
                  f"flange at {shown(r.get('smr_f'))} mm.")
    return out


def _sfi_md(r: dict[str, Any]) -> list[str]:
    out = ["| pose | spread (mm) | spread (deg) | s.e.m. (mm) | s.e.m. (deg) | visits |", "|---|--:|--:|--:|--:|--:|"]
    out += [f"| {p.get('name')} | {shown(p.get('spread_mm'))} | {shown(p.get('spread_deg'))} | "
            f"{shown(p.get('sem_mm'))} | {shown(p.get('sem_deg'))} | {shown(p.get('visits'))} |"
            for p in r.get("poses") or []]
    return [*out, "", f"Hand-eye T_f_c from the poses: spread {shown(r.get('T_f_c_spread_mm'))} mm, "
                      f"{shown(r.get('T_f_c_spread_deg'))} deg."]


def _verify_md(r: dict[str, Any]) -> list[str]:
    return [f"{shown(r.get('n'))} measurements of the reference part.", "",
            "| | x / rx | y / ry | z / rz | predicted |", "|---|--:|--:|--:|--:|",
            "| sigma (mm) | " + " | ".join(shown(v) for v in r.get("sigma_mm") or ["-"] * 3)
            + f" | {shown(r.get('predicted_sigma_mm'))} |",
            "| sigma (deg) | " + " | ".join(shown(v) for v in r.get("sigma_deg") or ["-"] * 3)
            + f" | {shown(r.get('predicted_sigma_deg'))} |",
            "", f"Largest excursion from the mean: {shown(r.get('max_mm'))} mm, {shown(r.get('max_deg'))} deg."]


def _accuracy_md(r: dict[str, Any]) -> list[str]:
    verdict = {True: "**passed**", False: "**failed**", None: "no verdict"}[r.get("passed")]
    return [str(r.get("markdown") or ""), "",
            f"RMS dR {shown(r.get('rms_dR_deg'))} deg, dT {shown(r.get('rms_dT_mm'))} mm: {verdict} (tolerance "
            f"{shown(r.get('tolerance_mm'))} mm, {shown(r.get('tolerance_deg'))} deg per pose)."]


_SECTION: dict[str, Callable[[dict[str, Any]], list[str]]] = {
    "intrinsics": _intrinsics_md, "cell": lambda r: _points_md(r, "benchmark"), "marks": _marks_md, "base": _base_md,
    "part": lambda r: _points_md(r, "hole"), "sfi": _sfi_md, "verify": _verify_md, "accuracy": _accuracy_md}
