"""The trend monitor: a CUSUM of every cycle's whitened residual, for a calibration that has slowly gone bad.

The chi-square test of one solve (``solver.consistency``) refuses a residual that is far off the noise model; a
calibration fault a little smaller moves the residual less than its noise and passes every cycle. It still moves
it every cycle, so the evidence adds up. Under the noise model the squared whitened residual ``x`` of a solve is
chi-square with ``k`` degrees of freedom; a fault makes it larger. The monitor is Page's one-sided CUSUM of the
log-likelihood ratio of ``x`` under a chi-square scaled by ``scale`` (``x / scale ~ chi2(k)``) against the null:

    S_0 = 0,  S_n = max(0, S_{n-1} + (x_n / 2) (1 - 1 / scale) - (k / 2) ln(scale))

It warns while ``S_n`` is above the warning level and alarms (latched until :meth:`TrendMonitor.reset`, a new
calibration) once it passes the alarm level. Each level is the one whose average run length under the null (good
cycles from a reset to the first crossing, ARL0) is the stated number of cycles, computed by Brook and Evans'
Markov chain of the CUSUM over its range (:func:`average_run_length`; the test checks it against a Monte Carlo).

A fault is a bias, not a scale: the residual's mean moves, so ``x`` is a non-central chi-square with
non-centrality ``delta``. ``scale`` is the design point; the default 1.5 is the chi-square's mean grown by half
(``delta = k / 2``): in the paper's roof cell (k = 2) about what a 0.1 deg turn of the camera about its x axis
does (delta about 1), and the one of 1.25, 1.5, 2, 3 that detects delta = 1 soonest at ARL0 10,000
(``docs/health.md``). Larger faults are refused by the per-cycle check anyway.

Per view. ``view_statistics`` gives each view's share of the residual normalised by its share of the residual
space, ``z_v^T (N_vv)^+ z_v``, chi-square with ``rank(N_vv)`` degrees of freedom under the noise model; the monitor
runs a CUSUM of each beside the total and reports them, but alarms on the total only. With one hole per view and
two degrees of freedom in total (the roof cell), every view's block of the residual space is invertible and each
view's statistic *equals* the total: a residual of two degrees of freedom cannot say which view moved (the data
snooping of ``solver.consistency`` says the same); with more points per view, or marks, they differ.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import scipy.optimize
import scipy.stats

from monoguide.solver.problem import PoseProblem, reprojection
from monoguide.solver.uncertainty import whitening

DEFAULT_SCALE = 1.5
ALARM_ARL0 = 10_000  # good cycles per false alarm (the stated default)
# The service's alarm: nominally 20,000, because the solver's chi-square runs a little heavier than the model's
# (mean 2.008 for 2, benchmarks/bench_trend.py); at the nominal 10,000 it alarmed 1.6 times per 10,000 good cycles.
SERVICE_ALARM_ARL0 = 20_000
WARNING_ARL0 = 1_000
STATE_FORMAT = "monoguide.trend/1"
# The chain's resolution over [0, level]. Coarser chains understate the ARL (the level errs on the safe side): at the
# default alarm level 9,883 with 200 states, 10,000 with 400, 10,036 with 800.
MARKOV_STATES = 400
RANK_RTOL = 1e-9


@dataclass(frozen=True)
class TrendLevels:
    """The CUSUM's levels for one layout: degrees of freedom, design scale, and the warning and alarm levels with
    the average run length (good cycles) each was chosen for."""

    dof: int
    scale: float
    warning: float
    alarm: float
    warning_arl0: float
    alarm_arl0: float


@dataclass(frozen=True)
class TrendReading:
    """One cycle's reading: the total statistic ``S_n`` and its levels, ``warning`` (S_n above its level now),
    ``alarm`` (passed the alarm level since the reset; latched), ``cycles`` since the reset, ``alarm_cycle`` (the
    cycle that first passed it, or None), and each view's statistic (empty without ``per_view``; a view with ``k``
    degrees of freedom has the levels of ``trend_levels(k)``)."""

    statistic: float
    warning_level: float
    alarm_level: float
    warning: bool
    alarm: bool
    cycles: int
    alarm_cycle: int | None
    views: tuple[float, ...]


def trend_levels(
    dof: int, scale: float = DEFAULT_SCALE, alarm_arl0: float = ALARM_ARL0, warning_arl0: float = WARNING_ARL0
) -> TrendLevels:
    """The levels whose average run lengths under the null are ``warning_arl0`` and ``alarm_arl0`` good cycles."""
    dof = _require_dof(dof)
    _require_scale(scale)
    if not 1.0 < warning_arl0 <= alarm_arl0 or not math.isfinite(alarm_arl0):
        raise ValueError(f"need 1 < warning_arl0 <= alarm_arl0 (finite), got {warning_arl0!r}, {alarm_arl0!r}")
    return TrendLevels(dof, float(scale), _level(dof, float(scale), float(warning_arl0)),
                       _level(dof, float(scale), float(alarm_arl0)), float(warning_arl0), float(alarm_arl0))


def average_run_length(level: float, dof: int, scale: float = DEFAULT_SCALE, noncentrality: float = 0.0) -> float:
    """Average number of cycles from ``S = 0`` until the CUSUM passes ``level`` when every cycle's statistic is
    chi-square with ``dof`` degrees of freedom and ``noncentrality`` (0: the null).

    Brook and Evans (1972): the CUSUM on a grid of ``MARKOV_STATES`` cells over [0, level], a Markov chain whose
    expected time to absorption solves ``(I - P) t = 1``.
    """
    dof = _require_dof(dof)
    _require_scale(scale)
    if not level > 0.0 or not math.isfinite(level):
        raise ValueError(f"level must be a positive number, got {level!r}")
    if not noncentrality >= 0.0 or not math.isfinite(noncentrality):
        raise ValueError(f"noncentrality must be >= 0, got {noncentrality!r}")
    n = MARKOV_STATES
    width = level / n
    slope, offset = _increment(dof, scale)
    centres = (np.arange(n) + 0.5) * width
    edges = np.arange(n + 1) * width  # S below the first edge is 0 or in the first cell: both restart there
    # P[S_prev + slope x + offset < edge]: x < (edge - offset - S_prev) / slope
    bounds = (edges[None, 1:] - offset - centres[:, None]) / slope
    distribution = scipy.stats.chi2(dof) if noncentrality == 0.0 else scipy.stats.ncx2(dof, noncentrality)
    cdf = distribution.cdf(np.maximum(bounds, 0.0))
    P = np.diff(np.concatenate([np.zeros((n, 1)), cdf], axis=1), axis=1)
    t = np.linalg.solve(np.eye(n) - P, np.ones(n))
    return float(t[0])


def residual_chi2(problem: PoseProblem, T_s1_w: np.ndarray) -> tuple[float, int]:
    """The squared whitened residual at ``T_s1_w`` (4, 4) and its degrees of freedom, ``2m - 6``: what
    ``check_consistency`` tests, also for a cycle it refuses (whose exception carries no statistic)."""
    z, _ = _whitened(problem, T_s1_w)
    return float(z @ z), 2 * problem.n_observations - 6


def view_statistics(problem: PoseProblem, T_s1_w: np.ndarray) -> list[tuple[float, int]]:
    """Each view's share of the whitened residual at ``T_s1_w`` (4, 4), normalised so that it is chi-square
    under the noise model: ``[(z_v^T (N_vv)^+ z_v, rank N_vv), ...]`` in the order of the views.

    ``z`` is the whitened residual and ``N`` the projector onto the residual space (what the pose cannot absorb);
    to first order ``z = N e`` with ``e`` white, so a view's rows ``z_v`` have covariance ``N_vv``. The whitening is
    block-diagonal over views (a view's pixels are correlated only among themselves), so ``z_v`` is that view's.
    """
    z, Jw = _whitened(problem, T_s1_w)
    basis, _ = np.linalg.qr(Jw)
    N = np.eye(len(z)) - basis @ basis.T
    out = []
    for view in range(len(problem.T_s1_si)):
        rows = np.flatnonzero(problem.view_index == view)
        idx = (2 * rows[:, None] + np.arange(2)).ravel()
        if len(idx) == 0:
            out.append((0.0, 0))
            continue
        block = N[np.ix_(idx, idx)]
        rank = int(np.linalg.matrix_rank(block, tol=RANK_RTOL * max(1.0, float(np.abs(block).max()))))
        zv = z[idx]
        statistic = float(zv @ np.linalg.pinv(block, rcond=RANK_RTOL, hermitian=True) @ zv) if rank else 0.0
        out.append((statistic, rank))
    return out


class TrendMonitor:
    """The CUSUM of one layout (one part's measuring poses) since its calibration.

    Its whole state is :attr:`state`, a small JSON-able dict of constant size (the daemon journals it and restores
    it with :meth:`from_state`); an update costs O(1).
    """

    def __init__(
        self, dof: int, scale: float = DEFAULT_SCALE, alarm_arl0: float = ALARM_ARL0,
        warning_arl0: float = WARNING_ARL0,
    ) -> None:
        self.levels = trend_levels(dof, scale, alarm_arl0, warning_arl0)
        self.reset()

    def reset(self) -> None:
        """Forget everything since the calibration (a new calibration: the cell starts good)."""
        self._statistic = 0.0
        self._cycles = 0
        self._alarm_cycle: int | None = None
        self._views: list[list[float]] = []  # per view: [statistic, dof]

    def update(self, chi2: float, dof: int, per_view: Sequence[tuple[float, int]] | None = None) -> TrendReading:
        """Add one cycle's chi-square ``chi2`` with ``dof`` degrees of freedom (``Consistency.chi2`` / ``.dof``, or
        :func:`residual_chi2` for a cycle the per-cycle check refused: it is evidence too), and optionally each
        view's (:func:`view_statistics`). Raises ValueError for a negative or non-finite value (a solve that went
        wrong: leave the cycle out) and for degrees of freedom other than the monitor's."""
        chi2 = _require_chi2(chi2, "chi2")
        if _require_dof(dof) != self.levels.dof:
            raise ValueError(f"dof {dof!r} differs from the monitor's {self.levels.dof}: a monitor watches one "
                             "layout; keep one per layout")
        views = self._checked_views(per_view)
        self._statistic = self._step(self._statistic, chi2, dof)
        for state, (x, k) in zip(self._views, views, strict=True):
            state[0] = self._step(state[0], x, k) if k else 0.0
        self._cycles += 1
        if self._alarm_cycle is None and self._statistic > self.levels.alarm:
            self._alarm_cycle = self._cycles
        return self.reading()

    def reading(self) -> TrendReading:
        """The current reading, without adding a cycle."""
        levels = self.levels
        return TrendReading(self._statistic, levels.warning, levels.alarm, self._statistic > levels.warning,
                            self._alarm_cycle is not None, self._cycles, self._alarm_cycle,
                            tuple(s for s, _ in self._views))

    @property
    def state(self) -> dict:
        """Everything needed to continue: the levels' inputs, the statistics, the cycle count."""
        levels = self.levels
        return {
            "format": STATE_FORMAT, "dof": levels.dof, "scale": levels.scale, "alarm_arl0": levels.alarm_arl0,
            "warning_arl0": levels.warning_arl0, "statistic": self._statistic, "cycles": self._cycles,
            "alarm_cycle": self._alarm_cycle, "views": [[s, int(k)] for s, k in self._views],
        }

    @classmethod
    def from_state(cls, state: dict) -> TrendMonitor:
        """A monitor that continues exactly where the one whose :attr:`state` this is stopped."""
        if not isinstance(state, dict) or state.get("format") != STATE_FORMAT:
            raise ValueError(f"not a trend monitor state ({STATE_FORMAT!r} expected): {state!r:.200}")
        try:
            monitor = cls(state["dof"], state["scale"], state["alarm_arl0"], state["warning_arl0"])
            statistic = _require_chi2(state["statistic"], "statistic")
            cycles, alarm_cycle, views = state["cycles"], state["alarm_cycle"], state["views"]
        except KeyError as missing:
            raise ValueError(f"trend monitor state: missing {missing}") from None
        if isinstance(cycles, bool) or not isinstance(cycles, int) or cycles < 0:
            raise ValueError(f"trend monitor state: cycles must be a count, got {cycles!r}")
        if alarm_cycle is not None and (isinstance(alarm_cycle, bool) or not isinstance(alarm_cycle, int)
                                        or not 0 < alarm_cycle <= cycles):
            raise ValueError(f"trend monitor state: alarm_cycle {alarm_cycle!r} is no cycle of {cycles}")
        monitor._statistic, monitor._cycles, monitor._alarm_cycle = statistic, cycles, alarm_cycle
        monitor._views = [[_require_chi2(s, "views statistic"), _require_view_dof(k)] for s, k in views]
        return monitor

    def _step(self, statistic: float, x: float, dof: int) -> float:
        slope, offset = _increment(dof, self.levels.scale)
        return max(0.0, statistic + slope * x + offset)

    def _checked_views(self, per_view: Sequence[tuple[float, int]] | None) -> list[tuple[float, int]]:
        if per_view is None:
            if self._views:
                raise ValueError(f"per_view missing: this monitor follows {len(self._views)} views since its reset")
            return []
        views = [(_require_chi2(x, f"per_view[{i}] chi2"), _require_view_dof(k)) for i, (x, k) in enumerate(per_view)]
        if not self._views and self._cycles == 0:
            self._views = [[0.0, k] for _, k in views]
        known = [int(k) for _, k in self._views]
        if [k for _, k in views] != known:
            raise ValueError(f"per_view dofs {[k for _, k in views]} differ from the monitor's {known}")
        return views


# --- private helpers ----------------------------------------------------------------------------


def _whitened(problem: PoseProblem, T_s1_w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The whitened residual (2m,) and its Jacobian (2m, 6) at ``T_s1_w``."""
    r, J, Q = reprojection(problem, T_s1_w[:3, :3], T_s1_w[:3, 3])
    L = whitening(problem, Q)
    return L @ r.ravel(), L @ J.reshape(-1, 6)


def _increment(dof: int, scale: float) -> tuple[float, float]:
    """The log-likelihood ratio of chi2 scaled by ``scale`` against chi2, ``slope * x + offset``."""
    return 0.5 * (1.0 - 1.0 / scale), -0.5 * dof * math.log(scale)


@lru_cache(maxsize=64)
def _level(dof: int, scale: float, arl0: float) -> float:
    """The level with ARL0 = ``arl0`` (ARL grows monotonically with the level; root of log ARL)."""
    target = math.log(arl0)
    high = 1.0
    while math.log(average_run_length(high, dof, scale)) < target:
        high *= 2.0
    return float(scipy.optimize.brentq(lambda h: math.log(average_run_length(h, dof, scale)) - target,
                                       1e-6, high, xtol=1e-6))


def _require_chi2(value: object, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value) or value < 0:
        raise ValueError(f"{name} must be a finite number >= 0 (a squared whitened residual), got {value!r}")
    return float(value)


def _require_dof(value: object) -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 1:
        raise ValueError(f"dof must be a whole number >= 1 (a residual with no degree of freedom says nothing), "
                         f"got {value!r}")
    return int(value)


def _require_view_dof(value: object) -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 0:
        raise ValueError(f"a view's dof must be a whole number >= 0, got {value!r}")
    return int(value)


def _require_scale(value: object) -> None:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value) or value <= 1.0:
        raise ValueError(f"scale must be a number > 1 (the chi-square's growth the CUSUM is designed for), "
                         f"got {value!r}")
