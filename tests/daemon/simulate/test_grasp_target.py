"""The honest grasp target: the RMS of N grasps against the upper 99 % bound of the RMS of N draws of the
predicted error. Ground truth: scipy's chi-square quantiles, a seeded Monte Carlo of the RMS, and seeded runs of
grasp errors drawn from the predicted distribution (honest) and from one 30 % worse."""

import numpy as np
import pytest
from scipy import stats

from monoguide.daemon.simulate._grasp_target import judge_grasp_errors, rms_bound_ratio
from monoguide.solver import frames

# The simulated roof cell's predicted covariance at the grasp point with the robot's repeatability
# (config/sim-cell.toml, f = 0): its principal variances, mm^2 and deg^2 (sigma 0.234 mm, 0.0226 deg).
ROOF_MM2 = (0.008058, 0.023004, 0.023715)
ROOF_DEG2 = (1.3691e-05, 2.3179e-04, 2.6516e-04)
TRIALS = 2000


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


def _runs(variances, n, scale, seed, shape_known=True):
    """Fraction of seeded runs of ``n`` grasps judged "met": each grasp error a 3-vector of the predicted
    covariance (principal variances ``variances`` in a random frame) times ``scale``."""
    rng = np.random.default_rng(seed)
    sigma = float(np.sqrt(np.sum(variances)))
    met = 0
    for _ in range(TRIALS):
        R = frames.rotvec_to_matrix(rng.normal(size=3))
        errors = (rng.normal(size=(n, 3)) * np.sqrt(variances) * scale) @ R.T
        met += judge_grasp_errors(np.linalg.norm(errors, axis=1), sigma, variances if shape_known else None).met
    return met / TRIALS


@pytest.mark.parametrize(("variances", "n"), [(ROOF_MM2, 30), (ROOF_DEG2, 30), (ROOF_MM2, 8), ((1.0, 1.0, 1.0), 60)])
def test_a_cell_as_predicted_is_met_in_99_percent_of_runs(variances, n):
    # 99 % of 2,000 runs: 1,980 +- 4.5 (binomial)
    assert 0.985 <= _runs(variances, n, 1.0, seed=n) <= 0.995
    assert _runs(variances, n, 1.0, seed=n + 1, shape_known=False) >= 0.99  # the widest shape: never stricter


@pytest.mark.parametrize("variances", [ROOF_MM2, ROOF_DEG2])
def test_a_cell_30_percent_worse_is_not_met_in_most_runs_of_30(variances):
    assert 1.0 - _runs(variances, 30, 1.3, seed=31) > 0.7  # the roof: 85 % (mm), 77 % (deg)
    assert 1.0 - _runs(variances, 100, 1.3, seed=32) > 0.99  # and the more grasps, the surer


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
