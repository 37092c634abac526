"""The trend monitor (``solver.trend``): its levels keep their false-alarm promise, a fault alarms, its state
survives a restart. Checked against seeded chi-square draws and solver-level ground truth, not the code's own
formulas: the run lengths by Monte Carlo of the CUSUM recursion written out here."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from monoguide.solver.consistency import check_consistency
from monoguide.solver.pose import solve_ml
from monoguide.solver.synthetic import deviated_part, paper_roof_cell, perturbed_views
from monoguide.solver.trend import (
    DEFAULT_SCALE,
    TrendMonitor,
    average_run_length,
    residual_chi2,
    trend_levels,
    view_statistics,
)


def _run_lengths(level: float, dof: int, chains: int, horizon: int, seed: int, scale: float = DEFAULT_SCALE,
                 noncentrality: float = 0.0) -> tuple[float, float]:
    """Monte Carlo ARL (cycles to the first crossing from 0) of the CUSUM on chi-square draws with ``dof`` and
    ``noncentrality``, and its standard error; chains still running at ``horizon`` enter as censored (the
    exponential MLE, exposure / events)."""
    rng = np.random.default_rng(seed)
    slope, offset = 0.5 * (1 - 1 / scale), -0.5 * dof * math.log(scale)
    S, running = np.zeros(chains), np.ones(chains, dtype=bool)
    stopped_at = np.full(chains, horizon)
    for n in range(1, horizon + 1):
        x = rng.noncentral_chisquare(dof, noncentrality, chains) if noncentrality else rng.chisquare(dof, chains)
        S = np.maximum(0.0, S + slope * x + offset)
        crossed = running & (level < S)
        stopped_at[crossed] = n
        running &= ~crossed
        if not running.any():
            break
    events = int(np.sum(~running))
    arl = float(np.sum(stopped_at)) / events
    return arl, arl / math.sqrt(events)


@pytest.mark.parametrize("dof", [2, 5])
def test_the_warning_level_keeps_its_average_run_length_under_the_null(dof: int) -> None:
    levels = trend_levels(dof)
    arl, error = _run_lengths(levels.warning, dof, chains=3000, horizon=8000, seed=dof)
    assert arl >= levels.warning_arl0 - 3 * error  # not shorter than promised beyond the Monte Carlo error
    assert arl <= levels.warning_arl0 + 3 * error + 0.03 * levels.warning_arl0  # nor wastefully long


def test_the_alarm_level_keeps_its_average_run_length_under_the_null() -> None:
    levels = trend_levels(2)
    arl, error = _run_lengths(levels.alarm, 2, chains=1500, horizon=12_000, seed=11)
    assert arl >= levels.alarm_arl0 - 3 * error
    assert levels.alarm > levels.warning > 0


@pytest.mark.parametrize("noncentrality", [1.0, 4.0])
def test_the_markov_chain_predicts_the_delay_of_a_bias(noncentrality: float) -> None:
    levels = trend_levels(2)
    arl, error = _run_lengths(levels.alarm, 2, chains=4000, horizon=2000, seed=3, noncentrality=noncentrality)
    assert average_run_length(levels.alarm, 2, noncentrality=noncentrality) == pytest.approx(arl, abs=3 * error + 0.5)


def test_a_clear_fault_alarms_within_a_bounded_number_of_cycles() -> None:
    """chi2 x4: each cycle adds 8 (1 - 1/1.5) / 2 - ln 1.5 = 0.93 on average; the alarm level is about 6 (Wald:
    some 7 cycles and the overshoot)."""
    rng = np.random.default_rng(4)
    delays = []
    for _ in range(200):
        monitor = TrendMonitor(2)
        for n in range(1, 1000):
            if monitor.update(4.0 * float(rng.chisquare(2)), 2).alarm:
                delays.append(n)
                break
    assert len(delays) == 200
    assert np.median(delays) <= 10 and max(delays) <= 40


def test_the_alarm_latches_the_warning_follows_the_statistic_and_reset_clears_both() -> None:
    monitor = TrendMonitor(2)
    for _ in range(5):
        reading = monitor.update(40.0, 2)
    assert reading.alarm and reading.warning and reading.alarm_cycle is not None
    first = reading.alarm_cycle
    for _ in range(100):  # each takes ln 1.5 = 0.41 off
        reading = monitor.update(0.0, 2)
    assert reading.statistic == 0.0 and not reading.warning
    assert reading.alarm and reading.alarm_cycle == first  # latched until a new calibration
    monitor.reset()
    reading = monitor.reading()
    assert (reading.statistic, reading.alarm, reading.warning, reading.cycles, reading.alarm_cycle) == (
        0.0, False, False, 0, None)
    assert monitor.state == TrendMonitor(2).state


def test_the_state_round_trips_through_json_and_a_restored_monitor_continues_identically() -> None:
    rng = np.random.default_rng(5)
    draws = [(float(rng.chisquare(2)) * 1.7, [(float(rng.chisquare(2)), 2), (float(rng.chisquare(1)), 1)])
             for _ in range(400)]
    original = TrendMonitor(2)
    for chi2, views in draws[:150]:
        original.update(chi2, 2, per_view=views)
    restored = TrendMonitor.from_state(json.loads(json.dumps(original.state)))
    assert restored.state == original.state
    for chi2, views in draws[150:]:
        assert restored.update(chi2, 2, per_view=views) == original.update(chi2, 2, per_view=views)
    assert len(json.dumps(original.state)) < 400  # constant size, whatever the number of cycles


@pytest.mark.parametrize(
    ("call", "named"),
    [
        (lambda m: m.update(-0.5, 2), "-0.5"),
        (lambda m: m.update(float("nan"), 2), "nan"),
        (lambda m: m.update(float("inf"), 2), "inf"),
        (lambda m: m.update(1.0, 0), "dof 0|got 0"),
        (lambda m: m.update(1.0, 3), "dof 3"),
        (lambda m: m.update(1.0, 2, per_view=[(float("nan"), 2)]), "per_view\\[0\\].*nan"),
        (lambda m: TrendMonitor(0), "got 0"),
        (lambda m: TrendMonitor(2, scale=1.0), "scale.*1.0"),
        (lambda m: TrendMonitor(2, alarm_arl0=100, warning_arl0=1000), "100"),
        (lambda m: TrendMonitor.from_state({**m.state, "statistic": -1.0}), "-1.0"),
        (lambda m: TrendMonitor.from_state({"format": "other"}), "other"),
        (lambda m: TrendMonitor.from_state({k: v for k, v in m.state.items() if k != "cycles"}), "cycles"),
    ],
)
def test_bad_input_is_refused_naming_the_value(call, named: str) -> None:
    with pytest.raises(ValueError, match=named):
        call(TrendMonitor(2))


def test_per_view_dofs_must_stay_those_the_monitor_started_with() -> None:
    monitor = TrendMonitor(2)
    monitor.update(1.0, 2, per_view=[(1.0, 2), (1.0, 2)])
    with pytest.raises(ValueError, match="per_view dofs"):
        monitor.update(1.0, 2, per_view=[(1.0, 2)])
    with pytest.raises(ValueError, match="per_view missing"):
        monitor.update(1.0, 2)


# --- against the solver ---------------------------------------------------------------------------------


CELL = paper_roof_cell()


def _good_solve(rng: np.random.Generator):
    T_true = deviated_part(CELL, rng, 5.0, 50.0)
    views = perturbed_views(CELL, rng, 0.05, 0.01)
    pixels = CELL.project(T_true, views) + rng.normal(0.0, 0.1, (4, 2))
    problem = CELL.problem(pixels, 0.1, 0.05, 0.01)
    return problem, solve_ml(problem).T_s1_w


def test_residual_chi2_is_what_the_per_cycle_check_tests_and_chi_square_distributed() -> None:
    rng = np.random.default_rng(6)
    values = []
    for _ in range(400):
        problem, T = _good_solve(rng)
        chi2, dof = residual_chi2(problem, T)
        assert dof == 2
        values.append(chi2)
    problem, T = _good_solve(rng)
    assert residual_chi2(problem, T)[0] == pytest.approx(check_consistency(problem, T, 1e-300).chi2, rel=1e-12)
    assert np.mean(values) == pytest.approx(2.0, abs=0.3)  # chi2(2): mean 2, sd of the mean 0.1
    assert np.mean(np.array(values) > 4.605) == pytest.approx(0.1, abs=0.045)  # its 0.9 quantile


def test_with_one_hole_per_view_every_views_statistic_is_the_total() -> None:
    """Two degrees of freedom in total: no view can be singled out; the normalised share says so exactly."""
    problem, T = _good_solve(np.random.default_rng(8))
    total, _ = residual_chi2(problem, T)
    views = view_statistics(problem, T)
    assert [k for _, k in views] == [2, 2, 2, 2]
    assert [s for s, _ in views] == pytest.approx([total] * 4, rel=1e-4)  # to the fit's convergence


def test_with_two_holes_per_view_the_views_statistics_differ_and_are_chi_square() -> None:
    """Each camera sees two holes (views 0-1 the first two, 2-3 the last two): 10 degrees of freedom; a view's
    normalised share has the rank of its block and its mean under the noise."""
    two = CELL.__class__(CELL.camera, CELL.points_w, CELL.T_s1_si, CELL.T_s1_w0,
                         ((0, 0), (0, 1), (1, 0), (1, 1), (2, 2), (2, 3), (3, 2), (3, 3)))
    # cameras 650 mm above one hole each see the other only through a wide lens: make it one
    wide = two.camera.__class__(**{**two.camera.as_dict(), "fx": 400.0, "fy": 400.0, "k1": 0.0, "k2": 0.0,
                                   "p1": 0.0, "p2": 0.0})
    two = two.__class__(wide, two.points_w, two.T_s1_si, two.T_s1_w0, two.observed)
    rng = np.random.default_rng(9)
    shares, ranks, totals = [], None, []
    for _ in range(300):
        T_true = deviated_part(two, rng, 1.0, 10.0)
        pixels = two.project(T_true) + rng.normal(0.0, 0.1, (8, 2))
        problem = two.problem(pixels, 0.1)
        T = solve_ml(problem, T_init=T_true).T_s1_w
        views = view_statistics(problem, T)
        ranks = [k for _, k in views]
        shares.append([s for s, _ in views])
        totals.append(residual_chi2(problem, T)[0])
    shares = np.array(shares)
    assert residual_chi2(problem, T)[1] == 10
    assert all(1 <= k <= 4 for k in ranks)
    assert np.mean(totals) == pytest.approx(10.0, rel=0.1)
    assert np.mean(shares, axis=0) == pytest.approx(ranks, rel=0.2)
    assert not np.allclose(shares[:, 0], np.array(totals))
