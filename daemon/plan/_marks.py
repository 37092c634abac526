"""The cell config's side of the fixed marks' check (``solver.planning.marks``): every measuring pose of the cell
with the marks it lists, and the part types measured from it, each anywhere in its own envelope.

A pose's marks must be seen whichever of the cell's part types is measured from it: each part type that lists
the pose in its views (``[[parts]] measuring_poses``; the single ``[part]`` lists them all) may hide them, with its
own envelope (its ``[layout]`` one, widened per axis to ``[checks] envelope_axis_mm`` / ``envelope_axis_deg``
when those let the cycle accept parts farther off); a part type that never stops at the pose is not there when it
is measured. A pose's marks keep its part types' largest ``[layout] margin_px`` from the image border.
"""

from __future__ import annotations

from typing import Any

from monoguide.daemon.config import CellConfig, LayoutConfig
from monoguide.solver.envelope import DeviationEnvelope
from monoguide.solver.planning.marks import Mark, MarkedView, MarksVisibility, PartSheet, check_marks


def cell_marks_check(config: CellConfig) -> MarksVisibility | None:
    """The marks' check of the cell, or None when it has no ``[[reference_marks]]``."""
    if not config.reference_marks:
        return None
    marks = [Mark(m.name, m.position_cf, m.radius_mm, m.normal_cf) for m in config.reference_marks]
    parts, uses = [], []
    for job in config.jobs:
        view = config.for_job(job)
        layout = view.layout or LayoutConfig()
        parts.append(PartSheet(view.part_name, view.reference.T_cf_w0, view.part.points_w,
                               _envelope(view, layout).at(view.part.points_w), view.part.outline_w))
        uses.append(({p.name for p in view.measuring_poses}, layout.constraints.margin_px))
    views = []
    for pose in config.cell_poses:
        if not pose.marks:
            continue
        by = tuple(j for j, (names, _) in enumerate(uses) if pose.name in names)
        margin = max((uses[j][1] for j in by), default=LayoutConfig().constraints.margin_px)
        views.append(MarkedView(pose.name, pose.T_cf_si, pose.marks, by, margin))
    return check_marks(config.camera.intrinsics, views, marks, parts)


def _envelope(view: CellConfig, layout: LayoutConfig) -> DeviationEnvelope:
    """The part type's ``[layout]`` envelope, each axis widened to what ``[checks]`` accepts."""
    planned = layout.envelope
    if view.checks is None:
        return planned
    checked = view.checks.envelope(planned)
    return DeviationEnvelope(
        tuple(max(a, b) for a, b in zip(planned.translation_mm, checked.translation_mm, strict=True)),
        tuple(max(a, b) for a, b in zip(planned.rotation_deg, checked.rotation_deg, strict=True)), planned.about_w)


def marks_report(check: MarksVisibility) -> dict[str, Any]:
    """The check as the JSON-ready part of ``monoguide plan``'s report (``marks``)."""
    rows = []
    for r in check.results:
        rows.append({
            "view": r.view,
            "mark": r.mark,
            "ok": r.ok,
            "status": r.status,
            "reasons": list(r.reasons),
            "clearance_mm": None if r.clearance_mm is None else round(r.clearance_mm, 2),
            "required_mm": round(r.required_mm, 2),
            "part": r.part,
            "worst_deviation_deg": None if r.deviation_deg is None else [round(v, 3) for v in r.deviation_deg],
            "worst_deviation_mm": None if r.deviation_mm is None else [round(v, 2) for v in r.deviation_mm],
            "margin_px": None if r.margin_px is None else round(r.margin_px, 1),
            "required_px": r.required_px,
            "radius_px": None if r.radius_px is None else round(r.radius_px, 1),
            "gap_px": None if r.gap_px is None else round(r.gap_px, 1),
            "nearest": r.nearest,
            "why": r.why(),
        })
    return {"ok": check.ok, "clearance_mm": check.clearance_mm, "parts_sampled": check.parts_sampled,
            "notes": list(check.notes), "marks": rows}
