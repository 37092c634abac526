"""Cell frame CF (step 2) and part frame WF (step 4) from tracker measurements (paper Sec. 2.2).

CF: the benchmark SMRs' nominal coordinates in CF, measured by the tracker in its own frame; the best fit
gives ``T_cf_tracker`` (every later tracker reading maps into CF with it). Or, without nominal coordinates,
CF is defined by three benchmarks (3-2-1). WF: the featured holes' coordinates in WF (Table 1), measured in
CF; the best fit is the reference part pose ``T_cf_w0``.
"""

from __future__ import annotations

import numpy as np

from monoguide.solver.calibration.errors import CalibrationError
from monoguide.solver.calibration.rigid import RigidFit, fit_rigid, fit_rigid_named, frame_321
from monoguide.solver.frames import invert

DEFAULT_MAX_RESIDUAL_MM = 0.15  # six times the tracker's 0.025 mm: beyond it a nest or a nominal is wrong


def fit_cell_frame(nominal_cf: dict[str, np.ndarray], measured_tracker: dict[str, np.ndarray],
                   max_residual_mm: float | None = DEFAULT_MAX_RESIDUAL_MM) -> RigidFit:
    """``T_cf_tracker`` (``fit.T``) from ≥ 3 benchmarks: name -> nominal (3,) mm in CF and name -> the tracker's
    reading (3,) mm. Residual per benchmark in ``fit.residuals_mm``."""
    unknown = sorted(set(measured_tracker) - set(nominal_cf))
    if unknown:
        raise CalibrationError(f"cell frame: measured benchmark(s) {', '.join(unknown)} have no nominal coordinates")
    # fit the readings onto the nominals: T maps tracker coordinates to CF
    names = [n for n in nominal_cf if n in measured_tracker]
    return fit_rigid(np.array([measured_tracker[n] for n in names]).reshape(-1, 3),
                     np.array([nominal_cf[n] for n in names]).reshape(-1, 3), names,
                     what="cell frame (benchmarks)", max_residual_mm=max_residual_mm)


def cell_frame_321(measured_tracker: dict[str, np.ndarray], origin: str, on_x: str, in_plane: str) -> np.ndarray:
    """``T_cf_tracker`` of the cell frame defined by three benchmarks (3-2-1): origin, x axis towards ``on_x``,
    xy plane through ``in_plane``."""
    T_tracker_cf = frame_321(measured_tracker[origin], measured_tracker[on_x], measured_tracker[in_plane],
                             (origin, on_x, in_plane), "cell frame 3-2-1")
    return invert(T_tracker_cf)


def fit_part_frame(points_w: dict[str, np.ndarray], measured_cf: dict[str, np.ndarray],
                   max_residual_mm: float | None = DEFAULT_MAX_RESIDUAL_MM) -> RigidFit:
    """The reference part pose ``T_cf_w0`` (``fit.T``) from its featured holes: name -> coordinates in WF (3,) mm
    (Table 1) and name -> the tracker's reading in CF (3,) mm. Residual per hole in ``fit.residuals_mm``."""
    return fit_rigid_named(points_w, measured_cf, what="part frame (featured holes)", max_residual_mm=max_residual_mm)
