"""Whether each measuring pose sees its fixed marks: in its image, facing it, apart from each other, and never
behind a part that lies anywhere inside its deviation envelope.

For every view and every mark it lists (all in one frame, the cell frame):

- **in the image**: the mark's whole circle (``radius_mm`` about its centre, in its plane) in front of the camera
  and imaged at least ``margin_px`` inside the image (the border as :func:`.envelope.pixel_margin`); the mark's
  plane faces the camera;
- **apart**: its image does not overlap the image of another mark of the same view;
- **never hidden**: the line of sight from the camera centre to the mark's centre does not pass through the sheet
  of any part measured from that view, wherever the part lies inside its envelope. The sheet is the part's outline
  polygon (``outline_w``, in its best-fit plane) or, without one, the convex hull of its holes grown by
  :data:`DEFAULT_OUTLINE_MARGIN_MM`. At each part pose the segment camera-mark is cut with the sheet's plane and the
  cut point's distance from the outline measured (the *clearance*: positive outside the sheet, negative inside); a
  mark is visible when the smallest clearance over the envelope is at least its radius plus ``clearance_mm``.

The sampling of the envelope. The part's displacement ``T_w0_w`` is a rotation vector about the envelope's point
and that point's shift (:class:`~monoguide.solver.envelope.DeviationEnvelope`). Beside a straight run of the
outline the clearance is linear in the shift and concave in the rotation, so the box's corners hold the worst
part; near a corner of the outline it is not: the distance to the corner is convex in the shift, and a rotation
about the envelope's centre sweeps the corner along an arc that passes closest to the mark at an intermediate
angle. So the per-axis box is sampled at :data:`GRID_LEVELS` levels per axis (its 64 corners, the cycle's 216
search extremes and the reference part among them, 15625 parts) and the clearance minimised from the worst
samples within the box (a bounded local search). The box is a superset of the envelope when its totals cut the
corners off. Pure geometry, no images.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from monoguide.solver import frames
from monoguide.solver.camera import CameraModel
from monoguide.solver.envelope import DeviationEnvelope, deviation_about
from monoguide.solver.planning.envelope import pixel_margin
from monoguide.solver.planning.errors import LayoutOutOfView, LayoutRequestInvalid

DEFAULT_OUTLINE_MARGIN_MM = 50.0  # a part without outline_w: its holes' convex hull grown by this
CLEARANCE_MM = 5.0  # beyond the mark's radius, between the line of sight and the part's edge
GRID_LEVELS = 5  # per axis of the envelope's 6-D box: -1, -0.5, 0, 0.5, 1 times its limits
REFINE_STARTS = 3  # local searches from the worst samples
REFINE_STEP = 2e-3  # down to this fraction of the envelope's limits (0.01 deg, 0.1 mm of +-5 deg, +-50 mm)
CIRCLE_SAMPLES = 72  # points of a mark's circle projected into the image

VISIBLE = "visible"
BEHIND_CAMERA = "behind_camera"
FACES_AWAY = "faces_away"
OUT_OF_IMAGE = "out_of_image"
HIDDEN = "hidden"
OVERLAPS = "overlaps"


@dataclass(frozen=True)
class Mark:
    """A fixed mark: a circle of ``radius_mm`` about ``position`` (3,), in the plane of normal ``normal`` (3,)."""

    name: str
    position: np.ndarray
    radius_mm: float
    normal: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))


@dataclass(frozen=True)
class PartSheet:
    """A part that can lie between a camera and a mark: its reference pose, holes and envelope, and its outline
    (``None``: the holes' convex hull grown by ``outline_margin_mm``)."""

    name: str
    T_cf_w0: np.ndarray  # (4, 4) the reference part
    points_w: np.ndarray  # (n, 3) its featured holes (the envelope's point, the outline without outline_w)
    envelope: DeviationEnvelope
    outline_w: np.ndarray | None = None  # (m, 3) its outer edge, a polygon in the part frame
    outline_margin_mm: float = DEFAULT_OUTLINE_MARGIN_MM

    @property
    def from_holes(self) -> bool:
        return self.outline_w is None


@dataclass(frozen=True)
class MarkedView:
    """A measuring pose: its camera ``T_cf_si``, the marks it sees (indices), the parts measured from it
    (indices: those whose sheet may hide its marks) and the margin its marks must keep from the image border."""

    name: str
    T_cf_si: np.ndarray
    marks: tuple[int, ...]
    parts: tuple[int, ...] = ()
    margin_px: float = 100.0


@dataclass(frozen=True)
class MarkVisibility:
    """One mark of one view, checked.

    status       : :data:`VISIBLE` or the first reason it is not (``reasons`` holds them all)
    clearance_mm : smallest distance of the line of sight's cut with a part's sheet from its outline over the
                   envelope (negative: through the sheet); None when the line never crosses a sheet (or no part)
    required_mm  : what it must keep: the mark's radius plus the clearance
    part         : the part of that smallest clearance; deviation_deg / deviation_mm: its pose in the envelope
                   (rotation vector and shift of the envelope's point, along the reference part's axes)
    margin_px    : the mark's circle's smallest distance from the image border (None: behind the camera)
    radius_px    : the circle's largest radius in the image
    gap_px / nearest : the smallest gap between its image and another mark's of the view, and that mark
    """

    view: str
    mark: str
    status: str
    reasons: tuple[str, ...]
    clearance_mm: float | None
    required_mm: float
    margin_px: float | None
    required_px: float
    radius_px: float | None
    part: str | None = None
    deviation_deg: tuple[float, float, float] | None = None
    deviation_mm: tuple[float, float, float] | None = None
    gap_px: float | None = None
    nearest: str | None = None

    @property
    def ok(self) -> bool:
        return not self.reasons

    def why(self) -> str:
        """Why it is not seen, naming the view and the mark ('' when it is)."""
        out = []
        for reason in self.reasons:
            if reason == BEHIND_CAMERA:
                out.append("it lies behind the camera")
            elif reason == FACES_AWAY:
                out.append("its plane faces away from the camera")
            elif reason == OUT_OF_IMAGE:
                out.append(f"it is imaged {self.margin_px:.0f} px from the image border (its whole circle, "
                           f"{self.radius_px:.0f} px radius), less than the {self.required_px:g} px margin")
            elif reason == HIDDEN:
                r, t = self.deviation_deg or (0, 0, 0), self.deviation_mm or (0, 0, 0)
                where = ("through the sheet" if (self.clearance_mm or 0.0) < 0
                         else "beside the edge")
                out.append(f"part {self.part} hides it: with the part turned ({_fmt(r)}) deg and shifted "
                           f"({_fmt(t)}) mm in its envelope the line of sight passes {where}, "
                           f"{self.clearance_mm:.1f} mm from its outline (needs >= {self.required_mm:g} mm)")
            elif reason == OVERLAPS:
                out.append(f"its image overlaps that of mark {self.nearest} ({self.gap_px:.1f} px apart)")
        return f"view {self.view}, mark {self.mark}: " + "; ".join(out) if out else ""


@dataclass(frozen=True)
class MarksVisibility:
    """Every (view, mark) checked, in view order; ``notes``: what the check assumed (a part without outline)."""

    results: tuple[MarkVisibility, ...]
    notes: tuple[str, ...] = ()
    clearance_mm: float = CLEARANCE_MM
    parts_sampled: int = 0  # part poses of the envelope's box sampled per part (before the local search)

    @property
    def ok(self) -> bool:
        return all(r.ok for r in self.results)

    def failures(self) -> tuple[MarkVisibility, ...]:
        return tuple(r for r in self.results if not r.ok)

    def error(self) -> LayoutOutOfView | None:
        """:class:`LayoutOutOfView` naming each view and mark that is not seen, or None."""
        bad = self.failures()
        if not bad:
            return None
        return LayoutOutOfView(f"{len(bad)} fixed mark(s) not seen: " + "; ".join(r.why() for r in bad))

    def raise_if_not_seen(self) -> None:
        error = self.error()
        if error is not None:
            raise error


def check_marks(
    camera: CameraModel,
    views: Sequence[MarkedView],
    marks: Sequence[Mark],
    parts: Sequence[PartSheet] = (),
    *,
    clearance_mm: float = CLEARANCE_MM,
    levels: int = GRID_LEVELS,
    refine: bool = True,
) -> MarksVisibility:
    """Check every mark of every view (see the module). Raises :class:`LayoutRequestInvalid` naming the view for
    a mark or part index out of range, a mark of no positive radius or a bad outline."""
    if clearance_mm < 0 or not math.isfinite(clearance_mm):
        raise LayoutRequestInvalid(f"marks: clearance_mm = {clearance_mm!r}: expected a finite value >= 0")
    for v in views:
        if bad := [k for k in v.marks if not 0 <= k < len(marks)]:
            raise LayoutRequestInvalid(f"view {v.name}: marks {bad} are not among the {len(marks)} marks")
        if bad := [k for k in v.parts if not 0 <= k < len(parts)]:
            raise LayoutRequestInvalid(f"view {v.name}: parts {bad} are not among the {len(parts)} parts")
    for m in marks:
        if not (m.radius_mm > 0 and math.isfinite(m.radius_mm)):
            raise LayoutRequestInvalid(f"mark {m.name}: radius {m.radius_mm!r} mm: expected > 0")
    sheets = [_Sheet.of(p) for p in parts]
    notes = tuple(f"part {p.name}: no outline_w; taken as the convex hull of its holes grown by "
                  f"{p.outline_margin_mm:g} mm" for p in parts if p.from_holes)
    results = []
    for v in views:
        T = np.asarray(v.T_cf_si, dtype=float)
        circles = {k: _circle_in_image(camera, T, marks[k]) for k in v.marks}
        for k in v.marks:
            mark = marks[k]
            points_c, pixels = circles[k]
            reasons: list[str] = []
            margin = radius_px = None
            centre_c = frames.transform_points(frames.invert(T), np.asarray(mark.position, float)[None])[0]
            if np.any(points_c[:, 2] <= 1e-6) or centre_c[2] <= 1e-6:
                reasons.append(BEHIND_CAMERA)
            else:
                margin = float(np.min(pixel_margin(camera, pixels)))
                centre_px = camera.project(centre_c[None])[0]
                radius_px = float(np.max(np.linalg.norm(pixels - centre_px, axis=1)))
                if margin < v.margin_px:
                    reasons.append(OUT_OF_IMAGE)
            if float(np.asarray(mark.normal, float) @ (T[:3, 3] - np.asarray(mark.position, float))) <= 0:
                reasons.append(FACES_AWAY)
            required = mark.radius_mm + clearance_mm
            worst: _Worst | None = None
            for j in v.parts:
                w = sheets[j].worst(T[:3, 3], np.asarray(mark.position, float), levels, refine)
                if w is not None and (worst is None or w.clearance < worst.clearance):
                    worst = w
            if worst is not None and worst.clearance < required:
                reasons.append(HIDDEN)
            gap, nearest = _nearest_image(circles, k, marks)
            if gap is not None and gap <= 0.0:
                reasons.append(OVERLAPS)
            results.append(MarkVisibility(
                v.name, mark.name, reasons[0] if reasons else VISIBLE, tuple(reasons),
                None if worst is None else worst.clearance, required, margin, float(v.margin_px), radius_px,
                None if worst is None else worst.part,
                None if worst is None else worst.rotation_deg, None if worst is None else worst.shift_mm,
                gap, nearest))
    sampled = max((len(s._grid(levels)[0]) for s in sheets), default=0)
    return MarksVisibility(tuple(results), notes, clearance_mm, sampled)


def sheet_clearance(part: PartSheet, camera_cf: np.ndarray, mark_cf: np.ndarray,
                    deviations: np.ndarray) -> np.ndarray:
    """The clearance (k,) mm of the segment ``camera_cf`` - ``mark_cf`` from ``part``'s outline for each part pose
    ``deviations`` (k, 4, 4) = ``T_w0_w``: the distance of its cut with the sheet's plane from the outline
    (negative inside), +inf where it does not cross the plane."""
    return _Sheet.of(part).clearance(np.asarray(camera_cf, float), np.asarray(mark_cf, float), deviations)


# --- private -----------------------------------------------------------------------------------

# the pattern search's moves: along each axis of the box (12) and to each corner of the step's cube (64)
_MOVES = np.vstack([np.eye(6), -np.eye(6), np.array(list(itertools.product((-1.0, 1.0), repeat=6)))])


def _fmt(v: Sequence[float]) -> str:
    return ", ".join(f"{x:+.1f}" for x in v)


@dataclass(frozen=True)
class _Worst:
    part: str
    clearance: float
    rotation_deg: tuple[float, float, float]
    shift_mm: tuple[float, float, float]


@dataclass(frozen=True, eq=False)
class _Sheet:
    """A part's sheet: its outline as a 2-D polygon in its plane frame P (``T_w_p``), grown by ``grow_mm``."""

    part: PartSheet
    T_w_p: np.ndarray
    polygon: np.ndarray  # (m, 2) in P's xy plane
    grow_mm: float
    about: np.ndarray  # (3,) the envelope's point in the part frame
    limits: np.ndarray  # (6,) rotation rad, shift mm
    _grids: dict[int, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)

    @classmethod
    def of(cls, part: PartSheet) -> _Sheet:
        points = np.asarray(part.points_w, dtype=float).reshape(-1, 3)
        if part.outline_w is not None:
            outline = np.asarray(part.outline_w, dtype=float).reshape(-1, 3)
            if len(outline) < 3 or not np.all(np.isfinite(outline)):
                raise LayoutRequestInvalid(f"part {part.name}: outline_w needs at least 3 finite corners")
            T_w_p = _plane_frame(outline)
            polygon = frames.transform_points(frames.invert(T_w_p), outline)[:, :2]
            if abs(_area(polygon)) < 1e-6:
                raise LayoutRequestInvalid(f"part {part.name}: outline_w encloses no area")
            grow = 0.0
        else:
            T_w_p = _plane_frame(points) if len(points) >= 3 and _spread(points) else frames.make_T(
                np.eye(3), points.mean(axis=0))
            polygon = _convex_hull(frames.transform_points(frames.invert(T_w_p), points)[:, :2])
            grow = float(part.outline_margin_mm)
        limits = np.concatenate([np.radians(part.envelope.rotation_deg),
                                 np.asarray(part.envelope.translation_mm, dtype=float)])
        return cls(part, T_w_p, polygon, grow, part.envelope.about(points), limits)

    def deviations(self, unit: np.ndarray) -> np.ndarray:
        """``T_w0_w`` (k, 4, 4) of the box's normalised points ``unit`` (k, 6) in [-1, 1]."""
        d = np.atleast_2d(unit) * self.limits
        R = _rotvecs_to_matrices(d[:, :3])
        out = np.tile(np.eye(4), (len(d), 1, 1))
        out[:, :3, :3] = R
        out[:, :3, 3] = self.about - R @ self.about + d[:, 3:]
        return out

    def clearance(self, camera_cf: np.ndarray, mark_cf: np.ndarray, deviations: np.ndarray) -> np.ndarray:
        T_w0_cf = frames.invert(np.asarray(self.part.T_cf_w0, float))
        ends_w0 = frames.transform_points(T_w0_cf, np.vstack([camera_cf, mark_cf]))  # (2, 3)
        R, t = deviations[:, :3, :3], deviations[:, :3, 3]
        R_p_w, o_w = self.T_w_p[:3, :3].T, self.T_w_p[:3, 3]
        # a point x_w0 in the sheet's frame: R_p_w (R^T (x_w0 - t) - o_w)
        c = (np.matmul((ends_w0[0] - t)[:, None, :], R)[:, 0] - o_w) @ R_p_w.T
        m = (np.matmul((ends_w0[1] - t)[:, None, :], R)[:, 0] - o_w) @ R_p_w.T
        cz, mz = c[:, 2], m[:, 2]
        crosses = (cz * mz <= 0.0) & (np.abs(cz - mz) > 1e-12)
        out = np.full(len(c), np.inf)
        if np.any(crosses):
            s = cz[crosses] / (cz[crosses] - mz[crosses])
            cut = c[crosses, :2] + s[:, None] * (m[crosses, :2] - c[crosses, :2])
            out[crosses] = _signed_distance(cut, self.polygon) - self.grow_mm
        return out

    def _grid(self, levels: int) -> tuple[np.ndarray, np.ndarray]:
        """The box sampled at ``levels`` per axis: normalised (k, 6) and as ``T_w0_w`` (k, 4, 4) (kept)."""
        if levels not in self._grids:  # an axis the envelope does not move along: at 0 alone
            axes = [np.linspace(-1.0, 1.0, levels) if lim > 0 else np.zeros(1) for lim in self.limits]
            grid = np.array(list(itertools.product(*axes)))
            self._grids[levels] = (grid, self.deviations(grid))
        return self._grids[levels]

    def worst(self, camera_cf: np.ndarray, mark_cf: np.ndarray, levels: int, refine: bool) -> _Worst | None:
        """The part pose of the smallest clearance: the box sampled at ``levels`` per axis, then a bounded local
        search from the worst samples. None when the line of sight never crosses the sheet's plane."""
        grid, deviations = self._grid(levels)
        values = self.clearance(camera_cf, mark_cf, deviations)
        finite = np.isfinite(values)
        if not np.any(finite):
            return None
        best_u, best = grid[int(np.argmin(values))], float(np.min(values))
        if refine:  # a pattern search in the box from each of the worst samples, its step halved when none helps
            moves = _MOVES
            for start in grid[np.argsort(values)[:REFINE_STARTS]]:
                u, value, step = start, float(self.clearance(camera_cf, mark_cf, self.deviations(start[None]))[0]), \
                    1.0 / (levels - 1)
                while step > REFINE_STEP:
                    trial = np.clip(u + step * moves, -1.0, 1.0)
                    got = self.clearance(camera_cf, mark_cf, self.deviations(trial))
                    i = int(np.argmin(got))
                    if got[i] < value - 1e-9:
                        u, value = trial[i], float(got[i])
                    else:
                        step /= 2.0
                if value < best:
                    best, best_u = value, u
        T = self.deviations(best_u[None])[0]
        rot, shift = deviation_about(T, self.about)
        return _Worst(self.part.name, best, tuple(float(x) for x in rot), tuple(float(x) for x in shift))


def _rotvecs_to_matrices(r: np.ndarray) -> np.ndarray:
    """Rodrigues' formula for rotation vectors (k, 3) -> (k, 3, 3)."""
    theta = np.linalg.norm(r, axis=1)
    small = theta < 1e-12
    axis = np.where(small[:, None], 0.0, r / np.where(small, 1.0, theta)[:, None])
    K = np.zeros((len(r), 3, 3))
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -axis[:, 2], axis[:, 1], -axis[:, 0]
    K[:, 1, 0], K[:, 2, 0], K[:, 2, 1] = axis[:, 2], -axis[:, 1], axis[:, 0]
    s, c = np.sin(theta)[:, None, None], np.cos(theta)[:, None, None]
    return np.eye(3) + s * K + (1.0 - c) * (K @ K)


def _signed_distance(p: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """Distance (k,) of points ``p`` (k, 2) from the boundary of ``polygon`` (m, 2), negative inside (even-odd);
    a polygon of one or two corners (a point, a segment) has no inside."""
    a, b = polygon, np.roll(polygon, -1, axis=0)
    ab = b - a
    ap = p[:, None, :] - a[None]
    denom = np.maximum(np.sum(ab * ab, axis=1), 1e-18)
    t = np.clip(np.sum(ap * ab[None], axis=2) / denom, 0.0, 1.0)
    d = np.min(np.linalg.norm(ap - t[..., None] * ab[None], axis=2), axis=1)
    if len(polygon) < 3:
        return d
    ya, yb = a[None, :, 1], b[None, :, 1]
    py, px = p[:, 1:2], p[:, 0:1]
    straddles = (ya > py) != (yb > py)
    with np.errstate(divide="ignore", invalid="ignore"):
        x_cross = a[None, :, 0] + (py - ya) * (b[None, :, 0] - a[None, :, 0]) / (yb - ya)
    inside = np.sum(straddles & (px < x_cross), axis=1) % 2 == 1
    return np.where(inside, -d, d)


def _plane_frame(points: np.ndarray) -> np.ndarray:
    """``T_w_p``: a frame whose xy plane is the best-fit plane of ``points`` (its z along the part's z where they
    lie flat), its origin their centroid."""
    centroid = points.mean(axis=0)
    normal = np.linalg.svd(points - centroid)[2][-1]
    if normal[2] < 0:
        normal = -normal
    x = np.array([1.0, 0.0, 0.0]) - normal[0] * normal
    if np.linalg.norm(x) < 1e-6:
        x = np.array([0.0, 1.0, 0.0]) - normal[1] * normal
    x /= np.linalg.norm(x)
    return frames.make_T(np.column_stack([x, np.cross(normal, x), normal]), centroid)


def _spread(points: np.ndarray) -> bool:
    """Whether ``points`` span a plane (not all on one line)."""
    s = np.linalg.svd(points - points.mean(axis=0), compute_uv=False)
    return len(s) >= 2 and s[1] > 1e-6 * max(s[0], 1.0)


def _convex_hull(p: np.ndarray) -> np.ndarray:
    """The convex hull (counter-clockwise) of 2-D points (n, 2) (monotone chain); one or two points as they are."""
    pts = sorted({(float(x), float(y)) for x, y in p})
    if len(pts) <= 2:
        return np.array(pts)

    def cross(o, a, b) -> float:
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    lower: list[tuple[float, float]] = []
    for q in pts:
        while len(lower) >= 2 and cross(lower[-2], lower[-1], q) <= 0:
            lower.pop()
        lower.append(q)
    upper: list[tuple[float, float]] = []
    for q in reversed(pts):
        while len(upper) >= 2 and cross(upper[-2], upper[-1], q) <= 0:
            upper.pop()
        upper.append(q)
    return np.array(lower[:-1] + upper[:-1])


def _area(polygon: np.ndarray) -> float:
    x, y = polygon[:, 0], polygon[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def _circle_in_image(camera: CameraModel, T_cf_si: np.ndarray, mark: Mark) -> tuple[np.ndarray, np.ndarray]:
    """The mark's circle in the camera frame (N, 3) and its pixels (N, 2; NaN behind the camera)."""
    n = np.asarray(mark.normal, dtype=float)
    n = n / np.linalg.norm(n)
    u = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(n, u)
    a = np.linspace(0.0, 2.0 * np.pi, CIRCLE_SAMPLES, endpoint=False)
    circle = np.asarray(mark.position, float) + mark.radius_mm * (np.cos(a)[:, None] * u + np.sin(a)[:, None] * v)
    points_c = frames.transform_points(frames.invert(T_cf_si), circle)
    pixels = np.full((len(points_c), 2), np.nan)
    front = points_c[:, 2] > 1e-6
    if np.any(front):
        pixels[front] = camera.project(points_c[front])
    return points_c, pixels


def _nearest_image(circles: dict[int, tuple[np.ndarray, np.ndarray]], k: int,
                   marks: Sequence[Mark]) -> tuple[float | None, str | None]:
    """The smallest gap (px) between mark ``k``'s image and another's of the view (negative: they overlap; the
    separating-axis distance of the two imaged circles), and that mark."""
    mine = circles[k][1]
    if np.any(~np.isfinite(mine)):
        return None, None
    best: tuple[float | None, str | None] = (None, None)
    for j, (_, other) in circles.items():
        if j == k or np.any(~np.isfinite(other)):
            continue
        gap = _separation(mine, other)
        if best[0] is None or gap < best[0]:
            best = (gap, marks[j].name)
    return best


def _separation(a: np.ndarray, b: np.ndarray) -> float:
    """The largest gap between two convex polygons (n, 2) along the normals of their edges (<= 0: they
    overlap)."""
    axes = []
    for poly in (a, b):
        e = np.roll(poly, -1, axis=0) - poly
        n = np.column_stack([-e[:, 1], e[:, 0]])
        axes.append(n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12))
    axes_all = np.vstack(axes)
    pa, pb = a @ axes_all.T, b @ axes_all.T
    gaps = np.maximum(pb.min(axis=0) - pa.max(axis=0), pa.min(axis=0) - pb.max(axis=0))
    return float(np.max(gaps))
