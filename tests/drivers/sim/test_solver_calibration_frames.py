"""Cell frame CF and part frame WF from simulated tracker readings (issue 12, steps 2 and 4)."""

from __future__ import annotations

import numpy as np
import pytest

from monoguide.daemon.assembly import build_sim_cell
from monoguide.daemon.config import load_cell_config
from monoguide.drivers.sim.target_renderer import tracker_reading
from monoguide.solver.calibration.cell import cell_frame_321, fit_cell_frame, fit_part_frame
from monoguide.solver.calibration.errors import (
    CalibrationDegenerate,
    CalibrationResidualTooLarge,
    CalibrationTooFewViews,
)
from monoguide.solver.frames import invert, pose_difference, transform_points

CONFIG = "config/sim-cell.toml"


@pytest.fixture(scope="module")
def cell():
    return build_sim_cell(load_cell_config(CONFIG))


def _benchmarks_in_tracker(cell, rng, noise=0.025):
    T_tracker_cf = invert(cell.spec.T_cf_tracker)
    names = list(cell.spec.benchmarks_cf)
    pts = transform_points(T_tracker_cf, np.array([cell.spec.benchmarks_cf[n] for n in names]))
    return dict(zip(names, tracker_reading(pts, rng, noise), strict=True))


def test_cell_frame_from_three_benchmarks_matches_the_truth(cell) -> None:
    rng = np.random.default_rng(11)
    fit = fit_cell_frame(cell.spec.benchmarks_cf, _benchmarks_in_tracker(cell, rng))
    deg, mm = pose_difference(fit.T, cell.spec.T_cf_tracker)
    # three nests 1.2-1.5 m apart, 0.025 mm each: the frame to a few thousandths of a degree
    assert deg < 0.005
    # the cell frame where it is used (the benchmarks) within 0.05 mm
    for p in cell.spec.benchmarks_cf.values():
        tracker_p = transform_points(invert(cell.spec.T_cf_tracker), p.reshape(1, 3))
        assert np.linalg.norm(transform_points(fit.T, tracker_p) - p) < 0.05
    assert fit.names == ("B1", "B2", "B3") and fit.residuals_mm.shape == (3,)
    assert mm < 1.0  # the tracker stands 3.5 m from CF's origin: its origin is an extrapolation


def test_cell_frame_321_is_the_frame_the_benchmarks_define(cell) -> None:
    rng = np.random.default_rng(12)
    measured = _benchmarks_in_tracker(cell, rng, noise=0.0)
    T = cell_frame_321(measured, "B1", "B2", "B3")  # B1 origin, B2 on x, B3 in the xy plane: CF itself
    deg, mm = pose_difference(T, cell.spec.T_cf_tracker)
    assert deg < 1e-9 and mm < 1e-6


def test_collinear_benchmarks_are_refused_naming_them(cell) -> None:
    nominal = {"B1": np.zeros(3), "B2": np.array([1000.0, 0, 0]), "B3": np.array([2000.0, 0.5, 0])}
    measured = {k: v + 5.0 for k, v in nominal.items()}
    with pytest.raises(CalibrationDegenerate, match="B1, B2, B3 are \\(nearly\\) collinear") as info:
        fit_cell_frame(nominal, measured)
    assert info.value.plc_code == 701 and info.value.code == "CALIBRATION_DEGENERATE"


def test_two_benchmarks_are_too_few(cell) -> None:
    measured = _benchmarks_in_tracker(cell, np.random.default_rng(1))
    del measured["B3"]
    with pytest.raises(CalibrationTooFewViews, match="2 point"):
        fit_cell_frame(cell.spec.benchmarks_cf, measured)


def test_a_moved_benchmark_is_refused_by_its_residual(cell) -> None:
    nominal = dict(cell.spec.benchmarks_cf)
    nominal["B4"] = np.array([1500.0, 1200.0, 0.0])
    T_tracker_cf = invert(cell.spec.T_cf_tracker)
    measured = {n: transform_points(T_tracker_cf, p.reshape(1, 3))[0] for n, p in nominal.items()}
    measured["B4"] = measured["B4"] + np.array([0.0, 0.0, 0.8])  # its SMR sits 0.8 mm proud of the nest
    with pytest.raises(CalibrationResidualTooLarge, match=r"tolerance 0\.15 mm") as info:
        fit_cell_frame(nominal, measured)
    assert "B4" in info.value.message


def test_part_frame_from_featured_holes(cell) -> None:
    rng = np.random.default_rng(13)
    names = cell.spec.point_names
    nominal = dict(zip(names, cell.spec.points_w, strict=True))
    measured = dict(zip(names, tracker_reading(transform_points(cell.spec.T_cf_w0, cell.spec.points_w), rng),
                        strict=True))
    fit = fit_part_frame(nominal, measured)
    deg, mm = pose_difference(fit.T, cell.spec.T_cf_w0)
    assert deg < 0.002 and mm < 0.05
    assert set(fit.as_dict()["residuals_mm"]) == set(names)
    assert fit.max_mm < 0.1
