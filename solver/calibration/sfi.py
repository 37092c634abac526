"""Measuring-pose frames SFi (step 5, paper Eq. 6): ``T_cf_si = T_cf_t · (T_si_t)^-1``.

At each visit of measuring pose i the tracker has measured the target frame ``T_cf_t`` (a rigid fit of its SMR
nests, :func:`fit_target_frame`) and the camera has measured the target ``T_si_t`` (:mod:`.target`). Each visit
carries the robot's repeatability and the tracker's and camera's noise; the visits (several per placement of
the target, the target placed more than once) are averaged: Karcher mean of the rotations, mean of the
translations. Each SFi's spread (RMS of the visits about the mean) and its standard error are reported.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from monoguide.solver.calibration.averaging import PoseMean, mean_pose
from monoguide.solver.calibration.errors import CalibrationSpreadTooLarge, CalibrationTooFewViews
from monoguide.solver.calibration.rigid import RigidFit, fit_rigid
from monoguide.solver.frames import compose, invert

MIN_VISITS = 3
DEFAULT_MAX_SPREAD_MM = 0.5  # RMS of the visits about their mean; the robot's repeatability is ~0.05 mm
DEFAULT_MAX_SPREAD_DEG = 0.1


def fit_target_frame(points_t: np.ndarray, measured_cf: np.ndarray, names: Sequence[str] | None = None,
                     max_residual_mm: float | None = 0.15) -> RigidFit:
    """``T_cf_t`` (``fit.T``) from the target's SMR nests: coordinates in TF (m, 3) mm, readings in CF (m, 3) mm."""
    return fit_rigid(points_t, measured_cf, names, what="target frame (nests)", max_residual_mm=max_residual_mm)


def visit_sfi(T_cf_t: np.ndarray, T_si_t: np.ndarray) -> np.ndarray:
    """Eq. 6 for one visit: ``T_cf_si = T_cf_t · (T_si_t)^-1``."""
    return compose(T_cf_t, invert(T_si_t))


@dataclass(frozen=True)
class SfiResult:
    """``T_cf_si`` (4, 4) averaged over the visits, and how the visits spread about it."""

    name: str
    mean: PoseMean

    @property
    def T_cf_si(self) -> np.ndarray:
        return self.mean.T

    def as_dict(self) -> dict[str, object]:
        m = self.mean
        return {"name": self.name, "T_cf_si": m.T.tolist(), "visits": m.n, "spread_mm": m.spread_mm,
                "spread_deg": m.spread_deg, "sigma_mean_mm": m.sigma_mean_mm, "sigma_mean_deg": m.sigma_mean_deg,
                "visit_dev_mm": m.dev_mm.tolist(), "visit_dev_deg": m.dev_deg.tolist()}


def calibrate_measuring_pose(visits: Sequence[tuple[np.ndarray, np.ndarray]], name: str = "S?", *,
                             min_visits: int = MIN_VISITS, max_spread_mm: float = DEFAULT_MAX_SPREAD_MM,
                             max_spread_deg: float = DEFAULT_MAX_SPREAD_DEG) -> SfiResult:
    """Average Eq. 6 over the visits ``[(T_cf_t, T_si_t), ...]`` of measuring pose ``name``. Refuses fewer than
    ``min_visits`` and a visit farther from the mean than ``3 × max_spread`` or a spread above ``max_spread``
    (:class:`CalibrationSpreadTooLarge`, naming the visit): the robot did not come back, the target moved."""
    if len(visits) < min_visits:
        raise CalibrationTooFewViews(f"measuring pose {name}: {len(visits)} visit(s), need at least {min_visits} "
                                     "(visit each pose several times, with the target placed more than once)")
    mean = mean_pose([visit_sfi(T_cf_t, T_si_t) for T_cf_t, T_si_t in visits])
    worst_mm, worst_deg = int(np.argmax(mean.dev_mm)), int(np.argmax(mean.dev_deg))
    if mean.spread_mm > max_spread_mm or mean.dev_mm[worst_mm] > 3.0 * max_spread_mm:
        raise CalibrationSpreadTooLarge(
            f"measuring pose {name}: visits spread {mean.spread_mm:.3f} mm RMS (tolerance {max_spread_mm:g}); "
            f"visit {worst_mm + 1} is {mean.dev_mm[worst_mm]:.3f} mm off the mean")
    if mean.spread_deg > max_spread_deg or mean.dev_deg[worst_deg] > 3.0 * max_spread_deg:
        raise CalibrationSpreadTooLarge(
            f"measuring pose {name}: visits spread {mean.spread_deg:.4f} deg RMS (tolerance {max_spread_deg:g}); "
            f"visit {worst_deg + 1} is {mean.dev_deg[worst_deg]:.4f} deg off the mean")
    return SfiResult(name, mean)
