"""Measuring-layout benchmark (issue 8). Prints tables; asserts nothing.

For each layout of the paper's roof cell (Table 1 holes, Table 2 camera):

- the predicted pose uncertainty at 0.1 px (``solver.planning.layout_covariance``, Eq. 29 / the CRB), with
  and without the robot's repeatability (0.05 mm / 0.01 deg per axis), at the part frame's origin (the
  issue's table) and at the grasp point (the holes' centroid);
- 10,000 parts drawn uniformly within +-50 mm / +-5 deg on every axis (rotation vector about the holes'
  centroid, as the simulated cell draws them, ``drivers.sim.cell.part_deviation``): for every (part, view)
  whether the hole lies in front of the camera, at least 50 px inside the image, inside the depth of field
  of ``config/sim-cell.toml`` ([layout] depth_of_field_mm); the worst margin, the depth range and the
  largest angle between line of sight and the sheet's normal.

Layouts: "today" (straight down from 650 mm, each hole a quarter of the image from the edge), "issue ref"
(each camera tilted 30 deg towards the part at 650 mm, its hole at the image centre: the issue's reference
point), "planned" (the measuring poses of config/sim-cell.toml, ``monoguide plan --layout``). Last, the
planner's run time on the cell's request (noisy on a shared machine).

    .venv/bin/python benchmarks/bench_layout.py                 # 10,000 parts (a few seconds)
    .venv/bin/python benchmarks/bench_layout.py --parts 1000
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np

from monoguide.daemon.config import load_cell_config
from monoguide.daemon.plan import cell_layout
from monoguide.drivers.sim.cell import part_deviation
from monoguide.solver import frames
from monoguide.solver.camera import CameraModel
from monoguide.solver.planning import layout_covariance, look_at_poses, plan_layout, pose_sigmas

SIM_CELL = Path(__file__).parents[1] / "config" / "sim-cell.toml"
SIGMA_PX, REP_MM, REP_DEG = 0.1, 0.05, 0.01
MARGIN_PX = 50.0  # the issue's target


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--parts", type=int, default=10000, help="deviated parts drawn")
    parser.add_argument("--seed", type=int, default=20261123)
    args = parser.parse_args()
    config = load_cell_config(SIM_CELL)
    camera, points = config.camera.intrinsics, config.part.points_w
    near, far = config.layout.constraints.depth_of_field_mm
    centre = points.mean(axis=0)
    T_w0_cf = frames.invert(config.reference.T_cf_w0)
    layouts = {
        "today": look_at_poses(points, camera, 650.0),
        "issue ref": [_tilted(camera, p, centre, 30.0, 650.0) for p in points],
        "planned": [T_w0_cf @ p.T_cf_si for p in config.measuring_poses],
    }
    print(f"monoguide layout benchmark: paper roof cell, {camera.width} x {camera.height} px, f {camera.fx:.0f} px")
    print(f"predicted sigma at {SIGMA_PX} px; 'rep.': with the robot's repeatability {REP_MM} mm / {REP_DEG} deg "
          "per axis; origin: the part frame's origin (the issue's table), grasp: the holes' centroid")
    header = (f"{'layout':<10} {'rot deg':>8} {'origin mm':>9} {'grasp mm':>8} {'rot deg rep.':>12} "
              f"{'origin mm rep.':>14} {'grasp mm rep.':>13}")
    print(header)
    print("-" * len(header))
    for name, poses in layouts.items():
        s = pose_sigmas(layout_covariance(camera, points, poses, SIGMA_PX), frames.invert(poses[0]), centre)
        r = pose_sigmas(layout_covariance(camera, points, poses, SIGMA_PX, REP_MM, REP_DEG), frames.invert(poses[0]),
                        centre)
        print(f"{name:<10} {s.sigma_rot_deg:>8.4f} {s.sigma_origin_mm:>9.3f} {s.sigma_trans_mm:>8.3f} "
              f"{r.sigma_rot_deg:>12.4f} {r.sigma_origin_mm:>14.3f} {r.sigma_trans_mm:>13.3f}")
    rng = np.random.default_rng(args.seed)
    parts = [part_deviation(np.radians(rng.uniform(-5.0, 5.0, 3)), rng.uniform(-50.0, 50.0, 3), centre)
             for _ in range(args.parts)]
    print()
    print(f"{args.parts} parts uniform in ±50 mm / ±5° on every axis (seed {args.seed}), {len(points)} views each; "
          f"depth of field {near:g}-{far:g} mm; share of (part, view) pairs")
    header = (f"{'layout':<10} {'in front':>9} {'≥50 px in':>10} {'in DoF':>8} {'all three':>10} "
              f"{'worst margin px':>15} {'depth mm':>12} {'max angle °':>11}")
    print(header)
    print("-" * len(header))
    for name, poses in layouts.items():
        _envelope_row(name, camera, points, poses, parts, near, far)
    request = cell_layout(config).request
    start = time.perf_counter()
    plan_layout(request)
    print()
    print(f"plan_layout on the cell's request: {time.perf_counter() - start:.1f} s "
          "(one run, this process; the machine is shared, so timing is indicative)")


def _envelope_row(name, camera: CameraModel, points, poses, parts, near, far) -> None:
    stacked = np.stack(parts)  # (k, 4, 4) T_w0_w
    front = inside = in_dof = every = 0
    worst, depth_lo, depth_hi, angle_max = math.inf, math.inf, -math.inf, 0.0
    for i, T_w0_c in enumerate(poses):
        p_w0 = stacked[:, :3, :3] @ points[i] + stacked[:, :3, 3]  # (k, 3)
        n_w0 = stacked[:, :3, 2]  # the sheet's normal, the part's z axis
        T_c_w0 = frames.invert(T_w0_c)
        p_c = p_w0 @ T_c_w0[:3, :3].T + T_c_w0[:3, 3]
        ok_front = p_c[:, 2] > 0.0
        margin = np.full(len(p_c), -np.inf)
        px = camera.project(p_c[ok_front])
        margin[ok_front] = np.minimum.reduce([px[:, 0] + 0.5, camera.width - 0.5 - px[:, 0], px[:, 1] + 0.5,
                                              camera.height - 0.5 - px[:, 1]])
        ok_margin = margin >= MARGIN_PX
        ok_dof = (p_c[:, 2] >= near) & (p_c[:, 2] <= far)
        front += int(ok_front.sum())
        inside += int(ok_margin.sum())
        in_dof += int(ok_dof.sum())
        every += int((ok_front & ok_margin & ok_dof).sum())
        worst = min(worst, float(margin.min()))
        depth_lo, depth_hi = min(depth_lo, float(p_c[:, 2].min())), max(depth_hi, float(p_c[:, 2].max()))
        to_camera = T_w0_c[:3, 3] - p_w0
        cos = np.sum(to_camera * n_w0, axis=1) / np.linalg.norm(to_camera, axis=1)
        angle_max = max(angle_max, float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))).max()))
    total = len(parts) * len(poses)
    print(f"{name:<10} {100 * front / total:>8.2f}% {100 * inside / total:>9.2f}% {100 * in_dof / total:>7.2f}% "
          f"{100 * every / total:>9.2f}% {worst:>15.1f} {f'{depth_lo:.0f}-{depth_hi:.0f}':>12} {angle_max:>11.1f}")


def _tilted(camera: CameraModel, point: np.ndarray, centre: np.ndarray, tilt_deg: float, standoff: float):
    """A camera ``standoff`` from ``point`` on the far side from ``centre``, its optical axis through the point
    and tilted ``tilt_deg`` from the vertical: the hole at the principal point."""
    inward = (centre - point) * np.array([1.0, 1.0, 0.0])
    inward /= np.linalg.norm(inward)
    t = math.radians(tilt_deg)
    z = -np.array([0.0, 0.0, 1.0]) * math.cos(t) + inward * math.sin(t)
    x = np.cross([0.0, 0.0, 1.0], z)
    x /= np.linalg.norm(x)
    return frames.make_T(np.column_stack([x, np.cross(z, x), z]), point - standoff * z)


if __name__ == "__main__":
    main()
