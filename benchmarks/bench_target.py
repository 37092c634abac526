"""Calibration-target measurement benchmark (issue 12, SFi step): time per image of
``solver.calibration.target.measure_target`` as it was ("old": every dark blob of each mark's window fitted,
the perspective correction one mark at a time) and as it is ("new": only the mark's own blob fitted, the
corrections batched, missed marks looked for again), alternating image by image in the same process so both
see the same load, and each one's pose error against the renderer's truth. Prints a table; asserts nothing.

Images: ``render_target`` (blur, grey noise, 8 bits; seeded) of the simulated cell's calibration target at
its place under each measuring pose S1..S4 (as benchmarks/bench_calibration.py ``_target_image`` at S1), 13 x 9
marks; the expected pose is the truth off by ~1 mm / 0.03 deg (the robot's absolute accuracy) or, with
``--far``, by 8 mm in the image plane (the documented limit). Wall time is what the wizard waits for; CPU
time (process time) is close to the unloaded wall time on a busy machine.

    .venv/bin/python benchmarks/bench_target.py            # 3 seeds x S1..S4, about a minute on a busy machine
    .venv/bin/python benchmarks/bench_target.py --seeds 1 --far
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np

from monoguide.daemon.assembly import build_sim_cell
from monoguide.daemon.config import load_cell_config
from monoguide.drivers.sim.target_renderer import render_target
from monoguide.solver.calibration.errors import CalibrationImageRejected
from monoguide.solver.calibration.target import (
    MIN_MARKS,
    TargetMarks,
    default_target_marks,
    measure_target,
    target_pose,
)
from monoguide.solver.camera import CameraModel
from monoguide.solver.errors import FeatureNotFound
from monoguide.solver.frames import compose, invert, make_T, pose_difference, pose_from_vector, transform_points
from monoguide.solver.holes import measure_hole, perspective_correction

SIM_CELL = Path(__file__).parents[1] / "config" / "sim-cell.toml"


def _reference_measure_target(image: np.ndarray, camera: CameraModel, marks: TargetMarks, T_guess: np.ndarray,
                              max_blur_px: float = 3.0):
    """measure_target as it was before the speed-up (same windows, same detector, same PnP)."""
    pts_c = transform_points(T_guess, marks.centers_t)
    expected = camera.project(pts_c)
    gaps = np.linalg.norm(expected[:, None, :] - expected[None, :, :], axis=2)
    np.fill_diagonal(gaps, np.inf)
    reach = 0.45 * gaps.min(axis=1)
    raw = np.full((len(expected), 2), np.nan)
    for k, (e, z) in enumerate(zip(expected, pts_c[:, 2], strict=True)):
        r_px = marks.radius_mm * camera.fx / float(z)
        if not bool(camera.in_image(e[None, :], margin=r_px + 3.0)[0]):
            continue
        offset = max(float(reach[k]), 1.5 * r_px)
        h, w = image.shape[:2]
        half = math.ceil(offset + 3.0 * r_px + 8.0)
        x0, y0 = max(int(e[0]) - half, 0), max(int(e[1]) - half, 0)
        crop = image[y0:min(int(e[1]) + half + 1, h), x0:min(int(e[0]) + half + 1, w)]
        try:
            hole = measure_hole(crop, (float(e[0]) - x0, float(e[1]) - y0), r_px, max_offset_px=offset,
                                radius_tol=0.35, max_blur_px=max_blur_px, photometric=False)
        except FeatureNotFound:
            continue
        raw[k] = hole.center + np.array([x0, y0], dtype=float)
    seen = np.all(np.isfinite(raw), axis=1)
    if int(seen.sum()) < MIN_MARKS:
        raise CalibrationImageRejected(f"target: {int(seen.sum())} marks measured")
    centers, T = raw.copy(), T_guess
    for _ in range(3):
        T = target_pose(camera, marks, centers, T).T_c_t
        for k in np.flatnonzero(seen):
            centers[k] = raw[k] - perspective_correction(camera, T, marks.centers_t[k], marks.normal_t,
                                                         marks.radius_mm, n_points=90)
    return target_pose(camera, marks, centers, T)


def _timed(fn, *args):
    w0, c0 = time.perf_counter(), time.process_time()
    out = fn(*args)
    return out, time.perf_counter() - w0, time.process_time() - c0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--far", action="store_true", help="the expected pose 8 mm off in the image plane")
    args = ap.parse_args()
    cell = build_sim_cell(load_cell_config(SIM_CELL))
    marks, cam = default_target_marks(), cell.camera
    print(f"measure_target on {cam.width} x {cam.height} px renders, {len(marks.centers_t)} marks, guess "
          f"{'8 mm off' if args.far else '~1 mm / 0.03 deg off'}; {args.seeds} seed(s) x {cell.n_measuring_poses} "
          "views; error against the renderer's truth\n")
    print("| view | seed | old s (cpu) | new s (cpu) | x faster | old deg | old mm | new deg | new mm "
          "| marks old/new |")
    print("| --- | --: | --: | --: | --: | --: | --: | --: | --: | --: |")
    rows = []
    for seed in range(1, args.seeds + 1):
        for i in range(cell.n_measuring_poses):
            rng = np.random.default_rng(1000 * seed + i)
            T_c_t = compose(invert(cell.spec.T_cf_si[i]), cell.spec.targets[i].T_cf_t)
            view = render_target(cam, T_c_t, marks.centers_t, marks.radius_mm, rng)
            if args.far:
                a = rng.uniform(0.0, 2.0 * math.pi)
                guess = make_T(np.eye(3), 8.0 * np.array([math.cos(a), math.sin(a), 0.0])) @ T_c_t
            else:
                guess = compose(T_c_t, pose_from_vector(np.concatenate([rng.normal(0, 5e-4, 3),
                                                                        rng.normal(0, 1.0, 3)])))
            old, t_old, c_old = _timed(_reference_measure_target, view.image, cam, marks, guess)
            new, t_new, c_new = _timed(measure_target, view.image, cam, marks, guess)
            e_old, e_new = pose_difference(old.T_c_t, T_c_t), pose_difference(new.T_c_t, T_c_t)
            n_old, n_new = (int(np.all(np.isfinite(v.centers_px), axis=1).sum()) for v in (old, new))
            rows.append((t_old, c_old, t_new, c_new, *e_old, *e_new))
            print(f"| S{i + 1} | {seed} | {t_old:.2f} ({c_old:.2f}) | {t_new:.2f} ({c_new:.2f}) | "
                  f"{t_old / t_new:.1f} | {e_old[0]:.5f} | {e_old[1]:.4f} | {e_new[0]:.5f} | {e_new[1]:.4f} | "
                  f"{n_old}/{n_new} |")
    r = np.array(rows)
    med = np.median(r, axis=0)
    print(f"| **median** | | **{med[0]:.2f} ({med[1]:.2f})** | **{med[2]:.2f} ({med[3]:.2f})** | "
          f"**{med[0] / med[2]:.1f}** | {med[4]:.5f} | {med[5]:.4f} | {med[6]:.5f} | {med[7]:.4f} | |")
    print(f"| max | | {r[:, 0].max():.2f} ({r[:, 1].max():.2f}) | {r[:, 2].max():.2f} ({r[:, 3].max():.2f}) | | "
          f"{r[:, 4].max():.5f} | {r[:, 5].max():.4f} | {r[:, 6].max():.5f} | {r[:, 7].max():.4f} | |")
    print(f"\nseconds per image, wall (process CPU); load average now {Path('/proc/loadavg').read_text().split()[0]}")


if __name__ == "__main__":
    main()
