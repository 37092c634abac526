"""The paper's object-space collinearity model (Eq. 13-16, 20), shared by the estimator and Eq. 29.

``F_j = (I - U_j) M_j``: the part of the point M_j (in camera j) orthogonal to the line of sight of its
image point, with ``U_j = m_j m_j^T`` for the unit ray ``m_j`` (Eq. 13-14). X is the 12 entries of
``T_s1_w``'s upper 3 x 4 block, row-major (Eq. 24).
"""

from __future__ import annotations

import numpy as np

from monoguide.solver import frames
from monoguide.solver.problem import PoseProblem


def linearised_system(problem: PoseProblem, T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eq. 20 about ``T``: rows (I - U_j) R_j R [-[P]x | I] and right side -(I - U_j) M_j."""
    R = T[:3, :3]
    Q = problem.points_in_views(T)
    rays = problem.rays
    # (I - U) y = y - m (m . y) for unit rays m
    A_cam = np.einsum("mij,jk->mik", problem.R_obs, R)  # (m, 3, 3): d(point in camera)/d(P + dP)
    P = problem.P_obs
    # d(P + w x P + d)/d(w, d) = [-[P]x | I]: columns of A_cam @ -[P]x are cross(P, rows...) -> build
    A = np.empty((len(P), 3, 6))
    A[:, :, :3] = frames.cross_rows(P, A_cam)  # row-wise: a @ (-[P]x) = P x a
    A[:, :, 3:] = A_cam
    A -= rays[:, :, None] * np.einsum("mi,mij->mj", rays, A)[:, None, :]
    b = -(Q - rays * np.sum(rays * Q, axis=1, keepdims=True))
    return A.reshape(-1, 6), b.ravel()


def object_space_residuals(problem: PoseProblem, X: np.ndarray) -> np.ndarray:
    """F_j = (I - U_j) M_j (Eq. 14), three components per observation, mm."""
    X = X.reshape(3, 4)
    M = problem.P_obs @ X[:, :3].T + X[:, 3]
    Q = np.einsum("mij,mj->mi", problem.R_obs, M) + problem.t_obs
    rays = problem.rays
    return (Q - rays * np.sum(rays * Q, axis=1, keepdims=True)).ravel()


def object_space_jacobian(problem: PoseProblem, X: np.ndarray) -> np.ndarray:
    """d F / d X, (3m, 12): F is linear in X."""
    m = problem.n_observations
    rays = problem.rays
    proj = np.eye(3)[None] - rays[:, :, None] * rays[:, None, :]  # I - U_j
    G = proj @ problem.R_obs  # (m, 3, 3): dF/dM
    Ph = np.concatenate([problem.P_obs, np.ones((m, 1))], axis=1)  # (m, 4)
    # M_a = sum_b X[a, b] Ph[b]  ->  dF_i/dX[a, b] = G[i, a] Ph[b]
    return np.einsum("mia,mb->miab", G, Ph).reshape(3 * m, 12)


def orthogonality(X: np.ndarray) -> np.ndarray:
    """f_1..f_6 of Eq. 15 on the columns of the rotation part."""
    R = X.reshape(3, 4)[:, :3]
    c = R.T @ R
    return np.array([c[0, 0] - 1.0, c[1, 1] - 1.0, c[2, 2] - 1.0, c[0, 1], c[1, 2], c[2, 0]])


def orthogonality_jacobian(X: np.ndarray) -> np.ndarray:
    R = X.reshape(3, 4)[:, :3]
    J = np.zeros((6, 3, 4))
    pairs = [(0, 0), (1, 1), (2, 2), (0, 1), (1, 2), (2, 0)]
    for row, (i, j) in enumerate(pairs):
        # c_ij = sum_a R[a, i] R[a, j]
        J[row, :, i] += R[:, j]
        J[row, :, j] += R[:, i]
    return J.reshape(6, 12)
