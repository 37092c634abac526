"""The honest grasp target: the RMS of N grasps against the upper 99 % bound of the RMS of N draws of the
predicted error. Ground truth: scipy's chi-square quantiles, a seeded Monte Carlo of the RMS, and seeded runs of
grasp errors drawn from the predicted distribution (honest) and from one 30 % worse."""

import numpy as np
import pytest
from helpers.grasp_runs import ROOF_DEG2, ROOF_MM2, met_fraction
from scipy import stats

from monoguide.daemon.simulate._grasp_target import judge_grasp_errors, rms_bound_ratio


@pytest.mark.parametrize("n", [1, 4, 30, 400])
def test_a_round_error_and_one_direction_are_chi_square(n):
    """Three equal variances: N RMS^2 / sigma^2 * 3 ~ chi2_3N; one direction (no shape known): chi2_N."""
    assert rms_bound_ratio(n, (2.0, 2.0, 2.0)) == pytest.approx(np.sqrt(stats.chi2.ppf(0.99, 3 * n) / (3 * n)),
                                                                rel=1e-9)
    assert rms_bound_ratio(n) == pytest.approx(np.sqrt(stats.chi2.ppf(0.99, n) / n), rel=1e-9)
    assert rms_bound_ratio(n, (5.0, 0.0, 0.0)) == pytest.approx(rms_bound_ratio(n), rel=1e-12)


@pytest.mark.parametrize("variances", [ROOF_MM2, ROOF_DEG2, (0.7, 0.2, 0.1), (0.98, 0.01, 0.01)])
@pytest.mark.parametrize("n", [3, 30, 150])
def test_an_uneven_error_has_the_bound_of_its_monte_carlo(variances, n):
    rng = np.random.default_rng(8)
    w = np.asarray(variances) / np.sum(variances)
    ratio2 = rng.chisquare(n, size=(400_000, 3)) @ w / n
    assert rms_bound_ratio(n, variances) == pytest.approx(np.sqrt(np.quantile(ratio2, 0.99)), rel=4e-3)


@pytest.mark.parametrize(("variances", "n"), [(ROOF_MM2, 30), (ROOF_DEG2, 30), (ROOF_MM2, 8), ((1.0, 1.0, 1.0), 60)])
def test_a_cell_as_predicted_is_met_in_99_percent_of_runs(variances, n):
    # 99 % of 2,000 runs: 1,980 +- 4.5 (binomial)
    assert 0.985 <= met_fraction(variances, n, 1.0, seed=n) <= 0.995
    assert met_fraction(variances, n, 1.0, seed=n + 1, shape_known=False) >= 0.99  # the widest shape: never stricter


@pytest.mark.parametrize("variances", [ROOF_MM2, ROOF_DEG2])
def test_a_cell_30_percent_worse_is_not_met_in_most_runs_of_30(variances):
    assert 1.0 - met_fraction(variances, 30, 1.3, seed=31) > 0.7  # the roof: about 84 % (mm), 77 % (deg)
    assert 1.0 - met_fraction(variances, 100, 1.3, seed=32) > 0.99  # and the more grasps, the surer


def test_the_judgement_of_one_jobs_grasps():
    errors = [0.1, 0.2, 0.3, 0.2]
    j = judge_grasp_errors(errors, 0.2, ROOF_MM2)
    assert j.n == 4 and j.rms == pytest.approx(np.sqrt(np.mean(np.square(errors))))
    assert j.ratio == pytest.approx(j.rms / 0.2) and j.bound == pytest.approx(0.2 * rms_bound_ratio(4, ROOF_MM2))
    assert j.met == (j.rms <= j.bound)
    assert not judge_grasp_errors([0.2 * j.bound_ratio * 1.001] * 4, 0.2, ROOF_MM2).met
    assert judge_grasp_errors([0.2 * j.bound_ratio * 0.999] * 4, 0.2, ROOF_MM2).met
    empty = judge_grasp_errors([], 0.2)
    assert empty.rms is None and not empty.met
    with pytest.raises(ValueError, match="sigma"):
        judge_grasp_errors(errors, 0.0)
