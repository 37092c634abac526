"""The one envelope definition (issue 19, item 4). Prints a table; asserts nothing.

For each job of the cell (``config/sim-cell.toml``'s parts by job; while it has one part, the hood of the issue
is built as job 2, ``tests/helpers/envelope_jobs.py``), and for the hood with an envelope of its own (totals
below the norms, its point off the holes' centroid):

- N parts drawn inside the job's envelope as the simulated part supply draws them
  (``solver.envelope.draw_deviation``), each judged by the offset check as the cycle meets it (the part's pose
  in SF1 against the reference in SF1, ``solver.offset.check_envelope``): how many are refused;
- the same parts with one component (rotation about x, y, z; shift along x, y, z) set to 1 % beyond its limit,
  on either side: how many are refused, and how many of those name that axis.

Solver level: the true displacement, no measurement (the definitions must agree exactly). ``--measured`` adds,
per job of the config, what its measurement noise does at the edges: the layout's predicted covariance (0.1 px
and the robot's repeatability at the flange, ``[layout]``) carried to the envelope's six quantities about its
point, drawn on top of parts inside the envelope (uniform to the very edge) and 1 % beyond one limit: the share
refused (docs/measurement-record.md, "The envelope").

    .venv/bin/python benchmarks/bench_envelope.py                 # 1,000 parts per job (about 20 s)
    .venv/bin/python benchmarks/bench_envelope.py --parts 200 --seed 3
    .venv/bin/python benchmarks/bench_envelope.py --measured      # and the measurement noise at the edges
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import numpy as np

from monoguide.daemon.config import load_cell_config
from monoguide.daemon.plan import cell_layout
from monoguide.solver import frames
from monoguide.solver.envelope import DeviationEnvelope
from monoguide.solver.planning import observed_covariance

sys.path.insert(0, str(Path(__file__).parents[1] / "tests"))  # the helpers the tests share

from helpers.envelope_jobs import (
    COMPONENTS,
    SIM_CELL,
    beyond_one_axis,
    envelope_jobs,
    inside_parts,
    issue_hood,
    names_component,
    refusal,
)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--parts", type=int, default=1000, help="parts drawn per job (default 1000)")
    parser.add_argument("--seed", type=int, default=2026, help="seed of the draws (default 2026)")
    parser.add_argument("--config", type=Path, default=SIM_CELL, help="the cell (default config/sim-cell.toml)")
    parser.add_argument("--measured", action="store_true", help="also the measurement noise at the edges")
    args = parser.parse_args()
    jobs = envelope_jobs(args.config)
    if not any(j.name == issue_hood().name for j in jobs):  # the hood with an envelope of its own, too
        jobs.append(issue_hood(job=99))
    print(f"{args.parts} parts per job drawn inside its envelope (seed {args.seed}); 1 % beyond one limit: the "
          "same parts, that component set to ±1.01 x its limit")
    print()
    header = f"{'job':>4}  {'part':<28} {'envelope':<58} {'inside: refused':>16}"
    print(header + "".join(f"  {c:>19}" for c in COMPONENTS))
    for job in jobs:
        parts = inside_parts(job, args.parts, args.seed + job.job)
        refused_inside = sum(refusal(job, T) is not None for T in parts)
        cells = []
        for component in range(6):
            messages = [refusal(job, beyond_one_axis(job, T, component, sign)) for T in parts for sign in (-1, 1)]
            refused = sum(m is not None for m in messages)
            named = sum(m is not None and names_component(m, component) for m in messages)
            cells.append(f"{refused}/{len(messages)} ({named} named)")
        about = ", ".join(f"{v:.0f}" for v in job.envelope.about_w)
        described = f"{job.envelope.describe()} about ({about})"
        print(f"{job.job:>4}  {job.name:<28} {described:<58} {refused_inside:>9}/{len(parts):<6}"
              + "".join(f"  {c:>19}" for c in cells))


    if args.measured:
        measured(args.config, 200_000, args.seed)


def measured(config_path: Path, n: int, seed: int) -> None:
    """Per job of the config: parts inside (uniform to the edge) and 1 % beyond along z, with the predicted noise
    of the six quantities the check compares (independent of where in the envelope the part lies: a model)."""
    print()
    print(f"measured (the predicted noise on the six quantities, {n} parts per job):")
    print(f"{'job':>4}  {'sigma about x, y, z (deg)':<28} {'sigma along x, y, z (mm)':<26} {'inside: refused':>16} "
          f"{'1 % beyond z: refused':>22}")
    cfg = load_cell_config(config_path)
    for job in getattr(cfg, "jobs", (1,)):
        view = cfg.for_job(job) if hasattr(cfg, "for_job") else cfg
        covariance, envelope = _six_covariance(view)
        limits = np.concatenate([envelope.rotation_deg, envelope.translation_mm])
        rng = np.random.default_rng(seed + job)
        noise = rng.multivariate_normal(np.zeros(6), covariance, size=(2, n))
        inside = rng.uniform(-1.0, 1.0, (n, 6)) * limits + noise[0]
        beyond = inside - noise[0] + noise[1]
        beyond[:, 5] = 1.01 * limits[5] + noise[1][:, 5]
        refused_inside = np.mean(np.any(np.abs(inside) > limits, axis=1))
        refused_beyond = np.mean(np.any(np.abs(beyond) > limits, axis=1))
        sigma = np.sqrt(np.diag(covariance))
        print(f"{job:>4}  {_fmt(sigma[:3], 4):<28} {_fmt(sigma[3:], 3):<26} {refused_inside:>15.3%} "
              f"{refused_beyond:>22.3%}")


def _six_covariance(view: Any) -> tuple[np.ndarray, DeviationEnvelope]:
    """The predicted covariance (6, 6) of the rotation vector (deg) and the shift of the envelope's point (mm),
    both along the reference part frame's axes, of one job's view of the cell; and its envelope (resolved)."""
    layout = cell_layout(view)
    request = layout.request
    planned = view.layout.envelope if view.layout is not None else DeviationEnvelope()
    envelope = planned.at(np.asarray(request.points_w))
    C = observed_covariance(request.camera, np.asarray(request.points_w), layout.T_w0_si, layout.observed,
                            request.sigma_px, request.repeatability_mm, request.repeatability_deg, request.T_f_c)
    R = frames.invert(layout.T_w0_si[0])[:3, :3]  # R_s1_w0
    lever = R @ np.asarray(envelope.about_w)  # a perturbation (w, dt) of (R, t) moves a point by w x (R a) + dt
    J = np.zeros((6, 6))
    J[:3, :3] = R.T
    J[3:, :3] = -R.T @ frames.skew(lever)
    J[3:, 3:] = R.T
    scale = np.diag([np.degrees(1.0)] * 3 + [1.0] * 3)
    return scale @ J @ C @ J.T @ scale, envelope


def _fmt(values: np.ndarray, digits: int) -> str:
    return ", ".join(f"{v:.{digits}f}" for v in values)


if __name__ == "__main__":
    main()
