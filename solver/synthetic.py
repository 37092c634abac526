"""Synthetic cells with known truth, for tests, benchmarks and the simulated cell (seeded, no I/O).

The paper's roof cell (Sec. 5): the Table 1 holes, the Table 2 camera, one measuring pose right above
each hole at ``standoff_mm``, the hole imaged a quarter of the image from the edge (Sec. 4).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from monoguide.solver import frames
from monoguide.solver.camera import PAPER_CAMERA, CameraModel
from monoguide.solver.planning import look_at_poses
from monoguide.solver.problem import PoseProblem

PAPER_ROOF_POINTS_W = np.array(
    [
        [0.0, 0.0, 0.0],
        [1218.078, 0.0, 0.0],
        [1218.028, 2058.764, 0.0],
        [-1.017, 2059.039, -2.677],
    ]
)
"""Centres of the roof's featured holes in the part frame, mm (Table 1)."""


@dataclass(frozen=True)
class SyntheticCell:
    """A measuring layout: camera, featured points, measuring poses in SF1, the reference part pose.

    T_s1_si : (k, 4, 4); ``observed`` lists (view, point) pairs seen by the layout.
    """

    camera: CameraModel
    points_w: np.ndarray
    T_s1_si: np.ndarray
    T_s1_w0: np.ndarray
    observed: tuple[tuple[int, int], ...]

    def problem(
        self, pixels: np.ndarray, sigma_px: float = 0.1, view_sigma_mm: float = 0.0, view_sigma_deg: float = 0.0
    ) -> PoseProblem:
        views = np.array([v for v, _ in self.observed])
        points = np.array([p for _, p in self.observed])
        return PoseProblem(
            self.camera, self.points_w, self.T_s1_si, views, points, pixels, self.T_s1_w0,
            sigma_px, view_sigma_mm, view_sigma_deg,
        )

    def project(self, T_s1_w: np.ndarray, T_s1_si: np.ndarray | None = None) -> np.ndarray:
        """Exact pixels (m, 2) of the observed points for a part at ``T_s1_w`` (cameras at ``T_s1_si``)."""
        T_s1_si = self.T_s1_si if T_s1_si is None else T_s1_si
        out = np.empty((len(self.observed), 2))
        for row, (view, point) in enumerate(self.observed):
            T_si_w = frames.invert(T_s1_si[view]) @ T_s1_w
            out[row] = self.camera.project(frames.transform_points(T_si_w, self.points_w[point : point + 1]))[0]
        return out


def paper_roof_cell(
    standoff_mm: float = 650.0, camera: CameraModel = PAPER_CAMERA, targets_px: np.ndarray | None = None
) -> SyntheticCell:
    """The paper's roof cell with one view per hole (view i sees point i)."""
    T_w0_si = look_at_poses(PAPER_ROOF_POINTS_W, camera, standoff_mm, targets_px)
    T_s1_w0 = frames.invert(T_w0_si[0])
    T_s1_si = np.stack([T_s1_w0 @ T for T in T_w0_si])
    observed = tuple((i, i) for i in range(len(PAPER_ROOF_POINTS_W)))
    return SyntheticCell(camera, PAPER_ROOF_POINTS_W.copy(), T_s1_si, T_s1_w0, observed)


def deviated_part(cell: SyntheticCell, rng: np.random.Generator, max_deg: float, max_mm: float) -> np.ndarray:
    """A part pose ``T_s1_w``: the reference turned about its centroid by a rotation vector with each
    component uniform in +-max_deg, and shifted by a translation uniform in +-max_mm per axis."""
    centroid = cell.points_w.mean(axis=0)
    rotvec = np.radians(rng.uniform(-max_deg, max_deg, size=3))
    shift = rng.uniform(-max_mm, max_mm, size=3)
    about_centroid = frames.make_T(np.eye(3), centroid) @ frames.make_T(
        frames.rotvec_to_matrix(rotvec), shift
    ) @ frames.make_T(np.eye(3), -centroid)
    return cell.T_s1_w0 @ about_centroid


def perturbed_views(
    cell: SyntheticCell, rng: np.random.Generator, sigma_mm: float, sigma_deg: float
) -> np.ndarray:
    """Where the cameras really stood: each ``T_s1_si`` moved by a small rigid motion of its camera with
    ``sigma_deg`` per rotation axis and ``sigma_mm`` per translation axis (robot repeatability)."""
    out = np.empty_like(cell.T_s1_si)
    for i, T in enumerate(cell.T_s1_si):
        motion = np.concatenate([rng.normal(0.0, math.radians(sigma_deg), 3), rng.normal(0.0, sigma_mm, 3)])
        out[i] = T @ frames.pose_from_vector(motion)
    return out
