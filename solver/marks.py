"""Fixed reference marks: every view's camera pose measured in each cycle, jointly with the part.

A view that sees a few marks of the cell (on the fixture, surveyed once with the laser tracker) observes where its
camera really stood. The estimator is maximum likelihood over, in SF1 of the calibration:

- the part pose ``T_s1_w`` (left perturbation ``(w rad, dt mm)``, as :mod:`solver.pose`),
- a correction ``e_i = (w rad, d mm)`` of each view's camera pose, ``T_s1_si_true = T_s1_si @ pose_from_vector(e_i)``
  (a right perturbation in the camera's axes, as :func:`solver.uncertainty.view_motion_factor`), with the prior
  ``e_i ~ N(0, S_i)``: the robot's repeatability at the flange (``holes.view_sigma_*``, ``holes.T_f_c``) plus the
  calibration's own sigma per camera axis,
- the true position of each mark, with its survey (tracker sigma) as its prior.

The cost is the squared whitened residual of the hole centres and the mark centres (pixels, Eq. 7-9 through the
camera model of Eq. 8), of the camera priors and of the mark surveys; Levenberg-Marquardt from the paper's initial
value (Eq. 17-21 on the holes). Rows minus unknowns leave ``2 (holes + marks seen) - 6`` degrees of freedom.

The problem is :mod:`solver.marks_problem`; the checks (:func:`solver.marks_check.assess_marks`) are generalised
likelihood-ratio tests of one block of the model at a time (Baarda's data snooping, as :mod:`solver.consistency`,
extended to blocks): a view's camera prior (6-D: "the camera stood elsewhere"), a mark's survey (3-D: "the mark is not
where it was surveyed"), a hole centre (2-D). See docs/cycle-marks.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from monoguide.solver import frames
from monoguide.solver.errors import DegenerateGeometry, NoConvergence, PointBehindCamera
from monoguide.solver.marks_problem import (
    CALIBRATION_SIGMA_DEG,
    CALIBRATION_SIGMA_MM,
    MARK_SIGMA_MM,
    MARK_SIGMA_PX,
    MIN_MARKS_PER_VIEW,
    MarksProblem,
    ReferenceMark,
)
from monoguide.solver.pose import initial_iterated

if TYPE_CHECKING:
    from monoguide.solver.marks_check import MarksAssessment

__all__ = [
    "CALIBRATION_SIGMA_DEG", "CALIBRATION_SIGMA_MM", "MARK_SIGMA_MM", "MARK_SIGMA_PX", "MEASURED_SHARE",
    "MIN_MARKS_PER_VIEW", "CameraCorrection", "MarksProblem", "MarksResult", "ReferenceMark", "fit_marks",
]

# A direction of a block counts as measured when the data take more than this share of its prior variance away.
MEASURED_SHARE = 0.05
MAX_ITERATIONS = 30
GAIN_LEFT = 1e-10  # converged when a step's predicted gain in the cost is below this share of it
STEP_RAD, STEP_MM = 1e-9, 1e-6


def shift_mm(e: np.ndarray) -> float:
    """The translation's length of a camera correction ``e = (w rad, d mm)``, mm."""
    return float(np.linalg.norm(e[3:]))


def turn_deg(e: np.ndarray) -> float:
    """The rotation's angle of a camera correction ``e = (w rad, d mm)``, deg."""
    return math.degrees(float(np.linalg.norm(e[:3])))


@dataclass(frozen=True)
class CameraCorrection:
    """Where one view's camera stood, relative to its calibrated pose: ``correction`` (6,) = (w rad, d mm) in its
    axes, ``covariance`` (6, 6) of it after the fit; ``marks`` seen; ``checked``: enough marks to test it."""

    view: str
    correction: np.ndarray
    covariance: np.ndarray
    marks: int
    checked: bool

    @property
    def mm(self) -> float:
        return shift_mm(self.correction)

    @property
    def deg(self) -> float:
        return turn_deg(self.correction)


@dataclass
class MarksResult:
    """The joint fit. ``T_s1_w`` (4, 4) and ``covariance`` (6, 6) as :class:`solver.pose.PoseResult` (over the left
    perturbation (w rad, dt mm) in SF1 of the calibration); ``T_cf_w`` the part in the cell frame; ``T_s1_si``
    (k, 4, 4) the estimated camera poses; ``chi2`` with ``dof`` of the whole fit."""

    T_s1_w: np.ndarray
    T_cf_w: np.ndarray
    covariance: np.ndarray
    cameras: tuple[CameraCorrection, ...]
    T_s1_si: np.ndarray
    chi2: float
    dof: int
    iterations: int
    problem: MarksProblem = field(repr=False)
    # the whitened residual (r,) and Jacobian (r, p) at the solution; each testable block: (kind, index, rows)
    z: np.ndarray = field(repr=False)
    Jw: np.ndarray = field(repr=False)
    blocks: tuple[tuple[str, int, np.ndarray], ...] = field(repr=False)
    assessment: MarksAssessment | None = None  # set by solver.marks_check.solve_with_marks

    @property
    def sigma_rot_deg(self) -> float:
        return math.degrees(math.sqrt(max(0.0, float(np.trace(self.covariance[:3, :3])))))


def fit_marks(problem: MarksProblem, T_init: np.ndarray | None = None) -> MarksResult:
    """The maximum-likelihood part pose and camera corrections (no checks; :func:`solve_with_marks` checks),
    started from ``T_init`` (e.g. the holes' own fit) or the paper's initial value (Eq. 17-21).

    Raises :class:`NoConvergence`, :class:`PointBehindCamera` (at the initial value), :class:`DegenerateGeometry`.
    """
    if T_init is None:
        T_init, init_iterations = initial_iterated(problem.holes)
    else:
        init_iterations = 0
    model = _Model(problem)
    state = model.start(T_init)
    z, J = model.linearise(state)
    cost, lam, iterations = float(z @ z), 1e-3, 0
    while True:
        if iterations == MAX_ITERATIONS:
            raise NoConvergence(f"the fit with marks did not converge in {MAX_ITERATIONS} iterations")
        iterations += 1
        H, g = J.T @ J, J.T @ z
        step = np.linalg.solve(H + lam * np.diag(np.diag(H)), -g)
        if -float(g @ step) <= GAIN_LEFT * max(cost, 1.0):
            break  # the step would gain nothing the cost can show (not ten rejections to find that out)
        trial = model.moved(state, step)
        try:
            z_new, J_new = model.linearise(trial)
        except PointBehindCamera:
            lam *= 10.0
            continue
        cost_new = float(z_new @ z_new)
        if cost_new <= cost:
            state, z, J = trial, z_new, J_new
            small = np.linalg.norm(step[:3]) < STEP_RAD and np.linalg.norm(step[3:6]) < STEP_MM
            if small or cost - cost_new <= 1e-12 * cost:
                break
            cost, lam = cost_new, max(lam * 0.1, 1e-12)
        else:
            lam *= 10.0
            if lam > 1e8:
                break  # at the minimum to machine precision
    return model.result(state, z, J, iterations + init_iterations)


# --- the model ----------------------------------------------------------------------------------


@dataclass
class _State:
    R: np.ndarray  # part, R_s1_w
    t: np.ndarray
    T_s1_si: np.ndarray  # (k, 4, 4) estimated cameras
    dm: np.ndarray  # (M, 3) marks' true minus surveyed position, SF1


class _Model:
    """Residual rows: hole pixels, mark pixels, camera priors, mark surveys; unknowns: part 6 | 6 per view |
    3 per mark used. Marks seen only by views that do not check (fewer than MIN_MARKS_PER_VIEW) are left out."""

    def __init__(self, problem: MarksProblem) -> None:
        self.p = problem
        self.h = problem.holes
        self.k = len(self.h.T_s1_si)
        use = np.array([problem.checked[v] for v in problem.mark_view], dtype=bool)
        self.sight_view, self.sight_mark = problem.mark_view[use], problem.mark_index[use]
        self.sight_pixels = problem.mark_pixels[use]
        self.used_marks = sorted(set(self.sight_mark.tolist()))
        self.sight_slot = np.array([self.used_marks.index(m) for m in self.sight_mark], dtype=int)
        self.sight_cols = 6 + 6 * self.k + 3 * self.sight_slot
        self.n = 6 + 6 * self.k + 3 * len(self.used_marks)
        self.L = np.linalg.inv(problem.prior_factor())  # L^T L = S^-1
        self.mark_sigma = np.array([problem.marks[m].sigma_mm for m in self.used_marks])

    def start(self, T_s1_w: np.ndarray) -> _State:
        return _State(T_s1_w[:3, :3].copy(), T_s1_w[:3, 3].copy(), self.h.T_s1_si.copy(),
                      np.zeros((len(self.used_marks), 3)))

    def moved(self, s: _State, step: np.ndarray) -> _State:
        T = np.stack([s.T_s1_si[v] @ frames.pose_from_vector(step[6 + 6 * v : 12 + 6 * v]) for v in range(self.k)])
        dm = s.dm + step[6 + 6 * self.k :].reshape(-1, 3)
        return _State(frames.rotvec_to_matrix(step[:3]) @ s.R, s.t + step[3:6], T, dm)

    def corrections(self, s: _State) -> np.ndarray:
        return np.stack([frames.pose_to_vector(frames.invert(self.h.T_s1_si[v]) @ s.T_s1_si[v]) for v in range(self.k)])

    def linearise(self, s: _State) -> tuple[np.ndarray, np.ndarray]:
        """The whitened residual (r,) and its Jacobian (r, n) over the unknowns' steps."""
        h, p = self.h, self.p
        RP = h.P_obs @ s.R.T
        X_holes = RP + s.t
        X_marks = p.marks_s1[self.sight_mark] + s.dm[self.sight_slot]
        views = np.concatenate([h.view_index, self.sight_view])
        X = np.concatenate([X_holes, X_marks])
        R_v, t_v = s.T_s1_si[views, :3, :3], s.T_s1_si[views, :3, 3]
        Q = np.einsum("mji,mj->mi", R_v, X - t_v)  # R_v^T (X - t_v)
        if np.any(Q[:, 2] <= 1e-6):
            j = int(np.argmin(Q[:, 2]))
            what = (f"point {int(h.point_index[j])}" if j < len(X_holes)
                    else f"mark {p.marks[self.sight_mark[j - len(X_holes)]].name}")
            raise PointBehindCamera(f"{what} lies behind the camera of view {p.view_names[views[j]]} at this pose")
        uv, Jp = h.camera.project_with_jacobian(Q)
        m_h, m = len(X_holes), len(Q)
        sigma = np.concatenate([np.full(m_h, h.sigma_px), np.full(m - m_h, p.mark_sigma_px)])
        observed = np.concatenate([h.pixels, self.sight_pixels])
        Jps = Jp / sigma[:, None, None]
        JpR = np.einsum("mij,mkj->mik", Jps, R_v)  # d(uv)/dX = Jp R_v^T
        n_prior = 6 * self.k + 3 * len(self.used_marks)
        z = np.concatenate([((uv - observed) / sigma[:, None]).ravel(), np.zeros(n_prior)])
        J = np.zeros((2 * m + n_prior, self.n))
        rows = (2 * np.arange(m)[:, None] + np.arange(2)).ravel()  # (2m,) row of (observation, u|v)
        holes = rows[: 2 * m_h]
        J[holes, :3] = frames.cross_rows(RP, JpR[:m_h]).reshape(-1, 3)  # dX/dw = -[RP]x (left, in SF1)
        J[holes, 3:6] = JpR[:m_h].reshape(-1, 3)
        # dQ/de = [[Q]x, -I] for a right perturbation of the camera: a row a of Jp gives a x Q and -a
        cam = (6 + 6 * np.repeat(views, 2))[:, None] + np.arange(6)
        J[rows[:, None], cam] = np.concatenate([np.cross(Jps, Q[:, None, :]), -Jps], axis=2).reshape(-1, 6)
        marks = rows[2 * m_h :]
        mark_cols = np.repeat(self.sight_cols, 2)[:, None] + np.arange(3)
        J[marks[:, None], mark_cols] = JpR[m_h:].reshape(-1, 3)
        e = self.corrections(s)
        prior = 2 * m + np.arange(6 * self.k)
        z[prior] = (e @ self.L.T).ravel()
        for v in range(self.k):
            J[prior[6 * v : 6 * v + 6], 6 + 6 * v : 12 + 6 * v] = self.L  # exact at e = 0, off by O(|e|) beyond
        survey = 2 * m + 6 * self.k + np.arange(3 * len(self.used_marks))
        z[survey] = (s.dm / self.mark_sigma[:, None]).ravel()
        J[survey, 6 + 6 * self.k + np.arange(3 * len(self.used_marks))] = np.repeat(1.0 / self.mark_sigma, 3)
        return z, J

    def result(self, s: _State, z: np.ndarray, J: np.ndarray, iterations: int) -> MarksResult:
        scale = 1.0 / np.maximum(np.linalg.norm(J, axis=0), 1e-300)
        Js = J * scale
        singular = np.linalg.svd(Js, compute_uv=False)
        if singular[-1] <= 1e-10 * singular[0]:
            raise DegenerateGeometry(f"the fit with marks leaves a direction unobservable (singular values "
                                     f"{singular[-1]:.3g} vs {singular[0]:.3g})")
        cov = np.linalg.inv(Js.T @ Js) * np.outer(scale, scale)
        e = self.corrections(s)
        m = self.h.n_observations + len(self.sight_view)
        cameras, blocks = [], []
        prior_row = 2 * m
        for v in range(self.k):
            c = slice(6 + 6 * v, 12 + 6 * v)
            seen = len(set(self.p.mark_index[self.p.mark_view == v].tolist()))
            cameras.append(CameraCorrection(self.p.view_names[v], e[v], cov[c, c], seen, self.p.checked[v]))
            if self.p.checked[v]:
                blocks.append(("view", v, np.arange(prior_row + 6 * v, prior_row + 6 * v + 6)))
        checked = [v for v in range(self.k) if self.p.checked[v]]
        if len(checked) >= 2:  # a move common to the cameras (the bracket) adds up over the views
            blocks.append(("cameras", -1, np.concatenate([np.arange(prior_row + 6 * v, prior_row + 6 * v + 6)
                                                          for v in checked])))
        mark_row = prior_row + 6 * self.k
        for j, mk in enumerate(self.used_marks):
            blocks.append(("mark", mk, np.arange(mark_row + 3 * j, mark_row + 3 * j + 3)))
        for j in range(self.h.n_observations):
            blocks.append(("hole", j, np.arange(2 * j, 2 * j + 2)))
        T_s1_w = frames.make_T(s.R, s.t)
        return MarksResult(T_s1_w, self.p.T_cf_s1 @ T_s1_w, cov[:6, :6], tuple(cameras), s.T_s1_si, float(z @ z),
                           2 * m - 6, iterations, self.p, z, J, tuple(blocks))
