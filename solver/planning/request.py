"""A layout request (part, camera, envelope, constraints) and the assessment of any layout against it.

:func:`assess_layout` is what ``monoguide plan --layout`` prints for both the cell's current measuring
poses and the planned ones: the predicted pose uncertainty (with and without the robot's repeatability),
the worst margin of every hole to the image border and its depth range over the whole envelope.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from monoguide.solver import frames
from monoguide.solver.camera import CameraModel
from monoguide.solver.errors import NotARotation, SolveFailed
from monoguide.solver.planning.envelope import DeviationEnvelope, envelope_deviations, hole_in_view
from monoguide.solver.planning.errors import LayoutRequestInvalid, LayoutTooFewPoints
from monoguide.solver.planning.prediction import PoseSigmas, observed_covariance, pose_sigmas


@dataclass(frozen=True)
class ReachRegion:
    """Where the robot can put its flange: a ball of ``radius_mm`` about ``centre_w`` (3,) (e.g. the robot
    base, in the reference part's frame). ``flange_c`` (3,) is the flange origin in the camera frame (the
    translation of ``inv(T_f_c)``), so that the reach applies to the flange, not to the lens."""

    centre_w: tuple[float, float, float]
    radius_mm: float
    flange_c: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class LayoutConstraints:
    """What a measuring pose must satisfy.

    standoff_mm        : (min, max) distance from the camera centre to its hole, reference part, mm
    max_view_angle_deg : largest angle between a line of sight and its hole's surface normal (reference part)
    max_view_angle_envelope_deg : the same over the whole envelope (None: not limited), for the detector
    margin_px          : smallest distance of a hole centre from the image border over the whole envelope
    depth_of_field_mm  : (near, far) depth (camera z) every hole must keep over the whole envelope
    reach              : where the flange can go (None: anywhere)
    """

    standoff_mm: tuple[float, float] = (400.0, 1000.0)
    max_view_angle_deg: float = 30.0
    margin_px: float = 50.0
    depth_of_field_mm: tuple[float, float] = (350.0, 1200.0)
    reach: ReachRegion | None = None
    max_view_angle_envelope_deg: float | None = None


@dataclass(frozen=True)
class LayoutRequest:
    """Everything the planner needs. View i observes point i.

    points_w : (n, 3) featured hole centres in the part frame, mm; normals_w : (n, 3) their surface normals
    (None: the part's z axis); grasp_point_w : (3,) (None: the holes' centroid); sigma_px: centre noise;
    repeatability_mm / _deg: the robot's pose repeatability per axis at a measuring pose;
    T_f_c : (4, 4) the camera on the flange: the repeatability acts at the flange (None: about the camera's
    centre, the older and smaller prediction);
    interior_samples, seed: the seeded sample of the envelope's interior checked beside its 64 corners.
    """

    camera: CameraModel
    points_w: np.ndarray
    envelope: DeviationEnvelope = field(default_factory=DeviationEnvelope)
    constraints: LayoutConstraints = field(default_factory=LayoutConstraints)
    normals_w: np.ndarray | None = None
    grasp_point_w: np.ndarray | None = None
    sigma_px: float = 0.1
    repeatability_mm: float = 0.0
    repeatability_deg: float = 0.0
    interior_samples: int = 192
    seed: int = 0
    point_names: tuple[str, ...] = ()
    T_f_c: np.ndarray | None = None

    def names(self) -> tuple[str, ...]:
        n = len(np.asarray(self.points_w).reshape(-1, 3))
        return self.point_names if len(self.point_names) == n else tuple(f"P{i + 1}" for i in range(n))

    def normals(self) -> np.ndarray:
        n = len(np.asarray(self.points_w).reshape(-1, 3))
        if self.normals_w is None:
            return np.tile([0.0, 0.0, 1.0], (n, 1))
        normals = np.asarray(self.normals_w, dtype=float).reshape(-1, 3)
        return normals / np.linalg.norm(normals, axis=1, keepdims=True)

    def grasp_point(self) -> np.ndarray:
        if self.grasp_point_w is None:
            return np.asarray(self.points_w, dtype=float).reshape(-1, 3).mean(axis=0)
        return np.asarray(self.grasp_point_w, dtype=float)

    def deviations(self) -> np.ndarray:
        """``T_w0_w`` (k, 4, 4) of the envelope's corners, reference and seeded interior."""
        return envelope_deviations(self.envelope, np.asarray(self.points_w, dtype=float), self.interior_samples,
                                   self.seed)


@dataclass(frozen=True)
class LayoutAssessment:
    """A layout judged against a request. Per observation j (view, point) = ``observed[j]``:

    margin_px (m,)      : worst distance of the hole from the image border over the envelope (-inf: behind)
    depth_mm (m, 2)     : (min, max) depth of the hole over the envelope
    view_angle_deg (m,) : line of sight vs surface normal at the reference part; view_angle_max_deg over it all
    standoff_mm (m,)    : camera centre to hole at the reference part
    pixels (m, 2)       : where the reference part's hole is imaged
    sigmas, sigmas_with_repeatability : predicted at the grasp point (None when degenerate: see ``degenerate``)
    """

    T_w0_si: tuple[np.ndarray, ...]
    observed: tuple[tuple[int, int], ...]
    margin_px: np.ndarray
    depth_mm: np.ndarray
    view_angle_deg: np.ndarray
    view_angle_max_deg: np.ndarray
    standoff_mm: np.ndarray
    pixels: np.ndarray
    sigmas: PoseSigmas | None
    sigmas_with_repeatability: PoseSigmas | None
    degenerate: str | None = None

    @property
    def margin_px_min(self) -> float:
        return float(np.min(self.margin_px))

    @property
    def depth_mm_min(self) -> float:
        return float(np.min(self.depth_mm[:, 0]))

    @property
    def depth_mm_max(self) -> float:
        return float(np.max(self.depth_mm[:, 1]))

    @property
    def in_front(self) -> bool:
        return bool(np.all(np.isfinite(self.margin_px)))


def validate_request(request: LayoutRequest) -> None:
    """Refuse a request the planner cannot use, naming the value: :class:`LayoutRequestInvalid`, or
    :class:`LayoutTooFewPoints` for fewer than three featured points or points on one line."""
    points = np.asarray(request.points_w, dtype=float)
    if points.ndim != 2 or points.shape[1] != 3 or not np.all(np.isfinite(points)):
        raise LayoutRequestInvalid(f"points_w: expected finite (n, 3) points in mm, got {points.tolist()}")
    c = request.constraints
    _finite_positive("sigma_px", request.sigma_px)
    _finite_nonnegative("repeatability_mm", request.repeatability_mm)
    _finite_nonnegative("repeatability_deg", request.repeatability_deg)
    if request.T_f_c is not None:
        try:
            frames.rigid_transform(request.T_f_c, "T_f_c")
        except NotARotation as error:
            raise LayoutRequestInvalid(error.message) from error
    _finite_nonnegative("margin_px", c.margin_px)
    _range("standoff_mm", c.standoff_mm)
    _range("depth_of_field_mm", c.depth_of_field_mm)
    if not (math.isfinite(c.max_view_angle_deg) and 0.0 <= c.max_view_angle_deg < 90.0):
        raise LayoutRequestInvalid(f"max_view_angle_deg = {c.max_view_angle_deg}: must lie in [0, 90)")
    envelope_angle = c.max_view_angle_envelope_deg
    if envelope_angle is not None and not (math.isfinite(envelope_angle) and 0.0 < envelope_angle < 90.0):
        raise LayoutRequestInvalid(f"max_view_angle_envelope_deg = {envelope_angle}: must lie in (0, 90)")
    for name, values in (("envelope translation_mm", request.envelope.translation_mm),
                         ("envelope rotation_deg", request.envelope.rotation_deg)):
        v = np.asarray(values, dtype=float)
        if v.shape != (3,) or not np.all(np.isfinite(v)) or np.any(v < 0):
            raise LayoutRequestInvalid(f"{name} = {list(values)}: expected three finite numbers >= 0")
    if np.any(np.asarray(request.envelope.rotation_deg, dtype=float) >= 45.0):
        raise LayoutRequestInvalid(f"envelope rotation_deg = {list(request.envelope.rotation_deg)}: must be < 45")
    normals = np.asarray(request.normals_w if request.normals_w is not None else np.ones_like(points), dtype=float)
    if normals.shape != points.shape or not np.all(np.isfinite(normals)) or np.any(
        np.linalg.norm(normals, axis=1) < 1e-9
    ):
        raise LayoutRequestInvalid(f"normals_w: expected one finite non-zero normal per point, got {normals.tolist()}")
    grasp = request.grasp_point()
    if grasp.shape != (3,) or not np.all(np.isfinite(grasp)):
        raise LayoutRequestInvalid(f"grasp_point_w = {grasp.tolist()}: expected three finite numbers (mm)")
    if c.reach is not None:
        _finite_positive("reach radius_mm", c.reach.radius_mm)
    if len(points) < 3:
        raise LayoutTooFewPoints(
            f"{len(points)} featured point(s): with fewer than 3 the part can turn about the line through them "
            "unseen; at least 3 not on one line are needed (4 to check the measurement)"
        )
    spread = np.linalg.svd(points - points.mean(axis=0), compute_uv=False)
    if spread[1] <= 1e-6 * max(spread[0], 1e-12):
        raise LayoutTooFewPoints(
            f"the {len(points)} featured points lie on one line: the part can turn about it unseen; "
            "at least 3 not on one line are needed"
        )


def assess_layout(
    request: LayoutRequest,
    T_w0_si: Sequence[np.ndarray],
    observed: Sequence[tuple[int, int]] | None = None,
    deviations: np.ndarray | None = None,
) -> LayoutAssessment:
    """Judge a layout: camera poses ``T_w0_si`` (k, 4, 4) in the reference part's frame observing the
    (view, point) pairs ``observed`` (default view i sees point i) over the request's envelope."""
    points = np.asarray(request.points_w, dtype=float)
    observed = tuple((int(v), int(p)) for v, p in observed) if observed is not None else tuple(
        (i, i) for i in range(len(points))
    )
    deviations = request.deviations() if deviations is None else deviations
    normals = request.normals()
    m = len(observed)
    margin, depth = np.empty(m), np.empty((m, 2))
    angle, angle_max, standoff, pixels = np.empty(m), np.empty(m), np.empty(m), np.empty((m, 2))
    for j, (view, point) in enumerate(observed):
        seen = hole_in_view(request.camera, T_w0_si[view], deviations, points[point], normals[point])
        margin[j] = float(np.min(seen.margin_px))
        depth[j] = (float(np.min(seen.depth_mm)), float(np.max(seen.depth_mm)))
        reference = _reference_index(deviations)
        angle[j] = float(seen.view_angle_deg[reference])
        angle_max[j] = float(np.max(seen.view_angle_deg))
        standoff[j] = float(np.linalg.norm(T_w0_si[view][:3, 3] - points[point]))
        pixels[j] = seen.pixels[reference]
    sigmas, with_rep, degenerate = _predict(request, T_w0_si, observed)
    return LayoutAssessment(tuple(np.array(T, dtype=float) for T in T_w0_si), observed, margin, depth, angle,
                            angle_max, standoff, pixels, sigmas, with_rep, degenerate)


# --- private -----------------------------------------------------------------------------------


def _predict(request: LayoutRequest, T_w0_si, observed) -> tuple[PoseSigmas | None, PoseSigmas | None, str | None]:
    points = np.asarray(request.points_w, dtype=float)
    T_s1_w0 = frames.invert(T_w0_si[0])
    grasp = request.grasp_point()
    try:
        plain = observed_covariance(request.camera, points, T_w0_si, observed, request.sigma_px)
        with_rep = observed_covariance(request.camera, points, T_w0_si, observed, request.sigma_px,
                                       request.repeatability_mm, request.repeatability_deg, request.T_f_c)
    except SolveFailed as error:
        return None, None, f"{error.code}: {error.message}"
    return pose_sigmas(plain, T_s1_w0, grasp), pose_sigmas(with_rep, T_s1_w0, grasp), None


def _reference_index(deviations: np.ndarray) -> int:
    """Index of the reference part (the identity) among the envelope's parts."""
    return int(np.argmin(np.abs(deviations - np.eye(4)).reshape(len(deviations), -1).sum(axis=1)))


def _finite_positive(name: str, value: float) -> None:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value) or value <= 0:
        raise LayoutRequestInvalid(f"{name} = {value!r}: must be a finite number > 0")


def _finite_nonnegative(name: str, value: float) -> None:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value) or value < 0:
        raise LayoutRequestInvalid(f"{name} = {value!r}: must be a finite number >= 0")


def _range(name: str, values: tuple[float, float]) -> None:
    v = np.asarray(values, dtype=float)
    if v.shape != (2,) or not np.all(np.isfinite(v)) or v[0] <= 0 or v[0] > v[1]:
        raise LayoutRequestInvalid(f"{name} = {list(values)}: expected (min, max) with 0 < min <= max")
