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


def layout_cell(camera: CameraModel, points_w: np.ndarray, T_w0_si: list[np.ndarray]) -> SyntheticCell:
    """Any layout as a synthetic cell: view i at ``T_w0_si[i]`` (in the reference part's frame, e.g. a
    planned layout, ``solver.planning.plan_layout``) sees point i."""
    points_w = np.asarray(points_w, dtype=float).reshape(-1, 3)
    T_s1_w0 = frames.invert(T_w0_si[0])
    T_s1_si = np.stack([T_s1_w0 @ T for T in T_w0_si])
    return SyntheticCell(camera, points_w.copy(), T_s1_si, T_s1_w0, tuple((i, i) for i in range(len(points_w))))


def calibrated_cell(
    camera: CameraModel,
    points_w: np.ndarray,
    T_cf_w0: np.ndarray,
    T_cf_si: list[np.ndarray],
    points_per_view: list[list[int]],
) -> SyntheticCell:
    """A cell as a cell config states it: the reference part ``T_cf_w0`` and the measuring poses
    ``T_cf_si`` (4, 4) in the cell frame, view i seeing the points ``points_per_view[i]``; expressed in
    SF1, the frame of the first measuring pose (``T_s1_x = inv(T_cf_si[0]) @ T_cf_x``)."""
    T_s1_cf = frames.invert(T_cf_si[0])
    T_s1_si = np.stack([T_s1_cf @ T for T in T_cf_si])
    observed = tuple((i, int(p)) for i, points in enumerate(points_per_view) for p in points)
    points_w = np.asarray(points_w, dtype=float).reshape(-1, 3)
    return SyntheticCell(camera, points_w.copy(), T_s1_si, T_s1_cf @ T_cf_w0, observed)


def measurement_record(
    cell: SyntheticCell,
    pixels: np.ndarray,
    sigma_px: float = 0.1,
    record_id: str | None = None,
    T_b_s1: np.ndarray | None = None,
    truth_T_s1_w: np.ndarray | None = None,
) -> dict:
    """A ``monoguide.measurement/1`` record (a JSON-ready dict) of ``cell`` observing ``pixels`` (m, 2);
    with ``truth_T_s1_w`` it carries its truth (and the true base offset when ``T_b_s1`` is given)."""
    record: dict = {
        "format": "monoguide.measurement/1",
        "id": record_id,
        "camera": cell.camera.as_dict(),
        "points_w": cell.points_w.tolist(),
        "views": [{"T_s1_si": T.tolist()} for T in cell.T_s1_si],
        "T_s1_w0": cell.T_s1_w0.tolist(),
        "observations": [
            {"view": int(v), "point": int(p), "pixel": [float(u) for u in pixels[j]]}
            for j, (v, p) in enumerate(cell.observed)
        ],
        "sigma_px": sigma_px,
    }
    if T_b_s1 is not None:
        record["T_b_s1"] = T_b_s1.tolist()
    if truth_T_s1_w is not None:
        record["truth"] = {"T_s1_w": truth_T_s1_w.tolist()}
        if T_b_s1 is not None:  # the motion, in the base frame, that carries the reference part onto the true one
            T_b_w, T_b_w0 = T_b_s1 @ truth_T_s1_w, T_b_s1 @ cell.T_s1_w0
            record["truth"]["base_offset"] = (T_b_w @ frames.invert(T_b_w0)).tolist()
    return record


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
