"""What the *One cycle* page draws over each view's image, from the journal's row alone (and the cell config
when it is given): the hole's measured centre, where the solved pose puts it, the residual between them scaled
so that it can be seen, the rim and the region the hole was sought in, each hole's name; and for a failed cycle
what its views found (holes, reference marks) and, where a hole was sought and not found, where it was expected.

Every coordinate is a raw (distorted) image pixel, as the record keeps them: pixel (0, 0)'s centre is at
(0, 0), so the image itself is drawn from (-0.5, -0.5) (``IMAGE_ORIGIN``). The record keeps centres, not the
fitted ellipses: the rim drawn is the hole's rim circle (``[part] hole_radius_mm``) projected at the solved pose
and moved by the residual, so its centre sits where the detector's ellipse was; without a config there is no
radius and no rim. The search region is the cycle's rule (``solver.planning.search.hole_search``) over the
config's deviation envelope (``[layout]``, else +-50 mm, +-5 deg). A config whose part is not the record's (other
holes: a journal of another config, or another job's part) is not used for the holes: their names, rims and regions
are left out and the page says so.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from monoguide.daemon.config import CellConfig
from monoguide.daemon.web._rows import MAX_PX, CycleRow, matrix4
from monoguide.daemon.web._sightings import (
    MAX_POINTS,
    MAX_VIEWS,
    Failure,
    RecordParts,
    VisitedView,
    failure_of,
    record_parts,
    visited_views,
)
from monoguide.solver import frames
from monoguide.solver.camera import CameraModel
from monoguide.solver.holes import circle_basis
from monoguide.solver.planning.envelope import DeviationEnvelope
from monoguide.solver.planning.search import hole_search, search_extremes

IMAGE_ORIGIN = -0.5  # where the image's top-left corner lies in pixel-centre coordinates
RESIDUAL_SCALE = 200.0  # a 0.1 px residual is drawn 20 px long
RIM_POINTS = 72
FIT_MM = 1e-3  # a config's part is the record's when every hole lies within this of the record's


@dataclass(frozen=True)
class HoleMark:
    """One hole in one view."""

    name: str
    point: int | None  # None: a hole the row names but does not number (no square of it)
    measured_px: tuple[float, float] | None  # the record's centre (perspective-corrected): None when not found
    predicted_px: tuple[float, float] | None  # the image of the hole's centre at the solved pose
    rim_px: tuple[tuple[float, float], ...] = ()  # the rim as fitted (see the module's doc)
    region: tuple[int, int, int, int] | None = None  # x, y, w, h: where it was sought
    expected_px: tuple[float, float] | None = None  # a failed cycle: where it was sought
    expected_radius_px: float | None = None
    failed: bool = False  # the hole the cycle stopped at

    @property
    def missing(self) -> bool:
        """Sought and not found."""
        return self.measured_px is None and self.expected_px is not None

    @property
    def residual_px(self) -> tuple[float, float] | None:
        if self.measured_px is None or self.predicted_px is None:
            return None
        return (self.measured_px[0] - self.predicted_px[0], self.measured_px[1] - self.predicted_px[1])

    @property
    def residual_end_px(self) -> tuple[float, float] | None:
        """Where the scaled residual arrow ends, drawn from the predicted centre."""
        r = self.residual_px
        if r is None or self.predicted_px is None:
            return None
        return (self.predicted_px[0] + RESIDUAL_SCALE * r[0], self.predicted_px[1] + RESIDUAL_SCALE * r[1])


@dataclass(frozen=True)
class MarkSeen:
    """A reference mark in a failed cycle's view: found at ``pixel``, or (``failed``) sought at ``expected_px``."""

    name: str
    pixel: tuple[float, float] | None
    expected_px: tuple[float, float] | None = None
    failed: bool = False


@dataclass(frozen=True)
class ViewMarks:
    index: int  # 0-based view (measuring pose) index
    name: str  # the measuring pose's name (S1, ...)
    width: int
    height: int
    holes: list[HoleMark] = field(default_factory=list)
    marks: list[MarkSeen] = field(default_factory=list)
    image: str | None = None  # the image's path as journaled
    visited: bool | None = None  # a failed cycle's: False for a pose it never reached; None when the row does not say
    T_b_f: np.ndarray | None = None  # the flange at the capture, when the row says


@dataclass(frozen=True)
class Overlay:
    views: list[ViewMarks]
    failure: Failure | None
    notes: list[str]  # what of the row could not be drawn, and why


def view_marks(row: CycleRow, config: CellConfig | None) -> Overlay:
    """The marks of every view of ``row``'s cycle (at least the record's, the config's and the visited ones)."""
    notes: list[str] = []
    seen = _seen_views(row, config, notes)
    record, config = seen.record, seen.config
    failure = failure_of(row)
    camera = record.camera if record is not None and record.camera is not None else (
        config.camera.intrinsics if config is not None else None)
    names = list(config.part.point_names) if config is not None else []
    T_s1_w = matrix4(row.result.get("T_s1_w"))
    failed_at = _failed_view(failure, seen.visited, seen.pose_names, seen.count)
    width, height = (camera.width, camera.height) if camera is not None else (0, 0)
    out = []
    for i in range(seen.count):
        visit = seen.visited.get(i)
        name = (seen.pose_names[i] if i < len(seen.pose_names) else visit.pose if visit is not None and visit.pose
                else _record_name(record, i) or f"S{i + 1}")
        holes = _holes(i, record, T_s1_w, config, camera, names)
        marks: list[MarkSeen] = []
        if row.failed:
            holes, marks = _sought(holes, visit, failure if failed_at == i else None, config, names)
        out.append(ViewMarks(i, name, int(width), int(height), holes, marks, _image(row, seen, i),
                             (visit is not None) if seen.visited else None, None if visit is None else visit.T_b_f))
    return Overlay(out, failure, notes)


def view_images(row: CycleRow, config: CellConfig | None) -> list[str | None]:
    """The journaled path of each view's image, as :func:`view_marks` places them (None: none)."""
    seen = _seen_views(row, config, [])
    return [_image(row, seen, i) for i in range(seen.count)]


# --- private ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Views:
    """What the views are drawn from: the record's usable parts, the config if it is the record's part's, the
    part type's pose names, a failed cycle's visited views, how many views there are."""

    record: RecordParts | None
    config: CellConfig | None
    pose_names: list[str]
    visited: dict[int, VisitedView]
    count: int


def _seen_views(row: CycleRow, config: CellConfig | None, notes: list[str]) -> _Views:
    record = record_parts(row.record, notes)
    if record is not None and config is not None and not _fits(record, config):
        notes.append(f"the record's {len(record.points_w)} holes are not those of the config's part "
                     f"({config.part_name}, job {config.job}, {len(config.part.points_w)} holes): drawn without the "
                     "config's hole names, rims and search regions")
        config = None
    pose_names = [p.name for p in config.measuring_poses] if config is not None else []
    visited = visited_views(row, notes, pose_names) if row.failed else {}
    count = max(len(row.image_paths), len(record.views) if record else 0, len(pose_names),
                max(visited, default=-1) + 1)
    if count > MAX_VIEWS:
        notes.append(f"the row names {count} views: the first {MAX_VIEWS} are shown")
    return _Views(record, config, pose_names, visited, min(count, MAX_VIEWS))


def _image(row: CycleRow, seen: _Views, i: int) -> str | None:
    visit = seen.visited.get(i)
    if visit is not None or seen.visited:
        return None if visit is None else visit.image
    return row.image_paths[i] if i < len(row.image_paths) else None


def _fits(record: RecordParts, config: CellConfig) -> bool:
    ours = config.part.points_w
    if len(record.points_w) != len(ours):
        return False
    return all(p is not None and float(np.max(np.abs(p - q))) <= FIT_MM for p, q in zip(record.points_w, ours,
                                                                                         strict=True))


def _record_name(record: RecordParts | None, i: int) -> str | None:
    return record.view_names[i] if record is not None and i < len(record.view_names) else None


def _failed_view(failure: Failure | None, visited: dict[int, VisitedView], pose_names: list[str],
                 count: int) -> int | None:
    """The view the cycle stopped at: the failure's pose by name, else the last visited."""
    if failure is None:
        return None
    if failure.view is not None:
        for i, seen in visited.items():
            if seen.pose == failure.view:
                return i
        if failure.view in pose_names:
            return pose_names.index(failure.view)
        if failure.view[:1] == "S" and failure.view[1:].isdigit() and 0 < int(failure.view[1:]) <= count:
            return int(failure.view[1:]) - 1
    return max(visited) if visited and failure.expected_px is not None else None


def _holes(i: int, record: RecordParts | None, T_s1_w: np.ndarray | None, config: CellConfig | None,
           camera: CameraModel | None, names: list[str]) -> list[HoleMark]:
    expected: list[int] = list(config.measuring_poses[i].points) if config and i < len(config.measuring_poses) else []
    measured = record.observations.get(i, {}) if record is not None else {}
    points = expected + [j for j in sorted(measured) if j not in expected]
    T_c_w = None
    if record is not None and T_s1_w is not None and i < len(record.views) and record.views[i] is not None:
        T_c_w = frames.invert(record.views[i]) @ T_s1_w
    holes = []
    for j in points:
        predicted = rim = None
        p_w = record.points_w[j] if record is not None and j < len(record.points_w) else None
        if T_c_w is not None and camera is not None and p_w is not None:
            predicted = _pixels(_project(camera, T_c_w, p_w[None]))
            if predicted is not None and config is not None and j in measured:
                shift = np.asarray(measured[j]) - np.asarray(predicted[0])
                rim = _pixels(_rim(camera, T_c_w, config, j) + shift)
        region = _region(config, camera, i, j) if config is not None and camera is not None else None
        holes.append(HoleMark(
            names[j] if j < len(names) else f"P{j + 1}", j, measured.get(j),
            None if predicted is None else predicted[0], () if rim is None else rim, region))
    return holes


def _sought(holes: list[HoleMark], seen: VisitedView | None, failure: Failure | None, config: CellConfig | None,
            names: list[str]) -> tuple[list[HoleMark], list[MarkSeen]]:
    """A failed cycle's view: the holes with what its row says was found and where each was sought, the marks
    found, and the hole (or mark) it stopped at."""
    found = {_key(h.point, h.name): h for h in holes}

    def at(index: int | None, name: str | None) -> str:
        index = _point_index(index, name, names)
        if index is None:  # a hole named, not numbered: the one of that name the view's row numbers
            index = next((h.point for h in found.values() if h.name == name and h.point is not None), None)
        key = _key(index, name)
        if key not in found:
            label = name or (names[index] if index is not None and index < len(names) else f"P{(index or 0) + 1}")
            found[key] = HoleMark(label, index, None, None)
        return key

    for s in seen.holes if seen is not None else ():
        key = at(s.index, s.name)
        if found[key].measured_px is None:
            found[key] = replace(found[key], measured_px=s.pixel)
    for s in seen.expected if seen is not None else ():
        key = at(s.index, s.name)
        found[key] = replace(found[key], expected_px=s.pixel, expected_radius_px=s.radius_px)
    marks = [MarkSeen(s.name or f"M{(s.index or 0) + 1}", s.pixel) for s in (seen.marks if seen is not None else ())]
    if failure is not None and _is_mark(failure, config):
        marks.append(MarkSeen(failure.point or "mark", None, failure.expected_px, True))
    elif failure is not None and (failure.point is not None or failure.expected_px is not None):
        key = at(None, failure.point or "?")
        hole = found[key]
        found[key] = replace(hole, failed=True, expected_px=hole.expected_px or failure.expected_px,
                             expected_radius_px=hole.expected_radius_px or failure.radius_px)
    return list(found.values()), marks


def _key(index: int | None, name: str | None) -> str:
    return f"#{index}" if index is not None else f"={name}"


def _point_index(index: int | None, name: str | None, names: list[str]) -> int | None:
    """The hole's index: given, else its name's place in the config's names (P<n> without a config)."""
    if index is not None or name is None:
        return index
    if name in names:
        return names.index(name)
    if not names and name[:1] == "P" and name[1:].isdigit() and 0 < int(name[1:]) <= MAX_POINTS:
        return int(name[1:]) - 1
    return None


def _is_mark(failure: Failure, config: CellConfig | None) -> bool:
    marks = [m.name for m in config.reference_marks] if config is not None else []
    return failure.is_mark or failure.exception == "MarkNotFound" or (failure.point is not None
                                                                        and failure.point in marks)


def _pixels(points: np.ndarray) -> tuple[tuple[float, float], ...] | None:
    """Projected points as pixels, None when one is not finite or beyond reach of the image."""
    if not np.all(np.isfinite(points)) or np.any(np.abs(points) > MAX_PX):
        return None
    return tuple((float(u), float(v)) for u, v in points)


def _project(camera: CameraModel, T_c_w: np.ndarray, points_w: np.ndarray) -> np.ndarray:
    with np.errstate(all="ignore"):  # a pose behind the camera: not finite, left out by _pixels
        return camera.project(frames.transform_points(T_c_w, points_w))


def _rim(camera: CameraModel, T_c_w: np.ndarray, config: CellConfig, j: int) -> np.ndarray:
    part = config.part
    normal = part.normals_w[j] if part.normals_w is not None else np.array([0.0, 0.0, 1.0])
    e1, e2 = circle_basis(normal)
    angles = np.linspace(0.0, 2 * np.pi, RIM_POINTS, endpoint=False)
    circle = part.points_w[j] + part.hole_radius_mm * (np.cos(angles)[:, None] * e1 + np.sin(angles)[:, None] * e2)
    return _project(camera, T_c_w, circle)


def _region(config: CellConfig, camera: CameraModel, i: int, j: int) -> tuple[int, int, int, int] | None:
    part = config.part
    if i >= len(config.measuring_poses) or j >= len(part.points_w):
        return None
    T_c_w0 = frames.invert(config.measuring_poses[i].T_cf_si) @ config.reference.T_cf_w0
    envelope = config.layout.envelope if config.layout is not None else DeviationEnvelope()
    normal = part.normals_w[j] if part.normals_w is not None else np.array([0.0, 0.0, 1.0])
    search = hole_search(camera, T_c_w0, part.points_w[j], normal, part.hole_radius_mm,
                         search_extremes(envelope, part.points_w))
    return None if search is None else search.roi
