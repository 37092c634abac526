"""Robot base frame BF in the cell frame (step 3, paper Sec. 2.2).

The robot carries an SMR on a flange tool to N poses; it reports each flange pose ``T_b_f_i``, the tracker
measures the SMR in CF, ``p_i``. The model is

    p_i = R_cb (R_bf_i s_f + t_bf_i) + t_cb

with the unknown base ``T_cf_b = (R_cb, t_cb)`` and the unknown SMR offset on the flange ``s_f``. Linear
start: with ``R_cb`` fixed the model is linear in (``t_cb``, ``s_f``), with ``s_f`` fixed ``R_cb`` is a Kabsch
fit; a few alternations from ``s_f = 0`` reach the basin. Then a nonlinear least-squares refinement of all
nine parameters (scipy ``least_squares``). Residuals per pose are the distances of the measured SMR from the
fitted one.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from monoguide.solver.calibration.errors import (
    CalibrationDegenerate,
    CalibrationResidualTooLarge,
    CalibrationTooFewViews,
)
from monoguide.solver.calibration.rigid import fit_rigid
from monoguide.solver.frames import make_T, pose_from_vector, pose_to_vector, transform_points

MIN_POSES = 6
MIN_ROTATION_SPREAD_DEG = 10.0  # the flange must turn at least this much about two axes, or s_f is unobservable
DEFAULT_MAX_RESIDUAL_MM = 0.15
_ALTERNATIONS = 30


@dataclass(frozen=True)
class BaseFit:
    """``T_cf_b`` (4, 4), the SMR's offset ``smr_f`` (3,) mm on the flange, residual per pose (mm) and the
    fit's 1-sigma uncertainty of the base (``sigma_mm`` translation, ``sigma_deg`` rotation) from the residuals."""

    T_cf_b: np.ndarray
    smr_f: np.ndarray
    residuals_mm: np.ndarray
    sigma_mm: float
    sigma_deg: float

    @property
    def rms_mm(self) -> float:
        return float(np.sqrt(np.mean(self.residuals_mm**2)))

    def as_dict(self) -> dict[str, object]:
        return {"T_cf_b": self.T_cf_b.tolist(), "smr_f": self.smr_f.tolist(), "rms_mm": self.rms_mm,
                "residuals_mm": self.residuals_mm.tolist(), "sigma_mm": self.sigma_mm, "sigma_deg": self.sigma_deg}


def _smr_in_base(T_b_f: np.ndarray, smr_f: np.ndarray) -> np.ndarray:
    return np.einsum("nij,j->ni", T_b_f[:, :3, :3], smr_f) + T_b_f[:, :3, 3]


def _check_poses(T_b_f: np.ndarray) -> None:
    n = len(T_b_f)
    if n < MIN_POSES:
        raise CalibrationTooFewViews(f"robot base: {n} pose(s); the base and the SMR offset need at least "
                                     f"{MIN_POSES} (12-20 well spread recommended)")
    # the SMR offset is seen only through the flange's rotations: their spread about the mean rotation
    R = T_b_f[:, :3, :3]
    U, _, Vt = np.linalg.svd(R.sum(axis=0))
    R_mean = U @ np.diag([1.0, 1.0, float(np.sign(np.linalg.det(U @ Vt)))]) @ Vt
    dev = np.array([R_mean.T @ Ri for Ri in R])
    vecs = np.array([[Ri[2, 1] - Ri[1, 2], Ri[0, 2] - Ri[2, 0], Ri[1, 0] - Ri[0, 1]] for Ri in dev]) / 2.0
    s = np.linalg.svd(vecs - vecs.mean(axis=0), compute_uv=False) / math.sqrt(n)
    if math.degrees(math.asin(min(1.0, float(s[1])))) < MIN_ROTATION_SPREAD_DEG / 4.0:
        raise CalibrationDegenerate(
            f"robot base: the {n} flange orientations turn about fewer than two axes (spread "
            f"{', '.join(f'{math.degrees(math.asin(min(1.0, float(v)))):.2f}' for v in s)} deg RMS); "
            f"the SMR offset on the flange is not determined: tilt the flange by ≥ {MIN_ROTATION_SPREAD_DEG:g} deg "
            "about different axes")
    positions = T_b_f[:, :3, 3]
    spread = np.linalg.svd(positions - positions.mean(axis=0), compute_uv=False) / math.sqrt(n)
    if spread[1] < 20.0:
        raise CalibrationDegenerate(f"robot base: the flange positions lie (nearly) on one line (spread "
                                    f"{spread[1]:.1f} mm RMS off it): spread them over the work space")


def fit_robot_base(T_b_f: Sequence[np.ndarray], smr_cf: np.ndarray, *,
                   max_residual_mm: float | None = DEFAULT_MAX_RESIDUAL_MM) -> BaseFit:
    """Fit ``T_cf_b`` and the SMR offset on the flange from flange poses ``T_b_f`` (n, 4, 4) mm and the tracker's
    SMR readings in CF ``smr_cf`` (n, 3) mm. Refuses fewer than :data:`MIN_POSES` poses, poses without
    rotation about two axes or on one line, and (with ``max_residual_mm``) a pose whose residual exceeds it."""
    T_b_f = np.asarray(T_b_f, dtype=float).reshape(-1, 4, 4)
    p = np.asarray(smr_cf, dtype=float).reshape(-1, 3)
    if len(p) != len(T_b_f):
        raise ValueError(f"robot base: {len(T_b_f)} flange poses but {len(p)} SMR readings")
    _check_poses(T_b_f)
    n = len(p)
    # --- linear start: alternate (t_cb, s_f | R_cb) linear and (R_cb | s_f) Kabsch
    smr_f = np.zeros(3)
    R_cb, t_cb = np.eye(3), np.zeros(3)
    for _ in range(_ALTERNATIONS):
        fit = fit_rigid(_smr_in_base(T_b_f, smr_f), p, min_spread_mm=1.0, what="robot base (start)")
        R_cb, t_cb = fit.T[:3, :3], fit.T[:3, 3]
        A = np.zeros((3 * n, 6))
        b = np.zeros(3 * n)
        for i in range(n):
            A[3 * i:3 * i + 3, :3] = np.eye(3)
            A[3 * i:3 * i + 3, 3:] = R_cb @ T_b_f[i, :3, :3]
            b[3 * i:3 * i + 3] = p[i] - R_cb @ T_b_f[i, :3, 3]
        x, *_ = np.linalg.lstsq(A, b, rcond=None)
        t_cb, smr_new = x[:3], x[3:]
        if np.linalg.norm(smr_new - smr_f) < 1e-6:
            smr_f = smr_new
            break
        smr_f = smr_new

    # --- nonlinear refinement of (rotation vector, t_cb, s_f)
    def residuals(v: np.ndarray) -> np.ndarray:
        return (transform_points(pose_from_vector(v[:6]), _smr_in_base(T_b_f, v[6:])) - p).ravel()

    v0 = np.concatenate([pose_to_vector(make_T(R_cb, t_cb)), smr_f])
    sol = least_squares(residuals, v0, method="lm", xtol=1e-12, ftol=1e-12)
    T_cf_b = pose_from_vector(sol.x[:6])
    smr_f = sol.x[6:]
    res = np.linalg.norm(sol.fun.reshape(-1, 3), axis=1)
    # 1-sigma of the base from the residual's per-axis sigma; the covariance in the base's own frame
    # (left perturbation at the origin of BF: translation of the base origin, rotation of its axes)
    dof = max(3 * n - 9, 1)
    s2 = float(sol.fun @ sol.fun) / dof
    J = sol.jac
    try:
        cov = s2 * np.linalg.inv(J.T @ J)
    except np.linalg.LinAlgError as exc:
        raise CalibrationDegenerate("robot base: the fit's normal matrix is singular; spread the poses") from exc
    sigma_deg = math.degrees(math.sqrt(max(float(np.trace(cov[:3, :3])), 0.0)))
    sigma_mm = math.sqrt(max(float(np.trace(cov[3:6, 3:6])), 0.0))
    out = BaseFit(T_cf_b, smr_f, res, sigma_mm, sigma_deg)
    if max_residual_mm is not None and float(res.max()) > max_residual_mm:
        worst = int(np.argmax(res))
        raise CalibrationResidualTooLarge(
            f"robot base: pose {worst + 1} of {n} is {res[worst]:.3f} mm off the fit (tolerance "
            f"{max_residual_mm:g} mm; RMS {out.rms_mm:.3f} mm): was the SMR moved in its nest, or the pose misread?")
    return out
