"""The *One cycle* page's facts: the row, each view with its image's state and its marks (``_overlay``), the
record's observations, the robot's pose at each capture, the stage timings, the offset's intent and what became
of it."""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any

import numpy as np

from monoguide.daemon.config import CellConfig
from monoguide.daemon.service import Journal, JournalRow
from monoguide.daemon.web._images import ImageGone, crop_box, image_file
from monoguide.daemon.web._meanings import meaning
from monoguide.daemon.web._overlay import IMAGE_ORIGIN, RESIDUAL_SCALE, HoleMark, ViewMarks, view_marks
from monoguide.solver import frames

DEFAULT_RADIUS_PX = 20.0  # the crop's size when the config gives no hole radius


@dataclass(frozen=True)
class ViewPage:
    marks: ViewMarks
    image_error: str | None  # why there is no image (pruned, gone, never written); None: there is one
    crops: list[tuple[HoleMark, tuple[int, int, int, int]]]  # each hole with a centre and its square


def cycle_facts(journal: Journal, number: int, config: CellConfig | None) -> dict[str, Any]:
    """Everything the page shows of cycle ``number`` (:class:`JournalEntryMissing` when there is none)."""
    row = journal.cycle(number)
    intent = journal.intent(number)
    marks = view_marks(row.record, row.result, part_config(config, row.job), len(row.image_paths))
    views = [_view_page(journal, row, m) for m in marks]
    return {
        "row": row, "meaning": meaning(row.error_code), "views": views, "origin": IMAGE_ORIGIN,
        "residual_scale": RESIDUAL_SCALE, "poses": [_xyzabc(T) for T in row.poses_at_capture],
        "timings": sorted(row.timings_s.items(), key=lambda kv: -kv[1]),
        "intent": intent, "pruned": row.images_pruned_at is not None,
        "record_text": None if row.record is None else json.dumps(row.record, indent=1),
        "result": {k: v for k, v in (row.result or {}).items() if k != "covariance"},
        "newer": number + 1 if journal.has_cycle(number + 1) else None,
        "older": number - 1 if number > 1 and journal.has_cycle(number - 1) else None,
    }


def hole_crop(row: JournalRow, config: CellConfig | None, view: int, point: int) -> tuple[ViewMarks, HoleMark,
                                                                                          tuple[int, int, int, int]]:
    """The marks and the square of hole ``point`` in ``view`` (``LookupError`` when the view does not have it)."""
    marks = view_marks(row.record, row.result, part_config(config, row.job), len(row.image_paths))
    if not 0 <= view < len(marks):
        raise LookupError(f"cycle {row.number} has no view {view + 1}")
    for hole in marks[view].holes:
        if hole.point == point:
            box = _box(hole, marks[view])
            if box is not None:
                return marks[view], hole, box
    raise LookupError(f"cycle {row.number} view {view + 1}: no hole P{point + 1} with a centre")


def part_config(config: CellConfig | None, job: int | None) -> CellConfig | None:
    """The cell as the cycle's part type sees it (its holes, names, poses: ``CellConfig.for_job``); the cell's
    own for a job the config does not have (a journal of another config), None without a config."""
    if config is None or job is None or job not in config.jobs:
        return config
    return config.for_job(job)


# --- private ------------------------------------------------------------------------------------


def _view_page(journal: Journal, row: JournalRow, marks: ViewMarks) -> ViewPage:
    try:
        image_file(journal.state_dir, row, marks.index)
        error = None
    except ImageGone as gone:
        error = str(gone)
    crops = [(hole, box) for hole in marks.holes if (box := _box(hole, marks)) is not None]
    return ViewPage(marks, error, crops)


def _box(hole: HoleMark, marks: ViewMarks) -> tuple[int, int, int, int] | None:
    centre = hole.measured_px or hole.predicted_px
    if centre is None or not marks.width:
        return None
    radius = DEFAULT_RADIUS_PX
    if hole.rim_px:
        rim = np.asarray(hole.rim_px)
        radius = float(np.max(np.linalg.norm(rim - np.asarray(centre), axis=1)))
    return crop_box(centre, radius, marks.width, marks.height)


def _xyzabc(T: list[list[float]]) -> list[float]:
    return [round(float(v), 3) for v in frames.T_to_kuka_frame(np.asarray(T, float))]
