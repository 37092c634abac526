"""Least-squares ellipses in the image: the fit of Sec. 5.3 and the conic algebra around it.

An ellipse is kept as its centre (2,), semi-axes (2,) major first, and the direction of the major axis
in degrees from +x toward +y (image y points down, so positive angles turn clockwise on screen).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from monoguide.solver.errors import FeatureNotFound

MIN_ELLIPSE_POINTS = 6


@dataclass(frozen=True, eq=False)
class Ellipse:
    """An ellipse in pixels: ``center`` (2,), semi-axes ``axes`` (2,) with ``axes[0] >= axes[1]``, and
    ``angle_deg`` in [0, 180) of the major axis."""

    center: np.ndarray
    axes: np.ndarray
    angle_deg: float

    @property
    def mean_radius(self) -> float:
        """Radius of the circle of equal area, sqrt(a b)."""
        return math.sqrt(float(self.axes[0] * self.axes[1]))

    def conic(self) -> np.ndarray:
        """Coefficients (6,) ``A B C D E F`` of ``A x^2 + B x y + C y^2 + D x + E y + F = 0``, F = -1 scaled."""
        th = math.radians(self.angle_deg)
        c, s = math.cos(th), math.sin(th)
        a2, b2 = float(self.axes[0]) ** 2, float(self.axes[1]) ** 2
        A = c * c / a2 + s * s / b2
        B = 2.0 * c * s * (1.0 / a2 - 1.0 / b2)
        C = s * s / a2 + c * c / b2
        x0, y0 = float(self.center[0]), float(self.center[1])
        D = -2.0 * A * x0 - B * y0
        E = -B * x0 - 2.0 * C * y0
        F = A * x0 * x0 + B * x0 * y0 + C * y0 * y0 - 1.0
        return np.array([A, B, C, D, E, F])

    def distances(self, points: np.ndarray) -> np.ndarray:
        """Signed distance (n,) of ``points`` (n, 2) from the rim, first-order (Sampson); positive outside."""
        A, B, C, D, E, F = self.conic()
        x, y = points[:, 0], points[:, 1]
        value = A * x * x + B * x * y + C * y * y + D * x + E * y + F
        gx = 2.0 * A * x + B * y + D
        gy = B * x + 2.0 * C * y + E
        return value / np.maximum(np.hypot(gx, gy), 1e-12)

    def points(self, n: int = 360) -> np.ndarray:
        """``n`` points (n, 2) on the rim, evenly spaced in the ellipse's parameter."""
        t = np.linspace(0.0, 2.0 * math.pi, n, endpoint=False)
        th = math.radians(self.angle_deg)
        R = np.array([[math.cos(th), -math.sin(th)], [math.sin(th), math.cos(th)]])
        local = np.stack([self.axes[0] * np.cos(t), self.axes[1] * np.sin(t)], axis=1)
        return local @ R.T + self.center


def fit_ellipse(points: np.ndarray, weights: np.ndarray | None = None) -> Ellipse:
    """Direct least-squares ellipse through ``points`` (n, 2) (Sec. 5.3), optionally ``weights`` (n,).

    Fitzgibbon's ellipse-specific algebraic fit in the numerically stable form of Halir and Flusser,
    on points centred and scaled to unit spread. Raises :class:`FeatureNotFound` for fewer than six
    points or a degenerate (collinear, hyperbolic) point set.
    """
    points = np.asarray(points, dtype=float).reshape(-1, 2)
    if len(points) < MIN_ELLIPSE_POINTS:
        raise FeatureNotFound(f"ellipse fit needs at least {MIN_ELLIPSE_POINTS} points, got {len(points)}")
    mean = points.mean(axis=0)
    scale = math.sqrt(float(np.mean(np.sum((points - mean) ** 2, axis=1))))
    if not scale > 0:
        raise FeatureNotFound(f"ellipse fit: all {len(points)} points coincide at {np.round(mean, 3).tolist()}")
    x = (points[:, 0] - mean[0]) / scale
    y = (points[:, 1] - mean[1]) / scale
    D1 = np.stack([x * x, x * y, y * y], axis=1)
    D2 = np.stack([x, y, np.ones_like(x)], axis=1)
    if weights is not None:
        sw = np.sqrt(np.asarray(weights, dtype=float))[:, None]
        D1, D2 = D1 * sw, D2 * sw
    S1, S2, S3 = D1.T @ D1, D1.T @ D2, D2.T @ D2
    try:
        T = -np.linalg.solve(S3, S2.T)
    except np.linalg.LinAlgError as exc:
        raise FeatureNotFound(f"ellipse fit: degenerate point set of {len(points)} points") from exc
    M = S1 + S2 @ T
    M = np.array([M[2] / 2.0, -M[1], M[0] / 2.0])
    _, vecs = np.linalg.eig(M)
    vecs = np.real(vecs)
    cond = 4.0 * vecs[0] * vecs[2] - vecs[1] ** 2
    ok = np.flatnonzero(cond > 0)
    if len(ok) == 0:
        raise FeatureNotFound(f"ellipse fit: the {len(points)} points do not lie on an ellipse")
    a1 = vecs[:, ok[0]]
    coeffs = np.concatenate([a1, T @ a1])
    unit = ellipse_from_conic(coeffs)
    return Ellipse(center=unit.center * scale + mean, axes=unit.axes * scale, angle_deg=unit.angle_deg)


def ellipse_from_conic(coeffs: np.ndarray) -> Ellipse:
    """Centre, semi-axes and angle of the conic ``A B C D E F`` (6,); raises if it is not a real ellipse."""
    A, B, C, D, E, F = (float(c) for c in coeffs)
    det = 4.0 * A * C - B * B
    if not det > 0:
        raise FeatureNotFound(f"conic {np.round(coeffs, 6).tolist()} is not an ellipse")
    x0 = (B * E - 2.0 * C * D) / det
    y0 = (B * D - 2.0 * A * E) / det
    f0 = A * x0 * x0 + B * x0 * y0 + C * y0 * y0 + D * x0 + E * y0 + F
    lam, vec = np.linalg.eigh(np.array([[A, B / 2.0], [B / 2.0, C]]))
    with np.errstate(divide="ignore", invalid="ignore"):
        semi = np.sqrt(-f0 / lam)
    if not np.all(np.isfinite(semi)) or np.any(semi <= 0):
        raise FeatureNotFound(f"conic {np.round(coeffs, 6).tolist()} is an imaginary ellipse")
    i_major = int(np.argmax(semi))
    major = vec[:, i_major]
    angle = math.degrees(math.atan2(major[1], major[0])) % 180.0
    return Ellipse(center=np.array([x0, y0]), axes=np.array([semi[i_major], semi[1 - i_major]]), angle_deg=angle)
