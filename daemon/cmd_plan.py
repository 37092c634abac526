"""``monoguide plan``: where the holes should land in the image (Sec. 4, Fig. 5), and what a layout gives."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Annotated

import cv2
import numpy as np
import typer
from rich.console import Console
from rich.table import Table

from monoguide.solver.camera import PAPER_CAMERA
from monoguide.solver.errors import MonoguideError
from monoguide.solver.planning import (
    UncertaintyMap,
    layout_covariance,
    look_at_poses,
    quarter_targets,
    uncertainty_map,
)
from monoguide.solver.record import parse_record
from monoguide.solver.synthetic import PAPER_ROOF_POINTS_W
from monoguide.solver.uncertainty import predicted_covariance


def plan(
    out: Annotated[Path | None, typer.Option(help="Write the Fig. 5 map (uncertainty vs image position), PNG.")] = None,
    record: Annotated[
        Path | None, typer.Option(help="Report the predicted uncertainty of this record's layout (views, points).")
    ] = None,
    standoff_mm: Annotated[float, typer.Option(help="Camera distance above the holes, mm.")] = 650.0,
    sigma_px: Annotated[float, typer.Option(help="Standard deviation of a hole centre, px.")] = 0.1,
    steps: Annotated[int, typer.Option(help="Grid steps of the map along each image axis.")] = 25,
    json_output: Annotated[bool, typer.Option("--json", help="Machine-readable output.")] = False,
) -> None:
    """Plan measuring poses for the paper's roof (Table 1 holes, Table 2 camera): the map of the pose
    uncertainty as every hole moves from the image centre outwards, and the recommended image positions."""
    console = Console()
    if sigma_px <= 0 or standoff_mm <= 0 or steps < 2:
        raise typer.BadParameter(
            f"need sigma_px > 0, standoff_mm > 0, steps >= 2 (got {sigma_px}, {standoff_mm}, {steps})"
        )
    camera, points_w = PAPER_CAMERA, PAPER_ROOF_POINTS_W
    fig5 = uncertainty_map(camera, points_w, standoff_mm, steps=steps)
    targets = quarter_targets(camera, points_w)
    recommended = _predict(camera, points_w, standoff_mm, targets, sigma_px)
    report: dict = {
        "camera": f"{camera.width} x {camera.height} px, f = {camera.fx:.1f} px",
        "standoff_mm": standoff_mm,
        "sigma_px": sigma_px,
        "recommended_pixels": targets.round(1).tolist(),
        "recommended": recommended,
        "map": {
            "offset_u_px": fig5.offsets_u_px.round(1).tolist(),
            "offset_v_px": fig5.offsets_v_px.round(1).tolist(),
            "sigma_trans_mm_per_px": fig5.sigma_trans_mm.round(5).tolist(),
            "sigma_rot_deg_per_px": fig5.sigma_rot_deg.round(6).tolist(),
        },
    }
    if record is not None:
        report["record"] = _record_layout(record)
    if out is not None:
        cv2.imwrite(str(out), _render_map(fig5, camera.width, camera.height, targets))
        report["map_png"] = str(out)
    if json_output:
        typer.echo(json.dumps(report))
        return
    _print_report(console, report, fig5, sigma_px)


def _predict(camera, points_w, standoff_mm, targets, sigma_px) -> dict:
    covariance = layout_covariance(camera, points_w, look_at_poses(points_w, camera, standoff_mm, targets), sigma_px)
    return _sigmas(covariance)


def _sigmas(covariance: np.ndarray) -> dict:
    return {
        "sigma_rot_deg": round(math.degrees(math.sqrt(np.trace(covariance[:3, :3]))), 6),
        "sigma_trans_mm": round(math.sqrt(np.trace(covariance[3:, 3:])), 5),
    }


def _record_layout(path: Path) -> dict:
    try:
        parsed = parse_record(json.loads(path.read_text()))
        return {"path": str(path), **_sigmas(predicted_covariance(parsed.problem, parsed.problem.T_s1_w0))}
    except (OSError, json.JSONDecodeError) as error:
        return {"path": str(path), "error": {"code": "RECORD_INVALID", "message": f"{path}: {error}"}}
    except MonoguideError as error:
        return {"path": str(path), "error": error.as_dict()}


def _print_report(console: Console, report: dict, fig5: UncertaintyMap, sigma_px: float) -> None:
    table = Table(title=f"Fig. 5: σ of the part position (mm) for {sigma_px} px centre noise, every hole moved "
                  "|du|, |dv| px outwards from the image centre")
    table.add_column("|dv| \\ |du|", justify="right")
    cols = range(0, len(fig5.offsets_u_px), max(1, len(fig5.offsets_u_px) // 6))
    rows = range(0, len(fig5.offsets_v_px), max(1, len(fig5.offsets_v_px) // 6))
    for iu in cols:
        table.add_column(f"{fig5.offsets_u_px[iu]:.0f}", justify="right")
    for iv in rows:
        table.add_row(
            f"{fig5.offsets_v_px[iv]:.0f}",
            *[f"{sigma_px * fig5.sigma_trans_mm[iv, iu]:.3f}" for iu in cols],
        )
    console.print(table)
    rec = report["recommended"]
    console.print(
        f"Recommended: each hole a quarter of the image from the edge, on the side away from the part's centre "
        f"(Sec. 4): predicted σ {rec['sigma_rot_deg']:.4f}° / {rec['sigma_trans_mm']:.3f} mm at {sigma_px} px."
    )
    for i, (u, v) in enumerate(report["recommended_pixels"]):
        console.print(f"  view {i + 1}: hole {i + 1} at pixel ({u:.0f}, {v:.0f})")
    if "record" in report:
        layout = report["record"]
        if "error" in layout:
            console.print(f"[red]{layout['path']}: {layout['error']['code']}[/red] {layout['error']['message']}")
        else:
            console.print(
                f"Layout of {layout['path']}: predicted σ {layout['sigma_rot_deg']:.4f}° / "
                f"{layout['sigma_trans_mm']:.3f} mm (its own sigma_px and view_sigma)"
            )
    if "map_png" in report:
        console.print(f"Map written to {report['map_png']}")


def _render_map(fig5: UncertaintyMap, width: int, height: int, targets: np.ndarray) -> np.ndarray:
    """The map as a false-colour picture of the image quadrant (centre at the top left), log scale, with
    the recommended position marked; two image pixels per picture pixel."""
    scale = 2
    w, h = width // (2 * scale), height // (2 * scale)
    values = np.log(fig5.sigma_trans_mm)
    grid = cv2.resize(values.astype(np.float32), (w, h), interpolation=cv2.INTER_LINEAR)
    norm = ((grid - grid.min()) / max(float(np.ptp(grid)), 1e-12) * 255).astype(np.uint8)
    picture = cv2.applyColorMap(255 - norm, cv2.COLORMAP_VIRIDIS)
    quarter = (int(width / 4 / scale), int(height / 4 / scale))
    cv2.circle(picture, quarter, 6, (255, 255, 255), 2)
    lo, hi = float(fig5.sigma_trans_mm.min()), float(fig5.sigma_trans_mm.max())
    lines = (
        "image quadrant: centre top left; colour: log sigma of the part position",
        f"per px of centre noise: {hi:.2f} mm (dark, near centre) .. {lo:.2f} mm (bright)",
        "o: hole a quarter of the image from the edge (recommended)",
    )
    for k, text in enumerate(lines):
        y = h - 10 - 18 * (len(lines) - 1 - k)
        cv2.putText(picture, text, (8, y), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1, cv2.LINE_AA)
    return picture
