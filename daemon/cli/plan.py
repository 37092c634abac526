"""``monoguide plan``: the measuring layout of a cell.

``--layout``: plan the measuring poses of the cell in ``--config`` for the whole deviation envelope
(``solver.planning.plan_layout``) and print them beside the cell's current ones; ``--write`` a copy of the
cell file with them, ``--out`` a picture. Without ``--layout``: the paper's Fig. 5 study (Sec. 4) for the
cell's camera and holes (the paper's roof without ``--config``). ``--record`` adds the predicted
uncertainty of a measurement record's layout. A cell with ``[[reference_marks]]`` is also checked for its
fixed marks (``solver.planning.marks``: each measuring pose's marks in its image, apart, and never behind a part
anywhere in its envelope), a table per pose; a mark not seen is a failure of the plan. Exit status: 0 done,
1 a failure (config, refused plan, a fixed mark not seen, bad record, unwritable output; named on standard
error), 2 a bad option.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import numpy as np
import typer

from monoguide.daemon.cli._console import say, stderr_console, stdout_console
from monoguide.daemon.cli._policy import error_line, exit_status
from monoguide.daemon.config import load_cell_config
from monoguide.daemon.errors import OutputNotWritten
from monoguide.daemon.figures import draw_style, new_figure, save_png
from monoguide.daemon.plan import (
    CellLayout,
    cell_layout,
    cell_marks_check,
    draw_layout,
    fig5_report,
    marks_report,
    planned_pose_names,
    print_fig5,
    print_layout,
    write_config_with_layout,
)
from monoguide.solver.camera import PAPER_CAMERA
from monoguide.solver.errors import MonoguideError
from monoguide.solver.frames import compose
from monoguide.solver.planning import LayoutAssessment, assess_layout, plan_layout, pose_sigmas, uncertainty_map
from monoguide.solver.record import parse_record
from monoguide.solver.synthetic import PAPER_ROOF_POINTS_W
from monoguide.solver.uncertainty import predicted_covariance

if TYPE_CHECKING:
    from matplotlib.figure import Figure

MAP_SIZE = (820, 640)  # width, height px of the Fig. 5 map (--out without --layout)


def _finite_positive(value: float | None) -> float | None:
    if value is not None and not (math.isfinite(value) and value > 0):
        raise typer.BadParameter(f"must be a finite number > 0, got {value}")
    return value


def _png(value: Path | None) -> Path | None:
    if value is not None and value.suffix.lower() != ".png":
        raise typer.BadParameter(f"expected a .png file, got {str(value)!r}")
    return value


def plan(
    config: Annotated[Path | None, typer.Option("--config", "-c", help="The cell config (TOML) to plan.")] = None,
    layout: Annotated[bool, typer.Option("--layout", help="Plan the measuring poses for the whole envelope.")] = False,
    write: Annotated[
        Path | None, typer.Option(help="With --layout: write a copy of the cell config with the planned poses.")
    ] = None,
    out: Annotated[
        Path | None, typer.Option(callback=_png, help="PNG: the layout (with --layout), else the Fig. 5 map.")
    ] = None,
    record: Annotated[
        Path | None, typer.Option(help="Also report the predicted uncertainty of this record's layout.")
    ] = None,
    standoff_mm: Annotated[
        float, typer.Option(callback=_finite_positive, help="Fig. 5: camera distance above the holes, mm.")
    ] = 650.0,
    sigma_px: Annotated[
        float | None,
        typer.Option(callback=_finite_positive,
                     help="Hole-centre noise, px (default: the config's layout sigma_px, or 0.1)."),
    ] = None,
    steps: Annotated[int, typer.Option(min=2, help="Fig. 5: grid steps of the map along each image axis.")] = 25,
    json_output: Annotated[bool, typer.Option("--json", help="One JSON object on standard output.")] = False,
) -> None:
    """Plan the measuring poses of a cell (--layout), or show the paper's Fig. 5 study for its camera."""
    if layout and config is None:
        raise typer.BadParameter("--layout plans the cell of a config file: give --config CELL.toml",
                                 param_hint="--config")
    if write is not None and not layout:
        raise typer.BadParameter("writes the planned poses: use it with --layout", param_hint="--write")
    if write is not None and config is not None and write.resolve() == config.resolve():
        raise typer.BadParameter("would overwrite the --config file: write a copy and review it", param_hint="--write")
    console, errors = stdout_console(), stderr_console()
    failed = False
    try:
        cfg = load_cell_config(config) if config is not None else None
    except MonoguideError as error:
        _fail(errors, f"config {config}", error, json_output)
        raise typer.Exit(exit_status(error)) from error
    if layout:
        assert cfg is not None
        report, failed = _layout(cfg, sigma_px, write, out, errors, json_output)
    else:
        report, failed = _fig5(cfg, standoff_mm, sigma_px, steps, out, errors)
    if report is None:
        raise typer.Exit(1)
    if cfg is not None and cfg.reference_marks:
        failed |= not _marks(cfg, report, errors)
    if record is not None:
        report["record"] = _record_layout(record)
        if "error" in report["record"]:
            failed = True
            e = report["record"]["error"]
            say(errors, f"{e['code']} record {record}: {e['message']}")
    if json_output:
        typer.echo(json.dumps(report))
    elif layout:
        print_layout(console, report)
    else:
        print_fig5(console, report)
    if failed:
        raise typer.Exit(1)


def _layout(cfg, sigma_px, write, out, errors, json_output) -> tuple[dict | None, bool]:
    try:
        cell = cell_layout(cfg, sigma_px)
        planned = plan_layout(cell.request)
    except MonoguideError as error:
        _fail(errors, "layout", error, json_output)
        return None, True
    current = assess_layout(cell.request, cell.T_w0_si, cell.observed)
    report = _layout_report(cfg, cell, planned, current)
    failed = False
    if write is not None:
        note = "planned by `monoguide plan --layout`"
        try:
            write_config_with_layout(cfg, planned, write, note)
            report["written"] = str(write)
        except MonoguideError as error:
            failed = True
            say(errors, error_line(error, f"--write {write}: not written"))
        except OSError as error:
            failed = True
            say(errors, error_line(OutputNotWritten(f"--write {write}: not written: {error.strerror or error}")))
    if out is not None:
        picture = draw_layout(cell.request, planned, cell.T_w0_si, title=f"{cfg.name}: planned measuring poses")
        failed |= not _write_png(out, picture, errors)
        if not failed:
            report["layout_png"] = str(out)
    return report, failed


def _layout_report(cfg, cell: CellLayout, planned: LayoutAssessment, current: LayoutAssessment) -> dict[str, Any]:
    r = cell.request
    names = planned_pose_names(cfg, len(planned.T_w0_si))
    report: dict[str, Any] = {
        "cell": cfg.name,
        "config": str(cfg.path),
        "sigma_px": r.sigma_px,
        "repeatability_mm": r.repeatability_mm,
        "repeatability_deg": r.repeatability_deg,
        "grasp_point_w": r.grasp_point().tolist(),
        "envelope": {
            "translation_mm": list(r.envelope.translation_mm),
            "rotation_deg": list(r.envelope.rotation_deg),
            "centre_w": r.envelope.about(r.points_w).tolist(),
            "parts_checked": int(64 + 1 + r.interior_samples),
        },
        "constraints": {
            "standoff_mm": list(r.constraints.standoff_mm),
            "max_view_angle_deg": r.constraints.max_view_angle_deg,
            "margin_px": r.constraints.margin_px,
            "depth_of_field_mm": list(r.constraints.depth_of_field_mm),
            "reach_radius_mm": None if r.constraints.reach is None else r.constraints.reach.radius_mm,
        },
    }
    report.update(_summary(planned))
    report["poses"] = _poses(cfg, r, planned, names)
    report["current"] = {**_summary(current), "poses": _poses(cfg, r, current, cell.names)}
    return report


def _summary(a: LayoutAssessment) -> dict[str, Any]:
    out: dict[str, Any] = {
        "margin_px_min": round(a.margin_px_min, 1) if a.in_front else None,
        "in_front": a.in_front,
        "depth_mm_min": round(a.depth_mm_min, 1),
        "depth_mm_max": round(a.depth_mm_max, 1),
        "degenerate": a.degenerate,
    }
    for suffix, s in (("", a.sigmas), ("_with_repeatability", a.sigmas_with_repeatability)):
        for key, value in (s.as_dict() if s is not None else dict.fromkeys(
                ("sigma_rot_deg", "sigma_trans_mm", "sigma_origin_mm"))).items():
            out[key + suffix] = None if value is None else round(value, 6)
    return out


def _poses(cfg, request, a: LayoutAssessment, view_names) -> list[dict[str, Any]]:
    point_names = request.names()
    rows = []
    for j, (view, point) in enumerate(a.observed):
        T_cf_si = compose(cfg.reference.T_cf_w0, a.T_w0_si[view])
        rows.append({
            "name": view_names[view],
            "hole": point_names[point],
            "position_cf_mm": np.round(T_cf_si[:3, 3], 3).tolist(),
            "optical_axis_cf": np.round(T_cf_si[:3, 2], 6).tolist(),
            "T_cf_si": T_cf_si.tolist(),
            "standoff_mm": round(float(a.standoff_mm[j]), 1),
            "view_angle_deg": round(float(a.view_angle_deg[j]), 2),
            "view_angle_max_deg": round(float(a.view_angle_max_deg[j]), 2),
            "pixel": np.round(a.pixels[j], 1).tolist(),
            "margin_px": round(float(a.margin_px[j]), 1) if math.isfinite(a.margin_px[j]) else None,
            "depth_mm": np.round(a.depth_mm[j], 1).tolist(),
        })
    return rows


def _fig5(cfg, standoff_mm, sigma_px, steps, out, errors) -> tuple[dict | None, bool]:
    if cfg is not None:
        camera, points = cfg.camera.intrinsics, cfg.part.points_w
        cell = f"{cfg.name} ({cfg.path})"
        sigma = sigma_px or (cfg.layout.sigma_px if cfg.layout is not None else 0.1)
    else:
        camera, points = PAPER_CAMERA, PAPER_ROOF_POINTS_W
        cell = "the paper's roof (Table 1 holes, Table 2 camera); give --config CELL.toml for your cell"
        sigma = sigma_px or 0.1
    try:
        fig5 = uncertainty_map(camera, points, standoff_mm, steps=steps)
        report = fig5_report(cell, camera, points, standoff_mm, sigma, fig5)
    except MonoguideError as error:
        _fail(errors, "Fig. 5", error, False)
        return None, True
    failed = False
    if out is not None:
        picture = _render_map(fig5, camera.width, camera.height)
        failed = not _write_png(out, picture, errors)
        if not failed:
            report["map_png"] = str(out)
    return report, failed


def _marks(cfg, report: dict[str, Any], errors) -> bool:
    """The fixed marks' check into ``report["marks"]``; False (named on standard error) when a mark is not seen."""
    try:
        check = cell_marks_check(cfg)
    except MonoguideError as error:
        report["marks"] = {"error": error.as_dict()}
        say(errors, error_line(error, "fixed marks"))
        return False
    report["marks"] = marks_report(check)
    error = check.error()
    if error is not None:
        report["marks"]["error"] = error.as_dict()
        say(errors, error_line(error, "fixed marks"))
        return False
    return True


def _record_layout(path: Path) -> dict:
    try:
        parsed = parse_record(json.loads(path.read_text()))
        problem = parsed.problem
        covariance = predicted_covariance(problem, problem.T_s1_w0)
        sigmas = pose_sigmas(covariance, problem.T_s1_w0, problem.points_w.mean(axis=0))
        return {"path": str(path), **{k: round(v, 6) for k, v in sigmas.as_dict().items()}}
    except (OSError, UnicodeDecodeError, ValueError, RecursionError) as error:
        return {"path": str(path), "error": {"code": "RECORD_INVALID", "message": f"{path}: {error}"}}
    except MonoguideError as error:
        return {"path": str(path), "error": error.as_dict()}


def _write_png(path: Path, figure: Figure, errors) -> bool:
    try:
        save_png(figure, path)
    except OSError as error:
        say(errors, error_line(OutputNotWritten(f"--out {path}: not written: {error.strerror or error}")))
        return False
    return True


def _fail(errors, what: str, error: MonoguideError, json_output: bool) -> None:
    say(errors, error_line(error, what))
    if json_output:
        typer.echo(json.dumps({"status": "error", "error": {**error.as_dict(), "plc_code": error.plc_code}}))


@draw_style
def _render_map(fig5, width: int, height: int) -> Figure:
    """The Fig. 5 map of a ``width`` x ``height`` px camera: the sigma of the part position per px of centre
    noise as every hole moves outwards from the image centre (top left) over the image quadrant, on a log
    colour scale from the map's smallest to its largest value, with the quarter-from-the-edge position marked
    (the paper draws the whole image; its quadrants are mirror images)."""
    from matplotlib.colors import LogNorm

    figure = new_figure(MAP_SIZE)
    ax = figure.add_subplot()
    u, v, sigma = fig5.offsets_u_px, fig5.offsets_v_px, fig5.sigma_trans_mm
    lo, hi = float(sigma.min()), float(sigma.max())
    image = ax.pcolormesh(u, v, sigma, shading="gouraud", cmap="viridis_r",
                          norm=LogNorm(vmin=lo, vmax=hi if hi > lo else lo * 1.001))  # smooth between the samples
    ax.set_xlim(0.0, width / 2)  # the whole quadrant, the centre top left and v down as in the image; blank:
    ax.set_ylim(height / 2, 0.0)  # the centre itself and the margin at the border, where nothing is computed
    ax.set_aspect("equal")
    bar = figure.colorbar(image, ax=ax, label="σ of the part position per px of centre noise (mm, log scale)")
    ticks = [m * 10.0**k for k in range(math.floor(math.log10(lo)), math.ceil(math.log10(hi)) + 1)
             for m in (1.0, 2.0, 5.0) if lo <= m * 10.0**k <= hi]
    bar.set_ticks(ticks, labels=[f"{t:g}" for t in ticks])
    bar.minorticks_off()
    ax.plot(width / 4, height / 4, "o", markersize=14, markerfacecolor="none", markeredgecolor="white",
            markeredgewidth=2, label="hole a quarter of the image from the edge (the paper's recommendation)")
    ax.grid(False)
    ax.set_xlabel("every hole's distance from the image centre along u (px)")
    ax.set_ylabel("every hole's distance from the image centre along v (px)")
    ax.set_title(f"Fig. 5: predicted σ of the part position as the holes move outwards from the image centre\n"
                 f"per px of centre noise: {hi:.2f} mm near the centre .. {lo:.2f} mm")
    ax.legend(loc="lower right", facecolor="0.3", labelcolor="white", edgecolor="none")
    return figure
