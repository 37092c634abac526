"""Uncertainty of the part pose (Sec. 4, Eq. 23-31).

The general law is the paper's Eq. 29, ``Q_X = H Q_P H^T`` with ``H = (dPhi/dX)^-1 dPhi/dP``, where
``Phi = dE/dX = 0`` at the optimum. Here ``Q_P`` is the covariance of the observed pixels: the centre
noise ``sigma_px`` on the diagonal (Eq. 30), plus what the robot's pose repeatability does to the pixels
of one view (a whole view moves together, so its pixels are correlated). For the maximum-likelihood
estimator H is ``(J^T Q_P^-1 J)^-1 J^T Q_P^-1`` and Q_X reduces to the Cramer-Rao bound
``(J^T Q_P^-1 J)^-1``.
"""

from __future__ import annotations

import math

import numpy as np

from monoguide.solver import frames
from monoguide.solver.collinearity import object_space_jacobian, orthogonality_jacobian
from monoguide.solver.errors import DegenerateGeometry
from monoguide.solver.problem import PoseProblem, reprojection

# Relative conditioning below which a direction of the pose is taken as unobservable.
DEGENERATE_RCOND = 1e-9


def observation_covariance(problem: PoseProblem, Q: np.ndarray) -> np.ndarray:
    """Covariance Q_P (2m, 2m) of the observed pixels, px^2, given the points in their cameras Q (m, 3).

    A measuring pose that is off its calibration by a small rigid motion ``e = (w, d)`` of the camera
    (its covariance :func:`view_motion_covariance`) moves a point in that camera by ``dQ = [Q]x w - d``.
    """
    m = len(Q)
    C = np.eye(2 * m) * problem.sigma_px**2
    if problem.view_sigma_mm == 0.0 and problem.view_sigma_deg == 0.0:
        return C
    _, Jp = problem.camera.project_with_jacobian(Q)
    dQ = np.zeros((m, 3, 6))
    dQ[:, :, :3] = -np.cross(Q[:, None, :], np.eye(3)[None])  # [Q]x: columns Q x e_k -> -(e_k x Q)
    dQ[:, :, 3:] = -np.eye(3)
    G = Jp @ dQ  # (m, 2, 6) pixels per camera motion
    G = G @ view_motion_factor(problem)  # (m, 2, 6): pixels per unit of the motion's independent parts
    for view in np.unique(problem.view_index):
        rows = np.flatnonzero(problem.view_index == view)
        idx = (2 * rows[:, None] + np.arange(2)).ravel()
        Gv = G[rows].reshape(-1, 6)
        C[np.ix_(idx, idx)] += Gv @ Gv.T
    return C


def view_motion_factor(problem: PoseProblem) -> np.ndarray:
    """F (6, 6) with ``F F^T`` the covariance of a view's camera motion ``e = (w rad, d mm)`` (a right
    perturbation of the camera pose, in the camera's axes).

    Without ``problem.T_f_c``: ``diag(sigma)``, ``w`` and ``d`` independent per axis with ``view_sigma_deg`` /
    ``view_sigma_mm`` (rotation about the camera's centre). With it, the robot stops at ``T_b_f N`` with N
    of those sigmas per axis in the flange's axes; the camera stands at ``T_b_f N T_f_c``, i.e. it moves by
    ``T_c_f N T_f_c``, so ``e = Ad(T_c_f) n``: ``w = R n_w``, ``d = R n_d + p x (R n_w)`` with
    ``(R, p) = T_c_f``, and F = ``Ad(T_c_f) diag(sigma)``.
    """
    F = np.diag([math.radians(problem.view_sigma_deg)] * 3 + [problem.view_sigma_mm] * 3)
    if problem.T_f_c is None:
        return F
    return adjoint(frames.invert(problem.T_f_c)) @ F


def view_motion_covariance(problem: PoseProblem) -> np.ndarray:
    """Covariance (6, 6) of a view's camera motion ``e = (w rad, d mm)``: see :func:`view_motion_factor`."""
    F = view_motion_factor(problem)
    return F @ F.T


def adjoint(T: np.ndarray) -> np.ndarray:
    """Adjoint (6, 6) of ``T = (R, p)`` over twists ``(w, d)``: ``T exp(n) T^-1 = exp(Ad(T) n)``."""
    R, p = T[:3, :3], T[:3, 3]
    A = np.zeros((6, 6))
    A[:3, :3] = R
    A[3:, 3:] = R
    A[3:, :3] = frames.skew(p) @ R
    return A


def whitening(problem: PoseProblem, Q: np.ndarray, J: np.ndarray | None = None) -> np.ndarray:
    """Matrix L (2m, 2m) with ``L^T L = Q_P^-1``: whitened residuals ``L r`` have unit covariance."""
    if problem.view_sigma_mm == 0.0 and problem.view_sigma_deg == 0.0:
        return np.eye(2 * len(Q)) / problem.sigma_px
    C = observation_covariance(problem, Q)
    return np.linalg.inv(np.linalg.cholesky(C))


def covariance_from_whitened_jacobian(Jw: np.ndarray, problem: PoseProblem) -> np.ndarray:
    """``(Jw^T Jw)^-1`` (6, 6), refusing geometry that leaves a direction of the pose unobservable.

    Jw : (2m, 6) Jacobian of the whitened residuals over (w rad, dt mm).
    """
    # Scale the rotation columns by the size of the point cloud so that both blocks are comparable.
    spread = problem.P_obs - problem.P_obs.mean(axis=0)
    extent = max(float(np.sqrt(np.mean(np.sum(spread**2, axis=1)))), 1.0)
    scale = np.array([1.0 / extent] * 3 + [1.0] * 3)
    Js = Jw * scale
    singular = np.linalg.svd(Js, compute_uv=False)
    if singular[-1] <= DEGENERATE_RCOND * singular[0]:
        raise DegenerateGeometry(
            "the observations do not constrain all six degrees of freedom "
            f"(singular values {singular[-1]:.3g} vs {singular[0]:.3g}): e.g. all lines of sight through "
            "one point or all points on one line"
        )
    return np.linalg.inv(Js.T @ Js) * np.outer(scale, scale)


def predicted_covariance(problem: PoseProblem, T_s1_w: np.ndarray) -> np.ndarray:
    """Cramer-Rao bound (6, 6) of ``T_s1_w`` for this geometry and noise (the pixels are not used)."""
    _, J, Q = reprojection(problem, T_s1_w[:3, :3], T_s1_w[:3, 3])
    L = whitening(problem, Q)
    return covariance_from_whitened_jacobian(L @ J.reshape(-1, 6), problem)


def paper_covariance(problem: PoseProblem, X: np.ndarray, penalty: float) -> np.ndarray:
    """Eq. 29 for the paper's estimator: Q_X = H Q_P H^T over X = the 12 entries of T_s1_w (Eq. 24),
    mapped to the 6 x 6 covariance over (w rad, dt mm).

    Gauss-Newton forms of the derivatives of Phi = dE/dX (Eq. 26), exact at zero residual:
    dPhi/dX = 2 (J_F^T J_F + M J_f^T J_f), dPhi/dP = 2 J_F^T dF/dP.
    """
    J_F = object_space_jacobian(problem, X)
    J_f = orthogonality_jacobian(X)
    dPhi_dX = 2.0 * (J_F.T @ J_F + penalty * (J_f.T @ J_f))
    dPhi_dP = 2.0 * J_F.T @ _object_residual_pixel_jacobian(problem, X)
    H = np.linalg.solve(dPhi_dX, dPhi_dP)
    T = frames.make_T(frames.orthonormalize(X.reshape(3, 4)[:, :3]), X.reshape(3, 4)[:, 3])
    Q_P = observation_covariance(problem, problem.points_in_views(T))
    Q_X = H @ Q_P @ H.T
    G = _twelve_to_six(X.reshape(3, 4)[:, :3])
    return G @ Q_X @ G.T


def _object_residual_pixel_jacobian(problem: PoseProblem, X: np.ndarray) -> np.ndarray:
    """dF/dP (3m, 2m): how the object-space residuals move with the observed pixels (through U_j)."""
    m = problem.n_observations
    Xm = X.reshape(3, 4)
    Q = np.einsum("mij,mj->mi", problem.R_obs, problem.P_obs @ Xm[:, :3].T + Xm[:, 3]) + problem.t_obs
    rays = problem.rays
    xy = problem.camera.undistort_pixels(problem.pixels)
    v = np.concatenate([xy, np.ones((m, 1))], axis=1)
    norm_v = np.linalg.norm(v, axis=1)
    # pixels -> normalised: inverse of d(uv)/d(xy) = diag(fx, fy) Jd(xy)
    cam = problem.camera
    Jd = cam.distort_jacobian(xy) * np.array([cam.fx, cam.fy])[None, :, None]
    dxy_duv = np.linalg.inv(Jd)
    eye = np.eye(3)[None]
    dm_dv = (eye - rays[:, :, None] * rays[:, None, :]) / norm_v[:, None, None]
    dm_duv = dm_dv[:, :, :2] @ dxy_duv  # (m, 3, 2)
    mQ = np.sum(rays * Q, axis=1)
    dF_dm = -(rays[:, :, None] * Q[:, None, :] + mQ[:, None, None] * eye)  # F = Q - m (m.Q)
    blocks = dF_dm @ dm_duv  # (m, 3, 2)
    out = np.zeros((3 * m, 2 * m))
    for j in range(m):
        out[3 * j : 3 * j + 3, 2 * j : 2 * j + 2] = blocks[j]
    return out


def _twelve_to_six(R: np.ndarray) -> np.ndarray:
    """Linear map (6, 12) from a perturbation of (R row-major | t) entries to (w, dt) on the left:
    ``dR R^T`` skew part gives w."""
    G = np.zeros((6, 12))
    for a in range(3):
        for b in range(3):
            E = np.zeros((3, 3))
            E[a, b] = 1.0
            S = E @ R.T
            w = 0.5 * np.array([S[2, 1] - S[1, 2], S[0, 2] - S[2, 0], S[1, 0] - S[0, 1]])
            G[:3, 4 * a + b] = w
        G[3 + a, 4 * a + 3] = 1.0
    return G
