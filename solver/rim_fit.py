"""Photometric refinement of a hole's ellipse: the grey levels of the rim fitted directly.

Sec. 5.3 ends with a least-squares ellipse through gradient centres of gravity, one point per edge
pixel. That estimator uses each grey level once, weighted by its gradient, and leaves noise on the
table. This step starts from that ellipse and fits a model of the blurred rim to every pixel within a
few blur widths of it, by Gauss-Newton (Levenberg-Marquardt damped), which is the maximum-likelihood
estimate under sensor noise and comes close to the Cramér-Rao bound (see benchmarks/bench_holes.py):

    I(p) = (1 + g . (p - p0)) * (h + (s - h) * Phi(d(p) / sigma))

``d(p)`` the distance of pixel ``p`` from the ellipse along the ray from its centre, ``Phi`` the normal
CDF (a Gaussian-blurred step), ``h`` and ``s`` the hole and sheet grey levels, ``g`` (2,) the relative
slope of the light across the hole (uneven lighting multiplies both levels). The ellipse is
``(p - c)^T M (p - c) = 1``: centre ``c`` and a symmetric ``M``, well conditioned for circles.
Saturated pixels do not vote; pixels that do not fit (a neighbouring hole, dirt) are dropped after a
first solve.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.special import ndtr

from monoguide.solver.ellipse import Ellipse

_MAX_ITER = 20
_STEP_TOL_PX = 1e-5
_OUTLIER_SIGMAS = 4.0
_INV_SQRT_2PI = 1.0 / math.sqrt(2.0 * math.pi)


def refine_ellipse_photometric(
    grey: np.ndarray, start: Ellipse, blur_sigma_px: float, saturation_grey: float = 254.5
) -> tuple[Ellipse, float]:
    """The ellipse (and the fitted blur sigma, px) that best explains the grey levels near the rim.

    ``grey`` (h, w) float32; ``start`` the Sec. 5.3 ellipse; ``blur_sigma_px`` a first guess of the rim's
    Gaussian width. Returns ``start`` unchanged (and the guess) when the fit does not converge or moves
    the centre implausibly far (more than a quarter of the blur width plus 0.25 px).
    """
    sigma0 = max(float(blur_sigma_px), 0.5)
    uv, values = _annulus(grey, start, 3.5 * sigma0 + 2.0, saturation_grey)
    if len(values) < 50:
        return start, sigma0
    theta = _initial_parameters(start, sigma0, uv, values)
    p0 = start.center.copy()
    keep = np.ones(len(values), dtype=bool)
    for rounds in range(2):
        theta, ok = _gauss_newton(theta, uv[keep], values[keep], p0)
        if not ok:
            return start, sigma0
        if rounds == 0:
            residual = _model(theta, uv, p0)[0] - values
            scale = 1.4826 * float(np.median(np.abs(residual[keep])))
            outliers = np.abs(residual) > _OUTLIER_SIGMAS * max(scale, 0.5)
            if not outliers.any():
                break
            keep = ~outliers
    fitted = _ellipse_from(theta)
    sigma = abs(float(theta[5]))
    if fitted is None or np.hypot(*(fitted.center - start.center)) > 0.25 + 0.25 * sigma0:
        return start, sigma0
    return fitted, sigma


# --- private helpers -----------------------------------------------------------------------------


def _annulus(
    grey: np.ndarray, ellipse: Ellipse, half_width: float, saturation_grey: float
) -> tuple[np.ndarray, np.ndarray]:
    """Pixel centres (n, 2) within ``half_width`` px of the rim and their grey levels (n,), unsaturated."""
    h, w = grey.shape
    reach = float(ellipse.axes[0]) + half_width + 1.0
    x0, y0 = max(int(ellipse.center[0] - reach), 0), max(int(ellipse.center[1] - reach), 0)
    x1, y1 = min(int(ellipse.center[0] + reach) + 2, w), min(int(ellipse.center[1] + reach) + 2, h)
    vv, uu = np.mgrid[y0:y1, x0:x1]
    uv = np.stack([uu.ravel(), vv.ravel()], axis=1).astype(float)
    patch = grey[y0:y1, x0:x1].ravel().astype(float)
    near = (np.abs(_radial_distance(uv, ellipse)) < half_width) & (patch < saturation_grey)
    return uv[near], patch[near]


def _radial_distance(uv: np.ndarray, ellipse: Ellipse) -> np.ndarray:
    th = math.radians(ellipse.angle_deg)
    R = np.array([[math.cos(th), -math.sin(th)], [math.sin(th), math.cos(th)]])
    q = (uv - ellipse.center) @ R
    rho = np.hypot(q[:, 0] / ellipse.axes[0], q[:, 1] / ellipse.axes[1])
    return np.hypot(q[:, 0], q[:, 1]) * (1.0 - 1.0 / np.maximum(rho, 1e-9))


def _initial_parameters(start: Ellipse, sigma: float, uv: np.ndarray, values: np.ndarray) -> np.ndarray:
    """theta = (cx, cy, m11, m12, m22, sigma, h, s, gx, gy)."""
    th = math.radians(start.angle_deg)
    R = np.array([[math.cos(th), -math.sin(th)], [math.sin(th), math.cos(th)]])
    M = R @ np.diag([1.0 / start.axes[0] ** 2, 1.0 / start.axes[1] ** 2]) @ R.T
    d = _radial_distance(uv, start)
    inner = values[d < -sigma]
    outer = values[d > sigma]
    h = float(np.median(inner)) if len(inner) else float(values.min())
    s = float(np.median(outer)) if len(outer) else float(values.max())
    return np.array([start.center[0], start.center[1], M[0, 0], M[0, 1], M[1, 1], sigma, h, s, 0.0, 0.0])


def _model(theta: np.ndarray, uv: np.ndarray, p0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Model grey levels (n,) and their Jacobian (n, 10) w.r.t. theta."""
    cx, cy, m11, m12, m22, sigma, h, s, gx, gy = theta
    qx, qy = uv[:, 0] - cx, uv[:, 1] - cy
    rho = np.sqrt(np.maximum(m11 * qx * qx + 2.0 * m12 * qx * qy + m22 * qy * qy, 1e-18))
    qn = np.maximum(np.hypot(qx, qy), 1e-9)
    d = qn * (1.0 - 1.0 / rho)
    u = d / sigma
    phi_cdf = ndtr(u)
    phi_pdf = np.exp(-0.5 * u * u) * _INV_SQRT_2PI
    dx, dy = uv[:, 0] - p0[0], uv[:, 1] - p0[1]
    light = 1.0 + gx * dx + gy * dy
    base = h + (s - h) * phi_cdf
    model = light * base
    dmodel_dd = light * (s - h) * phi_pdf / sigma
    # d = |q| (1 - 1/rho):  dd/dq = q/|q| (1 - 1/rho) + |q| M q / rho^3
    mqx, mqy = m11 * qx + m12 * qy, m12 * qx + m22 * qy
    k = qn / rho**3
    dd_dqx = qx / qn * (1.0 - 1.0 / rho) + k * mqx
    dd_dqy = qy / qn * (1.0 - 1.0 / rho) + k * mqy
    dd_drho = qn / rho**2
    J = np.empty((len(uv), 10))
    J[:, 0] = -dmodel_dd * dd_dqx
    J[:, 1] = -dmodel_dd * dd_dqy
    J[:, 2] = dmodel_dd * dd_drho * qx * qx / (2.0 * rho)
    J[:, 3] = dmodel_dd * dd_drho * qx * qy / rho
    J[:, 4] = dmodel_dd * dd_drho * qy * qy / (2.0 * rho)
    J[:, 5] = -dmodel_dd * u
    J[:, 6] = light * (1.0 - phi_cdf)
    J[:, 7] = light * phi_cdf
    J[:, 8] = dx * base
    J[:, 9] = dy * base
    return model, J


def _gauss_newton(theta: np.ndarray, uv: np.ndarray, values: np.ndarray, p0: np.ndarray) -> tuple[np.ndarray, bool]:
    """Levenberg-Marquardt on the sum of squared grey-level residuals; (theta, converged)."""
    lam = 1e-3
    model, J = _model(theta, uv, p0)
    cost = float(np.sum((model - values) ** 2))
    for _ in range(_MAX_ITER):
        r = model - values
        # columns differ by orders of magnitude (M ~ 1/r^2, gradients ~ 1/r): scale them for the solve
        col = np.maximum(np.linalg.norm(J, axis=0), 1e-12)
        Js = J / col
        A = Js.T @ Js
        b = Js.T @ r
        while True:
            try:
                step = -np.linalg.solve(A + lam * np.diag(np.diag(A)), b) / col
            except np.linalg.LinAlgError:
                return theta, False
            trial = theta + step
            new_model, new_J = _model(trial, uv, p0)
            new_cost = float(np.sum((new_model - values) ** 2))
            if new_cost <= cost:
                theta, model, J, cost = trial, new_model, new_J, new_cost
                lam = max(lam / 10.0, 1e-9)
                break
            lam *= 10.0
            if lam > 1e6:
                return theta, True  # no descent left: at the minimum to working precision
        if abs(step[0]) < _STEP_TOL_PX and abs(step[1]) < _STEP_TOL_PX:
            return theta, True
    return theta, True


def _ellipse_from(theta: np.ndarray) -> Ellipse | None:
    M = np.array([[theta[2], theta[3]], [theta[3], theta[4]]])
    lam, vec = np.linalg.eigh(M)
    if not np.all(lam > 0):
        return None
    semi = 1.0 / np.sqrt(lam)  # eigh ascending: the first is the major axis
    angle = math.degrees(math.atan2(vec[1, 0], vec[0, 0])) % 180.0
    return Ellipse(center=np.array([theta[0], theta[1]]), axes=semi, angle_deg=angle)
