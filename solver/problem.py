"""One pose problem: the observations of featured points in several calibrated views (Eq. 9)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from monoguide.solver import frames
from monoguide.solver.camera import CameraModel
from monoguide.solver.errors import PointBehindCamera, TooFewObservations, UnknownReference

MIN_OBSERVATIONS = 3  # solvable: six unknowns, two equations per point (Sec. 3.2); checkable needs 4


@dataclass(frozen=True)
class PoseProblem:
    """Everything the estimators need, as arrays.

    camera        : the calibrated camera (same camera at every view)
    points_w      : (n, 3) featured points in the part frame, mm
    T_s1_si       : (k, 4, 4) camera pose i in SF1 (view 0 is the identity)
    view_index    : (m,) int, the view of each observation
    point_index   : (m,) int, the point of each observation
    pixels        : (m, 2) raw (distorted) image coordinates
    T_s1_w0       : (4, 4) the reference part pose in SF1 (the initial value of Sec. 3.3)
    sigma_px      : standard deviation of a centre, px
    view_sigma_mm, view_sigma_deg : how far a measuring pose may be off its calibration (per axis)
    T_f_c         : (4, 4) the camera on the robot's flange, or None. None: the view sigmas act on the camera
                    (a small rigid motion about the camera's centre, in its axes). Given: they are the robot's
                    repeatability at the flange (``T_b_f_actual = T_b_f N``, N per axis in flange axes), and
                    the camera moves by ``T_c_f N T_f_c`` (a flange rotation also shifts the camera's centre)
    """

    camera: CameraModel
    points_w: np.ndarray
    T_s1_si: np.ndarray
    view_index: np.ndarray
    point_index: np.ndarray
    pixels: np.ndarray
    T_s1_w0: np.ndarray
    sigma_px: float = 0.1
    view_sigma_mm: float = 0.0
    view_sigma_deg: float = 0.0
    T_f_c: np.ndarray | None = None
    # Derived per observation: R_si_s1 (m, 3, 3), t_si_s1 (m, 3), the observed point P (m, 3),
    # and the unit line of sight of its pixel in the camera frame (m, 3).
    R_obs: np.ndarray = field(init=False, repr=False)
    t_obs: np.ndarray = field(init=False, repr=False)
    P_obs: np.ndarray = field(init=False, repr=False)
    rays: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        m = len(self.view_index)
        if m < MIN_OBSERVATIONS:
            raise TooFewObservations(
                f"{m} observation(s): at least {MIN_OBSERVATIONS} are needed for the six degrees of freedom"
            )
        if len(self.point_index) != m or self.pixels.shape != (m, 2):
            raise UnknownReference(
                f"observation arrays disagree: {m} views, {len(self.point_index)} points, "
                f"pixels of shape {self.pixels.shape}"
            )
        k, n = len(self.T_s1_si), len(self.points_w)
        for name, index, count in (("view", self.view_index, k), ("point", self.point_index, n)):
            bad = [int(i) for i in index if not 0 <= i < count]
            if bad:
                raise UnknownReference(f"observation names {name} {bad[0]}, but there are only {count} {name}s")
        T_si_s1 = np.stack([frames.invert(T) for T in self.T_s1_si])
        set_ = object.__setattr__
        if self.T_f_c is not None:
            set_(self, "T_f_c", frames.rigid_transform(np.asarray(self.T_f_c, dtype=float), "T_f_c"))
        set_(self, "R_obs", np.ascontiguousarray(T_si_s1[self.view_index, :3, :3]))
        set_(self, "t_obs", np.ascontiguousarray(T_si_s1[self.view_index, :3, 3]))
        set_(self, "P_obs", np.ascontiguousarray(self.points_w[self.point_index]))
        set_(self, "rays", self.camera.pixels_to_rays(self.pixels))

    @property
    def n_observations(self) -> int:
        return len(self.view_index)

    def points_in_views(self, T_s1_w: np.ndarray) -> np.ndarray:
        """Each observed point in the frame of the camera that observed it, (m, 3), mm (Eq. 11)."""
        M = self.P_obs @ T_s1_w[:3, :3].T + T_s1_w[:3, 3]
        return np.einsum("mij,mj->mi", self.R_obs, M) + self.t_obs

    def with_flange(self, T_f_c: np.ndarray | None) -> PoseProblem:
        """The same problem with the view sigmas acting at the flange of a camera mounted at ``T_f_c``
        (None: about the camera's centre)."""
        return PoseProblem(
            self.camera, self.points_w, self.T_s1_si, self.view_index, self.point_index, self.pixels,
            self.T_s1_w0, self.sigma_px, self.view_sigma_mm, self.view_sigma_deg, T_f_c,
        )

    def with_pixels(self, pixels: np.ndarray) -> PoseProblem:
        """The same problem with other observed pixels (e.g. a noisy draw of a synthetic scene)."""
        return PoseProblem(
            self.camera, self.points_w, self.T_s1_si, self.view_index, self.point_index, pixels,
            self.T_s1_w0, self.sigma_px, self.view_sigma_mm, self.view_sigma_deg, self.T_f_c,
        )


def reprojection(problem: PoseProblem, R: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Predicted minus observed pixels (m, 2) at ``T_s1_w = (R, t)``, their Jacobian (m, 2, 6) over a
    left perturbation (w rad, dt mm) in SF1, and the points in their cameras (m, 3) (Eq. 9).

    Raises :class:`PointBehindCamera` when the pose puts an observed point behind its camera.
    """
    RP = problem.P_obs @ R.T
    Q = np.einsum("mij,mj->mi", problem.R_obs, RP + t) + problem.t_obs
    if np.any(Q[:, 2] <= 1e-6):
        j = int(np.argmin(Q[:, 2]))
        raise PointBehindCamera(
            f"point {int(problem.point_index[j])} lies behind camera {int(problem.view_index[j])} "
            f"(z = {Q[j, 2]:.1f} mm) at this pose"
        )
    uv, Jp = problem.camera.project_with_jacobian(Q)
    JpR = Jp @ problem.R_obs  # d(uv)/d(M), M the point in SF1
    J = np.empty((len(Q), 2, 6))
    J[:, :, :3] = frames.cross_rows(RP, JpR)  # d(uv)/dw = JpR (-[RP]x): row a -> RP x a
    J[:, :, 3:] = JpR
    return uv - problem.pixels, J, Q
