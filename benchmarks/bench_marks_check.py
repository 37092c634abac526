"""The check job of a cell with reference marks (the marks alone, no part), at solver level. Prints tables; asserts
nothing.

A Monte Carlo over the simulated roof cell's own marks (``config/sim-cell-marks.toml``: its 4 roof views, 3 marks
each): each check, the robot stops at every measuring pose with its repeatability (0.05 mm / 0.01 deg per flange
axis, unseen by its report), the marks lie off their survey by 0.025 mm per axis, every centre has 0.1 px of noise;
``solver.marks_camera.check_cameras`` at its default rate, one false failure per 1,000 good checks. Then each
calibration fault (the camera bumped on its bracket, the focal length, a measuring pose drifting): how often the
check fails it. No images, no devices.

    .venv/bin/python benchmarks/bench_marks_check.py                          # 10,000 good checks: ~15 minutes
    .venv/bin/python benchmarks/bench_marks_check.py --good 2000 --faulty 100
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import numpy as np

from monoguide.daemon.config import load_cell_config
from monoguide.solver import frames
from monoguide.solver.calibration_faults import axis_motion
from monoguide.solver.marks_camera import check_cameras
from monoguide.solver.marks_problem import camera_prior_factor
from monoguide.solver.marks_synthetic import REPEATABILITY_DEG, REPEATABILITY_MM, repeatability_at_flange

MARKS_CELL = Path(__file__).parents[1] / "config" / "sim-cell-marks.toml"
SIGMA_PX = 0.1


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--good", type=int, default=10000, help="good checks for the false failures (default 10,000)")
    parser.add_argument("--faulty", type=int, default=200, help="checks per fault")
    parser.add_argument("--seed", type=int, default=2026)
    args = parser.parse_args()
    config = load_cell_config(MARKS_CELL).for_job(1)
    poses = config.measuring_poses
    T_cf_s1 = poses[0].T_cf_si
    T_s1_cf = frames.invert(T_cf_s1)
    T_s1_si = np.array([T_s1_cf @ p.T_cf_si for p in poses])
    marks = [dataclasses.replace(m.as_solver(), position_cf=frames.transform_points(T_s1_cf, m.position_cf[None])[0])
             for m in config.reference_marks]
    views = np.array([v for v, p in enumerate(poses) for _ in p.marks])
    index = np.array([m for p in poses for m in p.marks])
    names = [p.name for p in poses]
    prior = camera_prior_factor(REPEATABILITY_MM, REPEATABILITY_DEG, config.camera.T_f_c)
    camera = config.camera.intrinsics
    T_f_c = config.camera.T_f_c

    def check(rng: np.random.Generator, fault: np.ndarray | None = None, drift: tuple[int, np.ndarray] | None = None,
              focal: float = 0.0) -> bool:
        T_true = repeatability_at_flange(rng, T_s1_si, T_f_c, REPEATABILITY_MM, REPEATABILITY_DEG)
        if fault is not None:
            T_true = np.array([T @ fault for T in T_true])
        if drift is not None:
            v, D = drift
            T_true[v] = T_true[v] @ frames.invert(T_f_c) @ D @ T_f_c
        lens = camera if not focal else dataclasses.replace(camera, fx=camera.fx * (1 + focal / 100),
                                                            fy=camera.fy * (1 + focal / 100))
        truth = np.array([m.position_cf + rng.normal(0.0, m.sigma_mm, 3) for m in marks])
        pixels = np.array([lens.project(frames.transform_points(frames.invert(T_true[v]), truth[m][None]))[0]
                           for v, m in zip(views, index, strict=True)])
        pixels += rng.normal(0.0, SIGMA_PX, pixels.shape)
        return check_cameras(camera, T_s1_si, marks, views, index, pixels, names, prior, SIGMA_PX).passed

    rng = np.random.default_rng(args.seed)
    start = time.perf_counter()
    failed = sum(not check(rng) for _ in range(args.good))
    seconds = time.perf_counter() - start
    print(f"check job with marks, {MARKS_CELL.name}: {len(poses)} views x 3 marks, repeatability "
          f"{REPEATABILITY_MM} mm / {REPEATABILITY_DEG} deg unseen, survey 0.025 mm, {SIGMA_PX} px; seed {args.seed}")
    print(f"false failures: {failed} of {args.good} good checks = {failed / args.good * 1000:.2f} per 1,000 "
          f"(design 1 per 1,000); {seconds / args.good * 1e3:.1f} ms a check")
    rows = []
    for deg in (0.02, 0.05, 0.1, 0.3, 1.0):
        rows += [(f"bump {deg:g} deg about {a}", {"fault": axis_motion(a, deg=deg)}) for a in "xyz"]
    for mm in (0.3, 1.0, 3.0):
        rows += [(f"bump {mm:g} mm along {a}", {"fault": axis_motion(a, mm=mm)}) for a in "xyz"]
    rows += [(f"focal +{p:g} %", {"focal": p}) for p in (0.1, 0.5)]
    u = np.ones(3) / np.sqrt(3.0)
    drift = frames.make_T(frames.rotvec_to_matrix(np.radians(0.05) * u), 0.3 * u)
    rows += [(f"drift {names[v]} 0.3 mm / 0.05 deg", {"drift": (v, drift)}) for v in range(len(poses))]
    print(f"\n{'fault':30s} {'checks failed':>14s}")
    for name, kwargs in rows:
        n = sum(not check(rng, **kwargs) for _ in range(args.faulty))
        print(f"{name:30s} {n:>6d} of {args.faulty:<6d}", flush=True)


if __name__ == "__main__":
    main()
