"""Averaging of rigid poses: the geodesic (Karcher) mean of the rotations and the mean of the translations,
with each pose's deviation from the mean."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from monoguide.solver.frames import make_T, matrix_to_rotvec, orthonormalize, rotvec_to_matrix

_KARCHER_ITER = 20


def mean_rotation(R: Sequence[np.ndarray]) -> np.ndarray:
    """Geodesic L2 (Karcher) mean of rotations (n, 3, 3): start at the chordal mean (the SVD projection of
    the arithmetic mean), then Gauss-Newton steps on the mean of the logarithms until they vanish."""
    R = np.asarray(R, dtype=float).reshape(-1, 3, 3)
    M = orthonormalize(R.mean(axis=0))
    for _ in range(_KARCHER_ITER):
        step = np.mean([matrix_to_rotvec(M.T @ Ri) for Ri in R], axis=0)
        M = M @ rotvec_to_matrix(step)
        if float(np.linalg.norm(step)) < 1e-15:
            break
    return M


@dataclass(frozen=True)
class PoseMean:
    """Mean pose ``T`` (4, 4) of ``n`` samples; per sample its rotation (deg) and translation (mm) off the mean
    (rotation measured in the pose's own frame: ``R_mean^T R_i``)."""

    T: np.ndarray
    dev_deg: np.ndarray
    dev_mm: np.ndarray

    @property
    def n(self) -> int:
        return len(self.dev_mm)

    @property
    def spread_mm(self) -> float:
        """RMS translation deviation of a sample from the mean."""
        return float(np.sqrt(np.mean(self.dev_mm**2)))

    @property
    def spread_deg(self) -> float:
        return float(np.sqrt(np.mean(self.dev_deg**2)))

    @property
    def sigma_mean_mm(self) -> float:
        """Standard error of the mean's position (RMS 3-D deviation / sqrt(n - 1))."""
        return self.spread_mm / math.sqrt(max(self.n - 1, 1))

    @property
    def sigma_mean_deg(self) -> float:
        return self.spread_deg / math.sqrt(max(self.n - 1, 1))


def mean_pose(T: Sequence[np.ndarray]) -> PoseMean:
    """Mean of rigid poses (n, 4, 4): Karcher mean rotation, arithmetic mean translation."""
    T = np.asarray(T, dtype=float).reshape(-1, 4, 4)
    R = mean_rotation(T[:, :3, :3])
    t = T[:, :3, 3].mean(axis=0)
    dev_deg = np.array([math.degrees(float(np.linalg.norm(matrix_to_rotvec(R.T @ Ti[:3, :3])))) for Ti in T])
    dev_mm = np.linalg.norm(T[:, :3, 3] - t, axis=1)
    return PoseMean(make_T(R, t), dev_deg, dev_mm)
