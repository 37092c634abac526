"""Calibration faults at the solver level: what a cell whose calibration has gone bad observes while the solver
keeps the calibrated model (for Monte Carlos over a ``solver.synthetic`` cell; seeded, no I/O).

- camera bump: the camera turned and moved on its bracket by ``bump`` (a rigid motion in the camera's own axes,
  about its centre); the robot's poses unchanged. The calibration, made before the bump, then states the truth
  right-multiplied by the inverse of the bump (``T_f_c`` and every ``T_cf_si``), so
  the camera truly stands at ``T_s1_si @ bump`` (``T_s1_si`` the calibrated pose, SF1 the calibrated, cell-fixed
  frame the offset is written in);
- focal change: the lens's focal length (``fx``, ``fy``) differs by ``focal_pct`` percent, everything else kept;
- pose drift: measuring pose ``drift_view`` stops elsewhere while the robot reports the taught pose: its camera
  stands at ``T_s1_si @ drift`` (the camera-centred model of ``synthetic``, as ``PoseProblem`` without ``T_f_c``).

On top, every cycle the robot's repeatability moves each view afresh (``synthetic.perturbed_views``) and the
centres carry their noise.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from monoguide.solver import frames
from monoguide.solver.camera import CameraModel
from monoguide.solver.synthetic import SyntheticCell, perturbed_views

AXES = ("x", "y", "z")


def axis_motion(axis: str, deg: float = 0.0, mm: float = 0.0) -> np.ndarray:
    """A rigid motion (4, 4): ``deg`` about and ``mm`` along one axis (``"x"``, ``"y"`` or ``"z"``)."""
    if axis not in AXES:
        raise ValueError(f"axis must be one of {AXES}, got {axis!r}")
    unit = np.eye(3)[AXES.index(axis)]
    return frames.make_T(frames.rotvec_to_matrix(math.radians(deg) * unit), mm * unit)


@dataclass(frozen=True)
class CalibrationFault:
    """How the true cell differs from its calibration (none of it by default).

    bump       : (4, 4) the camera's motion on its bracket, in its own axes
    focal_pct  : the true focal length's change, percent
    drift_view : the measuring pose that stops elsewhere, or None
    drift      : (4, 4) where its camera stands, relative to the taught pose (in the camera's axes)
    """

    name: str = "none"
    bump: np.ndarray = field(default_factory=lambda: np.eye(4))
    focal_pct: float = 0.0
    drift_view: int | None = None
    drift: np.ndarray = field(default_factory=lambda: np.eye(4))

    def true_camera(self, camera: CameraModel) -> CameraModel:
        """The lens as it is: focal lengths scaled by ``1 + focal_pct / 100``."""
        factor = 1.0 + self.focal_pct / 100.0
        if not factor > 0.0:
            raise ValueError(f"focal_pct must be above -100, got {self.focal_pct!r}")
        return dataclasses.replace(camera, fx=camera.fx * factor, fy=camera.fy * factor)

    def taught_stops(self, T_s1_si: np.ndarray) -> np.ndarray:
        """Where the cameras (k, 4, 4) stand when the robot reports the taught poses, before the bump and before
        repeatability: the calibrated ``T_s1_si`` with the drifting pose moved."""
        out = np.array(T_s1_si, dtype=float, copy=True)
        if self.drift_view is not None:
            if not 0 <= self.drift_view < len(out):
                raise ValueError(f"drift_view {self.drift_view} is no measuring pose of {len(out)}")
            out[self.drift_view] = out[self.drift_view] @ self.drift
        return out


def camera_bump(axis: str, deg: float = 0.0, mm: float = 0.0) -> CalibrationFault:
    """The camera turned ``deg`` about and moved ``mm`` along its own ``axis`` on its bracket."""
    return CalibrationFault(f"camera bump {deg:g} deg / {mm:g} mm {axis}", bump=axis_motion(axis, deg, mm))


def focal_change(pct: float) -> CalibrationFault:
    """The lens's focal length changed by ``pct`` percent."""
    return CalibrationFault(f"focal {pct:+g} %", focal_pct=float(pct))


def pose_drift(view: int, axis: str, mm: float = 0.0, deg: float = 0.0) -> CalibrationFault:
    """Measuring pose ``view`` stops with its camera ``mm`` along and ``deg`` about its ``axis`` off the taught pose."""
    return CalibrationFault(f"pose {view} drift {mm:g} mm / {deg:g} deg {axis}", drift_view=int(view),
                            drift=axis_motion(axis, deg, mm))


def true_cameras(cell: SyntheticCell, fault: CalibrationFault, rng: np.random.Generator | None = None,
                 repeatability_mm: float = 0.0, repeatability_deg: float = 0.0) -> np.ndarray:
    """Where the cameras (k, 4, 4) truly stood in one cycle, in the calibrated SF1: the taught stops (drift),
    each moved by the robot's repeatability (a fresh draw from ``rng``), then the bump."""
    stops = fault.taught_stops(cell.T_s1_si)
    if rng is not None and (repeatability_mm or repeatability_deg):
        stops = perturbed_views(dataclasses.replace(cell, T_s1_si=stops), rng, repeatability_mm, repeatability_deg)
    return stops @ fault.bump


def faulty_pixels(
    cell: SyntheticCell, fault: CalibrationFault, T_s1_w: np.ndarray, rng: np.random.Generator,
    sigma_px: float = 0.1, repeatability_mm: float = 0.05, repeatability_deg: float = 0.01,
) -> np.ndarray:
    """The centres (m, 2) a cell with ``fault`` observes of a part at ``T_s1_w`` (4, 4) in one cycle: through the
    true lens from the true cameras (:func:`true_cameras`), with ``sigma_px`` of centre noise. Solve them with
    ``cell.problem(...)``: the calibrated model."""
    truth = dataclasses.replace(cell, camera=fault.true_camera(cell.camera))
    exact = truth.project(T_s1_w, true_cameras(cell, fault, rng, repeatability_mm, repeatability_deg))
    return exact + rng.normal(0.0, sigma_px, exact.shape)
