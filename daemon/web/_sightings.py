"""What a cycle's row says was found in its images and where it was sought, checked piece by piece: the
measurement record's camera, views, holes and observations; a failed cycle's failure (the stage, the error's
class, the view and the hole it stopped at, where that hole was expected) and the views it visited (each one's
image, the holes and marks found, where each hole was sought) — docs/journal.md. A row written before failed cycles
kept these says where the hole was expected only in its message (``S5, P3: hole expected at (812.4, 603.1) r=14.2
px: ...``, ``S2, mark M1: not found within 40 px of where the calibration puts it (812, 603) px: ...``): that is
read from the message then.

A piece that is not what the journal's format says is left out and named in ``notes``; the rest is shown.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from monoguide.daemon.web._rows import CycleRow, finite, matrix4, pixel, point3, text, whole
from monoguide.solver.camera import CameraModel
from monoguide.solver.errors import MonoguideError

MAX_VIEWS = 64  # views of one cycle the page draws (a cell has a handful)
MAX_POINTS = 1000  # holes of one part
MAX_SIZE_PX = 100_000  # an image wider or higher than this is no camera's
STAGES = ("measuring", "solving", "checking", "writing", "reporting")
_NUMBER = r"(-?\d+(?:\.\d+)?)"
_PREFIX = re.compile(r"^([^,:]{1,40}), ([^,:]{1,60}):")
_EXPECTED = re.compile(rf"(?:expected at|where the calibration puts it) \({_NUMBER}, {_NUMBER}\)(?: r={_NUMBER} px)?")
_MARK = "mark "


@dataclass(frozen=True)
class Failure:
    """Where and how a failed cycle stopped; None where the row does not say."""

    stage: str | None  # measuring, solving, checking, writing or reporting
    exception: str | None  # the Python class of the error (HoleNotFound, KeyError, ...)
    unexpected: bool | None  # True: an error monoguide did not expect (a bug to report)
    view: str | None  # the measuring pose's name
    point: str | None  # the hole's (or, from an older row's message, the mark's) name
    expected_px: tuple[float, float] | None  # where that hole was sought
    radius_px: float | None = None  # its expected radius, when the message gives it
    is_mark: bool = False  # ``point`` names a reference mark (read from the message)
    from_message: bool = False  # read from the error message (a row written before failures were kept)


@dataclass(frozen=True)
class Sighting:
    """A hole or mark found at ``pixel``, or sought there (``radius_px`` then its expected radius)."""

    index: int | None  # the point's (or mark's) index; None when the row does not say
    name: str | None
    pixel: tuple[float, float]
    radius_px: float | None = None


@dataclass(frozen=True)
class VisitedView:
    """One measuring pose a failed cycle visited, as its row keeps it."""

    view: int  # 0-based pose index
    pose: str | None
    image: str | None  # the image's path as journaled
    T_b_f: np.ndarray | None
    holes: tuple[Sighting, ...] = ()  # found
    marks: tuple[Sighting, ...] = ()  # found
    expected: tuple[Sighting, ...] = ()  # where each hole was sought


@dataclass(frozen=True)
class RecordParts:
    """The measurement record's parts the marks are drawn from; each None (or empty) when not usable."""

    camera: CameraModel | None = None
    views: tuple[np.ndarray | None, ...] = ()  # T_s1_si of each view
    view_names: tuple[str | None, ...] = ()
    points_w: tuple[np.ndarray | None, ...] = ()
    observations: dict[int, dict[int, tuple[float, float]]] = field(default_factory=dict)  # view -> point -> px
    marks: dict[int, dict[int, tuple[float, float]]] = field(default_factory=dict)  # view -> mark -> px
    mark_names: tuple[str | None, ...] = ()


def record_parts(record: dict[str, Any] | None, notes: list[str]) -> RecordParts | None:
    """The usable parts of ``record`` (None without one); what is not usable is named in ``notes``."""
    if record is None:
        return None
    camera = None
    try:
        camera = CameraModel.from_dict(record.get("camera"), "record camera")
        if camera.width > MAX_SIZE_PX or camera.height > MAX_SIZE_PX:
            raise ValueError(f"record camera: {camera.width} x {camera.height} px is no camera's image")
    except (MonoguideError, ValueError, TypeError) as exc:
        camera = None
        notes.append(f"the record's camera cannot be used ({_why(exc)})")
    views = _items(record.get("views"), "the record's views", MAX_VIEWS, notes)
    points = _items(record.get("points_w"), "the record's points_w", MAX_POINTS, notes)
    parts = RecordParts(
        camera, tuple(matrix4(v.get("T_s1_si")) if isinstance(v, dict) else None for v in views),
        tuple(text(v.get("name"), 40) if isinstance(v, dict) else None for v in views),
        tuple(point3(p) for p in points),
        _seen(record.get("observations"), "point", "the record's observations", notes),
        _seen(record.get("mark_observations"), "mark", "the record's mark observations", notes),
        tuple(text(m.get("name"), 40) if isinstance(m, dict) else None
              for m in _items(record.get("marks"), "the record's marks", MAX_POINTS, notes)))
    broken = sum(v is None for v in parts.views) + sum(p is None for p in parts.points_w)
    if broken:
        notes.append(f"{broken} of the record's views and points are not finite poses and points: left out")
    return parts


def failure_of(row: CycleRow) -> Failure | None:
    """How ``row``'s cycle stopped (None for a cycle that did not fail): the result's ``failure``, else what its
    error message says."""
    if not row.failed:
        return None
    given = row.result.get("failure")
    if isinstance(given, dict):
        stage = text(given.get("stage"), 40)
        unexpected = given.get("unexpected")
        return Failure(stage if stage in STAGES else None, _name(given.get("exception")),
                       unexpected if isinstance(unexpected, bool) else None, text(given.get("view"), 40),
                       text(given.get("point"), 60), pixel(given.get("expected_px")))
    message = row.error_message or ""
    expected = _EXPECTED.search(message)
    if expected is None:  # a message that does not say where something was sought
        return None
    prefix = _PREFIX.match(message)
    point = prefix.group(2) if prefix else None
    is_mark = point is not None and point.startswith(_MARK)
    return Failure(None, None, None, prefix.group(1) if prefix else None,
                   point[len(_MARK):] if is_mark and point else point,
                   pixel([float(expected.group(1)), float(expected.group(2))]),
                   finite(float(expected.group(3))) if expected.group(3) else None, is_mark, True)


def visited_views(row: CycleRow, notes: list[str], pose_names: list[str]) -> dict[int, VisitedView]:
    """The views a failed cycle visited, by pose index (empty for a row that does not keep them): the index of its
    pose's name among ``pose_names`` (the part type's measuring poses, when the config is known), else its own."""
    out: dict[int, VisitedView] = {}
    for k, entry in enumerate(_items(row.result.get("views"), "the result's views", MAX_VIEWS, notes)):
        view = whole(entry.get("view"), 0, MAX_VIEWS - 1) if isinstance(entry, dict) else None
        if view is None or view in out:
            notes.append(f"the result's views[{k}]: no view index of its own, left out")
            continue
        image = entry.get("image")
        if image is None and k < len(row.image_paths):  # its image by the visiting order
            image = row.image_paths[k]
        where = f"the result's views[{k}]"
        out[view] = VisitedView(
            view, text(entry.get("pose"), 40), image if isinstance(image, str) else None, matrix4(entry.get("T_b_f")),
            _sightings(entry.get("holes"), "point", f"{where}.holes", notes),
            _sightings(entry.get("marks"), "mark", f"{where}.marks", notes),
            _sightings(entry.get("expected"), "point", f"{where}.expected", notes))
    if pose_names and all(v.pose in pose_names for v in out.values()):
        return {pose_names.index(v.pose): v for v in out.values() if v.pose is not None}
    return out


# --- private ------------------------------------------------------------------------------------


def _items(value: Any, what: str, limit: int, notes: list[str]) -> list[Any]:
    if value is None:
        return []
    if not isinstance(value, list):
        notes.append(f"{what}: not a list")
        return []
    if len(value) > limit:
        notes.append(f"{what}: {len(value)} entries, only the first {limit} shown")
    return value[:limit]


def _seen(value: Any, key: str, what: str, notes: list[str]) -> dict[int, dict[int, tuple[float, float]]]:
    out: dict[int, dict[int, tuple[float, float]]] = {}
    left = 0
    for o in _items(value, what, MAX_VIEWS * MAX_POINTS, notes):
        view = whole(o.get("view"), 0, MAX_VIEWS - 1) if isinstance(o, dict) else None
        index = whole(o.get(key), 0, MAX_POINTS - 1) if isinstance(o, dict) else None
        at = pixel(o.get("pixel")) if isinstance(o, dict) else None
        if view is None or index is None or at is None:
            left += 1
        else:
            out.setdefault(view, {})[index] = at
    if left:
        notes.append(f"{what}: {left} not a view, a {key} and a pixel: left out")
    return out


def _sightings(value: Any, key: str, what: str, notes: list[str]) -> tuple[Sighting, ...]:
    out = []
    left = 0
    for s in _items(value, what, MAX_POINTS, notes):
        at = pixel(s.get("pixel")) if isinstance(s, dict) else None
        if at is None:
            left += 1
            continue
        radius = finite(s.get("radius_px"), 1e5)
        out.append(Sighting(whole(s.get(key), 0, MAX_POINTS - 1), text(s.get("name"), 60), at,
                            radius if radius is not None and radius > 0 else None))
    if left:
        notes.append(f"{what}: {left} without a pixel, left out")
    return tuple(out)


def _name(value: Any) -> str | None:
    return value if isinstance(value, str) and re.fullmatch(r"[A-Za-z_][A-Za-z0-9_.]{0,79}", value) else None


def _why(exc: BaseException) -> str:
    message = exc.message if isinstance(exc, MonoguideError) else str(exc)
    return message[:200]
