"""The grasp target of a ``monoguide simulate`` run, judged honestly: the RMS of N grasp errors against the
predicted sigma with its sampling spread for N (docs/simulate.md, "The grasp target").

The predicted grasp error is a Gaussian 3-vector ``e ~ N(0, C)`` (the layout's covariance at the grasp point;
the rotation's likewise), and the predicted sigma is the RMS of its norm: ``sigma^2 = E|e|^2 = trace C``. The
RMS of N independent grasps then scatters as

    N RMS^2 = sum_k lambda_k chi2_N(k)      (lambda_k the eigenvalues of C, the chi-squares independent)

so ``RMS / sigma`` has a distribution that depends only on N and the shape ``lambda_k / sigma^2``: between
``chi2_3N / 3N`` (a round error, three equal eigenvalues) and ``chi2_N / N`` (all of it in one direction). The
target is the upper ``LEVEL`` (99 %) quantile of ``RMS / sigma`` (computed exactly, Imhof 1961): a cell that
performs as predicted says "met" in 99 % of runs, whatever N; a cell worse than predicted is "not met" the more
often the more grasps it ran. Without the shape, the widest (one direction) is taken: never stricter than honest.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import integrate, optimize, stats

LEVEL = 0.99  # an honest run is "met" this often
_TAIL_LOG = 18.0  # Imhof's integrand is cut where its envelope has fallen below e^-18 (1.5e-8)


@dataclass(frozen=True)
class GraspJudgement:
    """One quantity (mm or deg) of one job's grasps against its prediction.

    n        : grasps judged
    rms      : their RMS (None without grasps)
    sigma    : the predicted sigma (the RMS of the error's norm)
    ratio    : rms / sigma
    bound_ratio : the upper ``level`` quantile of rms / sigma for n grasps of the predicted distribution
    bound    : sigma * bound_ratio, in the quantity's unit
    met      : rms <= bound (False without grasps)
    """

    n: int
    rms: float | None
    sigma: float
    ratio: float | None
    bound_ratio: float
    bound: float
    met: bool
    level: float = LEVEL

    def as_dict(self) -> dict[str, Any]:
        return {"n": self.n, "rms": self.rms, "sigma": self.sigma, "ratio": self.ratio,
                "bound_ratio": self.bound_ratio, "bound": self.bound, "met": self.met, "level": self.level}


def judge_grasp_errors(errors: Sequence[float], sigma: float, variances: Sequence[float] | None = None,
                       level: float = LEVEL) -> GraspJudgement:
    """Judge one job's grasp errors (norms, mm or deg, one per grasp) against its predicted ``sigma`` (the RMS
    of the norm) and, when known, the principal variances of the predicted covariance (3,; their sum is
    ``sigma**2``, only their proportions are used). Called once per job."""
    if not (math.isfinite(sigma) and sigma > 0):
        raise ValueError(f"the predicted sigma must be finite and > 0, got {sigma!r}")
    values = np.asarray(errors, dtype=float)
    n = len(values)
    bound_ratio = rms_bound_ratio(max(n, 1), variances, level)
    rms = float(np.sqrt(np.mean(values**2))) if n else None
    return GraspJudgement(n, rms, float(sigma), None if rms is None else rms / sigma, bound_ratio,
                          float(sigma) * bound_ratio, rms is not None and rms <= float(sigma) * bound_ratio, level)


def rms_bound_ratio(n: int, variances: Sequence[float] | None = None, level: float = LEVEL) -> float:
    """The upper ``level`` quantile of RMS / sigma over ``n`` draws of ``|e|``, ``e ~ N(0, diag(variances))``
    and ``sigma^2 = sum(variances)``; ``variances`` None: the widest shape, one direction (``chi2_n / n``)."""
    if n < 1 or not 0.0 < level < 1.0:
        raise ValueError(f"need n >= 1 and 0 < level < 1, got n = {n}, level = {level}")
    return _bound_ratio(n, tuple(float(w) for w in _shape(variances)), level)


@functools.lru_cache(maxsize=256)
def _bound_ratio(n: int, shape: tuple[float, ...], level: float) -> float:
    weights = np.array(shape)
    mean, spread = float(n), math.sqrt(2.0 * n * float(np.sum(weights**2)))

    def exceeds(x: float) -> float:
        return _imhof_tail(x, weights, n) - (1.0 - level)

    upper = mean + 4.0 * spread
    while exceeds(upper) > 0.0:
        upper += 4.0 * spread
    q = optimize.brentq(exceeds, mean, upper, xtol=1e-10 * mean, rtol=1e-12)
    return math.sqrt(q / n)


def _shape(variances: Sequence[float] | None) -> np.ndarray:
    """The eigenvalues' proportions (their sum 1), the negligible ones dropped; None: one direction."""
    if variances is None:
        return np.array([1.0])
    v = np.asarray(variances, dtype=float)
    if v.ndim != 1 or not np.all(np.isfinite(v)) or np.any(v < 0) or v.sum() <= 0:
        raise ValueError(f"variances: expected non-negative numbers with a positive sum, got {variances!r}")
    w = v / v.sum()
    return w[w > 1e-12]


def _imhof_tail(x: float, weights: np.ndarray, dof: int) -> float:
    """P(sum_k w_k chi2_dof(k) > x): a chi-square's when the weights are equal, else Imhof's (1961) inversion of
    the characteristic function, integrated on a grid fine against its oscillation up to where its envelope
    ``1 / (u rho(u))`` has fallen below ``e^-TAIL_LOG``."""
    if np.allclose(weights, weights[0], rtol=1e-9, atol=0.0):
        return float(stats.chi2.sf(x / weights[0], dof * len(weights)))
    half = 0.5 * dof

    def log_rho(u: np.ndarray | float) -> np.ndarray:
        return 0.5 * half * np.sum(np.log1p((np.multiply.outer(u, weights)) ** 2), axis=-1)

    top = 1.0 / float(np.max(weights))
    while float(log_rho(top)) + math.log(top) < _TAIL_LOG:
        top *= 2.0
    step = min(4.0 * math.pi / max(x, 1e-9) / 64.0, top / 4096.0)
    u = np.linspace(0.0, top, 2 * math.ceil(top / step / 2.0) + 1)[1:]
    theta = half * np.sum(np.arctan(np.multiply.outer(u, weights)), axis=-1) - 0.5 * x * u
    f = np.concatenate([[0.5 * (dof * float(np.sum(weights)) - x)], np.sin(theta) / u * np.exp(-log_rho(u))])
    return 0.5 + float(integrate.simpson(f, dx=top / (len(f) - 1))) / math.pi
