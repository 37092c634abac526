"""A camera's deviation from its calibrated pose over cycles: its scatter, its mean and its linear drift.

With fixed reference marks every cycle estimates where each view's camera stood (``solver.marks``): a deviation
``d`` (mm) and ``w`` (deg, a rotation vector), three components each in the camera's axes. Over a run of cycles a
good cell's deviations scatter about a mean by what the robot's repeatability at the measuring pose gives, cycle to
cycle; a camera working loose on its bracket, or a measuring pose creeping, adds a trend. :func:`vector_trend` fits
one three-component series by least squares against the cycle number,

    v(c) = a + b (c - c_mean) + e,       e ~ N(0, Sigma) independent from cycle to cycle,

and returns the mean, the scatter (each component's standard deviation about the fitted line: the repeatability,
the drift taken out), the slope ``b`` per ``per`` cycles with each component's standard error, and the slope's
norm with its standard error along its own direction.

**When a slope is a drift.** The three components of the slope are tested together (a drift may lie along any
axis, and the components are correlated, the flange's lever coupling rotation and shift): Hotelling's
``T^2 = b^T Cov(b)^-1 b`` with ``Cov(b) = Sigma_hat / S_cc`` (``S_cc`` the sum of squared cycle offsets,
``Sigma_hat`` the residuals' covariance on ``n - 2`` degrees of freedom) is, for no drift and Gaussian scatter,
exactly ``T^2(p, n - 2)``: ``(n - 2 - p + 1) / (p (n - 2)) T^2 ~ F(p, n - p - 1)`` (``p`` = 3, or fewer when a
component does not scatter at all). Its tail probability is given as the normal-equivalent number of standard
errors (two-sided), :attr:`VectorTrend.sigmas`; a slope is *significant* beyond 3 of them (a false call 0.27 % of
the time per series without drift). For a drift along one axis this is a little less sensitive than that axis'
own ``|b| / se > 3`` (it does not know the axis in advance): 4 standard errors along one axis read as about 3.3.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.stats

SIGNIFICANT_SIGMAS = 3.0  # a slope is a drift beyond this many (normal-equivalent) standard errors
MIN_TREND_CYCLES = 5  # the fewest cycles with a slope and its test (Hotelling's F needs n - p - 1 >= 1 for p = 3)
RANK_RTOL = 1e-12


@dataclass(frozen=True, eq=False)
class VectorTrend:
    """One three-component series over ``n`` cycles (see the module): mean, scatter and, from
    :data:`MIN_TREND_CYCLES` cycles spanning more than one cycle number, the slope per ``per`` cycles."""

    n: int
    per: float
    cycle_mean: float
    mean: np.ndarray  # (3,)
    scatter: np.ndarray | None  # (3,) standard deviation about the fitted line (about the mean without a slope)
    slope: np.ndarray | None  # (3,) per `per` cycles
    slope_se: np.ndarray | None  # (3,) each component's standard error
    statistic: float | None  # Hotelling's T^2 of the slope
    dof: int | None  # the components tested (the rank of the scatter)
    p_value: float | None  # of T^2 with no drift
    slope_covariance: np.ndarray | None = None  # (3, 3) of the slope per `per` cycles

    @property
    def mean_norm(self) -> float:
        return float(np.linalg.norm(self.mean))

    @property
    def scatter_norm(self) -> float | None:
        """The root of the summed variances: the RMS of the series' distance from its fitted line."""
        return None if self.scatter is None else float(np.linalg.norm(self.scatter))

    @property
    def slope_norm(self) -> float | None:
        return None if self.slope is None else float(np.linalg.norm(self.slope))

    @property
    def slope_norm_se(self) -> float | None:
        """The slope's standard error along its own direction (per ``per`` cycles); the largest component's
        standard error for a zero slope."""
        if self.slope is None or self.slope_se is None:
            return None
        norm = float(np.linalg.norm(self.slope))
        if norm == 0.0:
            return float(np.max(self.slope_se))
        return float(np.sqrt(self._direction_variance(self.slope / norm)))

    @property
    def sigmas(self) -> float | None:
        """The slope's significance as the normal-equivalent number of standard errors (two-sided)."""
        if self.p_value is None:
            return None
        return math.inf if self.p_value <= 0.0 else float(scipy.stats.norm.isf(self.p_value / 2.0))

    def significant(self, sigmas: float = SIGNIFICANT_SIGMAS) -> bool:
        return self.sigmas is not None and self.sigmas > sigmas

    def fitted(self, cycles: np.ndarray) -> np.ndarray:
        """(len(cycles), 3) the fitted line at ``cycles`` (the mean without a slope)."""
        c = np.asarray(cycles, dtype=float).reshape(-1, 1)
        slope = np.zeros(3) if self.slope is None else self.slope / self.per
        return self.mean + (c - self.cycle_mean) * slope

    def _direction_variance(self, u: np.ndarray) -> float:
        assert self.slope_covariance is not None
        return float(u @ self.slope_covariance @ u)


def vector_trend(cycles: np.ndarray, values: np.ndarray, per: float = 1000.0) -> VectorTrend:
    """Fit the series ``values`` (n, 3) against ``cycles`` (n,) (see the module); ``n`` >= 1."""
    c = np.asarray(cycles, dtype=float).reshape(-1)
    v = np.asarray(values, dtype=float).reshape(len(c), -1)
    n = len(c)
    if n == 0:
        raise ValueError("vector_trend: no cycle")
    mean = v.mean(axis=0)
    c_mean = float(c.mean())
    dc = c - c_mean
    s_cc = float(dc @ dc)
    if n < MIN_TREND_CYCLES or s_cc <= 0.0:
        scatter = v.std(axis=0, ddof=1) if n >= 2 else None
        return VectorTrend(n, per, c_mean, mean, scatter, None, None, None, None, None)
    b = (dc @ (v - mean)) / s_cc  # (3,) per cycle
    residual = v - mean - np.outer(dc, b)
    nu = n - 2
    sigma = residual.T @ residual / nu
    cov_b = sigma / s_cc
    lam, vec = np.linalg.eigh(cov_b)
    keep = lam > RANK_RTOL * max(float(lam.max()), 0.0) if lam.max() > 0 else np.zeros(len(lam), dtype=bool)
    p = int(keep.sum())
    p_value: float
    if p == 0:  # nothing scatters: any slope at all is certain, none is none
        t2, p_value = (math.inf, 0.0) if np.any(b != 0.0) else (0.0, 1.0)
    else:
        z = vec[:, keep].T @ b
        t2 = float(np.sum(z**2 / lam[keep]))
        p_value = float(scipy.stats.f.sf(t2 * (nu - p + 1) / (p * nu), p, nu - p + 1))  # n >= 5: nu - p + 1 >= 1
    return VectorTrend(n, per, c_mean, mean, np.sqrt(np.diag(sigma)), b * per, np.sqrt(np.diag(cov_b)) * per,
                       t2, p, p_value, cov_b * per**2)


def cycles_to_reach(trend: VectorTrend, at_cycle: float, tolerance: float) -> float | None:
    """Cycles after ``at_cycle`` until the fitted line's norm reaches ``tolerance``: 0 when it already has, None
    without a slope or when the line never gets there (moving away, or passing by below it)."""
    if trend.slope is None or not np.isfinite(tolerance) or tolerance <= 0.0:
        return None
    a = trend.fitted(np.array([at_cycle]))[0]
    if float(np.linalg.norm(a)) >= tolerance:
        return 0.0
    b = trend.slope / trend.per
    bb = float(b @ b)
    if bb == 0.0:
        return None
    # |a + b t|^2 = tol^2, the positive root (a inside the ball: exactly one)
    ab, aa = float(a @ b), float(a @ a)
    t = (-ab + math.sqrt(ab * ab - bb * (aa - tolerance**2))) / bb
    return t if t >= 0.0 else None
