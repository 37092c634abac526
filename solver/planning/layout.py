"""The layout planner: one measuring pose per featured hole, chosen for the lowest predicted uncertainty of
the part pose at its grasp point while every hole stays in the image (with a margin) and inside the depth
of field for every part of the deviation envelope.

Each camera stands at ``standoff`` from its hole, its line of sight tilted by ``tilt`` from the hole's
surface normal towards an ``azimuth`` (0: the camera stands on the far side of the hole from the holes'
centroid and looks back at the part, so that the lines of sight converge on it; pi: it stands over the
part and looks out). Given where a camera stands, it is turned so that the hole's sweep over the envelope is
centred in the image, its longer extent along the longer image side: the orientation that leaves the
largest margin. Tilting makes the lines of sight cross at an angle and the part's distance observable,
far better than moving holes outwards in the image with parallel views (the paper's Fig. 5).

The search: the predicted uncertainty falls as the standoff shrinks, so each camera stands at the
smallest standoff that still holds every constraint (found on a grid, then by Brent's method). Over a
grid of common tilts and both azimuth rules (converging, diverging) the best layout is kept, then every
camera's tilt and azimuth are refined in turn (coordinate descent, halving steps). The constraints are
evaluated over the envelope's 64 corners, its reference and a seeded interior sample. An infeasible
request is refused naming the binding constraint: the one whose relaxation alone would make some grid
point feasible.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import brentq

from monoguide.solver import frames
from monoguide.solver.errors import SolveFailed
from monoguide.solver.planning.envelope import hole_in_view
from monoguide.solver.planning.errors import (
    LayoutConstraintsConflict,
    LayoutDepthOfField,
    LayoutInfeasible,
    LayoutOutOfReach,
    LayoutOutOfView,
    LayoutStandoff,
    LayoutViewAngle,
)
from monoguide.solver.planning.prediction import layout_covariance, pose_sigmas
from monoguide.solver.planning.request import LayoutAssessment, LayoutRequest, assess_layout, validate_request

GRID_TILTS = 7  # tilt steps from 0 to the largest allowed angle
GRID_STANDOFFS = 13  # standoff steps over the allowed range
STANDOFF_TOL_MM = 0.05  # how close to its limit the smallest feasible standoff is found
REFINE_ROUNDS = 3  # coordinate-descent rounds over every camera's tilt and azimuth
REFINE_AZIMUTH_DEG = 20.0  # first azimuth step of the refinement (then halved every round)
_NAMES = {"margin": "margin_px", "depth_of_field": "depth_of_field_mm", "view_angle": "max_view_angle_envelope_deg",
          "reach": "reach"}  # the request's names of the constraints, as refusals say them
ROLL_STEPS = 90  # roll candidates over half a turn when fitting a sweep to the image
WIDE_STANDOFFS_MM = np.geomspace(50.0, 5000.0, 30)  # tried when no constraint binds alone: does the standoff?
KINDS = ("margin", "depth_of_field", "view_angle", "reach")  # constraints checked over the envelope


@dataclass(frozen=True)
class CameraPlacement:
    """Where one camera stands relative to its hole: tilt and azimuth (rad), standoff (mm)."""

    tilt: float
    azimuth: float
    standoff: float


@dataclass(frozen=True)
class _Fit:
    """A camera placed and turned: its placement, the roll that fits the sweep to the image, its pose."""

    placement: CameraPlacement
    roll: float
    T: np.ndarray


def plan_layout(request: LayoutRequest) -> LayoutAssessment:
    """The planned measuring poses (``T_w0_si``, view i sees point i) with their assessment.

    Raises a :class:`~monoguide.solver.planning.errors.LayoutInfeasible` subclass naming the binding
    constraint when no layout satisfies the request.
    """
    validate_request(request)
    planner = _Planner(request)
    fits = planner.search()
    return assess_layout(request, [f.T for f in fits], deviations=planner.deviations)


def camera_pose_for(request: LayoutRequest, point: int, placement: CameraPlacement) -> np.ndarray:
    """``T_w0_c`` (4, 4) of the camera placed at ``placement`` for hole ``point``, turned to centre the
    hole's sweep over the envelope in the image."""
    return _Planner(request).camera_pose(point, placement)[0]


# --- private -----------------------------------------------------------------------------------


class _Planner:
    def __init__(self, request: LayoutRequest) -> None:
        self.request = request
        self.camera = request.camera
        self.points = np.asarray(request.points_w, dtype=float)
        self.normals = request.normals()
        self.names = request.names()
        self.deviations = request.deviations()
        rotated = np.einsum("kab,nb->kna", self.deviations[:, :3, :3], self.points)
        self.sweeps = rotated + self.deviations[:, None, :3, 3]  # (k, n, 3) every hole of every part
        # cameras are placed around the holes' centroid (the part's own symmetry); the grasp point only
        # weighs the objective
        self.inward = self._inward_directions(self.points.mean(axis=0))
        grasp = request.grasp_point()
        self.lever = max(float(np.sqrt(np.mean(np.sum((self.points - grasp) ** 2, axis=1)))), 1.0)

    # --- one camera -----------------------------------------------------------------------------

    def camera_pose(self, i: int, placement: CameraPlacement, roll: float | None = None) -> tuple[np.ndarray, float]:
        """Pose of camera i and the roll (rad) that fits its hole's sweep to the image."""
        n, u = self.normals[i], self.inward[i]
        away = u * math.cos(placement.azimuth) + np.cross(n, u) * math.sin(placement.azimuth)
        line = n * math.cos(placement.tilt) - away * math.sin(placement.tilt)  # hole -> camera
        centre = self.points[i] + placement.standoff * line
        axis = -line
        x0 = away - (away @ axis) * axis
        if np.linalg.norm(x0) < 1e-9:
            x0 = np.cross(n, [1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.cross(n, [0.0, 1.0, 0.0])
            x0 = x0 - (x0 @ axis) * axis
        x0 /= np.linalg.norm(x0)
        R = np.column_stack([x0, np.cross(axis, x0), axis])
        sweep = self.sweeps[:, i]
        if roll is None:
            roll = self._best_roll(R, centre, sweep)
        c, s = math.cos(roll), math.sin(roll)
        R = R @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        return frames.make_T(self._centred(R, centre, sweep), centre), roll

    def _best_roll(self, R: np.ndarray, centre: np.ndarray, sweep: np.ndarray) -> float:
        rel = (sweep - centre) @ R
        if np.any(rel[:, 2] <= 1e-6):
            return 0.0
        xy = rel[:, :2] / rel[:, 2:3]
        rolls = np.linspace(0.0, math.pi, ROLL_STEPS, endpoint=False)
        c, s = np.cos(rolls)[:, None], np.sin(rolls)[:, None]
        xr = c * xy[None, :, 0] + s * xy[None, :, 1]
        yr = -s * xy[None, :, 0] + c * xy[None, :, 1]
        slack = np.minimum(self.camera.width - self.camera.fx * np.ptp(xr, axis=1),
                           self.camera.height - self.camera.fy * np.ptp(yr, axis=1))
        return float(rolls[int(np.argmax(slack))])

    def _centred(self, R: np.ndarray, centre: np.ndarray, sweep: np.ndarray) -> np.ndarray:
        """Turn the camera (about its centre) so that the sweep's pixel bounding box is centred."""
        cam = self.camera
        target_ray = cam.pixels_to_rays(np.array([[(cam.width - 1) / 2.0, (cam.height - 1) / 2.0]]))[0]
        for _ in range(3):
            rel = (sweep - centre) @ R
            if np.any(rel[:, 2] <= 1e-6):
                break
            px = cam.project(rel)
            middle = 0.5 * (px.min(axis=0) + px.max(axis=0))
            ray = cam.pixels_to_rays(middle[None])[0]
            axis = np.cross(ray, target_ray)
            angle = math.atan2(float(np.linalg.norm(axis)), float(ray @ target_ray))
            if angle < 1e-12:
                break
            R_fix = frames.rotvec_to_matrix(axis / np.linalg.norm(axis) * angle)
            R = R @ R_fix.T
        return R

    def violations(self, i: int, T_w0_c: np.ndarray) -> dict[str, float]:
        """How far camera i misses each constraint over the envelope (<= 0: satisfied), in px or mm."""
        c = self.request.constraints
        seen = hole_in_view(self.camera, T_w0_c, self.deviations, self.points[i], self.normals[i])
        margin = float(np.min(seen.margin_px))
        out = {"margin": c.margin_px - max(margin, -1e5)}
        if seen.in_front:
            near, far = c.depth_of_field_mm
            out["depth_of_field"] = max(near - float(np.min(seen.depth_mm)), float(np.max(seen.depth_mm)) - far)
        else:
            out["depth_of_field"] = 1e5
        out["view_angle"] = -math.inf  # unlimited: never binds (and leaves the worst miss continuous)
        if c.max_view_angle_envelope_deg is not None:
            out["view_angle"] = float(np.max(seen.view_angle_deg)) - c.max_view_angle_envelope_deg
        out["reach"] = -math.inf
        if c.reach is not None:
            flange = T_w0_c[:3, :3] @ np.asarray(c.reach.flange_c, dtype=float) + T_w0_c[:3, 3]
            out["reach"] = float(np.linalg.norm(flange - np.asarray(c.reach.centre_w, dtype=float))) - c.reach.radius_mm
        return out

    # --- the whole layout -----------------------------------------------------------------------

    def objective(self, poses: list[np.ndarray]) -> float:
        """RMS uncertainty (mm) of the part at its grasp point: the grasp point's position plus the rotation
        times the holes' RMS distance from it (with the robot's repeatability)."""
        r = self.request
        try:
            cov = layout_covariance(self.camera, self.points, poses, r.sigma_px, r.repeatability_mm,
                                    r.repeatability_deg, r.T_f_c)
        except SolveFailed:
            return math.inf
        s = pose_sigmas(cov, frames.invert(poses[0]), r.grasp_point())
        return math.hypot(s.sigma_trans_mm, math.radians(s.sigma_rot_deg) * self.lever)

    def search(self) -> list[_Fit]:
        """The best feasible layout: for both azimuth rules (converging, diverging) and every tilt of the
        grid, each camera at its smallest feasible standoff; then :meth:`refine`."""
        c = self.request.constraints
        max_tilt = math.radians(c.max_view_angle_deg)
        tilts = np.linspace(0.0, max_tilt, GRID_TILTS) if max_tilt > 0 else np.zeros(1)
        records: dict[tuple[float, float, float], list[dict[str, float]]] = {}
        best, best_value, any_feasible = None, math.inf, False
        for azimuth in (0.0, math.pi):
            for tilt in tilts:
                fits = [self.fit(i, float(tilt), azimuth, records) for i in range(len(self.points))]
                if any(f is None for f in fits):
                    continue
                any_feasible = True
                value = self.objective([f.T for f in fits])
                if value < best_value:
                    best, best_value = fits, value
        if best is None:
            # feasible only straight along the normals: that sees nothing of the distance; what binds is
            # whatever keeps the views from tilting
            tilted = [(CameraPlacement(*key), misses) for key, misses in records.items() if key[0] > 0.0]
            if any_feasible and not tilted:
                raise LayoutViewAngle(
                    f"lines of sight within max_view_angle_deg = {c.max_view_angle_deg:g}° of the surface normals "
                    "leave a direction of the part pose unobservable (parallel lines of sight cannot see its "
                    "distance): allow a larger angle"
                )
            raise self._refusal(tilted if any_feasible else [(CameraPlacement(*k), m) for k, m in records.items()])
        return self.refine(best, best_value)

    def fit(self, i: int, tilt: float, azimuth: float, records: dict | None = None) -> _Fit | None:
        """Camera i at ``tilt`` and ``azimuth`` at its smallest standoff that holds every constraint over the
        envelope (None: none does). ``records`` collects the misses on the standoff grid (for refusals)."""
        low, high = self.request.constraints.standoff_mm
        standoffs = np.linspace(low, high, GRID_STANDOFFS) if high > low else np.array([low])
        first, previous = None, None
        for standoff in standoffs:
            placement = CameraPlacement(tilt, azimuth, float(standoff))
            T, roll = self.camera_pose(i, placement)
            misses = self.violations(i, T)
            if records is not None:  # every standoff of the grid, for the refusal's analysis
                records.setdefault((tilt, azimuth, float(standoff)), []).append(misses)
            if max(misses.values()) <= 0.0 and first is None:
                first = _Fit(placement, roll, T) if previous is None else self._closest(
                    i, tilt, azimuth, previous, float(standoff), roll)
                if records is None:
                    break
            previous = float(standoff)
        return first

    def _closest(self, i: int, tilt: float, azimuth: float, infeasible: float, feasible: float, roll: float) -> _Fit:
        """Bisect (Brent) the standoff between an infeasible and a feasible one, the roll held fixed so that
        the worst miss is continuous in it; returns a feasible fit a hair on the feasible side."""
        def worst(standoff: float) -> float:
            T, _ = self.camera_pose(i, CameraPlacement(tilt, azimuth, standoff), roll)
            return max(self.violations(i, T).values())

        if worst(infeasible) > 0.0 and worst(feasible) <= 0.0:
            root = brentq(worst, infeasible, feasible, xtol=STANDOFF_TOL_MM)
            for standoff in (root + STANDOFF_TOL_MM, root + 10 * STANDOFF_TOL_MM, feasible):
                standoff = min(standoff, feasible)
                if worst(standoff) <= 0.0:
                    placement = CameraPlacement(tilt, azimuth, standoff)
                    return _Fit(placement, roll, self.camera_pose(i, placement, roll)[0])
        placement = CameraPlacement(tilt, azimuth, feasible)
        return _Fit(placement, roll, self.camera_pose(i, placement, roll)[0])

    def refine(self, fits: list[_Fit], value: float) -> list[_Fit]:
        """Coordinate descent: each camera's tilt and azimuth moved in turn (its standoff again the smallest
        feasible), kept when the layout's objective falls; steps halve each round."""
        max_tilt = math.radians(self.request.constraints.max_view_angle_deg)
        if max_tilt == 0.0:
            return fits
        step_tilt, step_azimuth = max_tilt / (GRID_TILTS - 1) / 2.0, math.radians(REFINE_AZIMUTH_DEG)
        for _ in range(REFINE_ROUNDS):
            for i in range(len(fits)):
                p = fits[i].placement
                for d_tilt, d_azimuth in ((-1, 0), (1, 0), (0, -1), (0, 1)):
                    tilt = min(max(p.tilt + d_tilt * step_tilt, 0.0), max_tilt)
                    fit = self.fit(i, tilt, p.azimuth + d_azimuth * step_azimuth)
                    if fit is None:
                        continue
                    trial = [*fits[:i], fit, *fits[i + 1 :]]
                    trial_value = self.objective([f.T for f in trial])
                    if trial_value < value:
                        fits, value, p = trial, trial_value, fit.placement
            step_tilt, step_azimuth = step_tilt / 2.0, step_azimuth / 2.0
        return fits

    def _refusal(self, records) -> LayoutInfeasible:
        """The error naming the constraint whose relaxation alone would make some grid point feasible."""
        def worst(misses, kinds):
            return max(miss[k] for miss in misses for k in kinds)

        binding = [k for k in KINDS if any(worst(m, [o for o in KINDS if o != k]) <= 0 for _, m in records)]
        envelope = self.request.envelope.describe()
        if len(binding) > 1:
            return LayoutConstraintsConflict(
                f"{' and '.join(_NAMES[k] for k in binding)} cannot hold together over the envelope {envelope}: "
                "each alone can be met, so relaxing either would do"
            )
        if not binding:
            _, misses = min(records, key=lambda r: sum(max(v, 0.0) for m in r[1] for v in m.values()))
            violated = [_NAMES[k] for k in KINDS if worst(misses, [k]) > 0]
            low, high = self.request.constraints.standoff_mm
            if (elsewhere := self._feasible_standoffs()) is not None:
                return LayoutStandoff(
                    f"standoff_mm = [{low:g}, {high:g}]: no measuring pose in that range satisfies "
                    f"{', '.join(violated)} over the envelope {envelope}; every hole can be held at standoffs "
                    f"of {elsewhere[0]:.0f}-{elsewhere[1]:.0f} mm: widen the range"
                )
            return LayoutConstraintsConflict(
                f"no measuring layout satisfies {', '.join(violated)} together over the envelope {envelope}, at the "
                f"allowed standoffs {low:g}-{high:g} mm nor at any from {WIDE_STANDOFFS_MM[0]:g} to "
                f"{WIDE_STANDOFFS_MM[-1]:g} mm; relaxing any one of them alone is not enough: narrow the envelope "
                "or relax several"
            )
        kind = binding[0]
        placement, misses = min(records, key=lambda r: worst(r[1], [kind]))
        i = int(np.argmax([m[kind] for m in misses]))
        return self._message(kind, i, placement, misses[i])

    def _feasible_standoffs(self) -> tuple[float, float] | None:
        """(lowest, highest) standoff, mm, of :data:`WIDE_STANDOFFS_MM` (and a fine grid over the depth of
        field) at which a hole holds every other constraint, at the first grid tilt and azimuth where every
        hole does at some standoff; None when there is no such tilt (the standoff range is not what binds)."""
        c = self.request.constraints
        max_tilt = math.radians(c.max_view_angle_deg)
        # a hole's depth is about its standoff: look closely (25 mm steps) inside the depth of field
        near, far = c.depth_of_field_mm
        standoffs = np.union1d(WIDE_STANDOFFS_MM, np.linspace(near, far, max(2, int((far - near) / 25.0) + 1)))
        for azimuth in (0.0, math.pi):
            for tilt in np.linspace(0.0, max_tilt, GRID_TILTS) if max_tilt > 0 else np.zeros(1):
                held: list[float] = []
                for i in range(len(self.points)):
                    mine = [float(s) for s in standoffs if max(self.violations(
                        i, self.camera_pose(i, CameraPlacement(tilt, azimuth, s))[0]).values()) <= 0.0]
                    if not mine:
                        break  # this hole cannot be held at this tilt: the others need not be tried
                    held += mine
                else:
                    return min(held), max(held)  # the first tilt that holds every hole is example enough
        return None

    def _message(self, kind: str, i: int, placement: CameraPlacement, miss: dict[str, float]) -> LayoutInfeasible:
        c, name = self.request.constraints, self.names[i]
        where = (f"standoff {c.standoff_mm[0]:g}-{c.standoff_mm[1]:g} mm, lines of sight within "
                 f"{c.max_view_angle_deg:g}° of the normal")
        best = (f"best: standoff {placement.standoff:.0f} mm, tilt {math.degrees(placement.tilt):.0f}°")
        envelope = self.request.envelope.describe()
        if kind == "margin":
            return LayoutOutOfView(
                f"margin_px: no measuring pose ({where}) keeps hole {name} {c.margin_px:g} px inside the image over "
                f"the envelope {envelope}; it comes to {c.margin_px - miss['margin']:.0f} px at best ({best})"
            )
        if kind == "view_angle":
            return LayoutViewAngle(
                f"max_view_angle_envelope_deg: no measuring pose ({where}) keeps the line of sight to hole {name} "
                f"within {c.max_view_angle_envelope_deg:g}° of its surface normal over the envelope {envelope}; "
                f"{miss['view_angle']:.1f}° beyond at best ({best})"
            )
        if kind == "depth_of_field":
            return LayoutDepthOfField(
                f"depth_of_field_mm: no measuring pose ({where}) keeps hole {name} inside the depth of field "
                f"{c.depth_of_field_mm[0]:g}-{c.depth_of_field_mm[1]:g} mm over the envelope {envelope}; it misses "
                f"by {miss['depth_of_field']:.0f} mm at best ({best})"
            )
        return LayoutOutOfReach(
            f"reach: no measuring pose ({where}) for hole {name} that holds the envelope {envelope} puts the flange "
            f"within {c.reach.radius_mm:g} mm of the reach centre; {miss['reach']:.0f} mm beyond at best ({best})"
        )

    def _inward_directions(self, centre: np.ndarray) -> np.ndarray:
        """Unit tangent (n, 3) at each hole pointing towards ``centre`` (or along x or y when it is above)."""
        out = np.empty_like(self.points)
        for i, (p, n) in enumerate(zip(self.points, self.normals, strict=True)):
            for towards in (centre - p, np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])):
                t = towards - (towards @ n) * n
                if np.linalg.norm(t) > 1e-6:
                    out[i] = t / np.linalg.norm(t)
                    break
        return out
