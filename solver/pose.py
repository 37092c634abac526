"""Pose of the part in SF1, ``T_s1_w``, from observations in several calibrated views (Sec. 3).

Estimators (``ESTIMATORS``):
- ``"ml"`` (the daemon's default): the paper's linear initial value (Eq. 17-21), iterated while the
  deviation is large, then maximum likelihood: reprojection error in pixels over a minimal 6-parameter
  pose, whitened by the pixel noise and the robot's pose repeatability, Levenberg-Marquardt with an
  analytic Jacobian, optional Huber loss. It reaches the Cramer-Rao bound.
- ``"paper"``: the paper's estimator, object-space collinearity error with the orthogonality penalty
  over the 12 entries of ``T_s1_w`` (Eq. 13-16), Levenberg-Marquardt, started from Eq. 21.

:func:`solve_pose` (what every caller uses) refuses what it cannot vouch for: fewer observed points
than ``min_observations`` (default 4), a residual that fails the chi-square test at
``false_alarm_rate`` (``solver.consistency``), and geometry that leaves a direction unobservable.

Pose perturbations are on the left, in SF1: ``R = exp([w]x) R0``, ``t = t0 + dt``; the covariance is
over ``(w rad, dt mm)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.optimize

from monoguide.solver import frames
from monoguide.solver.collinearity import (
    linearised_system,
    object_space_jacobian,
    object_space_residuals,
    orthogonality,
    orthogonality_jacobian,
)
from monoguide.solver.consistency import (
    DEFAULT_FALSE_ALARM_RATE,
    MIN_OBSERVATIONS,
    Consistency,
    check_consistency,
    require_redundancy,
)
from monoguide.solver.errors import DegenerateGeometry, NoConvergence, PointBehindCamera
from monoguide.solver.problem import PoseProblem, reprojection
from monoguide.solver.uncertainty import covariance_from_whitened_jacobian, paper_covariance, whitening

MAX_ITERATIONS = 50
INIT_MAX_ITERATIONS = 30
INIT_STEP_RAD, INIT_STEP_MM = 0.01, 10.0
# Refinement stops when a step moves the pose less than this (far below any physical meaning).
STEP_RAD, STEP_MM = 1e-8, 1e-5
PAPER_PENALTY = 1e6  # M of Eq. 16, in mm^2 per unit orthogonality defect squared


@dataclass
class PoseResult:
    """A solved pose. ``covariance`` (6, 6) is over (rotation vector rad, translation mm) of T_s1_w;
    ``consistency`` is the chi-square test it passed (set by :func:`solve_pose`, None from the bare
    estimators)."""

    T_s1_w: np.ndarray
    covariance: np.ndarray
    residuals_px: np.ndarray  # (m, 2) observed minus predicted, px
    iterations: int
    method: str
    consistency: Consistency | None = None

    @property
    def rms_px(self) -> float:
        return float(np.sqrt(np.mean(np.sum(self.residuals_px**2, axis=1))))

    @property
    def sigma_rot_deg(self) -> float:
        return math.degrees(math.sqrt(max(0.0, float(np.trace(self.covariance[:3, :3])))))

    @property
    def sigma_trans_mm(self) -> float:
        return math.sqrt(max(0.0, float(np.trace(self.covariance[3:, 3:]))))


def solve_pose(
    problem: PoseProblem,
    method: str = "ml",
    robust: bool = False,
    *,
    false_alarm_rate: float = DEFAULT_FALSE_ALARM_RATE,
    min_observations: int = MIN_OBSERVATIONS,
) -> PoseResult:
    """Estimate ``T_s1_w`` with the named estimator (see ``ESTIMATORS``) and check it.

    Raises :class:`TooFewObservations` below ``min_observations`` observed points (at least 3, the
    solvable minimum, where nothing can be checked), :class:`InconsistentMeasurement` when the whitened
    residual fails the chi-square test at ``false_alarm_rate`` (the fraction of good measurements
    refused), :class:`DegenerateGeometry` when a direction of the pose is unobservable.

    The test is of the measurement, not of the estimator: its statistic is the whitened residual at the
    maximum-likelihood fit (the result itself for ``ml``; for ``paper`` and ``robust`` a plain ML
    refinement started from their answer). So the false-alarm rate holds for every estimator, and the
    Huber loss can never turn an outlier into an accepted pose.
    """
    if method not in ESTIMATORS:
        raise ValueError(f"unknown estimator {method!r}; choose one of {sorted(ESTIMATORS)}")
    if robust and method != "ml":
        raise ValueError(f"the robust (Huber) loss belongs to the ml estimator, not {method!r}")
    if isinstance(min_observations, bool) or not isinstance(min_observations, int) or min_observations < 3:
        raise ValueError(f"min_observations must be an integer of at least 3, got {min_observations!r}")
    if not 0.0 < false_alarm_rate < 1.0:
        raise ValueError(f"false_alarm_rate must lie in (0, 1), got {false_alarm_rate!r}")
    require_redundancy(problem, min_observations)
    result = solve_ml(problem, robust=True) if robust else ESTIMATORS[method](problem)
    T_fit = result.T_s1_w if method == "ml" and not robust else refine_ml(problem, result.T_s1_w).T_s1_w
    result.consistency = check_consistency(problem, T_fit, false_alarm_rate)
    return result


def solve_ml(problem: PoseProblem, T_init: np.ndarray | None = None, robust: bool = False) -> PoseResult:
    """Maximum-likelihood pose: :func:`initial_iterated` then :func:`refine_ml`."""
    init_iterations = 0
    if T_init is None:
        T_init, init_iterations = initial_iterated(problem)
    result = refine_ml(problem, T_init, robust=robust)
    result.iterations += init_iterations
    return result


def solve_paper(problem: PoseProblem) -> PoseResult:
    """The paper's estimator: Eq. 21 initial value, then Eq. 16 by Levenberg-Marquardt."""
    T_init = initial_differential(problem, problem.T_s1_w0)
    return refine_paper(problem, T_init)


# --- initial value (Sec. 3.3) -------------------------------------------------------------------


def initial_differential(problem: PoseProblem, T_ref: np.ndarray) -> np.ndarray:
    """One linear least-squares step (Eq. 17-21) from the pose ``T_ref`` (4, 4).

    With ``T_s1_w = T_ref (I + dT)``, Eq. 14 is linear in ``x = (dx dy dz, dx dy dz)`` (Eq. 20): two
    independent rows per observed point. The step is applied as a proper rotation (exponential map)
    rather than ``I + dT``, so the result is orthonormal.
    """
    A, b = linearised_system(problem, T_ref)
    x = _solve_least_squares(A, b, "the linearised collinearity equations (Eq. 20)")
    return T_ref @ frames.pose_from_vector(x)


def initial_iterated(problem: PoseProblem, T_ref: np.ndarray | None = None) -> tuple[np.ndarray, int]:
    """Repeat Eq. 21 about the latest estimate until the step is negligible.

    Each step is exact to first order, so iterating removes the small-angle assumption of Eq. 22:
    deviations of +-20 deg / +-200 mm converge as long as the holes stay in view. Returns the pose and
    the number of steps taken.
    """
    T = problem.T_s1_w0 if T_ref is None else T_ref
    for iteration in range(1, INIT_MAX_ITERATIONS + 1):
        A, b = linearised_system(problem, T)
        x = _solve_least_squares(A, b, "the linearised collinearity equations (Eq. 20)", iteration == 1)
        T = T @ frames.pose_from_vector(x)
        # Close enough for the refinement to converge quadratically; it finishes the job.
        if np.linalg.norm(x[:3]) < INIT_STEP_RAD and np.linalg.norm(x[3:]) < INIT_STEP_MM:
            return T, iteration
    raise NoConvergence(
        f"the initial value did not settle in {INIT_MAX_ITERATIONS} steps of Eq. 21 (last step "
        f"{math.degrees(np.linalg.norm(x[:3])):.3g} deg, {np.linalg.norm(x[3:]):.3g} mm): is the part in view?"
    )


# --- maximum likelihood -------------------------------------------------------------------------


def refine_ml(
    problem: PoseProblem, T_init: np.ndarray, robust: bool = False, huber_sigmas: float = 3.0
) -> PoseResult:
    """Minimise the whitened reprojection error over a minimal pose (Levenberg-Marquardt).

    The residual of each view is whitened by its covariance: pixel noise ``sigma_px`` plus what the
    robot's repeatability (``view_sigma_*``) does to that view's pixels, so the estimate is the maximum
    likelihood under both. ``robust`` down-weights observations beyond ``huber_sigmas`` (Huber).
    """
    R, t = T_init[:3, :3].copy(), T_init[:3, 3].copy()
    r, J, Q = reprojection(problem, R, t)
    whiten = _whitener(problem, Q)
    rw, Jw = whiten(r, J)
    cost = _cost(rw, robust, huber_sigmas)
    lam = 1e-4
    iteration = 0
    while True:
        if iteration == MAX_ITERATIONS:
            raise NoConvergence(f"maximum-likelihood refinement did not converge in {MAX_ITERATIONS} iterations")
        iteration += 1
        if robust:
            weights = _huber_weights(rw, huber_sigmas)
            H, g = (Jw * weights[:, None] ** 2).T @ Jw, (Jw * weights[:, None] ** 2).T @ rw
        else:
            H, g = Jw.T @ Jw, Jw.T @ rw
        step = np.linalg.solve(H + lam * np.diag(np.diag(H)), -g)
        R_new = frames.rotvec_to_matrix(step[:3]) @ R
        t_new = t + step[3:]
        try:
            r_new, J_new, Q_new = reprojection(problem, R_new, t_new)
        except PointBehindCamera:
            lam *= 10.0
            continue
        rw_new, Jw_new = whiten(r_new, J_new)
        cost_new = _cost(rw_new, robust, huber_sigmas)
        if cost_new <= cost:
            R, t, r, J, Q, rw, Jw = R_new, t_new, r_new, J_new, Q_new, rw_new, Jw_new
            small = np.linalg.norm(step[:3]) < STEP_RAD and np.linalg.norm(step[3:]) < STEP_MM
            if small or cost - cost_new <= 1e-12 * cost:
                break
            cost = cost_new
            lam = max(lam * 0.1, 1e-12)
        else:
            lam *= 10.0
            if lam > 1e8:
                break  # no descent direction left: at the minimum to machine precision
    if problem.view_sigma_mm or problem.view_sigma_deg:  # the whitening at the solution, not the start
        rw, Jw = _whitener(problem, Q)(r, J)
    covariance = covariance_from_whitened_jacobian(Jw, problem)
    return PoseResult(frames.make_T(R, t), covariance, -r, iteration, "ml-huber" if robust else "ml")


# --- the paper's estimator (Eq. 13-16) ----------------------------------------------------------


def refine_paper(problem: PoseProblem, T_init: np.ndarray, penalty: float = PAPER_PENALTY) -> PoseResult:
    """Minimise Eq. 16 over X = the 12 entries of ``T_s1_w`` by Levenberg-Marquardt.

    The rotation comes out only approximately orthonormal (the penalty is finite); the reported pose is
    its nearest rotation. The covariance is the paper's propagation Q_X = H Q_P H^T (Eq. 29).
    """
    X0 = T_init[:3, :].ravel()
    sqrt_penalty = math.sqrt(penalty)

    def residuals(X: np.ndarray) -> np.ndarray:
        return np.concatenate([object_space_residuals(problem, X), sqrt_penalty * orthogonality(X)])

    def jacobian(X: np.ndarray) -> np.ndarray:
        return np.vstack([object_space_jacobian(problem, X), sqrt_penalty * orthogonality_jacobian(X)])

    solution = scipy.optimize.least_squares(
        residuals, X0, jac=jacobian, method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15, max_nfev=2000
    )
    if solution.status <= 0:
        raise NoConvergence(f"the paper's estimator (Eq. 16) did not converge: {solution.message}")
    X = solution.x.reshape(3, 4)
    T = frames.make_T(frames.orthonormalize(X[:, :3]), X[:, 3])
    r, _, _ = reprojection(problem, T[:3, :3], T[:3, 3])
    covariance = paper_covariance(problem, solution.x, penalty)
    return PoseResult(T, covariance, -r, int(solution.nfev), "paper")


ESTIMATORS = {"ml": solve_ml, "paper": solve_paper}


# --- private helpers ----------------------------------------------------------------------------


def _whitener(problem: PoseProblem, Q: np.ndarray):
    """A function (r, J) -> (L r, L J) with the whitening of the observations at the points Q."""
    if not (problem.view_sigma_mm or problem.view_sigma_deg):
        inv_sigma = 1.0 / problem.sigma_px
        return lambda r, J: (r.ravel() * inv_sigma, J.reshape(-1, 6) * inv_sigma)
    L = whitening(problem, Q)
    return lambda r, J: (L @ r.ravel(), L @ J.reshape(-1, 6))


def _cost(rw: np.ndarray, robust: bool, k: float) -> float:
    if not robust:
        return float(rw @ rw)
    a = np.abs(rw)
    return float(np.sum(np.where(a <= k, a * a, 2.0 * k * a - k * k)))


def _huber_weights(rw: np.ndarray, k: float) -> np.ndarray:
    """Square roots of the Huber IRLS weights."""
    a = np.abs(rw)
    return np.sqrt(np.where(a <= k, 1.0, k / np.maximum(a, 1e-300)))


def _solve_least_squares(A: np.ndarray, b: np.ndarray, what: str, check_rank: bool = True) -> np.ndarray:
    """Eq. 21, x = (A^T A)^-1 A^T b, refusing a rank-deficient system."""
    AtA = A.T @ A
    try:
        x = np.linalg.solve(AtA, A.T @ b)
    except np.linalg.LinAlgError:
        x = np.full(6, np.nan)
    if not np.all(np.isfinite(x)) or (check_rank and np.linalg.cond(AtA) > 1e15):
        raise DegenerateGeometry(f"{what} do not determine all six degrees of freedom (rank deficient)")
    return x
