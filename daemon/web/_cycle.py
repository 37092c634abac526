"""The *One cycle* page's facts: the row, each view with its image's state and its marks (``_overlay``), the
record's observations, the robot's pose at each capture, the stage timings, the offset's intent and what became
of it; for a failed cycle how it failed (the stage, the error's class, its code and message, the view and the hole
it stopped at); and what of the row could not be shown."""

from __future__ import annotations

import json
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from monoguide.daemon.config import CellConfig
from monoguide.daemon.service import Journal, OffsetIntent
from monoguide.daemon.web._cycles import MAX_NUMBER
from monoguide.daemon.web._images import ImageGone, crop_box, image_file, png_size
from monoguide.daemon.web._meanings import meaning
from monoguide.daemon.web._overlay import IMAGE_ORIGIN, RESIDUAL_SCALE, HoleMark, ViewMarks, view_marks
from monoguide.daemon.web._rows import UNDECODABLE, CycleRow, read_cycle
from monoguide.solver import frames

DEFAULT_RADIUS_PX = 20.0  # the crop's size when the config gives no hole radius
MAX_RECORD_TEXT = 2_000_000  # characters of the record shown on the page (the download has it all)


@dataclass(frozen=True)
class ViewPage:
    marks: ViewMarks
    image_error: str | None  # why there is no image (pruned, gone, never written); None: there is one
    crops: list[tuple[HoleMark, tuple[int, int, int, int]]]  # each hole with a centre and its square


def cycle_facts(journal: Journal, number: int, config: CellConfig | None) -> dict[str, Any]:
    """Everything the page shows of cycle ``number`` (:class:`JournalEntryMissing` when there is none)."""
    row = read_cycle(journal, number)
    config = part_config(config, row.job)
    overlay = view_marks(row, config)
    notes = [*row.unreadable, *overlay.notes]
    intent = _intent(journal, number, notes)
    views = [_view_page(journal.state_dir, row, m) for m in overlay.views]
    stopped = next((m for m in overlay.views if any(h.failed for h in m.holes) or any(k.failed for k in m.marks)),
                   None)
    return {
        "row": row, "meaning": meaning(row.error_code), "views": views, "origin": IMAGE_ORIGIN,
        "residual_scale": RESIDUAL_SCALE, "failure": overlay.failure, "notes": notes,
        "poses": [None if T is None else _xyzabc(T) for T in row.poses_at_capture],
        "visited_poses": {v.marks.index: _xyzabc(v.marks.T_b_f) for v in views if v.marks.T_b_f is not None},
        "timings": sorted(row.timings_s.items(), key=lambda kv: -kv[1]),
        "intent": intent, "pruned": row.images_pruned_at is not None,
        "record_text": _record_text(row.record),
        "stopped_square": next(((v, h, box) for v in views for h, box in v.crops if h.failed and not v.image_error),
                               None),
        "failed_view": None if stopped is None else stopped.name,
        "failed_view_index": None if stopped is None else stopped.index,
        "newer": number + 1 if number < MAX_NUMBER and journal.has_cycle(number + 1) else None,
        "older": number - 1 if number > 1 and journal.has_cycle(number - 1) else None,
    }


def hole_crop(state_dir: Path, row: CycleRow, config: CellConfig | None, view: int,
              point: int) -> tuple[Path, tuple[int, int, int, int]]:
    """The image and the square of hole ``point`` in ``view`` (``LookupError`` when the view does not have it,
    :class:`ImageGone` when its image is not there)."""
    views = view_marks(row, part_config(config, row.job)).views
    if not 0 <= view < len(views):
        raise LookupError(f"cycle {row.number} has no view {view + 1}")
    marks = views[view]
    path = image_file(state_dir, row.number, view, marks.image, row.images_pruned_at is not None)
    marks = _sized(marks, path)
    for hole in marks.holes:
        if hole.point == point:
            box = _box(hole, marks)
            if box is not None:
                return path, box
    raise LookupError(f"cycle {row.number} view {view + 1}: no hole P{point + 1} with a centre")


def part_config(config: CellConfig | None, job: int | None) -> CellConfig | None:
    """The cell as the cycle's part type sees it (its holes, names, poses: ``CellConfig.for_job``); the cell's
    own for a job the config does not have (a journal of another config), None without a config."""
    if config is None or job is None or job not in config.jobs:
        return config
    return config.for_job(job)


# --- private ------------------------------------------------------------------------------------


def _view_page(state_dir: Path, row: CycleRow, marks: ViewMarks) -> ViewPage:
    error = None
    if marks.visited is False:
        error = "not visited: the cycle stopped before this pose"
    else:
        try:
            marks = _sized(marks, image_file(state_dir, row.number, marks.index, marks.image,
                                             row.images_pruned_at is not None))
        except ImageGone as gone:
            error = str(gone)
    crops = [(hole, box) for hole in marks.holes if (box := _box(hole, marks)) is not None]
    return ViewPage(marks, error, crops)


def _sized(marks: ViewMarks, path: Path) -> ViewMarks:
    """A view without a camera (no record, no config) takes its size from its image."""
    if marks.width:
        return marks
    size = png_size(path)
    return marks if size is None else replace(marks, width=size[0], height=size[1])


def _box(hole: HoleMark, marks: ViewMarks) -> tuple[int, int, int, int] | None:
    centre = hole.measured_px or hole.predicted_px or hole.expected_px
    if centre is None or hole.point is None or not marks.width:
        return None
    radius = DEFAULT_RADIUS_PX
    if hole.rim_px:
        rim = np.asarray(hole.rim_px)
        radius = float(np.max(np.linalg.norm(rim - np.asarray(centre), axis=1)))
    elif hole.expected_radius_px is not None:
        radius = hole.expected_radius_px
    return crop_box(centre, radius, marks.width, marks.height)


def _intent(journal: Journal, number: int, notes: list[str]) -> OffsetIntent | None:
    try:
        return journal.intent(number)
    except (*UNDECODABLE, KeyError) as exc:
        notes.append(f"the offset sent to the robot: its journal row cannot be read ({type(exc).__name__})")
        return None


def _record_text(record: dict[str, Any] | None) -> str | None:
    if record is None:
        return None
    try:
        text = json.dumps(record, indent=1)
    except (ValueError, RecursionError):
        return None
    return text if len(text) <= MAX_RECORD_TEXT else text[:MAX_RECORD_TEXT] + "\n... (download the record)"


def _xyzabc(T: np.ndarray) -> list[float] | None:
    with np.errstate(all="ignore"):
        values = [round(float(v), 3) for v in frames.T_to_kuka_frame(T)]
    return values if all(np.isfinite(values)) else None
