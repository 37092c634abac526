"""Calibration faults of the simulated cell: the camera knocked on its bracket, the lens's focal length changed, a
measuring pose re-touched. The simulated camera renders with them; the service keeps its calibration, the part
supply its truth, so the grasp error in the truth log shows what the fault cost (docs/simulate.md).

The conventions (the same as ``monoguide simulate --calibration`` with a file made by
``benchmarks/make_bumped_calibration.py``):

- **camera bump** ``B = bump_motion(deg, mm, axis)``: a rotation of ``deg`` about the camera's own axis ``axis``
  (x, y or z of the camera frame) and a translation of ``mm`` along that same axis, both in the camera frame. The
  camera's true mounting becomes ``T_f_c_true = T_f_c · B`` (it turned and moved by ``B`` in its own axes), the
  robot's poses unchanged: every view's true camera pose is the calibrated one right-multiplied by ``B``. Put the
  other way, as the issue does: the calibration (``[camera] T_f_c`` and every ``T_cf_si``) is the truth
  right-multiplied by ``B⁻¹``.
- **focal change** ``pct``: the lens's true ``fx`` and ``fy`` are the model's times ``1 + pct / 100`` (the
  principal point and the distortion unchanged).
- **pose drift** of robot pose number ``K`` (1-based) by ``mm`` and ``deg``: that measuring pose stops at
  ``T_b_f_stop · D`` with ``D = make_T(rotvec(deg · u), mm · u)`` at the flange, ``u = (1, 1, 1)/√3`` of the flange
  frame (a fixed direction: every axis gets ``mm/√3`` and ``deg/√3``), while the robot reports the stop without
  ``D``. ``T_b_f_stop`` is the stop the controller made (the taught pose with its repeatability); the grasp is
  not moved.

Every fault persists until cleared (``bump 0 0``, ``focal 0``, ``drift K 0 0``). The state file's form
(``camera_fault.calibration``, written by ``monoguide sim-cell``) is :meth:`CalibrationFaults.from_state`'s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from monoguide.solver.calibration_faults import axis_motion
from monoguide.solver.camera import CameraModel
from monoguide.solver.frames import compose, invert, make_T, rotvec_to_matrix

# the commands ``monoguide sim-cell`` takes for them, per device word (daemon/simulate/_fault_channel.py copies
# them: runtime code never imports the simulator; tests/daemon/simulate/test_calibration_faults.py compares)
CALIBRATION_FAULTS: dict[str, tuple[str, ...]] = {"camera": ("bump", "focal"), "pose": ("drift",)}
DRIFT_DIRECTION_F = np.ones(3) / math.sqrt(3.0)  # the pose drift's direction in the flange frame (unit)


def bump_motion(deg: float, mm: float, axis: str = "x") -> np.ndarray:
    """``B`` (4, 4): ``deg`` about and ``mm`` along the camera's own ``axis`` (the solver's fault geometry)."""
    return axis_motion(axis, deg, mm)


def drift_motion(mm: float, deg: float) -> np.ndarray:
    """``D`` (4, 4) at the flange: ``mm`` along and ``deg`` about :data:`DRIFT_DIRECTION_F`."""
    return make_T(rotvec_to_matrix(math.radians(deg) * DRIFT_DIRECTION_F), mm * DRIFT_DIRECTION_F)


@dataclass(frozen=True)
class CalibrationFaults:
    """The calibration faults the simulated cell has now (none by default); see the module's doc."""

    bump_deg: float = 0.0
    bump_mm: float = 0.0
    bump_axis: str = "x"
    focal_pct: float = 0.0
    drift: dict[int, tuple[float, float]] = field(default_factory=dict)  # robot pose number -> (mm, deg)

    @classmethod
    def from_state(cls, entry: Any) -> CalibrationFaults:
        """From the state file's ``camera_fault.calibration`` (None or absent: none): ``{"bump": {"deg", "mm",
        "axis"} | null, "focal_pct", "drift": {"K": {"mm", "deg"}}, "serial"}``; a :class:`ValueError` naming what
        is wrong."""
        if entry is None:
            return cls()
        if not isinstance(entry, dict):
            raise ValueError(f"calibration faults must be an object, got {entry!r}")
        bump = entry.get("bump") or {}
        drift = entry.get("drift") or {}
        if not isinstance(bump, dict) or not isinstance(drift, dict):
            raise ValueError(f"calibration faults: bump and drift must be objects, got {bump!r}, {drift!r}")
        faults = cls(_finite(bump.get("deg", 0.0), "bump deg"), _finite(bump.get("mm", 0.0), "bump mm"),
                     str(bump.get("axis", "x")), _finite(entry.get("focal_pct", 0.0), "focal_pct"),
                     {int(k): (_finite(v["mm"], f"drift {k} mm"), _finite(v["deg"], f"drift {k} deg"))
                      for k, v in drift.items()})
        bump_motion(0.0, 0.0, faults.bump_axis)  # the axis is one of AXES
        if not 1.0 + faults.focal_pct / 100.0 > 0.0:
            raise ValueError(f"focal_pct {faults.focal_pct!r}: must be above -100")
        return faults

    @property
    def active(self) -> bool:
        return bool(self.bump_deg or self.bump_mm or self.focal_pct or self.drift)

    def bump(self) -> np.ndarray:
        return bump_motion(self.bump_deg, self.bump_mm, self.bump_axis)

    def true_mounting(self, T_f_c: np.ndarray) -> np.ndarray:
        """``T_f_c_true = T_f_c · B``: where the camera really sits on the flange."""
        return compose(T_f_c, self.bump())

    def true_camera(self, camera: CameraModel) -> CameraModel:
        """The lens as it is: ``fx``, ``fy`` times ``1 + focal_pct / 100``."""
        factor = 1.0 + self.focal_pct / 100.0
        return replace(camera, fx=camera.fx * factor, fy=camera.fy * factor)

    def drift_at(self, pose_number: int) -> np.ndarray:
        """``D`` of robot pose ``pose_number`` (1-based; identity when it does not drift)."""
        mm, deg = self.drift.get(pose_number, (0.0, 0.0))
        return drift_motion(mm, deg)

    def T_cf_c(self, T_cf_b: np.ndarray, T_b_f_stop: np.ndarray, T_f_c: np.ndarray, pose_number: int) -> np.ndarray:
        """The camera's true pose in the cell frame at a stop ``T_b_f_stop`` of robot pose ``pose_number``:
        ``T_cf_b · T_b_f_stop · D_K · T_f_c · B``."""
        return compose(T_cf_b, T_b_f_stop, self.drift_at(pose_number), self.true_mounting(T_f_c))

    def T_c_w(self, cell: Any, i: int | None = None) -> np.ndarray:
        """What the camera of a :class:`~monoguide.drivers.sim.cell.SimCell` sees of its part at the last stop at
        measuring pose index ``i`` (0-based; default: where the robot is now), with these faults."""
        i = cell.current_pose if i is None else i
        T_cf_c = self.T_cf_c(cell.spec.T_cf_b, cell.actual_flange_pose(i), cell.spec.T_f_c, i + 1)
        return compose(invert(T_cf_c), cell.T_cf_w_true)


def _finite(value: Any, name: str) -> float:
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} {value!r}: not a number") from None
    if not math.isfinite(number):
        raise ValueError(f"{name} {value!r}: not finite")
    return number
