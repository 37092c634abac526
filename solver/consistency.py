"""Is a solved pose consistent with its own measurement? Redundancy and the chi-square test.

With ``m`` observed points the six pose parameters leave ``2m - 6`` degrees of freedom in the residual.
Under the noise model the estimator whitens by (the centre noise ``sigma_px`` and, with ``view_sigma``,
what the robot's repeatability does to each view), the squared whitened residual at the solution is
chi-square distributed with those degrees of freedom. A value beyond its ``1 - false_alarm_rate``
quantile means a centre, a calibration or the record is wrong, and the pose is refused rather than
reported. With three points there is no degree of freedom left: the residual is zero whatever the
pixels, so nothing can be checked; four is the default minimum (the paper's choice).

The observation named in the refusal is the one whose single error best explains the residual (the
generalised likelihood ratio of a 2-D error at that observation, Baarda's data snooping): in a
nearly minimal layout a wrong centre spreads its residual over every observation, so the largest
residual is not necessarily the wrong one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.special

from monoguide.solver.errors import InconsistentMeasurement, TooFewObservations
from monoguide.solver.problem import PoseProblem, reprojection
from monoguide.solver.uncertainty import covariance_from_whitened_jacobian, whitening

DEFAULT_FALSE_ALARM_RATE = 1e-3
MIN_OBSERVATIONS = 4
# Two observations whose single error explains the residual within this ratio cannot be told apart.
AMBIGUOUS_RATIO = 0.9


@dataclass(frozen=True)
class Consistency:
    """The chi-square test of one solve: the statistic, its degrees of freedom and the threshold it was
    held against (None when no degree of freedom is left and nothing could be checked)."""

    chi2: float
    dof: int
    threshold: float | None

    def as_dict(self) -> dict:
        threshold = None if self.threshold is None else float(f"{self.threshold:.6g}")
        return {"chi2": float(f"{self.chi2:.6g}"), "dof": self.dof, "threshold": threshold}


def require_redundancy(problem: PoseProblem, min_observations: int = MIN_OBSERVATIONS) -> None:
    """Refuse a problem with fewer than ``min_observations`` observed points (:class:`TooFewObservations`)."""
    m = problem.n_observations
    if m < min_observations:
        raise TooFewObservations(
            f"{m} observed point(s), at least {min_observations} required: with 3 the pose fits any pixels "
            "exactly and nothing can be checked; a fourth point gives the redundancy that detects a wrong centre"
        )


def chi2_threshold(dof: int, false_alarm_rate: float) -> float:
    """The ``1 - false_alarm_rate`` quantile of the chi-square distribution with ``dof`` degrees of freedom."""
    return float(scipy.special.chdtri(dof, false_alarm_rate))


def check_consistency(
    problem: PoseProblem, T_s1_w: np.ndarray, false_alarm_rate: float = DEFAULT_FALSE_ALARM_RATE
) -> Consistency:
    """Chi-square test of the whitened reprojection residual at ``T_s1_w`` (4, 4).

    Raises :class:`InconsistentMeasurement` naming the worst observation (view, point, residual px) when
    the statistic exceeds the threshold, and :class:`DegenerateGeometry` when the observations leave a
    direction of the pose unobservable at this pose (whatever estimator produced it).
    """
    if not 0.0 < false_alarm_rate < 1.0:
        raise ValueError(f"false_alarm_rate must lie in (0, 1), got {false_alarm_rate!r}")
    r, J, Q = reprojection(problem, T_s1_w[:3, :3], T_s1_w[:3, 3])
    L = whitening(problem, Q)
    z = L @ r.ravel()
    Jw = L @ J.reshape(-1, 6)
    covariance_from_whitened_jacobian(Jw, problem)  # refuses degenerate geometry
    chi2 = float(z @ z)
    dof = 2 * problem.n_observations - 6
    if dof <= 0:
        return Consistency(chi2, 0, None)
    threshold = chi2_threshold(dof, false_alarm_rate)
    if not math.isfinite(chi2) or chi2 > threshold:
        residual_px = np.hypot(r[:, 0], r[:, 1])
        j = _worst_observation(L, Jw, z)
        if j is None:  # every observation explains it equally: name the largest residual, say so
            j = int(np.argmax(residual_px))
            located = (f"; with {dof} degree(s) of freedom the measurement cannot tell which observation is "
                       "wrong (a further point would locate it)")
        else:
            located = ": check that hole's centre and that view's calibration"
        raise InconsistentMeasurement(
            f"the residual does not fit the stated noise (sigma_px {problem.sigma_px:g}"
            f"{', view_sigma' if problem.view_sigma_mm or problem.view_sigma_deg else ''}): chi-square "
            f"{chi2:.4g} > {threshold:.4g} ({dof} degrees of freedom, false-alarm rate {false_alarm_rate:g}); "
            f"worst: observations[{j}] (view {int(problem.view_index[j])}, point {int(problem.point_index[j])}), "
            f"residual {float(residual_px[j]):.2f} px{located}"
        )
    return Consistency(chi2, dof, threshold)


def _worst_observation(L: np.ndarray, Jw: np.ndarray, z: np.ndarray) -> int | None:
    """Index of the observation whose 2-D error best explains the whitened residual ``z``, or None when
    another explains it (nearly) as well: with two degrees of freedom any one observation's error
    absorbs the whole residual, so none can be singled out.

    For an error ``b`` (2,) in the pixels of observation j the whitened residual moves along
    ``A = L[:, 2j:2j+2]``; after the pose has absorbed what it can (projector ``N`` onto the residual
    space), the test statistic is ``g^T (A^T N A)^+ g`` with ``g = A^T N z``.
    """
    basis, _ = np.linalg.qr(Jw)
    Nz = z - basis @ (basis.T @ z)
    m = len(z) // 2
    scores = np.zeros(m)
    for j in range(m):
        A = L[:, 2 * j : 2 * j + 2]
        NA = A - basis @ (basis.T @ A)
        g = NA.T @ Nz
        scores[j] = float(g @ np.linalg.pinv(A.T @ NA, rcond=1e-9, hermitian=True) @ g)
    best = int(np.argmax(scores))
    runner_up = np.max(np.delete(scores, best), initial=0.0)
    return None if runner_up >= AMBIGUOUS_RATIO * scores[best] else best
