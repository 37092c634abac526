"""Rigid best fits of measured points to nominal ones (Kabsch/Umeyama without scale) and the 3-2-1 frame.

Used for the cell frame (benchmarks), the part frame (featured holes) and the target frame (its SMR nests).
Lengths in mm.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from monoguide.solver.calibration.errors import (
    CalibrationDegenerate,
    CalibrationError,
    CalibrationResidualTooLarge,
    CalibrationTooFewViews,
)
from monoguide.solver.frames import make_T, transform_points

MIN_SPREAD_MM = 10.0  # the points must spread at least this far off their best-fit line


@dataclass(frozen=True)
class RigidFit:
    """``T`` maps nominal coordinates to measured ones (``measured ≈ T · nominal``); ``residuals_mm`` (n,)
    is the distance of each measured point from its fitted nominal, in the order of ``names``."""

    T: np.ndarray
    names: tuple[str, ...]
    residuals_mm: np.ndarray

    @property
    def rms_mm(self) -> float:
        return float(np.sqrt(np.mean(self.residuals_mm**2)))

    @property
    def max_mm(self) -> float:
        return float(np.max(self.residuals_mm))

    def as_dict(self) -> dict[str, object]:
        return {"T": self.T.tolist(), "rms_mm": self.rms_mm,
                "residuals_mm": {n: float(r) for n, r in zip(self.names, self.residuals_mm, strict=True)}}


def _names(n: int, names: Sequence[str] | None) -> tuple[str, ...]:
    return tuple(names) if names is not None else tuple(f"#{k + 1}" for k in range(n))


def check_spread(points: np.ndarray, names: Sequence[str], what: str, min_spread_mm: float = MIN_SPREAD_MM) -> None:
    """Refuse fewer than 3 points or points (nearly) on one line: the rotation about it is free."""
    if len(points) < 3:
        raise CalibrationTooFewViews(f"{what}: {len(points)} point(s) ({', '.join(names) or 'none'}); "
                                     "a frame needs at least 3 not on one line")
    centred = points - points.mean(axis=0)
    s = np.linalg.svd(centred, compute_uv=False)
    spread = float(s[1] / math.sqrt(len(points)))
    if spread < min_spread_mm:
        raise CalibrationDegenerate(f"{what}: points {', '.join(names)} are (nearly) collinear: they spread only "
                                    f"{spread:.3f} mm RMS off their common line (need {min_spread_mm:g} mm)")


def fit_rigid(nominal: np.ndarray, measured: np.ndarray, names: Sequence[str] | None = None, *,
              what: str = "rigid fit", max_residual_mm: float | None = None,
              min_spread_mm: float = MIN_SPREAD_MM) -> RigidFit:
    """Least-squares rigid transform ``T`` with ``measured ≈ T · nominal`` (Kabsch, no scale).

    ``nominal`` and ``measured`` (n, 3) mm, row k the same point. Refuses fewer than 3 or collinear points
    (:class:`CalibrationDegenerate`, naming them) and, with ``max_residual_mm``, a point farther than that
    from its fit (:class:`CalibrationResidualTooLarge`, naming the worst).
    """
    nominal = np.asarray(nominal, dtype=float).reshape(-1, 3)
    measured = np.asarray(measured, dtype=float).reshape(-1, 3)
    if nominal.shape != measured.shape:
        raise ValueError(f"{what}: {len(nominal)} nominal points but {len(measured)} measured")
    labels = _names(len(nominal), names)
    check_spread(nominal, labels, f"{what} (nominal)", min_spread_mm)
    check_spread(measured, labels, f"{what} (measured)", min_spread_mm)
    cn, cm = nominal.mean(axis=0), measured.mean(axis=0)
    H = (nominal - cn).T @ (measured - cm)
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, float(np.sign(np.linalg.det(Vt.T @ U.T)))])
    R = Vt.T @ D @ U.T
    T = make_T(R, cm - R @ cn)
    residuals = np.linalg.norm(transform_points(T, nominal) - measured, axis=1)
    fit = RigidFit(T, labels, residuals)
    if max_residual_mm is not None and fit.max_mm > max_residual_mm:
        worst = int(np.argmax(residuals))
        listed = ", ".join(f"{n} {r:.3f}" for n, r in zip(labels, residuals, strict=True))
        raise CalibrationResidualTooLarge(f"{what}: point {labels[worst]} is {residuals[worst]:.3f} mm off the fit "
                                          f"(tolerance {max_residual_mm:g} mm; residuals mm: {listed})")
    return fit


def fit_rigid_named(nominal: dict[str, np.ndarray], measured: dict[str, np.ndarray], *, what: str = "rigid fit",
                    max_residual_mm: float | None = None, min_spread_mm: float = MIN_SPREAD_MM) -> RigidFit:
    """:func:`fit_rigid` on the points named in both mappings (name -> (3,) mm); a measured name without a
    nominal is refused rather than ignored."""
    unknown = sorted(set(measured) - set(nominal))
    if unknown:
        raise CalibrationError(f"{what}: measured point(s) {', '.join(unknown)} have no nominal coordinates")
    names = [n for n in nominal if n in measured]
    return fit_rigid(np.array([nominal[n] for n in names]), np.array([measured[n] for n in names]), names,
                     what=what, max_residual_mm=max_residual_mm, min_spread_mm=min_spread_mm)


def frame_321(origin: np.ndarray, on_x: np.ndarray, in_plane: np.ndarray,
              names: Sequence[str] = ("origin", "x", "plane"), what: str = "3-2-1 frame") -> np.ndarray:
    """The 3-2-1 frame of three measured points (3,): origin at ``origin``, x axis towards ``on_x``, the xy plane
    through ``in_plane`` (y on its side), z = x × y. Returns ``T_meas_frame`` (the frame in the measuring frame)."""
    points = np.array([origin, on_x, in_plane], dtype=float)
    check_spread(points, list(names), what)
    x = points[1] - points[0]
    x /= np.linalg.norm(x)
    v = points[2] - points[0]
    y = v - (v @ x) * x
    y /= np.linalg.norm(y)
    return make_T(np.column_stack([x, y, np.cross(x, y)]), points[0])
