"""The one envelope definition (issue 19, item 4). Prints a table; asserts nothing.

For each job of the cell (``config/sim-cell.toml``'s parts by job; while it has one part, the hood of the issue
is built as job 2, ``tests/helpers/envelope_jobs.py``), and for the hood with an envelope of its own (totals
below the norms, its point off the holes' centroid):

- N parts drawn inside the job's envelope as the simulated part supply draws them
  (``solver.envelope.draw_deviation``), each judged by the offset check as the cycle meets it (the part's pose
  in SF1 against the reference in SF1, ``solver.offset.check_envelope``): how many are refused;
- the same parts with one component (rotation about x, y, z; shift along x, y, z) set to 1 % beyond its limit,
  on either side: how many are refused, and how many of those name that axis.

Solver level: the true displacement, no measurement (the definitions must agree exactly; a measured part at
the very edge is refused or passed by its measurement noise, docs/measurement-record.md).

    .venv/bin/python benchmarks/bench_envelope.py                 # 1,000 parts per job (a few seconds)
    .venv/bin/python benchmarks/bench_envelope.py --parts 200 --seed 3
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

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


if __name__ == "__main__":
    main()
