"""Pinhole camera with Brown-Conrady distortion (Eq. 7-8, OpenCV's k1 k2 p1 p2 convention).

Pixels are raw (distorted) image coordinates: x right, y down, pixel centres at integers.
Normalised coordinates are ``(X/Z, Y/Z)`` of a point in the camera frame (z along the optical axis).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np

from monoguide.solver.errors import MissingKey, RecordError, UnknownKey

UNDISTORT_TOL_PX = 1e-10
_UNDISTORT_MAX_ITER = 50


@dataclass(frozen=True)
class CameraModel:
    """Intrinsics of one calibrated camera: image size (px), focal lengths and principal point (px),
    radial ``k1 k2`` and tangential ``p1 p2`` distortion."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    k1: float = 0.0
    k2: float = 0.0
    p1: float = 0.0
    p2: float = 0.0

    @classmethod
    def from_dict(cls, values: dict, where: str = "camera") -> CameraModel:
        """Build from a mapping with exactly the field names; raises a :class:`RecordError` naming the
        bad key. Every coefficient is required (an undistorted camera says ``k1 = 0``): a missing one
        is :class:`MissingKey`, an unknown one :class:`UnknownKey` with the closest known name."""
        if not isinstance(values, dict):
            raise RecordError(f"{where}: expected an object, got {type(values).__name__}")
        names = [f.name for f in fields(cls)]
        for key in values:
            if key not in names:
                raise UnknownKey.naming(str(key), names, where)
        kwargs = {}
        for name in names:
            if name not in values:
                raise MissingKey(f"{where}.{name}: missing (every intrinsic is required; say 0.0 for none)")
            v = values[name]
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
                raise RecordError(f"{where}.{name}: expected a finite number, got {v!r}")
            if name in ("width", "height") and v != int(v):
                raise RecordError(f"{where}.{name}: expected a whole number of pixels, got {v!r}")
            kwargs[name] = int(v) if name in ("width", "height") else float(v)
        model = cls(**kwargs)
        if model.width <= 0 or model.height <= 0:
            raise RecordError(f"{where}: image size must be positive, got {model.width} x {model.height}")
        if model.fx <= 0 or model.fy <= 0:
            raise RecordError(f"{where}: focal lengths must be positive, got fx={model.fx}, fy={model.fy}")
        return model

    def as_dict(self) -> dict[str, float]:
        return {f.name: getattr(self, f.name) for f in fields(self)}

    @property
    def K(self) -> np.ndarray:
        """Intrinsic matrix A of Eq. 10 (3, 3)."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def dist_coeffs(self) -> np.ndarray:
        """OpenCV order (k1, k2, p1, p2)."""
        return np.array([self.k1, self.k2, self.p1, self.p2])

    # --- forward model ------------------------------------------------------------------------

    def distort(self, xy: np.ndarray) -> np.ndarray:
        """Ideal normalised coordinates (n, 2) -> distorted normalised coordinates (n, 2) (Eq. 8)."""
        x, y = xy[:, 0], xy[:, 1]
        r2 = x * x + y * y
        radial = 1.0 + r2 * (self.k1 + self.k2 * r2)
        xd = x * radial + 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x)
        yd = y * radial + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y
        return np.stack([xd, yd], axis=1)

    def distort_jacobian(self, xy: np.ndarray) -> np.ndarray:
        """d(distorted)/d(ideal) of normalised coordinates, (n, 2, 2)."""
        x, y = xy[:, 0], xy[:, 1]
        r2 = x * x + y * y
        radial = 1.0 + r2 * (self.k1 + self.k2 * r2)
        drad = 2.0 * (self.k1 + 2.0 * self.k2 * r2)  # d radial / d(x) = drad * x
        J = np.empty((len(x), 2, 2))
        J[:, 0, 0] = radial + x * x * drad + 2.0 * self.p1 * y + 6.0 * self.p2 * x
        J[:, 0, 1] = x * y * drad + 2.0 * self.p1 * x + 2.0 * self.p2 * y
        J[:, 1, 0] = x * y * drad + 2.0 * self.p1 * x + 2.0 * self.p2 * y
        J[:, 1, 1] = radial + y * y * drad + 6.0 * self.p1 * y + 2.0 * self.p2 * x
        return J

    def normalized_to_pixels(self, xy: np.ndarray) -> np.ndarray:
        """Ideal normalised coordinates (n, 2) -> raw pixels (n, 2)."""
        d = self.distort(xy)
        return np.stack([self.fx * d[:, 0] + self.cx, self.fy * d[:, 1] + self.cy], axis=1)

    def project(self, points_c: np.ndarray) -> np.ndarray:
        """Points in the camera frame (n, 3), z > 0 -> raw pixels (n, 2) (Eq. 7 with Eq. 8)."""
        points_c = np.asarray(points_c, dtype=float).reshape(-1, 3)
        xy = points_c[:, :2] / points_c[:, 2:3]
        return self.normalized_to_pixels(xy)

    def project_with_jacobian(self, points_c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Raw pixels (n, 2) and their Jacobian d(u, v)/d(X, Y, Z) (n, 2, 3) of camera-frame points.

        Written out term by term: the solver calls this in its inner loop on a handful of points, where
        numpy's per-call cost, not arithmetic, is the price.
        """
        X, Y, Z = np.asarray(points_c, dtype=float).reshape(-1, 3).T
        inv_z = 1.0 / Z
        x, y = X * inv_z, Y * inv_z
        x2, y2, xy = x * x, y * y, x * y
        r2 = x2 + y2
        radial = 1.0 + r2 * (self.k1 + self.k2 * r2)
        drad = 2.0 * self.k1 + 4.0 * self.k2 * r2  # d radial / d x = drad * x
        p1x2, p2x2 = 2.0 * self.p1, 2.0 * self.p2
        pixels = np.empty((len(x), 2))
        pixels[:, 0] = self.fx * (x * radial + p1x2 * xy + self.p2 * (r2 + 2.0 * x2)) + self.cx
        pixels[:, 1] = self.fy * (y * radial + self.p1 * (r2 + 2.0 * y2) + p2x2 * xy) + self.cy
        # d(distorted)/d(x, y) = [[a, b], [b, d]]; d(x, y)/d(X, Y, Z) = [[1, 0, -x], [0, 1, -y]] / Z
        a = radial + x2 * drad + p1x2 * y + 3.0 * p2x2 * x
        b = xy * drad + p1x2 * x + p2x2 * y
        d = radial + y2 * drad + 3.0 * p1x2 * y + p2x2 * x
        fu, fv = self.fx * inv_z, self.fy * inv_z
        J = np.empty((len(x), 2, 3))
        J[:, 0, 0] = fu * a
        J[:, 0, 1] = fu * b
        J[:, 0, 2] = -fu * (a * x + b * y)
        J[:, 1, 0] = fv * b
        J[:, 1, 1] = fv * d
        J[:, 1, 2] = -fv * (b * x + d * y)
        return pixels, J

    # --- inverse model ------------------------------------------------------------------------

    def undistort_pixels(self, pixels: np.ndarray) -> np.ndarray:
        """Raw pixels (n, 2) -> ideal normalised coordinates (n, 2).

        Newton iterations on the distortion; converged until re-projecting moves less than
        ``UNDISTORT_TOL_PX`` pixels (1e-10 px over the whole image for the paper's lens).
        """
        pixels = np.asarray(pixels, dtype=float).reshape(-1, 2)
        target = np.stack([(pixels[:, 0] - self.cx) / self.fx, (pixels[:, 1] - self.cy) / self.fy], axis=1)
        xy = target.copy()
        tol = UNDISTORT_TOL_PX / max(self.fx, self.fy)
        for _ in range(_UNDISTORT_MAX_ITER):
            err = self.distort(xy) - target
            if float(np.max(np.abs(err), initial=0.0)) < tol:
                break
            J = self.distort_jacobian(xy)
            xy = xy - np.linalg.solve(J, err[:, :, None])[:, :, 0]
        return xy

    def pixels_to_rays(self, pixels: np.ndarray) -> np.ndarray:
        """Raw pixels (n, 2) -> unit line-of-sight directions in the camera frame (n, 3)."""
        xy = self.undistort_pixels(pixels)
        rays = np.concatenate([xy, np.ones((len(xy), 1))], axis=1)
        return rays / np.linalg.norm(rays, axis=1, keepdims=True)

    def in_image(self, pixels: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """Boolean mask (n,) of pixels inside the image with ``margin`` px to spare."""
        pixels = np.asarray(pixels, dtype=float).reshape(-1, 2)
        return (
            (pixels[:, 0] >= -0.5 + margin)
            & (pixels[:, 0] <= self.width - 0.5 - margin)
            & (pixels[:, 1] >= -0.5 + margin)
            & (pixels[:, 1] <= self.height - 0.5 - margin)
        )


PAPER_CAMERA = CameraModel(
    width=2456, height=2058, fx=2421.402, fy=2419.707, cx=1237.997, cy=971.382,
    k1=-0.02568, k2=0.07839, p1=0.00103, p2=0.0007,
)
"""The camera of the paper's experiment (Table 2): 2456 x 2058 px behind an 8.5 mm lens."""
