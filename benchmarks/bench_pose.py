"""Pose-solver benchmark on a synthetic paper-like roof cell (issue 2). Prints tables; asserts nothing.

Cell: Table 1 holes, Table 2 camera, one view per hole. ``--layout planned`` (the default): the measuring
poses of ``config/sim-cell.toml``, planned by ``solver.planning.plan_layout`` for +-50 mm / +-5 deg (each
camera tilted towards its hole, issue 8); ``--layout today``: the old layout, four views 650 mm straight
above the holes, each hole imaged a quarter of the image from the edge. Seeded deviations of the part; the
"±5°/50" rows are the whole envelope. For each pixel noise and deviation range, every
estimator's RMS error against the truth, its ratio to the Cramer-Rao bound (CRB), how well its own
reported covariance predicts its error, the convergence rate and the median solve time; PoseLib's
``refine_generalized_absolute_pose`` runs on the same data as the peer, started from the reference pose
(as a user would) and from monoguide's initial value (to compare the refinements alone).

    .venv/bin/python benchmarks/bench_pose.py                  # full run (about ten minutes)
    .venv/bin/python benchmarks/bench_pose.py --quick          # a few seconds
    .venv/bin/python benchmarks/bench_pose.py --layout today   # the table of the old straight-down layout
"""

from __future__ import annotations

import argparse
import math
import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from monoguide.daemon.config import load_cell_config
from monoguide.solver import frames
from monoguide.solver.errors import MonoguideError
from monoguide.solver.pose import initial_iterated, solve_ml, solve_paper
from monoguide.solver.problem import PoseProblem
from monoguide.solver.synthetic import SyntheticCell, deviated_part, layout_cell, paper_roof_cell, perturbed_views
from monoguide.solver.uncertainty import predicted_covariance

GROSS_DEG, GROSS_MM = 0.5, 5.0  # an error beyond either is a failure to converge
SIM_CELL = Path(__file__).parents[1] / "config" / "sim-cell.toml"
MIN_DEPTH_MM = 200.0  # deviations that bring a hole closer than this to its camera are not drawn


@dataclass
class Tally:
    """Errors and effort of one estimator over the trials of one configuration."""

    rot_err2: list[float] = field(default_factory=list)  # deg^2
    trans_err2: list[float] = field(default_factory=list)  # mm^2
    rot_pred2: list[float] = field(default_factory=list)  # trace of its own covariance, deg^2
    trans_pred2: list[float] = field(default_factory=list)
    times: list[float] = field(default_factory=list)
    failures: int = 0

    def add(self, T_est: np.ndarray, T_true: np.ndarray, cov: np.ndarray | None, seconds: float) -> None:
        d_rot, d_trans = frames.pose_difference(T_est, T_true)
        self.times.append(seconds)
        if d_rot > GROSS_DEG or d_trans > GROSS_MM:
            self.failures += 1
            return
        self.rot_err2.append(d_rot**2)
        self.trans_err2.append(d_trans**2)
        if cov is not None:
            self.rot_pred2.append(math.degrees(1.0) ** 2 * float(np.trace(cov[:3, :3])))
            self.trans_pred2.append(float(np.trace(cov[3:, 3:])))

    def rms(self) -> tuple[float, float]:
        return math.sqrt(statistics.fmean(self.rot_err2)), math.sqrt(statistics.fmean(self.trans_err2))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--trials", type=int, default=10000, help="trials per configuration")
    parser.add_argument("--quick", action="store_true", help="200 trials, sigma 0.1 px only")
    parser.add_argument("--seed", type=int, default=20261122)
    parser.add_argument("--layout", choices=("planned", "today"), default="planned",
                        help="planned: config/sim-cell.toml's measuring poses; today: straight down from 650 mm")
    args = parser.parse_args()
    trials = 200 if args.quick else args.trials
    sigmas = (0.1,) if args.quick else (0.05, 0.1, 0.3)
    cell, layout = _cell(args.layout)
    peer = _poselib_peer(cell)
    estimators: dict[str, Callable[[PoseProblem], tuple[np.ndarray, np.ndarray | None]]] = {
        "ml (default)": lambda p: _pose_and_cov(solve_ml(p)),
        "paper Eq.16": lambda p: _pose_and_cov(solve_paper(p)),
    }
    if peer is not None:
        estimators["poselib, ref"] = lambda p: peer(p, p.T_s1_w0)
        estimators["poselib, init"] = lambda p: peer(p, initial_iterated(p)[0])
    print(f"monoguide pose benchmark: paper roof cell, {layout}, {trials} trials per row, seed {args.seed}")
    print("ratio CRB = observed RMS / Cramer-Rao bound; ratio cov = observed RMS / RMS its own covariance predicts")
    print(f"convergence: error below {GROSS_DEG} deg and {GROSS_MM} mm; time: median per solve, this process")
    header = (
        f"{'sigma':>5} {'range':>9} {'estimator':<15} {'rot deg':>9} {'mm':>8} {'ratio CRB':>14} "
        f"{'ratio cov':>14} {'converged':>10} {'median ms':>9}"
    )
    print(header)
    print("-" * len(header))
    for sigma in sigmas:
        for max_deg, max_mm in ((5.0, 50.0), (20.0, 200.0)):
            rng = np.random.default_rng([args.seed, int(sigma * 1000), int(max_deg)])
            _run_configuration(cell, estimators, rng, trials, sigma, max_deg, max_mm)
    _repeatability_section(cell, np.random.default_rng([args.seed, 7]), trials)


def _cell(layout: str) -> tuple[SyntheticCell, str]:
    if layout == "today":
        return paper_roof_cell(), "4 views straight down from 650 mm, holes a quarter from the edge (today)"
    config = load_cell_config(SIM_CELL)
    T_w0_cf = frames.invert(config.reference.T_cf_w0)
    poses = [T_w0_cf @ p.T_cf_si for p in config.measuring_poses]
    standoff = np.mean([np.linalg.norm(T[:3, 3] - config.part.points_w[i]) for i, T in enumerate(poses)])
    return (layout_cell(config.camera.intrinsics, config.part.points_w, poses),
            f"4 views of config/sim-cell.toml planned for ±50 mm/±5° (tilted, about {standoff:.0f} mm)")


def _run_configuration(cell, estimators, rng, trials, sigma, max_deg, max_mm) -> None:
    tallies = {name: Tally() for name in estimators}
    crb_rot2, crb_trans2 = [], []
    for _ in range(trials):
        T_true = _draw_part(cell, rng, max_deg, max_mm)
        exact = cell.project(T_true)
        problem = cell.problem(exact + rng.normal(0.0, sigma, exact.shape), sigma_px=sigma)
        crb = predicted_covariance(problem, T_true)
        crb_rot2.append(math.degrees(1.0) ** 2 * float(np.trace(crb[:3, :3])))
        crb_trans2.append(float(np.trace(crb[3:, 3:])))
        for name, estimate in estimators.items():
            start = time.perf_counter()
            try:
                T_est, cov = estimate(problem)
            except MonoguideError:
                tallies[name].failures += 1
                continue
            tallies[name].add(T_est, T_true, cov, time.perf_counter() - start)
    bound = (math.sqrt(statistics.fmean(crb_rot2)), math.sqrt(statistics.fmean(crb_trans2)))
    label = f"±{max_deg:g}°/{max_mm:g}"
    print(f"{sigma:>5} {label:>9} {'CRB':<15} {bound[0]:>9.5f} {bound[1]:>8.4f}")
    for name, tally in tallies.items():
        rot, trans = tally.rms()
        ratio_crb = f"{rot / bound[0]:.3f}/{trans / bound[1]:.3f}"
        ratio_cov = "-"
        if tally.rot_pred2:
            pred = (math.sqrt(statistics.fmean(tally.rot_pred2)), math.sqrt(statistics.fmean(tally.trans_pred2)))
            ratio_cov = f"{rot / pred[0]:.3f}/{trans / pred[1]:.3f}"
        converged = 100.0 * (trials - tally.failures) / trials
        print(
            f"{'':>5} {'':>9} {name:<15} {rot:>9.5f} {trans:>8.4f} {ratio_crb:>14} {ratio_cov:>14} "
            f"{converged:>9.2f}% {1e3 * statistics.median(tally.times):>9.3f}"
        )


def _repeatability_section(cell: SyntheticCell, rng: np.random.Generator, trials: int) -> None:
    """The robot's pose repeatability (0.05 mm, 0.01 deg per axis) at sigma = 0.1 px, +-5 deg / 50 mm."""
    sigma, rep_mm, rep_deg = 0.1, 0.05, 0.01
    print()
    print(f"robot repeatability {rep_mm} mm / {rep_deg} deg per axis at each measuring pose, sigma {sigma} px")
    print(f"{'estimator':<42} {'rot deg':>9} {'mm':>8} {'ratio cov':>14} {'mahalanobis/6':>14}")
    rows = {
        "ml, pixels only (no repeatability)": (False, False),
        "ml, repeatability in the data, ignored": (True, False),
        "ml, repeatability folded in (view_sigma)": (True, True),
    }
    for label, (perturb, fold) in rows.items():
        tally, mahal = Tally(), []
        for _ in range(trials):
            T_true = _draw_part(cell, rng, 5.0, 50.0)
            views = perturbed_views(cell, rng, rep_mm, rep_deg) if perturb else cell.T_s1_si
            exact = cell.project(T_true, views)
            pixels = exact + rng.normal(0.0, sigma, exact.shape)
            problem = cell.problem(pixels, sigma, rep_mm if fold else 0.0, rep_deg if fold else 0.0)
            start = time.perf_counter()
            result = solve_ml(problem)
            tally.add(result.T_s1_w, T_true, result.covariance, time.perf_counter() - start)
            err = frames.pose_to_vector(T_true @ frames.invert(result.T_s1_w))
            e = np.concatenate([err[:3], T_true[:3, 3] - result.T_s1_w[:3, 3]])
            mahal.append(float(e @ np.linalg.solve(result.covariance, e)))
        rot, trans = tally.rms()
        pred = (math.sqrt(statistics.fmean(tally.rot_pred2)), math.sqrt(statistics.fmean(tally.trans_pred2)))
        print(
            f"{label:<42} {rot:>9.5f} {trans:>8.4f} {rot / pred[0]:>6.3f}/{trans / pred[1]:.3f} "
            f"{statistics.fmean(mahal) / 6:>14.3f}"
        )


def _draw_part(cell: SyntheticCell, rng: np.random.Generator, max_deg: float, max_mm: float) -> np.ndarray:
    """A deviated part with every hole at least MIN_DEPTH_MM in front of its camera."""
    views = np.array([v for v, _ in cell.observed])
    points = cell.points_w[[p for _, p in cell.observed]]
    while True:
        T = deviated_part(cell, rng, max_deg, max_mm)
        depth = [
            frames.transform_points(frames.invert(cell.T_s1_si[v]) @ T, points[j : j + 1])[0, 2]
            for j, v in enumerate(views)
        ]
        if min(depth) >= MIN_DEPTH_MM:
            return T


def _pose_and_cov(result) -> tuple[np.ndarray, np.ndarray]:
    return result.T_s1_w, result.covariance


def _poselib_peer(cell: SyntheticCell):
    """PoseLib's generalized absolute pose refinement from a given start: the reference pose T_s1_w0
    ("ref") as a user would, or monoguide's own initial value ("init", its time included)."""
    try:
        import poselib
    except ImportError:
        print("poselib is not installed (pip install -e '.[bench]'): the peer column is left out")
        return None
    cam = cell.camera
    camera = {
        "model": "OPENCV", "width": cam.width, "height": cam.height,
        "params": [cam.fx, cam.fy, cam.cx, cam.cy, cam.k1, cam.k2, cam.p1, cam.p2],
    }
    views = sorted({v for v, _ in cell.observed})

    def to_pose(T: np.ndarray):
        pose = poselib.CameraPose()
        pose.R, pose.t = T[:3, :3], T[:3, 3]
        return pose

    extrinsics = [to_pose(frames.invert(cell.T_s1_si[v])) for v in views]

    def estimate(problem: PoseProblem, T_start: np.ndarray) -> tuple[np.ndarray, None]:
        p2d = [problem.pixels[problem.view_index == v] for v in views]
        p3d = [problem.P_obs[problem.view_index == v] for v in views]
        pose, _ = poselib.refine_generalized_absolute_pose(
            p2d, p3d, to_pose(T_start), extrinsics, [camera] * len(views),
            {"loss_type": "TRIVIAL", "max_iterations": 100},
        )
        return frames.make_T(pose.R, pose.t), None

    return estimate


if __name__ == "__main__":
    main()
