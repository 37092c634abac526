"""What ``monoguide plan`` prints for people: the layout comparison and the Fig. 5 table.

Both read the report dictionary that ``--json`` prints, so that the two outputs cannot disagree.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from monoguide.solver.camera import CameraModel
from monoguide.solver.frames import invert
from monoguide.solver.planning import UncertaintyMap, look_at_poses, pose_sigmas, quarter_targets
from monoguide.solver.planning.prediction import layout_covariance


def print_layout(console: Console, report: dict[str, Any]) -> None:
    """The planned layout beside the cell's current one."""
    env, con = report["envelope"], report["constraints"]
    t = "/".join(f"{v:g}" for v in env["translation_mm"])
    r = "/".join(f"{v:g}" for v in env["rotation_deg"])
    centre = ", ".join(f"{v:.0f}" for v in env["centre_w"])
    console.print(f"Cell: {escape(report['cell'])} ({escape(report['config'])})")
    console.print(
        f"Envelope: ±{t} mm and ±{r}° per part axis about ({centre}) mm; checked at its 64 corners, the reference "
        f"and a seeded interior sample ({env['parts_checked']} parts)"
    )
    reach = "" if con["reach_radius_mm"] is None else f", flange within {con['reach_radius_mm']:g} mm of the base"
    console.print(
        f"Constraints: standoff {con['standoff_mm'][0]:g}-{con['standoff_mm'][1]:g} mm, line of sight within "
        f"{con['max_view_angle_deg']:g}° of the surface normal, margin ≥ {con['margin_px']:g} px, depth of field "
        f"{con['depth_of_field_mm'][0]:g}-{con['depth_of_field_mm'][1]:g} mm{reach}"
    )
    grasp = ", ".join(f"{v:.0f}" for v in report["grasp_point_w"])
    table = Table(title=f"Predicted σ at {report['sigma_px']:g} px (grasp point ({grasp}) mm of the part frame); "
                  f"repeatability {report['repeatability_mm']:g} mm / {report['repeatability_deg']:g}° per axis")
    for column in ("layout", "rot °", "grasp mm", "origin mm", "rot ° rep.", "grasp mm rep.", "origin mm rep.",
                   "worst margin px", "depth mm"):
        table.add_column(column, justify="left" if column == "layout" else "right")
    for label, s in (("current", report["current"]), ("planned", report)):
        table.add_row(label, *_sigma_cells(s), _margin(s["margin_px_min"]),
                      f"{s['depth_mm_min']:.0f}-{s['depth_mm_max']:.0f}")
    console.print(table)
    if report["current"]["degenerate"]:
        console.print(f"current layout: {escape(report['current']['degenerate'])}")
    poses = Table(title="Measuring poses (cell frame; margin and depth over the whole envelope)")
    for column in ("pose", "hole", "layout", "camera x y z mm", "optical axis", "standoff mm", "view angle °",
                   "pixel u v", "margin px", "depth mm"):
        poses.add_column(column, justify="left" if column in ("pose", "hole", "layout") else "right")
    for label, rows in (("current", report["current"]["poses"]), ("planned", report["poses"])):
        for p in rows:
            poses.add_row(
                p["name"], p["hole"], label, " ".join(f"{v:.1f}" for v in p["position_cf_mm"]),
                " ".join(f"{v:+.3f}" for v in p["optical_axis_cf"]), f"{p['standoff_mm']:.0f}",
                f"{p['view_angle_deg']:.1f} (≤{p['view_angle_max_deg']:.1f})",
                " ".join(f"{v:.0f}" for v in p["pixel"]), _margin(p["margin_px"]),
                f"{p['depth_mm'][0]:.0f}-{p['depth_mm'][1]:.0f}",
            )
    console.print(poses)
    if "written" in report:
        console.print(f"Cell config with the planned poses written to {escape(report['written'])}")
    if "layout_png" in report:
        console.print(f"Layout picture written to {escape(report['layout_png'])}")
    print_marks(console, report)
    _print_record(console, report)


def fig5_report(cell: str, camera: CameraModel, points_w: np.ndarray, standoff_mm: float, sigma_px: float,
                fig5: UncertaintyMap) -> dict[str, Any]:
    """The Fig. 5 study as a JSON-ready dict: the map and the quarter-from-the-edge recommendation."""
    targets = quarter_targets(camera, points_w)
    poses = look_at_poses(points_w, camera, standoff_mm, targets)
    sigmas = pose_sigmas(layout_covariance(camera, points_w, poses, sigma_px), invert(poses[0]),
                         np.asarray(points_w).mean(axis=0))
    return {
        "cell": cell,
        "camera": f"{camera.width} x {camera.height} px, f = {camera.fx:.1f} px",
        "standoff_mm": standoff_mm,
        "sigma_px": sigma_px,
        "recommended_pixels": targets.round(1).tolist(),
        "recommended": {k: round(v, 6) for k, v in sigmas.as_dict().items()},
        "map": {
            "offset_u_px": fig5.offsets_u_px.round(1).tolist(),
            "offset_v_px": fig5.offsets_v_px.round(1).tolist(),
            "sigma_trans_mm_per_px": fig5.sigma_trans_mm.round(5).tolist(),
            "sigma_rot_deg_per_px": fig5.sigma_rot_deg.round(6).tolist(),
        },
    }


def print_fig5(console: Console, report: dict[str, Any]) -> None:
    sigma_px = report["sigma_px"]
    m = report["map"]
    u, v, trans = m["offset_u_px"], m["offset_v_px"], np.array(m["sigma_trans_mm_per_px"])
    console.print(f"Cell: {escape(report['cell'])}")
    table = Table(title=f"Fig. 5: σ of the part position (mm) for {sigma_px:g} px centre noise, cameras looking "
                  f"straight down from {report['standoff_mm']:g} mm, every hole moved |du|, |dv| px outwards "
                  "from the image centre")
    table.add_column("|dv| \\ |du|", justify="right")
    cols = range(0, len(u), max(1, len(u) // 6))
    rows = range(0, len(v), max(1, len(v) // 6))
    for iu in cols:
        table.add_column(f"{u[iu]:.0f}", justify="right")
    for iv in rows:
        table.add_row(f"{v[iv]:.0f}", *[f"{sigma_px * trans[iv, iu]:.3f}" for iu in cols])
    console.print(table)
    rec = report["recommended"]
    console.print(
        f"Each hole a quarter of the image from the edge, away from the part's centre (the paper's Sec. 4): "
        f"predicted σ {rec['sigma_rot_deg']:.4f}° / {rec['sigma_origin_mm']:.3f} mm at the part origin, "
        f"{rec['sigma_trans_mm']:.3f} mm at the holes' centroid, for {sigma_px:g} px. "
        "`monoguide plan --layout` plans tilted views that do better and hold the whole envelope."
    )
    for i, (pu, pv) in enumerate(report["recommended_pixels"]):
        console.print(f"  view {i + 1}: hole {i + 1} at pixel ({pu:.0f}, {pv:.0f})")
    if "map_png" in report:
        console.print(f"Map written to {escape(report['map_png'])}")
    print_marks(console, report)
    _print_record(console, report)


def print_marks(console: Console, report: dict[str, Any]) -> None:
    """The fixed marks' check (``report["marks"]``, when the cell has marks): a table per measuring pose."""
    marks = report.get("marks")
    if marks is None:
        return
    console.print(
        f"Fixed marks: each mark's whole circle in front of its view's camera and inside the image by the margin, its "
        f"image apart from the view's other marks, and its line of sight never through a part measured from that view: "
        f"≥ its radius + {marks['clearance_mm']:g} mm outside the part's outline wherever the part lies in its "
        f"envelope ({marks['parts_sampled']} part poses of the envelope's box and a local search from the worst)")
    for note in marks["notes"]:
        console.print(f"  {escape(note)}")
    views: dict[str, list[dict[str, Any]]] = {}
    for row in marks["marks"]:
        views.setdefault(row["view"], []).append(row)
    for view, rows in views.items():
        table = Table(title=f"Fixed marks of {escape(view)}")
        for column in ("mark", "clearance mm", "image margin px", "ok/why"):
            table.add_column(column, justify="right" if column in ("clearance mm", "image margin px") else "left")
        for row in rows:
            clearance = "-" if row["clearance_mm"] is None else f"{row['clearance_mm']:.1f} (≥{row['required_mm']:g})"
            margin = "behind" if row["margin_px"] is None else f"{row['margin_px']:.0f} (≥{row['required_px']:g})"
            table.add_row(escape(row["mark"]), clearance, margin, "ok" if row["ok"] else escape(_mark_why(row)))
        console.print(table)
    bad = sum(not row["ok"] for row in marks["marks"])
    console.print(f"Fixed marks: all {len(marks['marks'])} seen" if not bad
                  else f"Fixed marks: {bad} of {len(marks['marks'])} not seen (an error of the plan)")


def _mark_why(row: dict[str, Any]) -> str:
    out = []
    for reason in row["reasons"]:
        if reason == "hidden":
            r = ", ".join(f"{v:+.1f}" for v in row["worst_deviation_deg"])
            t = ", ".join(f"{v:+.0f}" for v in row["worst_deviation_mm"])
            out.append(f"hidden by {row['part']} turned ({r})° shifted ({t}) mm")
        elif reason == "out_of_image":
            out.append("out of the image")
        elif reason == "behind_camera":
            out.append("behind the camera")
        elif reason == "faces_away":
            out.append("faces away")
        elif reason == "overlaps":
            out.append(f"overlaps {row['nearest']} in the image")
    return "; ".join(out)


def _print_record(console: Console, report: dict[str, Any]) -> None:
    layout = report.get("record")
    if layout is not None and "error" not in layout:
        console.print(
            f"Layout of {escape(layout['path'])}: predicted σ {layout['sigma_rot_deg']:.4f}° / "
            f"{layout['sigma_trans_mm']:.3f} mm at the holes' centroid, {layout['sigma_origin_mm']:.3f} mm at the "
            "part origin (its own sigma_px and view_sigma)"
        )


def _sigma_cells(s: dict[str, Any]) -> list[str]:
    keys = ("sigma_rot_deg", "sigma_trans_mm", "sigma_origin_mm")
    cells = []
    for suffix in ("", "_with_repeatability"):
        for key in keys:
            value = s[key + suffix]
            cells.append("-" if value is None else (f"{value:.4f}" if "rot" in key else f"{value:.3f}"))
    return cells


def _margin(value: float | None) -> str:
    return "behind" if value is None else f"{value:.0f}"
